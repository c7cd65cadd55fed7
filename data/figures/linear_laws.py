#!/usr/bin/env python3
"""Figure 1's point pokes with each held-out poke's law a ridge regression on features (a study).

The same draws as ``figure1_oracles.py`` and ``python -m pointforce_ros.lab.figures
--learning-only --sizes 5 10`` (seed 0, 10 random training subsets per size of the committed
30-poke fixtures, sizes in order; every held-out poke scored on its measured contact samples;
median RMSE over the draws, newtons, and the ratio to ET). Each training poke's power law
``(d0, log F, p)`` is fitted to its own curve (as ours does); a held-out poke gets the law a
ridge regression of those parameters on a few standardised features predicts. The ridge
weight is chosen per draw from 1e-3, 0.1, 1 and 10 by leave-one-poke-out force RMSE over the
training pokes (no held-out data). Columns:

- ``const``: no feature (the training laws' mean parameters);
- ``z``: the surface height;
- ``rgb``: the colour;
- ``z_rgb``: both;
- ``z_lap``: the height on every parameter, and on the onset also the surface's local
  curvature (the Laplacian of a quadric fitted to the cloud within 8 mm of the poke);
- ``z2``: the height and its square (about the surface's median height);
- ``z_clamped``: ``z``'s law kept within the training pokes' range as ours keeps its
  predictions (``response/ours.py``, point 4: the onset within the detected onsets +-
  ``ONSET_MARGIN``, ``log F`` within +- ``LOG_FORCE_MARGIN``, ``p`` within);
- ``pick``: per draw, ours or one of the columns above but ``z_lap``, whichever has the lowest
  leave-one-poke-out force RMSE over the training pokes (ours': its ``law_scores``);
- ``z_own_onset``, ``z2_own_onset``: oracles, ``z``'s and ``z2``'s laws with the held-out
  poke's own fitted onset (what a perfect onset would leave).

Then, per object, what the onset left by ``z2`` (over all 30 pokes) correlates with: the
local curvature, and the nearest other poke's left-over onset.

Session 42 (record ``linear_laws.log``): no column reaches 0.9x ET on every object. On the
dome, where the training laws follow the height almost exactly (correlation of ``log F`` and
``p`` with it -0.98 and 0.98 over the 30 pokes), ``z2`` scores 1.04 and 1.08 of ET at 5 and 10
pokes (ours 1.77 and 1.23); with a perfect onset (``z2_own_onset``) 0.82 at both. What is
left there is the onset: after ``z2`` its spread is 0.19 mm (of 0.52), correlated with the
local curvature (-0.67) and with the nearest poke's (0.59). On thin_layer ``z_rgb`` scores
0.79 at 5 pokes but 1.24 at 10, ``rgb`` 0.88 and 1.42. On plush no column beats ours; on
lamb at 10 every column (1.20-1.33) beats ours' 1.45, none reaches ET. ``pick`` helps where a
line in a feature carries the law (dome 1.26 | 1.08, thin_layer 0.81 | 1.24, vest at 10 1.00)
and hurts where it does not (plush 1.37 | 1.51, lamb 1.10 | 1.59): with 5-10 pokes the
leave-one-poke-out scores choose too noisily to take the better of the two per object.

Usage: python data/figures/linear_laws.py [--objects dome thin_layer] [--sizes 5 10]
(about 30 s per object on one core; set OPENBLAS_NUM_THREADS=1).
"""

import argparse
import time

import numpy as np
from scipy.spatial import cKDTree

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.figures import load_poke_fixture
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel, LOG_FORCE_MARGIN, ONSET_MARGIN
from pointforce_ros.response.scoring import CONTACT_MARGIN

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
Z, RGB, LAP, Z2 = [2], [3, 4, 5], [9], [10]
VARIANTS = {'const': ([], []), 'z': (Z, Z), 'z2': (Z + Z2, Z + Z2), 'rgb': (RGB, RGB),
            'z_rgb': (Z + RGB, Z + RGB),
            'z_lap': (Z + LAP, Z)}
