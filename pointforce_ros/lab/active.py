"""Active against random poking: does the suggestion need fewer pokes (seed 000, Fig. 4)."""

from typing import Callable, Dict, Sequence

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.scoring import rmse
from pointforce_ros.response.suggest import suggest_pokes
from pointforce_ros.types import Surface


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
