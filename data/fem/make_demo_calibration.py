"""Precompute the demo's calibration push: a sphere pushed once, away from every planner query.

The demo identifies the shape constant ``c`` of the contact simulator from this one push with
a second, known probe (seed 000 picks ``c`` by eye; here it is fitted to a measurement): the
sphere of :func:`pointforce_ros.bringup.demo.calibration_push` at two depths, full nonlinear FEM
solve (:func:`pointforce_ros.sim.fem.indentation.probe_wrench_full`, element size
``mesh_live``), as the F/T sensor would read it without noise. Writes
``demo_calibration_<object>.npz`` (depths (T,) m, force (T, 3) N, base frame).

A second push with a rod (``--probe rod``, :func:`~pointforce_ros.bringup.demo.
calibration_rod_push`) writes ``demo_calibration_rod_<object>.npz``: with the sphere it fixes
both ``c`` and the tail decay length ``L``. The third (``--probe streak``, :func:`~pointforce_ros.
bringup.demo.calibration_streak_push`: the rod across the paler streak over the lamb's bone,
15 mm beyond query site 2, 3 min) writes ``demo_calibration_streak_<object>.npz`` (session 22
made it as ``demo_floor_rod_over_bone_lamb.npz`` with ``--probe rod --site 0.03,0``, a study
push; session 31 made it the demo's third).

``--site DX,DY --out NAME`` moves a rod (its axis along y) to ``(DX, DY)`` from the centre and
writes ``NAME`` in this folder instead: a push for studies, not read by the demo
(``demo_floor_law.py --extra-push``).

Usage: python data/fem/make_demo_calibration.py [--object lamb] [--probe sphere|rod|streak]
       [--site DX,DY --out NAME] (minutes)
"""

import argparse
import time
from pathlib import Path

import numpy as np

from pointforce_ros.sim.fem.indentation import probe_wrench_full
from pointforce_ros.sim.objects import load_object
from pointforce_ros.bringup.demo import CALIBRATIONS

HERE = Path(__file__).resolve().parent


def main():
    """Compute and write the fixture."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--object', default='lamb')
    parser.add_argument('--probe', default='sphere', choices=sorted(CALIBRATIONS))
    parser.add_argument('--site', default=None, help='rod only: DX,DY from the centre, m')
    parser.add_argument('--out', default=None, help='file name (with --site)')
    args = parser.parse_args()
    spec = load_object(args.object)
    pattern, push = CALIBRATIONS[args.probe]
    if (args.site is None) != (args.out is None) or (args.site and args.probe == 'sphere'):
        parser.error('--site and --out go together, with --probe rod or streak')
    if args.site:
        mesh, poses, depths = push(spec, tuple(float(v) for v in args.site.split(',')))
        pattern = args.out
    else:
        mesh, poses, depths = push(spec)
    start = time.monotonic()
    force = []
    for k, pose in enumerate(poses):
        f, _ = probe_wrench_full(spec, mesh, pose, pose.position, h=spec.mesh_live)
        force.append(f)
        print(f'{k + 1}/{len(poses)}: F = {np.round(f, 3)} N, {time.monotonic() - start:.0f} s',
              flush=True)
    # the poses (position and quaternion) let the demo refuse a file made for another push
    np.savez(HERE / pattern.format(spec.name), depths=np.asarray(depths),
             force=np.array(force),
             positions=np.array([np.r_[p.position, p.orientation] for p in poses]))


if __name__ == '__main__':
    main()
