"""Candidate successor of ours: a shape-free monotone curve per poke, spread by one GP.

:class:`~pointforce_ros.response.ours.ContactGpModel` fits ``F ((d - d0)_+ / s_ref) ** p`` to
each poke. On the simulated cell's dome many curves soften with depth; the law cannot follow
them (its exponent sits on the lower bound) and its three parameters trade off against each
other, so interpolating them separately over the surface mixes inconsistent sets. Here:

1. **Onset** ``d0`` of each poke is the curve's detected onset (:func:`~pointforce_ros.pokes.
   curves.extract_curve`: fitted on the early loading phase only), spread over the surface by
   a GP (``rigid`` basis, as in ours).
2. **Shape**: the loading curve against ``s = d - d0`` is made monotone (isotonic regression)
   and read at fixed knots ``s_k`` (0.25-20 mm); beyond the deepest sample it continues as a
   power law with the exponent of the curve's last 40 %. The targets are
   ``y_k = log(f(s_k) + EPS)`` (``EPS`` = 0.05 N keeps the near-zero start from dominating).
3. **One GP for all knots**: hyperparameters are chosen once (on the knot-averaged ``y``) and
   every knot is conditioned with them; the prediction is made monotone in ``s`` again
   (running maximum) and interpolated linearly between knots, zero at and before the onset.

Status: evaluated in :mod:`pointforce_ros.lab.figures` beside ours and the baselines; it predicts
but does not bake or serialise yet, so the learner still uses ``ContactGpModel``.
"""

import time
from typing import Dict, List, Sequence

import numpy as np
from sklearn.isotonic import IsotonicRegression

from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.blas import single_threaded_blas
from pointforce_ros.response.common import (check_curves, check_query, curve_features,
                                            DEFAULT_MAX_SURFACE_DISTANCE)
from pointforce_ros.response.gp import FeatureFrame, FeatureGp, GpGrid, GpState
from pointforce_ros.types import Surface

KNOTS = np.array([0.25, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 14.0, 17.0,
                  20.0]) * 1e-3
"""Knots ``s_k`` of the curve, metres past the onset."""

EPS = 0.05
"""Offset of the log-force targets, newtons."""


MIN_PAST_ONSET = 3
"""Fewest samples past the contact onset a curve needs (a step poke may have only a few)."""


def curve_knots(curve: PokeCurve, knots: np.ndarray = KNOTS,
                min_past_onset: int = MIN_PAST_ONSET) -> np.ndarray:
    """``log(f(s_k) + EPS)`` (K,) of one loading curve (monotone fit, power-law tail).

    The tail exponent is fitted on the samples of the curve's last 40 % that carry more than
    2 % of its deepest force (at least 3; else 1.5): relative, so step data with a few samples
    and a soft region's small forces get a fitted tail too.

    Raises:
        InvalidInput: fewer than ``min_past_onset`` samples past the onset.

    """
    s = curve.d - curve.onset_d
    keep = s > 0
    if int(keep.sum()) < min_past_onset:
        raise InvalidInput(f'poke {curve.poke_id}: {int(keep.sum())} samples past the contact '
                           f'onset, fewer than {min_past_onset}')
    s, f = s[keep], curve.f[keep]
    iso = IsotonicRegression(increasing=True, out_of_bounds='clip').fit(s, f)
    s_max = float(s.max())
    inside = knots <= s_max
    out = np.empty(len(knots))
    out[inside] = iso.predict(knots[inside])
    tail = s > 0.6 * s_max
    f_tail = iso.predict(s[tail])
    ok = f_tail > 0.02 * max(float(f_tail.max()), 1e-12)
    exponent = 1.5
    if int(ok.sum()) >= 3 and np.ptp(np.log(s[tail][ok])) > 0:
        exponent = float(np.polyfit(np.log(s[tail][ok]), np.log(f_tail[ok]), 1)[0])
    exponent = float(np.clip(exponent, 1.0, 4.0))
    f_end = float(iso.predict([s_max])[0])
    out[~inside] = f_end * (knots[~inside] / s_max) ** exponent
    return np.log(np.maximum(out, 0.0) + EPS)


