"""Law parameters spread over the features by Extra Trees: ``ContactGpModel(spread='trees')``.

Ours fits a contact law to each poke (``response/ours.py``, point 1) and spreads the laws'
parameters over the surface. The default spreads them with Gaussian processes over position,
colour and normal. This module spreads them with Extra Trees over the same nine features
instead: a forest regresses the standardised parameters ``(d0, log F, p[, q])`` of the
training pokes on their features, and a point's law is the forest's mean. A tree's leaf holds
training pokes, so a tree predicts one of their laws or their mean: the forest never leaves
the laws the pokes showed (nothing to clamp), and it finds the feature that tells the laws
apart (the dome's height, thin_layer's colour) where a process over position needs many pokes.

Measured (``data/figures/tree_laws.py``, record ``tree_laws.log``; held-out pokes only): on
figure 1's draws the trees score 1.02-1.18 of the seed's Extra Trees where the processes score
1.00-1.77, on the step tables of another generator 0.98-1.34 where the processes score
0.97-1.74, and their spread is the better calibrated (68-94 % of held-out samples inside the
nominal 90 % against 42-77 %). They lose where the field is smooth (the unit tests' synthetic
dome: 1.30 of ET at 5 pokes against 0.82) and under wide probes whose footprint spans pokes
(figure 2: lamb 1.06 against 0.81 N, plush 0.73 against 0.63 N). The product's point model
takes the trees and the processes in equal parts (``spread='mix'``, ``response/ours.py``),
better held out than the processes on both figures (session 47).

- **Relevance.** The number of features a split may draw from (``max_features``: 1, 3 or all
  nine) is chosen by the leave-one-poke-out force error over the training pokes (K folds of
  pokes past :data:`MAX_FOLDS`); with fewer than :data:`CHOOSE_MIN_POKES` pokes all nine.
- **Spread.** The parameters' covariance at a point is the covariance of the trees'
  predictions there (which training laws apply) plus a per-parameter scatter ``s^2`` of a new
  poke about them, chosen so that the held-out pokes' squared residuals over their predicted
  variance average one (with :data:`CALIBRATION_PRIOR` pseudo-pokes at one). With one poke
  the scatter is the model's prior scales.
- **Deterministic.** The forest is seeded; a saved model stores ``max_features`` and the scatter
  and refits the forest on load from the stored parameters (the same arrays, the same trees).
"""

from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
from sklearn.ensemble import ExtraTreesRegressor

from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.common import SCALE_FLOOR

TREE_COUNT = 100
"""Trees in a forest (one forest of 5-30 pokes fits in about a tenth of a second; a model's
fit makes about 30 of them for the held-out choice, about 4 s)."""
MAX_FEATURES = (1, 3, None)
"""``max_features`` offered to the held-out choice (``None``: all nine features)."""
CHOOSE_MIN_POKES = 4
"""Fewest pokes with which ``max_features`` is chosen by leave-one-poke-out."""
MAX_FOLDS = 10
"""Most folds of the held-out choice (leave-one-poke-out up to this many pokes)."""
CALIBRATION_PRIOR = 2.0
"""Pseudo-pokes of a calibrated spread (z^2 = 1) in the scatter's calibration."""
SEED = 0
CHUNK = 4096
"""Points whose parameters every tree predicts at once (a few MB)."""


@dataclass(frozen=True)
class TreeState:
    """What a fitted spread keeps: ``max_features`` (None = all) and the scatter (P,)."""

    max_features: Optional[int]
    scatter: Tuple[float, ...]

    def to_dict(self) -> dict:
        """JSON-serialisable form."""
        return {'max_features': self.max_features, 'scatter': [float(s) for s in self.scatter]}

    @classmethod
    def from_dict(cls, data) -> 'TreeState':
        """Rebuild a state saved by :meth:`to_dict`.

        Raises:
            InvalidInput: missing fields, an unknown ``max_features`` or a bad scatter.

        """
        try:
            mf = data['max_features']
            scatter = tuple(float(s) for s in data['scatter'])
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f'TreeState.from_dict: malformed tree state: {exc}') from exc
        if mf not in MAX_FEATURES or not all(np.isfinite(s) and s >= 0 for s in scatter):
            raise InvalidInput(f'TreeState.from_dict: max_features must be one of '
                               f'{MAX_FEATURES} and the scatter finite and >= 0, got {data!r}')
        return cls(mf, scatter)


