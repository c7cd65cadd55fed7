#!/usr/bin/env python3
"""Where ours loses to ET on figure 1's measured samples: the error by depth past the onset.

For each object and training size, 10 random subsets of the committed 30-poke fixture (seed 0,
a fresh generator per size, so the 10-poke subsets are not figure 1's), ours
(:class:`~pointforce_ros.response.ours.ContactGpModel`) and ET trained on each and scored on
every held-out poke's measured contact samples (figure 1's region). Prints each model's median
RMSE and, pooled over the draws, the mean signed error and the RMSE in bands of depth past the
held-out poke's own detected onset (0-2, 2-4, 4-7 and over 7 mm; ``nan``: no sample there).
Pokes stop at the force cap, so only the softer sites have samples in the deepest band.

Usage: python data/figures/depth_bands.py [--objects plush dome] (about 30 s per object on one
core; set OPENBLAS_NUM_THREADS=1).
"""

import argparse

import numpy as np

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.figures import load_poke_fixture
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.response.scoring import CONTACT_MARGIN

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
MODELS = {'et': EtBaseline, 'ours': ContactGpModel}
BANDS = ((-1.0, 0.002), (0.002, 0.004), (0.004, 0.007), (0.007, 1.0))
"""Depth past the held-out poke's onset, metres: [lo, hi)."""


def bands(name, size, repeats=10, seed=0):
    """``{model: (median RMSE, (4, 3) per band [sum of errors, sum of squares, samples])}``."""
    surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
    feats = curve_features(curves, surface)
    rng = np.random.default_rng(seed)
    rmse = {k: [] for k in MODELS}
    sums = {k: np.zeros((len(BANDS), 3)) for k in MODELS}
    for _ in range(repeats):
        train = rng.choice(len(curves), size=size, replace=False)
        held = np.setdiff1d(np.arange(len(curves)), train)
        for key, factory in MODELS.items():
            model = factory().fit([curves[i] for i in train], surface)
            errs = []
            for i in held:
                c = curves[i]
                keep = c.d >= c.onset_d - CONTACT_MARGIN
                d, f = c.d[keep], c.f[keep]
                e = model.predict(np.repeat(feats[i][None], len(d), axis=0), d) - f
                errs.append(e)
                past = d - c.onset_d
                for b, (lo, hi) in enumerate(BANDS):
                    w = (past >= lo) & (past < hi)
                    sums[key][b] += (e[w].sum(), (e[w] ** 2).sum(), w.sum())
            e = np.concatenate(errs)
            rmse[key].append(np.sqrt(np.mean(e * e)))
    return {k: (float(np.median(rmse[k])), sums[k]) for k in MODELS}


def main():
    """Print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args = parser.parse_args()
    print('bands of depth past the onset: 0-2, 2-4, 4-7, over 7 mm')
    for name in args.objects:
        for size in args.sizes:
            out = bands(name, size)
            print(f'{name} @{size}: ' + ', '.join(f'{k} {v[0]:.3f} N' for k, v in out.items()))
            with np.errstate(invalid='ignore', divide='ignore'):
                for key, (_, s) in out.items():
                    print(f'  {key:5s} mean error {np.round(s[:, 0] / s[:, 2], 3)}  '
                          f'RMSE {np.round(np.sqrt(s[:, 1] / s[:, 2]), 3)}', flush=True)


if __name__ == '__main__':
    main()
