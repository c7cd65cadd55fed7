#!/usr/bin/env python3
"""The mix with the trees' scatter calibrated by the median z^2 (a study, session 47, not kept).

The trees' scatter (:func:`pointforce_ros.response.trees.calibrated_scatter`) makes the
held-out pokes' mean ``r^2 / (v + s^2)`` one; one poke far from the others (session 47's demo
47d: a poke at the force cap whose power law puts its onset 3 mm before the others') then
widens every point's spread. Here the scatter makes the MEDIAN ``r^2 / (v + s^2)`` that of a
chi-square with one degree of freedom (0.455) instead, patched in for this run only:

- ``--part figure1``: figure 1's draws, the product's mix (median RMSE, ratio to ET, share of
  held-out samples inside ``+- Z90 predict_std``);
- ``--part demo DEMO_OUT ...``: stored demos relearned under each spread
  (``data/fem/demo_spread_replay.py``).

Session 47 (record ``mix_spread.log``, its last block): 47d's intervals 13.79 -> 5.74 N mean
width but its RMSE unchanged (9.41 %: the law choice, not the scatter); figure 1 the same on
most cells, thin_layer at 10 pokes 1.34 -> 1.27; coverage 1-5 points lower.

Usage: python data/figures/mix_robust_scatter.py --part figure1 [OBJECTS]
       python data/figures/mix_robust_scatter.py --part demo DEMO_OUT [DEMO_OUT ...]
(set OPENBLAS_NUM_THREADS=1)
"""

import runpy
import sys
import time
from pathlib import Path

import numpy as np

import pointforce_ros.response.trees as trees
from pointforce_ros.contact.uncertainty import Z90
from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.response.ours import product_model

MEDIAN_Z2 = 0.4549364
"""Median of a chi-square with one degree of freedom."""
HERE = Path(__file__).resolve().parent
CALIBRATED = trees.calibrated_scatter


def robust_scatter(residual, variance):
    """(P,) scatter ``s``: the held-out median of ``r^2 / (v + s^2)`` is :data:`MEDIAN_Z2`."""
    return CALIBRATED(residual, variance, lambda z2: float(np.median(z2)) - MEDIAN_Z2)


def figure1(objects):
    sys.path.insert(0, str(HERE))
    from nugget_floor import figure1_sets
    for label, start, draws in figure1_sets(objects, [5, 10]):
        rows, hits = [], []
        for train, surface, queries in draws:
            et, mx = EtBaseline().fit(train, surface), product_model().fit(train, surface)
            e = {'et': [], 'mix': []}
            for x, d, f in queries:
                p = mx.predict(x, d)
                e['et'].append(et.predict(x, d) - f)
                e['mix'].append(p - f)
                hits.append(np.abs(p - f) <= Z90 * mx.predict_std(x, d))
            rows.append({k: float(np.sqrt(np.mean(np.concatenate(v) ** 2)))
                         for k, v in e.items()})
        med = {k: float(np.median([r[k] for r in rows])) for k in ('et', 'mix')}
        print(f"{label} mix_robust {med['mix']:.3f} ({med['mix'] / med['et']:.2f}) coverage "
              f'{100 * np.mean(np.concatenate(hits)):.0f} %   [{time.monotonic() - start:.0f} s]',
              flush=True)


def main():
    trees.calibrated_scatter = robust_scatter
    if sys.argv[1:3] == ['--part', 'demo']:
        sys.path.insert(0, str(HERE.parent / 'fem'))
        sys.argv = ['demo_spread_replay.py'] + sys.argv[3:]
        runpy.run_path(str(HERE.parent / 'fem' / 'demo_spread_replay.py'), run_name='__main__')
    else:
        objects = sys.argv[3:] if sys.argv[1:3] == ['--part', 'figure1'] else sys.argv[1:]
        figure1(objects or ['plush', 'vest', 'lamb', 'dome', 'thin_layer'])


if __name__ == '__main__':
    main()
