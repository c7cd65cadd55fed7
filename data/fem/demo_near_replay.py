#!/usr/bin/env python3
"""Stored demo models with ``(c, L)`` from their two pushes under each near field (a study).

Session 27 gave the shape function a flat-topped near field, ``(1 + r / c) exp(-r / c)``
beside the paper's ``c / (c + r)`` (:data:`~pointforce_ros.contact.lcp.NEARS`), chosen per
object by held-out error where three or more calibration pushes allow it
(:func:`~pointforce_ros.contact.identify.choose_near`; figure 2's trials choose the flat one on
the vest). Should the demo's two pushes choose too? This replays ``pointforce demo --out DIR``
runs: each run's last model served as the contact service serves it, ``(c, L)`` from the
sphere and the rod (:func:`~pointforce_ros.contact.identify.calibrate_shape`, the capped decay
grid) under each near field, the pushes' held-out share (each push predicted with ``c``
refitted on the other at the joint ``L``: what two pushes can test) and the 9 planner queries
against their FEM truth (the force vector's RMSE as a share of the largest true force, the
demo's figure, and how many ``Fz`` lie below the truth).

Result (session 27, eight lamb runs of sessions 25-26, ``demo_near_replay.log``): the flat near
field fits the pushes far better (held-out share 2.1-5.0 % against 4.2-9.6 %) and the queries
worse on every run (8.9-10.5 % against 8.4-9.3 % of the largest true force, 8-9 of 9 below
against 7): the pushes sit beside the bone, the queries over it, and two pushes cannot test
the shape's reach. So the demo keeps the paper's near field
(``choose_near`` needs :data:`~pointforce_ros.contact.identify.NEAR_PUSHES` pushes).

Usage: python data/fem/demo_near_replay.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
"""

import numpy as np

from demo_floor_setup import (pushed_answers, replay_arguments,  # this folder
                              served_last_model)
from pointforce_ros.contact.identify import small_sample_factor
from pointforce_ros.contact.lcp import NEARS


def main():
    """Print one line per run and near field."""
    args, demo, pushes, true, big = replay_arguments(__doc__.splitlines()[0])
    for out in args.demo_out:
        served = served_last_model(out)
        for near in NEARS:
            cal, fitted, pred = pushed_answers(served.with_shape_constant(served.c, near=near),
                                               pushes, demo.queries)
            vector = float(np.sqrt(np.mean(np.sum((pred - true) ** 2, axis=1))))
            share = cal.relative_std / small_sample_factor(2)
            print(f'{out} {near:5s}: c {1e3 * cal.fit.c:.2f} mm, L {1e3 * cal.fit.decay:.0f} mm,'
                  f' held-out push share {100 * share:.1f} %; queries {100 * vector / big:.1f} %,'
                  f' {int(np.sum(pred[:, 2] < true[:, 2]))} of 9 below; Fz pred / true '
                  + ' '.join(f'{v:.2f}' for v in pred[:, 2] / true[:, 2]), flush=True)


if __name__ == '__main__':
    main()
