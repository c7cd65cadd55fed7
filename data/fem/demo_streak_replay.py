#!/usr/bin/env python3
"""Stored demo models with ``(c, L)`` from two pushes and from three (a study, session 31).

The demo's sphere and rod both press the lamb's red muscle beside the bone; the queries over
the bone (sphere and cylinder #1 and #2) came out low in nearly every run (7 of 9 below the
truth), and no decay or near-field law chosen from those two pushes fixed it
(``demo_floor_law.py``, ``demo_layer_replay.py``, ``demo_near_replay.py``). Session 22 made a
third push, the rod across the paler streak over the bone (``demo_calibration_streak_lamb.npz``,
``make_demo_calibration.py --probe streak``), and found it lifted everything on the models of
sessions 17-21. This replays the last model of each ``pointforce demo --out DIR`` run as the
contact service serves it (its decay law, the paper's near field), with ``(c, L)`` from

* ``2``: the sphere and the rod (the demo before session 31);
* ``3``: the sphere, the rod and the streak (the demo since);
* ``3near``: the same, with the near field chosen from the three by held-out error
  (:func:`~pointforce_ros.contact.identify.choose_near`, what three pushes allow elsewhere),

each through :func:`~pointforce_ros.contact.identify.calibrate_shape` with its uncertainty
sources, and scores the 9 planner queries through
:func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty` (the service's answer and
``wrench_std``) against their FEM truth: the force vector's RMSE as a share of the largest true
force, how many ``Fz`` lie below the truth, how many true ``Fz`` lie inside the nominal 90 %
intervals and their mean width, and a summary per variant (both demo goals: under 8 % and at
most 6 of 9 on one side). The ``2`` row reproduces what the run's demo printed.

Usage: python data/fem/demo_streak_replay.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
(about 25 s per run on one core)
"""


import numpy as np

from demo_floor_setup import (meets_demo_goals, query_score, replay_arguments,  # this folder
                              served_variant)
from pointforce_ros.bringup.demo import _calibration_pokes
from pointforce_ros.contact.lcp import NEARS
from pointforce_ros.contact.uncertainty import Z90


def main():
    """Print one line per run and variant, and a summary per variant."""
    args, demo, pushes, true, big = replay_arguments(__doc__.splitlines()[0])
    vectors = _calibration_pokes(demo.spec, vectors=True)
    three = pushes + [vectors['streak']]
    variants = (('2', pushes, None), ('3', three, None), ('3near', three, NEARS))
    scores = {name: [] for name, _, _ in variants}
    for out in args.demo_out:
        for name, used, nears in variants:
            cal, pred, std = served_variant(out, used, demo.queries, nears)
            pct, below = query_score(pred, true, big)
            inside = int(np.sum(np.abs(pred[:, 2] - true[:, 2]) <= Z90 * std))
            width = float(np.mean(2 * Z90 * std))
            scores[name].append((pct, below, inside, width))
            print(f'{out} {name:6s}: {cal.near} near field, c {1e3 * cal.fit.c:.2f} mm, L '
                  f'{1e3 * cal.fit.decay:.0f} mm, pushes predicted from the others '
                  f'{100 * cal.relative_std:.0f} %; queries {pct:.1f} %, {below} of 9 below, '
                  f'{inside} of 9 inside (width {width:.2f} N); Fz pred / true '
                  + ' '.join(f'{v:.2f}' for v in pred[:, 2] / true[:, 2]), flush=True)
    for name, rows in scores.items():
        pct = np.array([r[0] for r in rows])
        meet = sum(1 for p, b, _, _ in rows if meets_demo_goals(p, b))
        print(f'{name:6s}: {len(rows)} runs, RMSE {pct.min():.1f}-{pct.max():.1f} % (mean '
              f'{pct.mean():.2f} %, median {np.median(pct):.2f} %), both goals {meet} of '
              f'{len(rows)}; true Fz inside {sum(r[2] for r in rows)} of {9 * len(rows)}, mean '
              f'width {np.mean([r[3] for r in rows]):.2f} N')


if __name__ == '__main__':
    main()