"""Name: (feature columns for the onset, for ``log F`` and ``p``)."""
COLUMNS = ('et', 'ours', *VARIANTS, 'z_clamped', 'pick', 'z_own_onset', 'z2_own_onset')
RIDGES = (1e-3, 0.1, 1.0, 10.0)
CURVATURE_RADIUS = 0.008


def curvature(points: np.ndarray, at: np.ndarray) -> np.ndarray:
    """(n,) Laplacian of a quadric ``z(x, y)`` fitted to the cloud round each poked point."""
    tree = cKDTree(points[:, :2])
    out = np.zeros(len(at))
    for i, p in enumerate(at):
        q = points[tree.query_ball_point(p[:2], CURVATURE_RADIUS)]
        dx, dy = q[:, 0] - p[0], q[:, 1] - p[1]
        a = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=1)
        coef = np.linalg.lstsq(a, q[:, 2], rcond=None)[0]
        out[i] = 2.0 * (coef[3] + coef[5])
    return out


def ridge(x, y, weight):
    """``predict(rows)`` of a ridge regression of ``y`` on standardised ``x`` (free intercept)."""
    mu, sd = x.mean(axis=0), x.std(axis=0) + 1e-12
    a = np.hstack([np.ones((len(x), 1)), (x - mu) / sd])
    reg = weight * np.eye(a.shape[1])
    reg[0, 0] = 0.0
    coef = np.linalg.solve(a.T @ a + reg, a.T @ y)
    return lambda rows: np.hstack([np.ones((len(rows), 1)), (rows - mu) / sd]) @ coef


class LinearLaw:
    """Law parameters of a new poke from a ridge regression on its features."""

    def __init__(self, model, cols):
        self.model, self.cols = model, cols

    def fit(self, feats, laws, curves):
        """Choose the ridge weight by leave-one-poke-out force RMSE, then fit on all pokes."""
        scores = [self._loo(feats, laws, curves, w) for w in RIDGES]
        self.weight, self.score = RIDGES[int(np.argmin(scores))], min(scores)
        self.parts = self._fit(feats, laws, self.weight)
        return self

    def _fit(self, feats, laws, weight):
        return [ridge(feats[:, c], laws[:, k], weight) for c, k in zip(self.cols, (
            slice(0, 1), slice(1, None)))]

    def law(self, feats):
        """(n, 3) predicted ``(d0, log F, p)``."""
        return np.hstack([part(feats[:, c]) for part, c in zip(self.parts, self.cols)])

    def force(self, law, d):
        """The power law's force at depths ``d``."""
        return self.model.force_from_params(np.repeat(law[None], len(d), axis=0), d)

    def _loo(self, feats, laws, curves, weight):
        errs = []
        for i in range(len(laws)):
            keep = np.arange(len(laws)) != i
            self.parts = self._fit(feats[keep], laws[keep], weight)
            d, f = contact_samples(curves[i])
            errs.append(self.force(self.law(feats[i:i + 1])[0], d) - f)
        return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))


def contact_samples(curve):
    """Figure 1's scored samples of one poke: from the margin before its onset on."""
    keep = curve.d >= curve.onset_d - CONTACT_MARGIN
    return curve.d[keep], curve.f[keep]


