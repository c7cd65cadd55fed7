#!/usr/bin/env python3
"""Regenerate ``fused_lamb.npz``: the lamb's pushes and the learner's point model (issue 18).

Usage::

    OPENBLAS_NUM_THREADS=1 python test/data/deformation/held_out_study.py --object lamb \\
        --out out/held_out_lamb5 --field learned --fuse     # solves and caches the truth
    python test/data/deformation/make_fused_fixtures.py --study out/held_out_lamb5

Scenario (lengths metres, forces newtons, frame ``base``): the held-out study's lamb (a buried
bone; the cell's neo-Hookean FEM truth of its cached ``truth_lamb.npz``, point probe) seen by
the demo cell's realistic camera (2 mm depth bias, noise ``2e-4 + 4e-3 z^2`` m, two ring
viewpoints at 0.35 m, 55 deg; seeded), and the learner's point model of the study
(``learned_lamb_12_model``: 12 seeded pokes of its own, realistic scenario; none within 5 mm of
the sites below). Stored:

- ``rest_points``, ``rest_normals`` (R, 3): the merged two-view rest scan thinned to a 2 mm
  voxel (the mesh's surface); ``rest_frame`` (F, 3): one rest frame of the pushing camera;
- per state ``s``: ``q`` (S, 3) contact point, ``tip`` (S, 3) probe tip (the TCP), ``force``
  (S, 3) F/T truth (force on the object), ``site`` (S,), ``depth`` (S,) and the pushing
  camera's frame ``cloud`` (P, 3) float32 with ``cloud_start`` (S + 1,) offsets. Sites 0 and 1
  lie over the bone, site 2 off it (the held-out one, 3, 5 and 8 mm); 0 and 1 at 3 and 5 mm;
- the point model, cropped to the top within 15 mm of the sites (float32 tables): ``model_points``,
  ``model_normals`` (N, 3), ``model_depths`` (D,), ``model_forces``, ``model_std`` (N, D),
  ``model_slopes`` (N,), ``model_shape_constant``.
"""

import argparse
import os
import sys

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.abspath(os.path.join(HERE, '..', '..', '..')))

from held_out_study import load_truth, render_views  # noqa: E402 - this folder
from pointforce_ros.model.files import load_latest_model  # noqa: E402

STATES = [(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)]
"""(site, stored depth index: 3, 5, 8 mm) of the states kept."""


def thin(points, normals, voxel=0.002):
    """One point per ``voxel`` cube (the first), with its normal."""
    key = np.unique(np.round(points / voxel).astype(np.int64), axis=0, return_index=True)[1]
    key = np.sort(key)
    return points[key], normals[key]


def main(argv=None):
    """Render the states, crop the point model, write the fixture."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--study', default='out/held_out_lamb5')
    ap.add_argument('--seed', type=int, default=7)
    ap.add_argument('--out', default=os.path.join(HERE, 'fused_lamb.npz'))
    args = ap.parse_args(argv)
    nodes, tris, pushes = load_truth(os.path.join(args.study, 'truth_lamb.npz'))
    pushes = pushes[:3]
    rest, normals, view_rest, _ = render_views(nodes, tris, pushes, 1, args.seed)
    rest, normals = thin(rest, normals)
    model, path = load_latest_model(os.path.join(args.study, 'learned_lamb_12_model'))
    q = np.array([pushes[s]['q'] for s, _ in STATES])
    tip = np.array([pushes[s]['q'] + pushes[s]['depths'][k] * pushes[s]['d']
                    for s, k in STATES])
    force = np.array([pushes[s]['force'][k] for s, k in STATES])
    clouds = [pushes[s]['clouds'][k].astype(np.float32) for s, k in STATES]
    start = np.concatenate([[0], np.cumsum([len(c) for c in clouds])])
    pts = model.surface.points
    near = np.min(np.linalg.norm(pts[:, None, :2] - q[None, :, :2], axis=2), axis=1)
    keep = (near < 0.015) & (model.surface.normals[:, 2] > 0.3)
    r = model.response
    np.savez_compressed(
        args.out, rest_points=rest.astype(np.float32), rest_normals=normals.astype(np.float32),
        rest_frame=view_rest.astype(np.float32), q=q, tip=tip, force=force,
        site=np.array([s for s, _ in STATES]),
        depth=np.array([pushes[s]['depths'][k] for s, k in STATES]),
        cloud=np.concatenate(clouds), cloud_start=start, model_points=pts[keep],
        model_normals=model.surface.normals[keep], model_depths=r.depths,
        model_forces=r.forces[keep].astype(np.float32),
        model_std=r.std[keep].astype(np.float32), model_slopes=r.slopes[keep],
        model_shape_constant=model.shape_constant, model_source=str(path))
    print(f'{args.out}: {len(rest)} rest points, {len(STATES)} states '
          f'({start[-1]} cloud points), point model {keep.sum()} of {len(pts)} rows, '
          f'{os.path.getsize(args.out) / 1024:.0f} KiB')


if __name__ == '__main__':
    main()