class ShapeFreeGpModel:
    """Monotone shape-free curve per poke + one GP over the surface (module docstring).

    Args:
        max_surface_distance: farthest a poke may be from the surface, metres.
        onset_prior: prior standard deviation of the onset about its mean, metres.
        shape_prior: prior standard deviation of the log-force targets about their mean.
        grid: GP hyperparameter grid.
        min_past_onset: fewest samples past the onset a curve needs; a curve with fewer is
            skipped with its reason in :attr:`skipped` (a fit or a learning curve goes on).

    """

    kind = 'pointforce.response.shape_free_gp'

    def __init__(self, max_surface_distance: float = DEFAULT_MAX_SURFACE_DISTANCE,
                 onset_prior: float = 0.003, shape_prior: float = 1.0, grid=None,
                 min_past_onset: int = MIN_PAST_ONSET):
        self.max_surface_distance = float(max_surface_distance)
        self.min_past_onset = int(min_past_onset)
        self.skipped: Dict[str, str] = {}
        self.onset_prior = float(onset_prior)
        self.shape_prior = float(shape_prior)
        self.grid = grid or GpGrid()
        self._ids: List[str] = []
        self._onset_gp = None
        self._knot_gps: List[FeatureGp] = []
        self.fit_seconds = 0.0

    @property
    def poke_ids(self) -> List[str]:
        """Ids of the training pokes, in training order."""
        return list(self._ids)

    def fit(self, curves: Sequence[PokeCurve], surface: Surface) -> 'ShapeFreeGpModel':
        """Fit from scratch on ``curves`` poked on ``surface``; returns ``self``.

        A curve with too few samples past its onset is skipped (:attr:`skipped` says which
        and why).

        Raises:
            InvalidInput: no curves, duplicate ids, pokes off the surface, or no usable curve.

        """
        start = time.perf_counter()
        curves = check_curves(curves, surface)
        self.skipped = {}
        usable, rows = [], []
        for curve in curves:
            try:
                rows.append(curve_knots(curve, min_past_onset=self.min_past_onset))
            except InvalidInput as exc:
                self.skipped[curve.poke_id] = str(exc)
                continue
            usable.append(curve)
        if not usable:
            raise InvalidInput('ShapeFreeGpModel.fit: no usable curve ('
                               + '; '.join(list(self.skipped.values())[:3]) + ')')
        curves = usable
        x = curve_features(curves, surface, self.max_surface_distance)
        y = np.array(rows)                                              # (n, K)
        onsets = np.array([c.onset_d for c in curves])
        frame = FeatureFrame.of_surface(surface.points, surface.colors)
        with single_threaded_blas():
            self._onset_gp = FeatureGp(frame, self.onset_prior, basis='rigid', grid=self.grid)
            self._onset_gp.fit(x, onsets)
            shared = FeatureGp(frame, self.shape_prior, grid=self.grid)
            state = shared.fit(x, y.mean(axis=1))
            self._knot_gps = []
            for k in range(y.shape[1]):
                beta, s2 = shared.gls_mean_scale(y[:, k])
                gp = FeatureGp(frame, self.shape_prior, grid=self.grid)
                gp.condition(x, y[:, k], GpState(state.lp, state.lc, state.ln, state.tau,
                                                 state.nugget, s2, beta))
                self._knot_gps.append(gp)
        self._ids = [c.poke_id for c in curves]
        self.fit_seconds = time.perf_counter() - start
        return self

    def predict(self, features: np.ndarray, d) -> np.ndarray:
        """Mean force (M,), newtons, at ``features`` (M, 9) and depths ``d`` (M,) metres.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        if self._onset_gp is None:
            raise ModelNotReady('ShapeFreeGpModel: no pokes yet; fit the model first')
        features, d = check_query(features, d)
        sq = {}
        with single_threaded_blas():
            onset = self._onset_gp.predict(features)
            y = np.stack([gp.predict(features, sq=sq) for gp in self._knot_gps], axis=1)
        force = np.maximum(np.exp(np.maximum.accumulate(y, axis=1)) - EPS, 0.0)   # (M, K)
        knots = np.concatenate([[0.0], KNOTS])
        table = np.hstack([np.zeros((len(d), 1)), force])
        s = d - onset
        j = np.clip(np.searchsorted(knots, s) - 1, 0, len(knots) - 2)
        w = (s - knots[j]) / (knots[j + 1] - knots[j])
        rows = np.arange(len(s))
        out = table[rows, j] * (1.0 - w) + table[rows, j + 1] * w
        beyond = s > knots[-1]
        slope = (table[:, -1] - table[:, -2]) / (knots[-1] - knots[-2])
        out[beyond] = table[beyond, -1] + slope[beyond] * (s[beyond] - knots[-1])
        out[s <= 0] = 0.0
        return out
