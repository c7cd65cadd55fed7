"""Where to poke next: the surface points the model is least sure about, spread apart.

:func:`suggest_pokes` scores every candidate surface point by the model's predictive standard
deviation of force at a reference depth and picks greedily: the most uncertain point, then the
most uncertain one farther than ``exclude_radius`` from every pick and every earlier poke, and
so on. Whether that beats poking at random is measured in
:mod:`pointforce_ros.lab.active`.
"""

from typing import NamedTuple, Optional, Sequence

import numpy as np

from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.types import Surface


def reference_depth(model) -> float:
    """Depth (m) at which uncertainty is compared: the model's own choice when it has one.

    ``ContactGpModel.reference_depth()`` (latest trained onset + its reference contact depth),
    otherwise 80 % of the deepest trained displacement (``d_top``).

    Raises:
        ModelNotReady: the model is not fitted.

    """
    if hasattr(model, 'reference_depth'):
        return float(model.reference_depth())
    d_top = getattr(model, 'd_top', None)
    if d_top is None:
        raise ModelNotReady('suggest: the model is not fitted')
    return 0.8 * float(d_top)


class Suggestion(NamedTuple):
    """Suggested poke locations; unpacks as ``indices, std = suggest_pokes(...)``."""

    indices: np.ndarray
    """(k,) int64 surface indices, most uncertain first."""
    std: np.ndarray
    """(k,) the score of each: predictive std of force at the reference depth(s), newtons."""


def suggest_pokes(model, surface: Surface, count: int, exclude_radius: float, *,
                  depth=None, candidates: Optional[Sequence[int]] = None) -> Suggestion:
    """Pick up to ``count`` surface indices to poke next.

    Args:
        model: a fitted model with ``predict_std`` and ``poke_points``.
        surface: the equilibrium surface (N points).
        count: how many points to suggest (>= 1).
        exclude_radius: minimum distance (m) between suggestions and from earlier pokes.
        depth: depth(s) in metres at which the std is taken; an array scores the RMS std over
            them; ``None`` uses :func:`reference_depth`.
        candidates: surface indices allowed (e.g. reachable ones); ``None`` = all.

    Returns:
        :class:`Suggestion` ``(indices, std)``: (k,) int64 surface indices, most uncertain
        first, and their std (N); ``k < count`` when the exclusion radius leaves no more
        candidates.

    Raises:
        InvalidInput: ``count < 1``, negative radius, out-of-range candidates.
        ModelNotReady: the model is not fitted.

    """
    if int(count) < 1:
        raise InvalidInput(f'suggest_pokes: count must be >= 1, got {count}')
    if not (np.isfinite(exclude_radius) and exclude_radius >= 0):
        raise InvalidInput(f'suggest_pokes: exclude_radius must be >= 0 m, got {exclude_radius}')
    n = len(surface)
    cand = np.arange(n) if candidates is None else np.unique(np.asarray(candidates, np.int64))
    if len(cand) and (cand.min() < 0 or cand.max() >= n):
        raise InvalidInput(f'suggest_pokes: candidate indices must lie in 0..{n - 1}')
    depths = np.atleast_1d(reference_depth(model) if depth is None
                           else np.asarray(depth, dtype=float))
    feats = surface.features[cand]
    var = np.zeros(len(cand))
    for dd in depths:
        std = model.predict_std(feats, float(dd))
        var += np.asarray(std, dtype=float) ** 2
    score = np.sqrt(var / len(depths))
    pts = surface.points[cand]
    # Distance to the nearest earlier poke breaks ties (models with flat uncertainty).
    done = np.asarray(getattr(model, 'poke_points', np.zeros((0, 3))), dtype=float)
    nearest = np.full(len(cand), np.inf)
    if len(done):
        for p in done:
            nearest = np.minimum(nearest, np.linalg.norm(pts - p, axis=1))
    allowed = nearest > exclude_radius if exclude_radius > 0 else np.ones(len(cand), bool)
    finite_near = np.where(np.isfinite(nearest), nearest, 0.0)
    return greedy_picks(pts, cand, score + 1e-12 * finite_near, score, allowed, int(count),
                        exclude_radius)


def greedy_picks(points: np.ndarray, indices: np.ndarray, order: np.ndarray, std: np.ndarray,
                 allowed: np.ndarray, count: int, exclude_radius: float) -> Suggestion:
    """Pick up to ``count`` candidates by descending ``order`` among ``allowed``.

    Each pick lies at least ``exclude_radius`` from the picks before it; ``indices`` and
    ``std`` are reported per pick.
    """
    allowed = allowed.copy()
    picks, stds = [], []
    for _ in range(count):
        if not np.any(allowed):
            break
        k = int(np.argmax(np.where(allowed, order, -np.inf)))
        picks.append(int(indices[k]))
        stds.append(float(std[k]))
        allowed &= np.linalg.norm(points - points[k], axis=1) > exclude_radius
        allowed[k] = False
    return Suggestion(np.array(picks, dtype=np.int64), np.array(stds, dtype=float))
