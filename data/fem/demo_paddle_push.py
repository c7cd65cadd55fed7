#!/usr/bin/env python3
"""A fourth calibration push with the line paddle, replayed on stored demo models (session 35).

``demo_footprint.py`` found the contact family over-predicting the paddle queries (paddle #2 at
1.14-1.25 of the truth with a perfect point model) while the demo's calibration pushes are a
sphere and two rods: no narrow line contact. This asks whether a push with the paddle itself
(the planner's tool, 60 mm long, 6 mm thick, :func:`~pointforce_ros.sim.fem.probes.
paddle_probe`) at the rod's site, long axis along y, at 2, 3 and 4 mm, fixes it. ``--make``
computes its FEM truth (full nonlinear solve, ``mesh_live``, about 2.5 min) into
``demo_study_paddle_<object>.npz`` here; then the last served model of each ``pointforce demo
--out DIR`` run is scored as :mod:`demo_streak_replay` does (``calibrate_shape`` with its
uncertainty sources, the 9 queries through ``wrench_uncertainty``) with ``(c, L)`` from

* ``3``: the demo's three pushes (sphere, rod, streak; what the demo does);
* ``4``: the same and the paddle (the paper's near field);
* ``4near``: the four, the near field chosen by held-out error (``choose_near``).

Usage: python data/fem/demo_paddle_push.py [--make] DEMO_OUT [...] [--object lamb]
(about 1 min per run)
"""

import argparse
from pathlib import Path

import numpy as np

from demo_floor_setup import load_demo_queries, replay_variants  # this folder
from pointforce_ros.bringup.demo import _calibration_pokes, ROD_SITE
from pointforce_ros.contact.lcp import NEARS
from pointforce_ros.sim.fem.indentation import probe_wrench_full
from pointforce_ros.sim.fem.probes import paddle_probe, pose_for_push

HERE = Path(__file__).resolve().parent
DEPTHS = (0.002, 0.003, 0.004)


def paddle_push(spec):
    """``(mesh, poses, depths)``: the paddle at the rod's site, its long axis along y."""
    cx, cy = spec.centre
    top = np.asarray(spec.top_point(cx + ROD_SITE[0], cy + ROD_SITE[1]))
    down = np.array([0.0, 0.0, -1.0])
    poses = [pose_for_push(top + down * d, down, np.pi / 2) for d in DEPTHS]
    return paddle_probe(), poses, np.array(DEPTHS)


def make(spec, path: Path) -> None:
    """Solve the paddle push in FEM and write ``path``."""
    mesh, poses, depths = paddle_push(spec)
    force = []
    for k, pose in enumerate(poses):
        f, _ = probe_wrench_full(spec, mesh, pose, pose.position, h=spec.mesh_live)
        force.append(f)
        print(f'paddle {1e3 * depths[k]:.0f} mm: F = {np.round(f, 3)} N', flush=True)
    np.savez(path, depths=depths, force=np.array(force))


def main() -> None:
    """Print one line per run and variant, and a summary per variant."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('demo_out', nargs='+')
    parser.add_argument('--object', default='lamb')
    parser.add_argument('--make', action='store_true', help='compute the FEM push first')
    args = parser.parse_args()
    demo = load_demo_queries(args.object)
    path = HERE / f'demo_study_paddle_{demo.spec.name}.npz'
    if args.make or not path.exists():
        make(demo.spec, path)
    mesh, poses, depths = paddle_push(demo.spec)
    with np.load(path) as z:
        if not np.allclose(z['depths'], depths):
            raise SystemExit(f'{path.name} is for other depths: run with --make')
        paddle = (mesh, poses, [0.0, 0.0, -1.0], np.asarray(z['force'], dtype=float))
    vectors = _calibration_pokes(demo.spec, vectors=True)
    three = [vectors['sphere'], vectors['rod'], vectors['streak']]
    true = np.asarray(demo.gt['force'], dtype=float)
    big = float(np.max(np.linalg.norm(true, axis=1)))
    variants = (('3', three, None), ('4', three + [paddle], None),
                ('4near', three + [paddle], NEARS))
    replay_variants(args.demo_out, variants, demo.queries, true, big)


if __name__ == '__main__':
    main()
