"""Argument parsing of ``pointforce replica``.

Wired into the ``pointforce`` command as::

    from pointforce_ros.replica import cli as replica_cli
    replica_cli.add_parser(sub)          # in build_parser, beside the other sub-commands

``main`` of the ``pointforce`` command turns a ``PointforceError`` into a one-line error.
"""

import argparse

from pointforce_ros import arguments
from pointforce_ros.errors import PointforceError

MIN_H = 0.001
"""Smallest replica mesh edge, metres: 1.2 million tetrahedra on a 80 x 60 x 40 mm block (a
1 um edge asked numpy for 36 GiB and ended in a MemoryError traceback)."""

MAX_PAPER_GRID = 10
"""Most points per Lame parameter of the paper calibrator's grid (its square is the number of
simulations, minutes each; 10^8 took 9 GB in a minute before the first)."""


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``replica`` sub-command to ``subparsers``; returns its parser."""
    p = subparsers.add_parser('replica', help='calibrate a PyBullet replica of the poked '
                              'object to measured pokes (seed 002) and write it')
    p.add_argument('--engine', default='pybullet', help='simulation engine (pybullet)')
    p.add_argument('--data', required=True, help='poke store, generated data set, or poke '
                   'fixture .npz')
    p.add_argument('--out', required=True, help='replica directory')
    p.add_argument('--h', type=arguments.positive_float, default=0.01,
                   help='mesh edge length, m (recorded)')
    p.add_argument('--train', type=arguments.positive_int, default=3, help='training pokes')
    p.add_argument('--held-out', type=arguments.positive_int, default=3, help='held-out pokes')
    p.add_argument('--no-damping', action='store_true', help='skip the damping step')
    p.add_argument('--seed', type=arguments.seed, default=0, help='train/held-out split seed')
    p.add_argument('--calibrators', default='scaling,paper',
                   help='comma-separated: scaling (ours), paper (seed 002 MLP)')
    p.add_argument('--paper-grid', type=int, default=3,
                   help="points per Lame parameter of the paper calibrator's grid")
    p.set_defaults(func=run)
    return p


def run(args) -> int:
    """Run ``pointforce replica`` with parsed ``args``; returns the exit status.

    Raises:
        PointforceError: ``--h`` below :data:`MIN_H` or ``--paper-grid`` outside
            2..:data:`MAX_PAPER_GRID`, before the data is read.

    """
    if args.h < MIN_H:
        raise PointforceError(f'--h {args.h:g} m is below {MIN_H:g} m (the mesh would not fit '
                              'in memory)')
    if not 2 <= args.paper_grid <= MAX_PAPER_GRID:
        raise PointforceError(f'--paper-grid must be in 2..{MAX_PAPER_GRID} (its square is the '
                              f'number of simulations), got {args.paper_grid}')
    from pointforce_ros.replica.build import build_replica  # loads pybullet: this command only
    build_replica(args.data, args.out, engine=args.engine, h=args.h, train=args.train,
                  held_out=args.held_out, damping=not args.no_damping, seed=args.seed,
                  calibrators=tuple(c for c in args.calibrators.split(',') if c),
                  paper_grid=args.paper_grid)
    return 0
