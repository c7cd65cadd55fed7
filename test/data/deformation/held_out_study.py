#!/usr/bin/env python3
"""Camera-only force on held-out static pushes, leave one site out (issue 18's scoring).

Usage::

    OPENBLAS_NUM_THREADS=1 python test/data/deformation/held_out_study.py --object foam_block
    python test/data/deformation/held_out_study.py --object plush --sites 3 --field learned
    python test/data/deformation/held_out_study.py --object plush --sites 3 --field learned \\
        --refine                                       # the learned seed refined by the fit
    python test/data/deformation/held_out_study.py --object foam_block --frames 1 \\
        --reference merged                                               # the old check
    python test/data/deformation/held_out_study.py --object lamb --sites 3 --field learned \\
        --fuse --calibrate-point --fem-std cross     # fused with the point model (issue 18)

Scenario: the object (``foam_block`` from this folder's YAML, or a cell object such as
``lamb`` or ``plush``) is pushed at a few sites (normal, and tilted 20 deg) by the cell's point
probe to 3, 5 and 8 mm; the truth is the cell's neo-Hookean FEM on one hexahedral mesh over all
sites (``--truth-h``, cached under ``--out`` as ``truth_<object>.npz``: minutes per push). The
demo cell's camera (realistic scenario: 2 mm depth bias, noise ``2e-4 + 4e-3 z^2`` m; ring of
two viewpoints at 0.35 m, 55 deg) scans the rest shape from both viewpoints; the first one
films every push, the probe hiding what it hides, ``--frames`` frames per static state. Each
push is held out in turn: (E, nu) (and with ``--field`` a modulus field seeded by the other
sites' own moduli, the cell's point-probe truth, or the learner's point model fitted on its own
simulated pokes: ``--field pokes|point|learned``; ``--refine`` then fits the seed's exponent
and a depth layer by the identification's residual,
:func:`pointforce_ros.deformation.cell_check.refine_field`) is identified once per held-out
push on the other sites' 3 and 5 mm states with their F/T forces,
and the held-out push's force at each depth is estimated from its clouds alone
(:func:`pointforce_ros.deformation.cell_check.estimate_from_views`). Printed per state: the
magnitude error, the direction error, the reported 1-sigma, and whether the truth is inside
2 sigma; then the means. A held-out push whose identification or estimate is refused is
printed as FAILED and counted in the summary.

``--fuse`` (:func:`pointforce_ros.deformation.cell_check.fused_from_views`) also fuses each
estimate with the learner's point model (the ``--field learned`` campaign, its whole model
cached in ``learned_<object>_<pokes>_model/``): the normal force at the probe tip's depth below
the scanned surface (the tip is the arm's TCP: no F/T), its predictive std, averaged with the
FEM's magnitude by inverse variance along the FEM's direction; the FEM's std carries the
identification sites' modulus spread. Learner pokes within ``--exclude-radius`` (5 mm) of the
held-out site are dropped and the point model refitted for that push. ``--calibrate-point``
first reads the point model's depth offset at the identification states (the other sites' 3
and 5 mm pushes and their F/T, as the FEM's identification does); ``--spread-t`` widens the
sites' spread to the Student-t interval of their number. The summary adds the fused and the
point model's own figures.

Measured (issue 18; solve minutes per push at load 5-7 on 2 cores: foam 136-495 s at
``--truth-h 0.0025``, plush 220-658 s and lamb 398-597 s at 3 mm; mean / worst magnitude error,
mean / worst direction error, truth inside 2 sigma):

- foam_block, 6 sites x 3 depths: ``--frames 1 --reference merged`` (the check before the
  fix) 17.9 / 39.2 %, 9.5 / 19.1 deg, 14/18; ``--frames 1`` 9.4 / 20.0 %, 9.3 / 22.9 deg,
  18/18; default (4 frames) 7.1 / 19.5 %, 3.9 / 9.8 deg, 18/18.
- plush, ``--sites 3`` (firm wad, its edge, soft pocket; normal pushes): before 156 / 647 %
  (the pocket identified on the wad sites), 12.7 / 23.7 deg, 3/9; one E 18.1 / 48.5 %,
  5.5 / 7.8 deg, 6/9; ``--field pokes`` 17.3 / 50.2 %; ``--field point`` 13.3 / 22.8 %,
  5.7 / 8.5 deg, 7/9.
- plush with the LEARNED point model (``--field learned``: 12 seeded pokes of the cell's point
  probe, realistic scenario, fitted by the product's learner; its 3 mm force map 0.96-4.22 N,
  half the truth's contrast): 12.0 / 28.0 %, 5.7 / 8.0 deg, 7/9 (per held-out site: firm wad
  4.1 %, its edge 14.4 %, soft pocket 17.6 %). ``--refine``: the optimum (exponent 2, depth
  layer +2.5) lowered the residual by 0.7 % (495.7 -> 493.9 um: the camera's noise floor)
  and, taken unchecked, put the wad's push at +66..+85 %; with the 5 % gain gate
  (``--refine``, 20 identifications per site, 267-901 s) it is taken at none of the three
  sites (gains 0.0-0.7 %), so the numbers are those of the seed as given.
- lamb, ``--sites 3`` (two over the bone, one off it): before, the identification is refused
  with the off-bone site held out, 59 / 88 % and 92 / 133 deg on the other six states; one E
  54.4 / 96.5 %, 17.7 / 42.3 deg, 4/9; ``--field pokes`` 72.0 / 143 %; ``--field point``
  51.5 / 90.2 %. The bone shields the far field the camera sees without stiffening the point
  contact: the 3 mm forces are 0.95 N over it and 0.90 N off it, while the moduli the pokes
  read from their clouds are 175-180 kPa over it and 78-82 kPa off it. ``--field learned``:
  57.9 / 103.5 %, 18.0 / 43.7 deg, 4/9: the learned 3 mm map is flat (1.14-1.28 N), it
  cannot see the bone. ``--field learned --refine --refine-evaluations 10``: the optima
  (exponent 0.25-2, depth layer -3.75..+1.5: softer AND stiffer cores) gain 0.1-1.0 %, taken
  at no site: 57.9 %. A depth layer does not find the bone from these clouds.
- vest, ``--sites 3`` (on the stiff insert panel, off it, its edge; truth 249-404 s per push
  at load 17): one E 59.9 / 118 %, 9.2 / 16.7 deg, 1/9 (the off-panel push identified on the
  panel sites: E 453 kPa, +100..+118 %; the panel's push -46..-58 %); ``--field learned``
  47.3 / 85.3 %, 8.9 / 16.5 deg, 1/9 (map 5.9-12.0 N at 3 mm); ``--refine
  --refine-evaluations 10``: gains 0.0-0.2 %, taken at no site: 47.3 %.
- FUSED with the learner's point model (issue 18; one command per cell, on the cached
  truths, 1-6 min each at load ~1 on 2 cores; ``lamb|vest|plush``: ``--sites 3 --field
  learned``, ``foam_block``: its default sites and field; all with ``--fuse`` and the flags of
  the column; the FEM column is the FEM alone, as above). Mean / worst magnitude error, truth
  inside 2 sigma, and the point model alone (its mean) in brackets:

  ==========  ==================  ==================  ==================  ==================
  object      FEM alone           (plain)             --calibrate-point   --calibrate-point
                                                                          --fem-std cross
  ==========  ==================  ==================  ==================  ==================
  foam_block  7.1 / 19.5, 18/18   7.5 / 15.4, 18/18   5.7 / 13.7, 18/18   5.6 / 13.4, 18/18
                                  (15.3)              (4.2)               (4.2)
  plush       12.0 / 28.0, 7/9    12.7 / 28.3, 8/9    12.5 / 30.2, 8/9    12.6 / 30.4, 8/9
                                  (22.1)              (30.2)              (30.2)
  vest        47.3 / 85.3, 1/9    16.7 / 28.3, 9/9    18.6 / 29.9, 9/9    17.4 / 28.5, 9/9
                                  (10.0)              (11.8)              (11.8)
  lamb        57.9 / 103.5, 4/9   29.8 / 47.6, 2/9    19.4 / 36.2, 9/9    14.7 / 24.7, 9/9
                                  (28.2)              (11.1)              (11.1)
  ==========  ==================  ==================  ==================  ==================

  The direction is the FEM's (foam 3.9 / 9.8, plush 5.7 / 8.0, vest 8.9 / 16.5, lamb 18.0 /
  43.7 deg). ``--calibrate-point``: the learner's contact onset sits off the scan's plane by
  +0.53..+0.57 mm on the foam block and +0.76..+1.02 mm on the lamb (-0.09..+0.11 mm vest;
  plush +0.04..+0.66 mm, two sites 1.3 mm apart, so its std makes the point model weigh
  little there). The FEM's std at the held-out site: by default the identification sites'
  modulus spread (of log E, the learned field's residual: 0.06-0.08 foam, 0.04-0.13 plush,
  0.23-0.58 vest, 0.21-0.71 lamb), which from two sites is a one-degree-of-freedom estimate
  and stays too small where the FEM is most wrong (lamb over the bone: -56 % against an
  11-17 % std, point weight 0.5); ``--fem-std cross`` cross-validates it instead (each
  identification site left out, identified on the others, its 3 and 5 mm F/T compared; 2-5
  extra identifications per held-out push): rms log error 0.08-0.10 foam, 0.12-0.22 plush,
  0.26-0.73 vest, 0.55-1.00 lamb; point weight 0.24-0.62 foam, 0.05-0.39 plush, 0.52-0.91
  vest, 0.78-0.99 lamb. The vest's off-panel push (FEM +70..+85 %) keeps a 0.26 rms from its
  two sites (the panel and its edge agree with each other): 24.3 % there, 17.4 % mean, the
  vest's bar (15 %) not met; lamb 14.7 %, plush 12.6 % met. ``--calibrate-point --spread-t``
  (the default spread widened to the Student-t interval, x6.5 for two sites, x1.4 for five):
  lamb 11.7 / 19.0, 9/9; vest 12.1 / 21.9, 9/9; foam 5.5 / 12.2, 18/18; but plush 22.9 /
  48.5 %, 9/9 (its soft pocket, which the point model reads +53..+58 % with a 64 % std, then
  outweighs the FEM's good estimate). The learner's 12 pokes are seeded uniform draws over
  the footprint, not placed on the held-out sites: the nearest is 5.7-10.4 mm from the lamb,
  vest and plush sites and 0.9-2.4 mm from three foam sites, whose pokes within 5 mm are
  dropped and the point model refitted for that push (``--exclude-radius``); the
  ``--field learned`` seed keeps all 12.
- All five sites (the three normal ones and the two tilted 20 deg), each held out and
  identified on the other FOUR (``--field learned --fuse --calibrate-point --fem-std cross``,
  no ``--sites``; ``--out out/held_out_<object>5``, the learner's cached model copied in;
  session 13, truth 80-160 s per push, the study 15-20 min per object): mean / worst
  magnitude error, truth inside 2 sigma, FEM alone -> fused (point model alone):
  vest 30.1 / 54.4 %, 2/15 -> **14.1 / 31.5 %, 15/15** (10.8 %); lamb 33.4 / 62.3 %, 9/15 ->
  **12.6 / 27.0 %, 15/15** (8.5 %); plush 12.4 / 29.1 %, 10/15 -> **11.1 / 31.7 %, 15/15**
  (18.7 %); direction (the FEM's) 6.7 / 17.2, 14.8 / 44.4, 6.5 / 19.1 deg. Under 15 % on all
  three, but not because the hard push got easier: the vest's off-panel push is still +27 to
  +32 % fused (FEM alone worse, the point model +15 to +24 %, point weight 0.54-0.80); the two
  tilted pushes are among the easier ones (vest 0-21 %, lamb 4-11 %, plush 3-15 %) and the
  other sites' estimates improve with four identification sites instead of two.
"""

