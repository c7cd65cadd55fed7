#!/usr/bin/env python3
"""Figure 1's point-poke table for ours combined with ET (a study, session 20).

Same draws as ``python -m pointforce_ros.lab.figures --learning-only --sizes 5 10`` and
``data/figures/spread_variants.py`` (seed 0, 10 random training subsets per size from the
committed 30-poke fixtures, held-out pokes scored on their measured contact samples). Asks
whether what ET finds and ours misses can be added to ours, or the two averaged, on held-out
data. Both combinations learn from *leave-one-poke-out* predictions of the training pokes (an
in-sample prediction of ours reproduces each training poke's own fitted law, so its residual
says nothing about a new poke). Variants:

- ``ours``, ``et``: the default :class:`~pointforce_ros.response.ours.ContactGpModel` and the
  seed's Extra Trees baseline.
- ``et_residual``: ours times ``exp(r)``, ``r`` an Extra Trees regression on ``[p, rgb, n, d]``
  of ours' leave-one-poke-out log residual ``log(f / f_ours)`` (clipped to +-1.5; depth capped
  at the deepest training sample); ``et_residual_half`` applies ``r / 2``.
- ``loo_blend``: ``w f_ours + (1 - w) f_ET``, ``w`` on a 0.05 grid minimising both models'
  leave-one-poke-out squared error over the training samples. Whatever it reaches bounds
  what averaging the two can do.

None of these is the product's default; the closing note of issue 17 (session 20) quotes
this table. Each fit of a combination refits ours (and ET) once per training poke: about 4-5
minutes per object on one core (set OPENBLAS_NUM_THREADS=1).

Usage: python data/figures/combine_variants.py [--objects dome vest] [--sizes 5 10]
"""

import numpy as np
from sklearn.ensemble import ExtraTreesRegressor
from spread_variants import print_table   # this script's folder is on sys.path

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel

FLOOR = 0.05
"""Newtons: samples below it (no contact yet) are left out of the combinations' fits."""


def loo_predictions(curves, surface, factory):
    """Features (n, 9) and, per poke, the force a model fitted on the other pokes predicts."""
    feats = curve_features(curves, surface)
    out = []
    for k, c in enumerate(curves):
        model = factory().fit([o for j, o in enumerate(curves) if j != k], surface)
        out.append(np.asarray(model.predict(np.repeat(feats[k][None], len(c.d), 0), c.d), float))
    return feats, out


class EtResidual:
    """Ours corrected by Extra Trees on its leave-one-poke-out log residuals."""

    def __init__(self, shrink=1.0):
        self.shrink = float(shrink)

    def fit(self, curves, surface):
        """Fit ours on all pokes and the residual trees on its held-out residuals; ``self``."""
        self.ours = ContactGpModel().fit(curves, surface)
        self.poke_ids = self.ours.poke_ids
        feats, preds = loo_predictions(curves, surface, ContactGpModel)
        xs, ys = [], []
        for x, c, p in zip(feats, curves, preds):
            keep = (c.f > FLOOR) & (p > 1e-3)
            xs.append(np.hstack([np.repeat(x[None], keep.sum(), 0), c.d[keep, None]]))
            ys.append(np.log(c.f[keep] / p[keep]))
        self.trees = ExtraTreesRegressor(n_estimators=100, min_samples_leaf=5, random_state=0)
        self.trees.fit(np.vstack(xs), np.concatenate(ys))
        self.d_max = max(float(c.d.max()) for c in curves)
        return self

    def predict(self, features, d):
        """Ours' force (N) times the exponentiated residual the trees predict."""
        d = np.asarray(d, dtype=float)
        x = np.hstack([np.asarray(features), np.minimum(d, self.d_max)[:, None]])
        r = np.clip(self.trees.predict(x), -1.5, 1.5)
        return np.asarray(self.ours.predict(features, d), float) * np.exp(self.shrink * r)


class LooBlend:
    """``w`` ours + ``(1 - w)`` ET, ``w`` from leave-one-poke-out squared error."""

    def fit(self, curves, surface):
        """Fit both on all pokes and pick ``w``; returns ``self``."""
        self.ours = ContactGpModel().fit(curves, surface)
        self.et = EtBaseline().fit(curves, surface)
        self.poke_ids = self.ours.poke_ids
        _, ours = loo_predictions(curves, surface, ContactGpModel)
        _, et = loo_predictions(curves, surface, EtBaseline)
        a, b = np.concatenate(ours), np.concatenate(et)
        f = np.concatenate([c.f for c in curves])
        keep = f > FLOOR
        grid = np.linspace(0.0, 1.0, 21)
        errors = [np.mean((w * a[keep] + (1 - w) * b[keep] - f[keep]) ** 2) for w in grid]
        self.w = float(grid[int(np.argmin(errors))])
        return self

    def predict(self, features, d):
        """The blended force (N)."""
        return self.w * np.asarray(self.ours.predict(features, d)) \
            + (1.0 - self.w) * np.asarray(self.et.predict(features, d))


VARIANTS = {
    'ours': ContactGpModel,
    'et': EtBaseline,
    'et_residual': EtResidual,
    'et_residual_half': lambda: EtResidual(0.5),
    'loo_blend': LooBlend,
}


def main():
    """The combinations' table (``spread_variants.print_table``)."""
    print_table(VARIANTS, __doc__.splitlines()[0])


if __name__ == '__main__':
    main()