def draw_errors(train, test, data, model):
    """``{column: RMSE}`` of one draw (``train``, ``test``: indices into the 30 pokes)."""
    surface, curves, feats, laws = data
    et = EtBaseline().fit([curves[i] for i in train], surface)
    ours = ContactGpModel().fit([curves[i] for i in train], surface)
    linear = {k: LinearLaw(model, cols).fit(feats[train], laws[train],
                                            [curves[i] for i in train])
              for k, cols in VARIANTS.items()}
    # 'pick': ours or one of the columns, the lowest leave-one-poke-out force RMSE per draw
    scores = {k: lin.score for k, lin in linear.items() if k not in ('z_lap',)}
    scores['ours'] = min(ours.law_scores.values()) if ours.law_scores else np.inf
    pick = min(scores, key=scores.get)
    onsets = np.array([curves[i].onset_d for i in train])
    clamp = (np.array([onsets.min() - ONSET_MARGIN, laws[train, 1].min() - LOG_FORCE_MARGIN,
                       laws[train, 2].min()]),
             np.array([onsets.max() + ONSET_MARGIN, laws[train, 1].max() + LOG_FORCE_MARGIN,
                       laws[train, 2].max()]))
    out = {k: [] for k in COLUMNS}
    for i in test:
        d, f = contact_samples(curves[i])
        rows = np.repeat(feats[i][None, :9], len(d), axis=0)
        out['et'].append(et.predict(rows, d) - f)
        out['ours'].append(ours.predict(rows, d) - f)
        out['pick'].append(out['ours'][-1] if pick == 'ours' else
                           linear[pick].force(linear[pick].law(feats[i:i + 1])[0], d) - f)
        for k, lin in linear.items():
            out[k].append(lin.force(lin.law(feats[i:i + 1])[0], d) - f)
        law = linear['z'].law(feats[i:i + 1])[0]
        out['z_clamped'].append(linear['z'].force(np.clip(law, *clamp), d) - f)
        for k in ('z', 'z2'):
            law = linear[k].law(feats[i:i + 1])[0]
            law[0] = laws[i][0]
            out[f'{k}_own_onset'].append(linear[k].force(law, d) - f)
    return {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in out.items()}


def onset_left(feats, laws, name):
    """One line: the onset ``z2`` leaves over all pokes, and what it correlates with."""
    a = np.hstack([np.ones((len(laws), 1)), feats[:, Z + Z2]])
    left = laws[:, 0] - a @ np.linalg.lstsq(a, laws[:, 0], rcond=None)[0]
    gap, near = cKDTree(feats[:, :2]).query(feats[:, :2], k=2)
    return (f'  {name} onset left by z2: std {left.std() * 1e3:.3f} mm (of '
            f'{laws[:, 0].std() * 1e3:.3f}); correlation with the curvature '
            f'{np.corrcoef(left, feats[:, 9])[0, 1]:.2f}, with the nearest poke\'s '
            f'{np.corrcoef(left, left[near[:, 1]])[0, 1]:.2f} (median '
            f'{np.median(gap[:, 1]) * 1e3:.1f} mm away)')


def main(argv=None):
    """Print one line per object and size: each column's median RMSE and its ratio to ET."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args = parser.parse_args(argv)
    columns = COLUMNS
    print('object pokes | ' + ' | '.join(columns))
    for name in args.objects:
        start = time.monotonic()
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        model = ContactGpModel(law='power')
        bend = curvature(surface.points, np.stack([c.point for c in curves]))
        height = surface.points[:, 2]
        square = (np.stack([c.point[2] for c in curves]) - np.median(height)) ** 2
        feats = np.hstack([curve_features(curves, surface), bend[:, None], square[:, None]])
        laws = np.array([model.fit_curve(c, 'power')[0] for c in curves])
        rng = np.random.default_rng(0)              # the figure's draws: sizes in order
        for size in args.sizes:
            rows = []
            for _ in range(10):
                train = rng.choice(len(curves), size=size, replace=False)
                test = np.setdiff1d(np.arange(len(curves)), train)
                rows.append(draw_errors(train, test, (surface, curves, feats, laws), model))
            med = {k: float(np.median([r[k] for r in rows])) for k in columns}
            print(f'{name} {size} | ' + ' | '.join(f'{med[k]:.3f} ({med[k] / med["et"]:.2f})'
                                                   for k in columns)
                  + f'   [{time.monotonic() - start:.0f} s]', flush=True)
        print(onset_left(feats, laws, name), flush=True)


if __name__ == '__main__':
    main()