class Forest:
    """A seeded forest of the standardised parameters on the features."""

    def __init__(self, features: np.ndarray, theta: np.ndarray, max_features: Optional[int]):
        self.mu = theta.mean(axis=0)
        self.sd = np.maximum(theta.std(axis=0), SCALE_FLOOR[:theta.shape[1]])
        self.trees = ExtraTreesRegressor(n_estimators=TREE_COUNT, max_features=max_features,
                                         random_state=SEED, n_jobs=1).fit(
            features, (theta - self.mu) / self.sd)

    def per_tree(self, features: np.ndarray) -> np.ndarray:
        """(T, M, P) each tree's parameters at ``features``."""
        out = np.stack([t.predict(features) for t in self.trees.estimators_])
        return out.reshape(len(self.trees.estimators_), len(features), -1) * self.sd + self.mu

    def dist(self, features: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Mean (M, P) and covariance (M, P, P) of the trees' parameters.

        In chunks of :data:`CHUNK` points: every tree's parameters at once for a whole
        surface (40 000 points) would take over 100 MB.
        """
        k = len(self.mu)
        mean, cov = np.zeros((len(features), k)), np.zeros((len(features), k, k))
        for lo in range(0, len(features), CHUNK):
            per = self.per_tree(features[lo:lo + CHUNK])
            mean[lo:lo + CHUNK] = per.mean(axis=0)
            dev = per - mean[lo:lo + CHUNK]
            cov[lo:lo + CHUNK] = np.einsum('tmi,tmj->mij', dev, dev) / len(per)
        return mean, cov


def _folds(n: int) -> List[np.ndarray]:
    return [np.arange(n)[k::min(n, MAX_FOLDS)] for k in range(min(n, MAX_FOLDS))]


def held_out_dist(features: np.ndarray, theta: np.ndarray, max_features: Optional[int]
                  ) -> Tuple[np.ndarray, np.ndarray]:
    """Out-of-fold mean (n, P) and tree covariance (n, P, P) of each training poke's law."""
    n, k = theta.shape
    mean, cov = np.zeros((n, k)), np.zeros((n, k, k))
    for fold in _folds(n):
        keep = np.setdiff1d(np.arange(n), fold)
        mean[fold], cov[fold] = Forest(features[keep], theta[keep], max_features).dist(
            features[fold])
    return mean, cov


def calibrated_scatter(residual: np.ndarray, variance: np.ndarray,
                       excess_of: Optional[Callable[[np.ndarray], float]] = None) -> np.ndarray:
    """(P,) scatter ``s`` per parameter: held-out ``r^2 / (v + s^2)`` averages one.

    ``residual`` and ``variance`` (n, P): held-out residuals and the trees' variances there.
    ``CALIBRATION_PRIOR`` pseudo-pokes sit at ``z^2 = 1``; ``s = 0`` where the trees' own
    variance already covers the residuals. ``excess_of(z2)``: another statistic of the (n,)
    ``z^2`` to bring to zero (falling as ``s`` grows; a study tried their median,
    ``data/figures/mix_robust_scatter.py``).
    """
    n = len(residual)
    if excess_of is None:
        def excess_of(z2):
            return (np.sum(z2) + CALIBRATION_PRIOR) / (n + CALIBRATION_PRIOR) - 1.0
    out = np.zeros(residual.shape[1])
    for j in range(residual.shape[1]):
        r2, v = residual[:, j] ** 2, variance[:, j]

        def excess(s2):
            return excess_of(r2 / np.maximum(v + s2, 1e-300))
        if excess(0.0) <= 0.0:
            continue
        lo, hi = 0.0, max(float(np.max(r2)), 1e-30)
        while excess(hi) > 0.0:
            hi *= 4.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if excess(mid) > 0.0 else (lo, mid)
        out[j] = np.sqrt(hi)
    return out


Score = Callable[[np.ndarray, np.ndarray], float]
"""``score(mean, cov) -> RMSE`` of held-out parameter distributions (:class:`TreeSpread`)."""


class TreeSpread:
    """Parameters ``theta`` (n, P) of the training pokes spread over their ``features`` (n, 9).

    Args:
        features, theta: the training pokes' features and law parameters.
        state: a saved :class:`TreeState` (no choice, no calibration), or None to choose.
        score: ``score(mean, cov) -> RMSE`` of held-out parameter distributions (n, P),
            (n, P, P) against the training pokes' own samples; needed when ``state`` is None
            and there are at least :data:`CHOOSE_MIN_POKES` pokes.
        prior: (P,) or longer scatter used with one poke (ours' prior scales).
    """

    def __init__(self, features: np.ndarray, theta: np.ndarray,
                 state: Optional[TreeState], score: Optional[Score],
                 prior: Sequence[float]):
        features = np.asarray(features, dtype=float)
        theta = np.asarray(theta, dtype=float)
        n, k = theta.shape
        self.scores: Dict[str, float] = {}
        self._held_out: Optional[Tuple[np.ndarray, np.ndarray]] = None
        if state is None:
            choice = None
            if n >= CHOOSE_MIN_POKES and score is not None:
                outs = {mf: held_out_dist(features, theta, mf) for mf in MAX_FEATURES}
                self.scores = {str(mf): float(score(*outs[mf])) for mf in MAX_FEATURES}
                choice = min(MAX_FEATURES, key=lambda mf: self.scores[str(mf)])
                self._held_out = outs[choice]
            if n >= 2:
                if self._held_out is None:
                    self._held_out = held_out_dist(features, theta, choice)
                mean, cov = self._held_out
                scatter = calibrated_scatter(theta - mean,
                                             np.diagonal(cov, axis1=1, axis2=2))
            else:
                scatter = np.asarray(prior, dtype=float)[:k]
            state = TreeState(choice, tuple(float(s) for s in scatter))
        if len(state.scatter) != k:
            raise InvalidInput(f'TreeSpread: the scatter has {len(state.scatter)} values for '
                               f'{k} parameters')
        self.state = state
        self.forest = Forest(features, theta, state.max_features)
        self._features, self._theta = features, theta

    def dist(self, features: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Mean (M, P) and covariance (M, P, P) of ``theta`` at ``features``."""
        mean, cov = self.forest.dist(features)
        return mean, cov + np.diag(np.square(self.state.scatter))

    def held_out(self) -> Tuple[np.ndarray, np.ndarray]:
        """Out-of-fold mean (n, P) and covariance (n, P, P) of each training poke's law."""
        if self._held_out is None:
            self._held_out = held_out_dist(self._features, self._theta,
                                           self.state.max_features)
        mean, cov = self._held_out
        return mean, cov + np.diag(np.square(self.state.scatter))