import argparse
import dataclasses
import json
import os
import sys
import time

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..')))

from make_deformation_fixtures import push_direction, spec_of  # noqa: E402 - this folder
from pointforce_ros.bringup.camera_check import render_view  # noqa: E402
from pointforce_ros.deformation.cell_check import (cross_site_error,  # noqa: E402
                                                   estimate_from_views, fused_from_views,
                                                   identify_from_views, point_calibration)
from pointforce_ros.model.files import latest_model_path, load_model, save_model  # noqa: E402
from pointforce_ros.model.fit import fit_contact_model  # noqa: E402
from pointforce_ros.deformation.fused import small_sample_factor  # noqa: E402
from pointforce_ros.errors import PointforceError  # noqa: E402
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints  # noqa: E402
from pointforce_ros.sim.fem.live import LiveContact, POINT_PROBE  # noqa: E402
from pointforce_ros.sim.fem.probes import point_probe, pose_for_push  # noqa: E402
from pointforce_ros.sim.fem.solver import FemModel  # noqa: E402
from pointforce_ros.sim.scenario import load_scenario  # noqa: E402
from pointforce_ros.sim.session import fem_object, simulate_campaign  # noqa: E402
from pointforce_ros.types import Mesh, Surface  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))

SITES = {
    # object: [(dx, dy from the footprint centre m, tilt deg, tilt azimuth deg)]
    'foam_block': [(-0.010, 0.006, 0, 0), (0.010, -0.006, 0, 0), (0.0, 0.0, 0, 0),
                   (0.012, 0.010, 0, 0), (-0.012, -0.008, 20, 0), (0.005, 0.008, 20, 90)],
    'lamb': [(0.015, 0.005, 0, 0), (0.028, 0.008, 0, 0), (-0.020, -0.015, 0, 0),
             (-0.015, 0.010, 20, 0), (0.005, -0.015, 20, 90)],   # the first two over the bone
    'plush': [(0.020, 0.012, 0, 0), (0.008, 0.018, 0, 0), (-0.025, -0.015, 0, 0),
              (-0.010, 0.0, 20, 0), (0.010, -0.015, 20, 90)],   # firm wad, its edge, pocket
    'vest': [(0.025, 0.010, 0, 0), (-0.025, -0.012, 0, 0), (0.002, 0.015, 0, 0),
             (-0.012, 0.012, 20, 0), (0.030, -0.015, 20, 90)],  # on the insert, off, its edge
}
DEPTHS = np.array([1.5, 3.0, 4.0, 5.0, 6.5, 8.0]) * 1e-3
"""Probe travel steps of the truth solve, metres."""
KEEP = (1, 3, 5)
"""Stored steps: 3, 5 and 8 mm."""
IDENTIFY = (0, 1)
"""Stored states of the other sites used for identification: 3 and 5 mm."""


