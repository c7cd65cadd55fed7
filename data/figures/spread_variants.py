#!/usr/bin/env python3
"""Figure 1's point-poke table for variants of how ours spreads its laws (a study, session 19).

The same draws as ``python -m pointforce_ros.lab.figures --learning-only --sizes 5 10`` (seed
0, 10 random training subsets per size from the committed 30-poke fixtures, held-out pokes
scored on their measured contact samples); each variant's median and mean RMSE over the
draws and its ratio to ET's (the figure quotes the median; the mean shows the bad draws).
None of these is the product's default; the closing note of issue 17 (session 19) quotes
this table. Variants:

- ``ours``: the default :class:`~pointforce_ros.response.ours.ContactGpModel`.
- ``independent``: no decorrelation (each parameter its own process).
- ``pick_decorrelation``: both, the one with the lower leave-one-poke-out error
  (``law_scores``) kept per fit.
- ``colour_all``: a colour linear basis on every parameter process.
- ``measured_ref_6mm``: power law, median force, ``log F`` referenced at a *measured* depth
  of 6 mm instead of 3 mm past the fitted onset (``log F_m = log F + p log((6 mm - d0) /
  s_ref)``): an earlier onset with a softer law keeps ``F_m``, so the process spreads what
  the pokes measured, as ET averages forces at equal measured depth.
- ``curve_mean_nz`` / ``curve_mean_z`` (diagnostics, not models a planner would want: no
  uncertainty, no extrapolation): the held-out force is a kernel-weighted mean of the
  training pokes' own fitted curves, weights by the surface normal's z component (0.05) or
  the height (3 mm) alone. On the dome one such scalar carries what ET finds.

Usage: python data/figures/spread_variants.py [--objects dome vest] [--sizes 5 10]
(about 40 s per object per size pair on one core; set OPENBLAS_NUM_THREADS=1).
"""

import argparse
import time

import numpy as np

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.evaluate import learning_curve
from pointforce_ros.lab.figures import load_poke_fixture
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')


def law_loo_score(model) -> float:
    """The lowest leave-one-poke-out RMSE of ``model``'s laws (0 where none was scored)."""
    laws = [v for k, v in model.law_scores.items() if '/' not in k and '+' not in k]
    return min(laws) if laws else 0.0


class PickByLoo:
    """Fit every candidate; keep the one whose ``score`` (leave-one-poke-out) is lowest."""

    def __init__(self, factories, score=law_loo_score):
        self.factories, self.score = list(factories), score

    def fit(self, curves, surface):
        """Fit each and keep one; returns ``self``."""
        best = None
        for factory in self.factories:
            model = factory().fit(curves, surface)
            score = self.score(model)
            if best is None or score < best[0]:
                best = (score, model)
        self.model = best[1]
        self.poke_ids = self.model.poke_ids
        return self

    def predict(self, features, d):
        """The kept model's force (N)."""
        return self.model.predict(features, d)


class OursWithin:
    """Ours fitted and queried inside ``within()``, a context manager that patches it."""

    def __init__(self, within):
        self.within = within

    def fit(self, curves, surface):
        """Fit ours inside the block; returns ``self``."""
        with self.within():
            self.model = ContactGpModel().fit(curves, surface)
        self.poke_ids = self.model.poke_ids
        return self

    def predict(self, features, d):
        """Ours' force (N) inside the block."""
        with self.within():
            return self.model.predict(features, d)


class PickDecorrelation(PickByLoo):
    """Fit ours with and without decorrelation; keep the lower leave-one-poke-out error."""

    def __init__(self):
        super().__init__([lambda: ContactGpModel(decorrelate=True),
                          lambda: ContactGpModel(decorrelate=False)])


class MeasuredReference(ContactGpModel):
    """Ours with ``log F`` referenced at a measured depth ``d_ref`` for the processes."""

    def __init__(self, d_ref=0.006, **kw):
        kw.setdefault('law', 'power')
        kw.setdefault('mean', 'median')
        super().__init__(**kw)
        self.d_ref = float(d_ref)

    def _shift(self, theta):
        return theta[:, 2] * np.log(np.maximum(self.d_ref - theta[:, 0], 1e-4)
                                    / self.ref_depth)

    def _condition(self, law, states, rows=None, grid=None):
        saved = self._thetas[law]
        moved = saved.copy()
        moved[:, 1] += self._shift(saved)
        self._thetas[law] = moved
        try:
            return super()._condition(law, states, rows, grid)
        finally:
            self._thetas[law] = saved

    def _param_dist(self, field, features, with_cov=True):
        mean, cov = super()._param_dist(field, features, with_cov)
        mean = mean.copy()
        mean[:, 1] -= self._shift(mean)
        return mean, cov


class CurveMean:
    """Kernel-weighted mean of the training pokes' own power-law curves over one feature."""

    def __init__(self, column, length):
        self.column, self.length = column, length

    def fit(self, curves, surface):
        """Fit each poke's own law; returns ``self``."""
        self.law = ContactGpModel(law='power')
        self.theta = np.array([self.law.fit_curve(c)[0] for c in curves])
        self.x = curve_features(curves, surface)[:, self.column]
        self.poke_ids = [c.poke_id for c in curves]
        return self

    def predict(self, features, d):
        """Weighted mean force (N) of the training curves at each row's depth."""
        gap = (np.asarray(features)[:, self.column, None] - self.x[None, :]) / self.length
        w = np.exp(-0.5 * gap ** 2) + 1e-12
        w /= w.sum(axis=1, keepdims=True)
        d = np.asarray(d, dtype=float)
        forces = np.stack([self.law.force_from_params(np.repeat(t[None], len(d), 0), d)
                           for t in self.theta], axis=1)
        return np.sum(w * forces, axis=1)


VARIANTS = {
    'ours': ContactGpModel,
    'et': EtBaseline,
    'independent': lambda: ContactGpModel(decorrelate=False),
    'pick_decorrelation': PickDecorrelation,
    'colour_all': lambda: ContactGpModel(bases=('colour', 'colour', 'colour', 'none')),
    'measured_ref_6mm': MeasuredReference,
    'curve_mean_nz': lambda: CurveMean(8, 0.05),
    'curve_mean_z': lambda: CurveMean(2, 0.003),
}


def print_table(variants, description, argv=None):
    """Print two lines per object: each variant's median and mean RMSE (N), ratio to ET."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args = parser.parse_args(argv)
    print('object | ' + ' | '.join(f'{name} @{s}' for name in variants for s in args.sizes))
    for name in args.objects:
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        start = time.monotonic()
        rows = learning_curve(curves, surface, variants, sizes=args.sizes, repeats=10, seed=0)
        for stat in ('median', 'mean'):
            val = {(r['model'], r['size']): r[stat] for r in rows}
            cells = [f"{val[(v, s)]:.3f} ({val[(v, s)] / val[('et', s)]:.2f})"
                     for v in variants for s in args.sizes]
            print(f'{name} {stat} | ' + ' | '.join(cells)
                  + f'   [{time.monotonic() - start:.0f} s]', flush=True)


def main():
    """The spreading variants' table."""
    print_table(VARIANTS, __doc__.splitlines()[0])


if __name__ == '__main__':
    main()
