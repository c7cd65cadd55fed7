#!/usr/bin/env python3
"""Regenerate the cached ground truth of ``pointforce_ros.lab.figures`` (data/figures/).

Usage::

    python data/figures/make_figures_data.py --object plush --part pokes
    python data/figures/make_figures_data.py --object plush --part probes   # minutes
    python data/figures/make_figures_data.py --all                          # everything

Scenario of each file (seeded; same seed, same arrays):

- ``pokes_<object>.npz``: the equilibrium surface of ``config/objects/<object>.yaml`` as the
  ``realistic`` scenario's camera sees it (2 views, :func:`pointforce_ros.sim.generate.
  scan_object` + ``build_equilibrium_surface``, float32) and the loading curves
  (:func:`pointforce_ros.pokes.curves.extract_curve`) of a 30-poke campaign
  (:func:`pointforce_ros.sim.session.simulate_campaign`, ``realistic`` scenario, FEM live
  contact path, force cap and depth limit of the object), float32, every 250 Hz sample.
  Needs the object's live cache (``data/fem/make_fem_cache.py --object NAME``).
- ``probes_<object>.npz``: line-paddle and cylinder probe trials at random locations and
  orientations (:func:`pointforce_ros.sim.generate.probe_trials`: tilt up to 15 deg, random
  roll, 6 steps to the object's max depth, full nonlinear FEM at ``mesh.live``), plus the
  displaced top surface of one full nonlinear point poke at the object's centre (the dent used
  to identify the shape constant ``c``). Minutes per trial on a shared 2-core machine.

Every file stores ``spec_hash`` (:func:`pointforce_ros.lab.figures.physics_hash`): the figures
refuse
a file made for other object physics.
"""

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..')))

from pointforce_ros.lab.figures import (DATA_DIR, make_poke_fixture,  # noqa: E402
                                        make_probe_fixture, OBJECTS)


def main(argv=None):
    """Build the requested fixtures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--object', action='append', help='object name (repeatable)')
    parser.add_argument('--all', action='store_true', help='all five objects, both parts')
    parser.add_argument('--part', choices=('pokes', 'probes', 'both'), default='both')
    parser.add_argument('--pokes', type=int, default=30, help='campaign size')
    parser.add_argument('--lines', type=int, default=3, help='line trials per object')
    parser.add_argument('--cylinders', type=int, default=2, help='cylinder trials per object')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--out', default=DATA_DIR)
    args = parser.parse_args(argv)
    objects = list(OBJECTS) if args.all else (args.object or [])
    if not objects:
        parser.error('give --object NAME or --all')
    for name in objects:
        started = time.monotonic()
        if args.part in ('pokes', 'both'):
            path = make_poke_fixture(name, args.out, count=args.pokes, seed=args.seed)
            print(f'[figures-data] {path} in {time.monotonic() - started:.0f} s', flush=True)
        if args.part in ('probes', 'both'):
            started = time.monotonic()
            path = make_probe_fixture(name, args.out, lines=args.lines,
                                      cylinders=args.cylinders, seed=args.seed)
            print(f'[figures-data] {path} in {time.monotonic() - started:.0f} s', flush=True)
    return 0


if __name__ == '__main__':
    np.set_printoptions(precision=3, suppress=True)
    sys.exit(main())