def say(msg):
    """Print a progress line at once."""
    print(msg, flush=True)


def report(rows, failed, summary, json_path=None):
    """Print the summary line; with ``json_path``, also write rows, failures and summary there.

    ``rows`` and ``failed``: one dict per scored or failed push; ``summary``: a dict of plain
    numbers and strings. The JSON holds ``{'rows', 'failed', 'summary'}``.
    """
    say('summary ' + json.dumps(summary))
    if json_path:
        with open(json_path, 'w') as f:
            json.dump(dict(rows=rows, failed=failed, summary=summary), f, indent=1)


def solve_truth(name, path, h, count=None):
    """Solve the first ``count`` sites' pushes with the cell's FEM on one mesh; cache them."""
    spec = spec_of(name)
    sites = SITES[name][:count]
    cx, cy = spec.centre
    half = (max(abs(s[0]) for s in sites) + 0.008, max(abs(s[1]) for s in sites) + 0.008)
    mesh = spec.build_mesh(h, refine_at=(cx, cy), fine_radius=half, growth=1.5)
    mesh = dataclasses.replace(mesh, top_nodes=np.arange(mesh.n_nodes))
    model = FemModel(mesh, spec.gauss_young(mesh), spec.poisson, support=spec.support)
    probe = point_probe(**POINT_PROBE)
    out = dict(nodes=mesh.nodes, faces=mesh.boundary_faces, young=spec.young,
               poisson=spec.poisson, truth_h=h)
    for k, (dx, dy, tilt, az) in enumerate(sites):
        t0 = time.time()
        q = np.asarray(spec.top_point(cx + dx, cy + dy), dtype=float)
        d = push_direction(spec.top_normal(cx + dx, cy + dy), tilt, az)
        res = model.indent(probe, pose_for_push(q, d), d, DEPTHS, torque_centre=q,
                           keep_solved=True)
        keep = [i for i in KEEP if i < len(res.depths)]
        out.update({f'p{k}_q': q, f'p{k}_dir': d, f'p{k}_tilt': tilt,
                    f'p{k}_depths': res.depths[keep], f'p{k}_force': -res.force[keep],
                    f'p{k}_surface': np.stack([res.surface[i] for i in keep]).astype(np.float32),
                    'count': k + 1})
        np.savez_compressed(path, **out)
        say(f'{name} push {k}: {np.round(res.depths[keep] * 1e3, 1)} mm, |F| '
            f'{np.round(np.linalg.norm(-res.force[keep], axis=1), 2)} N, {time.time() - t0:.0f} s')


