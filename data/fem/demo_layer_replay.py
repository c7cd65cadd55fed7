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

from pathlib import Path

import numpy as np

from demo_floor_setup import demo_runs_arguments  # this folder
from pointforce_ros.bringup.demo import _calibration_pokes
from pointforce_ros.contact.identify import calibrate_shape, decay_grid
from pointforce_ros.model.serving import WrenchServer

LAWS = ('penetration', 'layer')


def main():
    """Print one line per run and law, and a summary per law."""
    args, demo = demo_runs_arguments(__doc__.splitlines()[0])
    vectors = _calibration_pokes(demo.spec, vectors=True)
    pushes = [vectors['sphere'], vectors['rod']]
    true = np.asarray(demo.gt['force'], dtype=float)
    big = float(np.max(np.linalg.norm(true, axis=1)))
    scores = {law: [] for law in LAWS}
    for out in args.demo_out:
        models = sorted((Path(out) / 'cell' / 'models').glob('model-v*.npz'))
        server = WrenchServer()
        server.load(models[-1])
        served = server.simulator()
        for law in LAWS:
            sim = served.with_shape_constant(served.c, decay_law=law)
            cal = calibrate_shape(sim, pushes, decays=decay_grid(sim.surface))
            fitted = sim.with_shape_constant(cal.fit.c, cal.fit.decay)
            pred = np.array([fitted.query(m, p, a, ctr).wrench.force
                             for _, m, p, a, ctr in demo.queries])
            batch = np.array([fitted.query_batch(m, [p, p], a, ctr).wrenches[0, :3]
                              for _, m, p, a, ctr in demo.queries])
            gap = float(np.max(np.abs(batch - pred)))
            vector = float(np.sqrt(np.mean(np.sum((pred - true) ** 2, axis=1))))
            below = int(np.sum(pred[:, 2] < true[:, 2]))
            scores[law].append((100 * vector / big, below))
            print(f'{out} {law:11s}: c {1e3 * cal.fit.c:.2f} mm, L {1e3 * cal.fit.decay:.0f} '
                  f'mm, push fit {100 * cal.in_sample_std:.1f} %; queries '
                  f'{100 * vector / big:.1f} %, {below} of 9 below; batch - single '
                  f'{gap:.1e} N; Fz pred / true '
                  + ' '.join(f'{v:.2f}' for v in pred[:, 2] / true[:, 2]), flush=True)
    for law, rows in scores.items():
        pct = np.array([r[0] for r in rows])
        meet = sum(1 for p, b in rows if p < 8.0 and 3 <= b <= 6)
        print(f'{law:11s}: {len(rows)} runs, RMSE {pct.min():.1f}-{pct.max():.1f} % (mean '
              f'{pct.mean():.2f} %), both goals {meet} of {len(rows)}')


if __name__ == '__main__':
    main()
