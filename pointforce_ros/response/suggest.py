"""Where to poke next: the surface points the model is least sure about, spread apart.

:func:`suggest_pokes` scores every candidate surface point by the model's predictive standard
deviation of force at a reference depth and picks greedily: the most uncertain point, then the
most uncertain one farther than ``exclude_radius`` from every pick and every earlier poke, and
so on. :func:`active_vs_random_curve` measures whether that beats poking at random (held-out
RMSE against the number of pokes) and :func:`plot_active_vs_random` draws it.
"""

from typing import Callable, Dict, NamedTuple, Optional, Sequence

import numpy as np

from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.evaluate import rmse
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
    order_key = score + 1e-12 * finite_near
    picks, stds = [], []
    for _ in range(int(count)):
        if not np.any(allowed):
            break
        k = int(np.argmax(np.where(allowed, order_key, -np.inf)))
        picks.append(int(cand[k]))
        stds.append(float(score[k]))
        allowed &= np.linalg.norm(pts - pts[k], axis=1) > exclude_radius
        allowed[k] = False
    return Suggestion(np.array(picks, dtype=np.int64), np.array(stds, dtype=float))


def active_vs_random_curve(curves: Sequence[PokeCurve], surface: Surface,
                           model_factory: Callable, *, start: int = 2, max_pokes: int = 12,
                           test_fraction: float = 0.3, repeats: int = 5, seed: int = 0,
                           exclude_radius: float = 0.0, region: str = 'contact') -> Dict:
    """Held-out RMSE against the number of pokes, choosing pokes actively or at random.

    The pool ``curves`` stands for the locations a cell could poke (the paper pokes a grid).
    Each repeat splits it into a fixed test set (``test_fraction``, never trained on) and
    candidates; both strategies start from the same ``start`` random candidates, then add one
    poke at a time (``partial_fit``): *active* takes :func:`suggest_pokes` restricted to the
    remaining candidates, *random* a random remaining candidate.

    Returns:
        ``{'sizes': [...], 'active': {'median', 'q25', 'q75', 'rmse'}, 'random': {...}}``
        with RMSE in newtons (lists over sizes; ``rmse`` is repeats x sizes).

    Raises:
        InvalidInput: a pool too small for the split, or bad arguments.

    """
    curves = list(curves)
    n_test = int(round(test_fraction * len(curves)))
    if not (0 < test_fraction < 1) or n_test < 1 or len(curves) - n_test < max_pokes:
        raise InvalidInput(f'active_vs_random_curve: {len(curves)} curves cannot give '
                           f'{max_pokes} candidates plus a test set of {test_fraction:.0%}')
    if not 1 <= start <= max_pokes:
        raise InvalidInput('active_vs_random_curve: need 1 <= start <= max_pokes')
    pts = np.stack([c.point for c in curves])
    d2 = (pts * pts).sum(1)[:, None] + (surface.points ** 2).sum(1)[None] \
        - 2.0 * pts @ surface.points.T
    on_surface = np.argmin(d2, axis=1)
    sizes = list(range(start, max_pokes + 1))
    rng = np.random.default_rng(seed)
    out = {'active': [], 'random': []}
    for _ in range(repeats):
        perm = rng.permutation(len(curves))
        test = [curves[i] for i in perm[:n_test]]
        pool = list(perm[n_test:])
        first = list(rng.choice(pool, size=start, replace=False))
        for strategy in ('active', 'random'):
            chosen = list(first)
            errs = []
            model = model_factory().fit([curves[i] for i in chosen], surface)
            while True:
                errs.append(rmse(model, test, surface, region))
                if len(chosen) == max_pokes:
                    break
                remaining = [i for i in pool if i not in chosen]
                if strategy == 'random':
                    chosen.append(int(rng.choice(remaining)))
                    model.partial_fit(curves[chosen[-1]], surface)
                    continue
                pick = suggest_pokes(model, surface, 1, exclude_radius,
                                     candidates=on_surface[remaining]).indices
                if len(pick) == 0:
                    pick = suggest_pokes(model, surface, 1, 0.0,
                                         candidates=on_surface[remaining]).indices
                by_index = {int(on_surface[i]): i for i in remaining}
                chosen.append(int(by_index[int(pick[0])]))
                model.partial_fit(curves[chosen[-1]], surface)
            out[strategy].append(errs)
    result = {'sizes': sizes, 'test_fraction': test_fraction, 'repeats': repeats}
    for strategy, runs in out.items():
        e = np.array(runs)
        result[strategy] = {'median': np.median(e, axis=0).tolist(),
                            'q25': np.percentile(e, 25, axis=0).tolist(),
                            'q75': np.percentile(e, 75, axis=0).tolist(), 'rmse': e.tolist()}
    return result


def plot_active_vs_random(result: Dict, path, title: str = 'Active vs random poking') -> None:
    """Write a PNG of :func:`active_vs_random_curve`'s result (median and quartile band)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5.0, 3.6), dpi=120)
    x = result['sizes']
    for strategy in ('active', 'random'):
        r = result[strategy]
        ax.plot(x, r['median'], marker='o', label=strategy)
        ax.fill_between(x, r['q25'], r['q75'], alpha=0.2)
    ax.set_xlabel('pokes')
    ax.set_ylabel('held-out RMSE [N]')
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