def load_truth(path):
    """The cached pushes: ``(nodes, triangles, [dict(q, d, tilt, depths, force, surface)])``."""
    t = dict(np.load(path))
    f = t['faces']
    tris = np.concatenate([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
    pushes = [dict(q=t[f'p{k}_q'], d=t[f'p{k}_dir'], tilt=float(t[f'p{k}_tilt']),
                   depths=t[f'p{k}_depths'], force=t[f'p{k}_force'],
                   surface=t[f'p{k}_surface'].astype(float)) for k in range(int(t['count']))]
    return t['nodes'], tris, pushes


def render_views(nodes, tris, pushes, frames, seed, distance=0.35, views=2, per_frame=False):
    """Rest scan (all viewpoints), the first viewpoint's rest frames and every push's clouds.

    Default (this study): the rest scan's first view is the first of ``frames`` rest frames,
    returned stacked, and each push state's cloud stacks ``frames`` frames. ``per_frame`` (the
    node's view, ``node_fused_study.py``): ``frames`` rest frames rendered after the scan,
    returned as a list of clouds, and one frame per push state. The camera draws in the same
    order either way: scan, rest frames, push states.
    """
    kw = load_scenario('realistic').camera_kwargs()
    kw['seed'] = seed
    camera = DepthCamera(**kw)
    lo, hi = nodes[:, :2].min(axis=0), nodes[:, :2].max(axis=0)
    poses = ring_viewpoints([*(0.5 * (lo + hi)), 0.0], distance, count=views)
    scans = [render_view(camera, p, nodes, tris) for p in poses]
    rest = np.concatenate([s[0] for s in scans])
    normals = np.concatenate([s[1] for s in scans])
    rest_frames = [] if per_frame else [scans[0][0]]
    rest_frames += [render_view(camera, poses[0], nodes, tris)[0]
                    for _ in range(frames - len(rest_frames))]
    probe = point_probe(**POINT_PROBE)
    for p in pushes:
        p['clouds'] = []
        for i, depth in enumerate(p['depths']):
            pose = pose_for_push(p['q'] + depth * p['d'], p['d'])
            rot = Rotation.from_quat(pose.orientation).as_matrix()
            occluder = Mesh(probe.vertices @ rot.T + pose.position, probe.triangles)
            p['clouds'].append(np.concatenate([
                render_view(camera, poses[0], p['surface'][i], tris, occluder)[0]
                for _ in range(1 if per_frame else frames)]))
    return (rest, normals, rest_frames if per_frame else np.concatenate(rest_frames),
            np.asarray(poses[0])[:3, 3])


def point_samples(name, depth=0.003, spacing=0.004):
    """``(xy (n, 2), force (n,))``: the cell's point-probe force at ``depth`` over a grid."""
    spec = spec_of(name)
    live = LiveContact.load(spec.name, build=False)
    half = 0.5 * np.asarray(spec.size[:2]) - 0.004
    gx, gy = np.meshgrid(*(np.arange(-h, h + 1e-9, spacing) for h in half), indexing='ij')
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + np.asarray(spec.centre)
    force = np.array([live.normal_force(x, y, depth) for x, y in xy])
    ok = force > 0
    return xy[ok], force[ok]


def learned_samples(name, rest, normals, path, pokes=12, seed=3, depth=0.003, voxel=0.002):
    """``(xy (n, 2), force (n,))``: the LEARNED point model's force at ``depth`` over the top.

    The learner's own training pokes (``pokes`` point pokes at seeded random sites of the
    object, realistic scenario, commanded on the scanned surface as the product pokes:
    :func:`pointforce_ros.sim.session.simulate_campaign`) are fitted by the product's learner
    (:func:`pointforce_ros.model.fit.fit_contact_model`) on the merged rest scan thinned to
    ``voxel``; its baked force at ``depth`` on the upward-facing points is the map. Cached at
    ``path`` (the pokes take a minute or two).
    """
    if os.path.isfile(path):
        with np.load(path) as z:
            return z['xy'], z['force']
    key = np.unique(np.round(rest / voxel).astype(np.int64), axis=0, return_index=True)[1]
    surface = Surface(rest[key], normals[key])
    t0 = time.time()
    records = simulate_campaign(fem_object(name), load_scenario('realistic'), count=pokes,
                                seed=seed, surface=surface)
    model = fit_contact_model(records, surface)
    top = np.flatnonzero(surface.normals[:, 2] > 0.5)
    force = model.response.force(top, np.full(len(top), depth))
    xy = surface.points[top, :2]
    np.savez_compressed(path, xy=xy, force=force,
                        poked=np.array([r.point for r in records]))
    say(f'learned point model on {pokes} pokes ({time.time() - t0:.0f} s): force at '
        f'{depth * 1e3:.0f} mm {force.min():.2f}-{force.max():.2f} N over {len(top)} points')
    return xy, force


CAMPAIGNS = {}
"""The learner's simulated pokes per ``(object, pokes, seed)``, kept for the run's refits."""


def learned_model(name, rest, normals, path, pokes=12, seed=3, voxel=0.002, away_from=None,
                  radius=0.0):
    """The learner's point model (:class:`~pointforce_ros.model.files.ContactModel`), cached.

    The same campaign and fit as :func:`learned_samples` (``pokes`` seeded point pokes of the
    cell's probe at random sites, realistic scenario, on the merged rest scan thinned to
    ``voxel``); the whole model (surface, baked force and predictive std over depth) is kept in
    the folder ``path`` (:func:`~pointforce_ros.model.files.save_model`) for ``--fuse``. The
    learner's pokes are its own: the held-out pushes' F/T never enters it. With ``away_from``
    ((3,) a held-out site) the learner pokes within ``radius`` of it in x-y are dropped and
    the model is refitted (not cached): a poke that happens to sit on the held-out site
    stays out of its estimate. Returns ``(model, number of pokes dropped)``.
    """
    found = latest_model_path(path) if os.path.isdir(path) else None
    if found is not None and away_from is not None:
        poked = np.asarray(load_model(found).meta['poked'])
        if not np.any(np.linalg.norm(poked[:, :2] - np.asarray(away_from)[:2], axis=1)
                      < radius):
            away_from = None
    if found is not None and away_from is None:
        return load_model(found), 0
    key = np.unique(np.round(rest / voxel).astype(np.int64), axis=0, return_index=True)[1]
    surface = Surface(rest[key], normals[key])
    t0 = time.time()
    if (name, pokes, seed) not in CAMPAIGNS:
        CAMPAIGNS[name, pokes, seed] = simulate_campaign(
            fem_object(name), load_scenario('realistic'), count=pokes, seed=seed,
            surface=surface)
    records = CAMPAIGNS[name, pokes, seed]
    if away_from is not None:
        kept = [r for r in records if np.linalg.norm(np.asarray(r.point)[:2]
                                                     - np.asarray(away_from)[:2]) >= radius]
        model = fit_contact_model(kept, surface)
        say(f'point model refitted on {len(kept)} of {len(records)} learner pokes (those '
            f'within {radius * 1e3:.1f} mm of the held-out site dropped, '
            f'{time.time() - t0:.0f} s)')
        return model, len(records) - len(kept)
    model = fit_contact_model(records, surface)
    meta = dict(model.meta, poked=np.array([r.point for r in records]).tolist())
    model = dataclasses.replace(model, meta=meta)
    save_model(model, path)
    say(f'learned point model on {pokes} pokes ({time.time() - t0:.0f} s), kept in {path}')
    return model, 0


def main(argv=None):
    """Parse the command line, solve or load the truth, score every held-out push."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--object', default='foam_block', choices=sorted(SITES))
    ap.add_argument('--out', default='out/held_out_pushes')
    ap.add_argument('--truth-h', type=float, default=0.003, help='truth element size, m')
    ap.add_argument('--frames', type=int, default=4, help='frames stacked per static state')
    ap.add_argument('--reference', choices=('view', 'merged'), default='view',
                    help="residual reference: the pushing camera's rest frames, or the "
                         'merged multi-view scan (the check before issue 18\'s fix)')
    ap.add_argument('--field', choices=('none', 'pokes', 'point', 'learned'), default='none',
                    help="heterogeneous modulus field seeded by the other sites' own moduli "
                         "(pokes), by the cell's point-probe response at 3 mm on a 4 mm grid "
                         '(point: the live cache, the truth standing in for a learned model) '
                         "or by the learner's point model fitted on its own pokes (learned)")
    ap.add_argument('--refine', action='store_true',
                    help='refine the field (or, with --field none, a depth term alone) by the '
                         "identification's fit: seed exponent and depth layer")
    ap.add_argument('--refine-evaluations', type=int, default=20,
                    help='identifications at most per refinement (Nelder-Mead)')
    ap.add_argument('--learner-pokes', type=int, default=12,
                    help='training pokes of the learned point model (--field learned)')
    ap.add_argument('--fuse', action='store_true',
                    help="also fuse each estimate with the learner's point model at the tip's "
                         'depth below the scan (its magnitude by inverse variance, the FEM\'s '
                         'direction); the learner fitted on --learner-pokes of its own pokes')
    ap.add_argument('--calibrate-point', action='store_true',
                    help="with --fuse: shift the point model's depth by the offset read at the "
                         "identification pushes (the other sites' 3 and 5 mm states and F/T)")
    ap.add_argument('--fem-std', choices=('spread', 'cross'), default='spread',
                    help="with --fuse: the FEM's std at the held-out site from the "
                         "identification sites' modulus spread, or cross-validated over them "
                         '(each left out, identified on the rest, its F/T compared)')
    ap.add_argument('--spread-t', action='store_true',
                    help="with --fuse: widen the identification sites' modulus spread to the "
                         "Student-t interval of their number (x6.5 for two sites)")
    ap.add_argument('--exclude-radius', type=float, default=0.005,
                    help='with --fuse: refit the point model without the learner pokes this '
                         'close to the held-out site (x-y), m')
    ap.add_argument('--sites', type=int, help='only the first N sites (default all)')
    ap.add_argument('--seed', type=int, default=7)
    ap.add_argument('--json', help='write the rows and the summary here')
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, f'truth_{args.object}.npz')
    if not os.path.isfile(path):
        solve_truth(args.object, path, args.truth_h, args.sites)
    nodes, tris, pushes = load_truth(path)
    pushes = pushes[:args.sites]
    rest, normals, view_rest, origin = render_views(nodes, tris, pushes, args.frames, args.seed)
    samples = None
    if args.field == 'point':
        samples = point_samples(args.object)
    elif args.field == 'learned':
        samples = learned_samples(args.object, rest, normals, os.path.join(
            args.out, f'learned_{args.object}_{args.learner_pokes}.npz'), args.learner_pokes)
    point_model = None
    model_dir = os.path.join(args.out, f'learned_{args.object}_{args.learner_pokes}_model')
    if args.fuse:
        point_model = learned_model(args.object, rest, normals, model_dir,
                                    args.learner_pokes)[0]
        poked = np.asarray(point_model.meta['poked'])
        for j, p in enumerate(pushes):
            say(f'push {j}: nearest learner poke '
                f'{np.min(np.linalg.norm(poked[:, :2] - p["q"][:2], axis=1)) * 1e3:.1f} mm away')
    rows, failed = [], []
    for j, held in enumerate(pushes):
        states = [(p['q'], p['force'][i], p['clouds'][i]) for k, p in enumerate(pushes)
                  if k != j for i in IDENTIFY if i < len(p['depths'])]
        t0 = time.time()
        try:
            model = identify_from_views(
                rest, normals, states, origin, field=args.field == 'pokes',
                field_samples=samples, refine=args.refine,
                refine_evaluations=args.refine_evaluations,
                view_rest=view_rest if args.reference == 'view' else None)
        except PointforceError as exc:   # counted, not hidden: the summary says how many
            model = exc
        fem_spread = None if isinstance(model, Exception) else model.young_spread
        if point_model is not None and args.fem_std == 'cross' and fem_spread is not None:
            t1 = time.time()
            try:
                fem_spread, errs = cross_site_error(
                    rest, normals, states, origin, field=args.field == 'pokes',
                    field_samples=samples,
                    view_rest=view_rest if args.reference == 'view' else None)
            except PointforceError as exc:   # the fused estimate then has no FEM spread
                say(f'push {j} held out: no cross-validated FEM error ({exc})')
                fem_spread = float('nan')
            else:
                say(f'push {j} held out: FEM cross-validated over the other sites in '
                    f'{time.time() - t1:.0f} s: log errors {np.round(errs, 2).tolist()}, rms '
                    f'{fem_spread:.2f} (site spread {model.young_spread:.2f})')
        calibration = None
        if point_model is not None:
            point_model, dropped = learned_model(args.object, rest, normals, model_dir,
                                                 args.learner_pokes, away_from=held['q'],
                                                 radius=args.exclude_radius)
        if point_model is not None and args.calibrate_point:
            try:
                calibration = point_calibration(point_model, [
                    (p['q'], p['q'] + p['depths'][i] * p['d'], p['force'][i])
                    for k, p in enumerate(pushes) if k != j
                    for i in IDENTIFY if i < len(p['depths'])])
            except PointforceError as exc:   # fused without it, and said so
                say(f'push {j} held out: no point calibration ({exc})')
            else:
                say(f'push {j} held out: point model depth offset '
                    f'{calibration.offset * 1e3:+.2f} +- {calibration.std * 1e3:.2f} mm (sites '
                    f'{np.round(calibration.site_offsets * 1e3, 2).tolist()})')
        if not isinstance(model, Exception) and model.refinement is not None:
            r = model.refinement
            say(f'push {j} held out: field refinement in {time.time() - t0:.0f} s, '
                f'{r.evaluations} identifications: optimum exponent {r.best[0]:.2f}, depth '
                f'layer {r.best[1]:+.2f}, residual {r.start_rms * 1e6:.1f} -> '
                f'{r.best_rms * 1e6:.1f} um: ' + ('taken' if r.accepted else 'NOT taken (gain '
                                                  'below the noise floor; the seed as given)'))
        for i, depth in enumerate(held['depths']):
            try:
                if isinstance(model, Exception):
                    raise model
                c = estimate_from_views(model, (held['q'], held['force'][i],
                                                held['clouds'][i]), depth=float(depth))
            except PointforceError as exc:   # counted, not hidden: the summary says how many
                failed.append(dict(push=j, depth=float(depth), reason=str(exc)))
                say(f'push {j} {depth * 1e3:.1f} mm: FAILED ({exc})')
                continue
            rows.append(dict(push=j, tilt=held['tilt'], depth=float(depth),
                             force=float(np.linalg.norm(c.ft_force)),
                             magnitude_error=float(np.linalg.norm(c.camera_force)
                                                   / np.linalg.norm(c.ft_force) - 1.0),
                             direction_deg=c.direction_error_deg,
                             magnitude_std=c.camera_std / float(np.linalg.norm(c.ft_force)),
                             direction_std_deg=c.direction_std_deg, inside=c.inside,
                             young=c.young, poisson=c.poisson))
            r = rows[-1]
            if point_model is not None:
                tip = held['q'] + float(depth) * held['d']   # the arm's TCP: no F/T
                try:
                    factor = small_sample_factor(len(pushes) - 1) if (
                        args.spread_t and len(pushes) > 2) else 1.0
                    fc, fu = fused_from_views(c, fem_spread, tip, point_model,
                                              calibration=calibration, spread_factor=factor)
                except PointforceError as exc:   # counted: the fused summary says how many
                    failed.append(dict(push=j, depth=float(depth), reason=f'fuse: {exc}'))
                    say(f'push {j} {depth * 1e3:.1f} mm: fuse FAILED ({exc})')
                else:
                    ft = float(np.linalg.norm(c.ft_force))
                    r.update(fused_magnitude_error=float(np.linalg.norm(fc.camera_force) / ft
                                                         - 1.0),
                             fused_direction_deg=fc.direction_error_deg,
                             fused_std=fc.camera_std / ft, fused_inside=fc.inside,
                             point_error=fu.point_magnitude / ft - 1.0,
                             point_std=fu.point_std / ft, fem_std=fu.fem_std / ft,
                             point_weight=fu.point_weight, young_spread=model.young_spread,
                             fem_spread=fem_spread,
                             learner_pokes_dropped=dropped)
                    say(f'push {j} {depth * 1e3:.1f} mm fused: magnitude '
                        f'{100 * r["fused_magnitude_error"]:+.1f} % +- {100 * r["fused_std"]:.1f}'
                        f' ({"inside" if r["fused_inside"] else "OUTSIDE"}); point model '
                        f'{100 * r["point_error"]:+.1f} % +- {100 * r["point_std"]:.1f}, FEM +- '
                        f'{100 * r["fem_std"]:.1f} (spread {fem_spread:.2f}), '
                        f'point weight {fu.point_weight:.2f}')
            say(f'push {j} (tilt {r["tilt"]:.0f}) {depth * 1e3:.1f} mm |F| {r["force"]:.2f} N: '
                f'magnitude {100 * r["magnitude_error"]:+.1f} % +- '
                f'{100 * r["magnitude_std"]:.1f}, direction {r["direction_deg"]:.1f} +- '
                f'{r["direction_std_deg"]:.1f} deg, {"inside" if r["inside"] else "OUTSIDE"} '
                f'2 sigma; E {r["young"] / 1e3:.1f} kPa, nu {r["poisson"]:.2f}')
    mag = np.abs([r['magnitude_error'] for r in rows])
    ang = np.array([r['direction_deg'] for r in rows])
    summary = dict(object=args.object, frames=args.frames, reference=args.reference,
                   field=args.field, refine=args.refine, fuse=args.fuse,
                   calibrate_point=args.calibrate_point, spread_t=args.spread_t,
                   fem_std=args.fem_std if args.fuse else None,
                   exclude_radius=args.exclude_radius if args.fuse else None,
                   states=len(rows), failed=len(failed),
                   magnitude_mean_pct=100 * float(mag.mean()),
                   magnitude_max_pct=100 * float(mag.max()),
                   direction_mean_deg=float(ang.mean()), direction_max_deg=float(ang.max()),
                   inside_2sigma=float(np.mean([r['inside'] for r in rows])))
    fused = [r for r in rows if 'fused_magnitude_error' in r]
    if fused:
        fmag = np.abs([r['fused_magnitude_error'] for r in fused])
        fang = np.array([r['fused_direction_deg'] for r in fused])
        pmag = np.abs([r['point_error'] for r in fused])
        summary.update(fused_states=len(fused), fused_magnitude_mean_pct=100 * float(fmag.mean()),
                       fused_magnitude_max_pct=100 * float(fmag.max()),
                       fused_direction_mean_deg=float(fang.mean()),
                       fused_direction_max_deg=float(fang.max()),
                       fused_inside_2sigma=float(np.mean([r['fused_inside'] for r in fused])),
                       point_magnitude_mean_pct=100 * float(pmag.mean()),
                       point_magnitude_max_pct=100 * float(pmag.max()),
                       point_inside_2sigma=float(np.mean([abs(r['point_error'])
                                                          <= 2 * r['point_std'] for r in fused])))
    report(rows, failed, summary, args.json)


if __name__ == '__main__':
    main()
