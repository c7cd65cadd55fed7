#!/usr/bin/env python3
"""Stored demo models with ``(c, L)`` from their two pushes under each decay law (a study).

Session 29 measured offline (``demo_floor_law.py``, law ``Tpd``) that scaling each query's tail
length by the layer proxy under it lowers the demo's query error on all 14 stored lamb runs.
Session 30 built it into the simulator as ``decay_law='layer'``
(:func:`~pointforce_ros.contact.simulator.layer_proxy`, both the batch and the compiled
single-pose path). This replays ``pointforce demo --out DIR`` runs through the product: each
run's last model served as the contact service serves it, ``(c, L)`` from the sphere and the
rod (:func:`~pointforce_ros.contact.identify.calibrate_shape`, the capped decay grid) under
each law, the pushes' calibration error, and the 9 planner queries against their FEM truth
(the force vector's RMSE as a share of the largest true force, the demo's figure, how many
``Fz`` lie below the truth, each query's ``Fz`` predicted / true). Single queries and one
``query_batch`` of the 9 must agree (the two paths of the law).

Usage: python data/fem/demo_layer_replay.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
"""

import numpy as np

from demo_floor_setup import (meets_demo_goals, pushed_answers,  # this folder
                              query_score, replay_arguments, served_last_model)

LAWS = ('penetration', 'layer')


def main():
    """Print one line per run and law, and a summary per law."""
    args, demo, pushes, true, big = replay_arguments(__doc__.splitlines()[0])
    scores = {law: [] for law in LAWS}
    for out in args.demo_out:
        served = served_last_model(out)
        for law in LAWS:
            cal, fitted, pred = pushed_answers(served.with_shape_constant(served.c, decay_law=law),
                                               pushes, demo.queries)
            batch = np.array([fitted.query_batch(m, [p, p], a, ctr).wrenches[0, :3]
                              for _, m, p, a, ctr in demo.queries])
            gap = float(np.max(np.abs(batch - pred)))
            pct, below = query_score(pred, true, big)
            scores[law].append((pct, below))
            print(f'{out} {law:11s}: c {1e3 * cal.fit.c:.2f} mm, L {1e3 * cal.fit.decay:.0f} '
                  f'mm, push fit {100 * cal.in_sample_std:.1f} %; queries '
                  f'{pct:.1f} %, {below} of 9 below; batch - single '
                  f'{gap:.1e} N; Fz pred / true '
                  + ' '.join(f'{v:.2f}' for v in pred[:, 2] / true[:, 2]), flush=True)
    for law, rows in scores.items():
        pct = np.array([r[0] for r in rows])
        meet = sum(1 for p, b in rows if meets_demo_goals(p, b))
        print(f'{law:11s}: {len(rows)} runs, RMSE {pct.min():.1f}-{pct.max():.1f} % (mean '
              f'{pct.mean():.2f} %), both goals {meet} of {len(rows)}')


if __name__ == '__main__':
    main()
