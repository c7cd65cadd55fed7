#!/usr/bin/env python3
"""A stored demo's last model, ``(c, L)`` from its two pushes over the whole decay grid and capped.

Session 26 capped the shape function's tail decay length at 1.5 thicknesses of the object
(:func:`~pointforce_ros.contact.identify.decay_grid`). This replays a ``pointforce demo --out
DIR`` run: its last model served as the contact service serves it, ``(c, L)`` from the sphere
and the rod (:func:`~pointforce_ros.contact.identify.calibrate_shape`) over
:data:`~pointforce_ros.contact.identify.DECAY_GRID` and over the capped grid, and the 9 planner
queries against their FEM truth for each: the force vector's RMSE as a share of the largest
true force (the demo's figure) and ``Fz``'s, how many ``Fz`` lie below the truth, and each
query's predicted / true ``Fz``.

Result (record ``demo_cap_replay.log``): on a foam block demo the two pushes alone chose an
endless tail (c 3.04 mm), the queries at 8.1 % (Fz 7.5 %, 6 of 9 below); capped (38 mm thick:
L at most 57 mm) they choose 32 mm (c 5.84 mm), 6.7 % (Fz 4.6 %, 5 below), although the pushes
are fitted worse (0.82 against 0.63 N). On a lamb demo the pushes choose 16 mm either way.

Usage: python data/fem/demo_cap_replay.py DEMO_OUT [--object lamb]
"""

import argparse
from pathlib import Path

import numpy as np

from demo_floor_setup import load_demo_queries  # this folder
from pointforce_ros.bringup.demo import _calibration_pokes
from pointforce_ros.contact.identify import (calibrate_shape, DECAY_GRID, decay_grid,
                                             object_thickness)
from pointforce_ros.model.serving import WrenchServer


def main():
    """Print one line per grid."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('demo_out', help="a demo's --out folder (its cell/models)")
    parser.add_argument('--object', default='lamb')
    args = parser.parse_args()
    demo = load_demo_queries(args.object)
    models = sorted((Path(args.demo_out) / 'cell' / 'models').glob('model-v*.npz'))
    server = WrenchServer()
    server.load(models[-1])
    sim = server.simulator()
    vectors = _calibration_pokes(demo.spec, vectors=True)
    true = np.asarray(demo.gt['force'], dtype=float)
    big = float(np.max(np.linalg.norm(true, axis=1)))
    print(f'{args.object} ({models[-1].name}): thickness {1e3 * object_thickness(sim.surface):.1f}'
          f' mm, capped grid {[round(1e3 * v) for v in decay_grid(sim.surface)]} mm')
    for label, grid in (('whole grid', DECAY_GRID), ('capped', decay_grid(sim.surface))):
        cal = calibrate_shape(sim, [vectors['sphere'], vectors['rod']], decays=grid)
        fitted = sim.with_shape_constant(cal.fit.c, cal.fit.decay)
        pred = np.array([fitted.query(m, p, a, ctr).wrench.force
                         for _, m, p, a, ctr in demo.queries])
        vector = float(np.sqrt(np.mean(np.sum((pred - true) ** 2, axis=1))))
        fz = pred[:, 2] - true[:, 2]
        fz_pct = 100 * np.sqrt(np.mean(fz ** 2)) / np.max(np.abs(true[:, 2]))
        print(f'{label}: c {1e3 * cal.fit.c:.2f} mm, L {1e3 * cal.fit.decay:.0f} mm, pushes '
              f'fitted within {cal.fit.rmse:.3f} N; queries {100 * vector / big:.1f} % of '
              f'{big:.2f} N (Fz {fz_pct:.1f} %, '
              f'{int(np.sum(fz < 0))} of 9 below); Fz pred / true '
              f'{np.round(pred[:, 2] / true[:, 2], 2).tolist()}', flush=True)


if __name__ == '__main__':
    main()
