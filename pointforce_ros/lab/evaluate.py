"""Held-out evaluation of force-response models: learning curves (seed 000, Fig. 3a).

The protocol of the paper: train on random subsets of the poked locations, test on the *other*
locations, repeat over subsets and report the error against the number of training pokes. A
model is never scored on a poke it was trained on.

Error: root-mean-square of ``predict - f`` over the held-out samples in the ``contact`` region
(``d >= onset_d - 0.5 mm`` of the held-out curve, the default: the long force-free approach
would otherwise dilute the error) or over ``all`` loading samples.
"""

from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.common import curve_features
from pointforce_ros.types import Surface
from pointforce_ros.lab.baseline import AutoEtBaseline, EtBaseline
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.lab.active import active_vs_random_curve, plot_active_vs_random
from pointforce_ros.response.scoring import rms, rmse, sample_errors


def learning_curve(curves: Sequence[PokeCurve], surface: Surface,
                   model_factory: Union[Callable, Mapping[str, Callable]],
                   sizes: Sequence[int] = (2, 3, 5, 10, 20), repeats: int = 10, seed: int = 0,
                   region: str = 'contact', truth: Optional[Mapping[str, Tuple]] = None
                   ) -> List[Dict]:
    """Held-out RMSE against the number of training pokes.

    Args:
        curves: every poked location's curve (the pool).
        surface: equilibrium surface the pokes were made on.
        model_factory: callable returning a fresh model, or ``{name: callable}`` to compare
            several models on the *same* training subsets.
        sizes: training-set sizes; sizes leaving no held-out poke are skipped.
        repeats: random subsets per size.
        seed: seed of the subset draws.
        region: ``contact`` or ``all`` (see the module docstring).
        truth: optional ``{poke_id: (d (K,), f (K,))}``: true forces at the poked points, also
            at depths the pokes did not reach (a simulated cell knows them); each held-out
            poke is then also scored against them.

    Returns:
        One row per (model, size): ``model``, ``size``, ``median``, ``q25``, ``q75``, ``mean``
        (RMSE in newtons over the repeats), ``rmse`` (the list), ``fit_s`` (median fit time);
        with ``truth`` also ``truth_median`` and ``truth_rmse`` (the list).

    Raises:
        InvalidInput: fewer than 2 curves, ``repeats < 1``, an unknown region, or ``truth``
            without a poke of ``curves``.

    """
    curves = list(curves)
    if len(curves) < 2:
        raise InvalidInput('learning_curve: need at least 2 curves (one to train, one to test)')
    if repeats < 1:
        raise InvalidInput('learning_curve: repeats must be >= 1')
    factories = dict(model_factory) if isinstance(model_factory, Mapping) \
        else {'model': model_factory}
    rng = np.random.default_rng(seed)
    rows = []
    results = {(name, s): ([], []) for name in factories for s in sizes}
    truth_errs = {key: [] for key in results}
    if truth is not None:
        missing = [c.poke_id for c in curves if c.poke_id not in truth]
        if missing:
            raise InvalidInput(f'learning_curve: no true forces for pokes {missing[:3]}')
        truth_x = dict(zip((c.poke_id for c in curves), curve_features(curves, surface)))
    for size in sizes:
        if not 1 <= size < len(curves):
            continue
        for _ in range(repeats):
            train_idx = rng.choice(len(curves), size=size, replace=False)
            mask = np.zeros(len(curves), bool)
            mask[train_idx] = True
            train = [curves[i] for i in train_idx]
            test = [c for c, m in zip(curves, mask) if not m]
            for name, factory in factories.items():
                model = factory().fit(train, surface)
                errs, times = results[(name, size)]
                errs.append(rmse(model, test, surface, region))
                times.append(float(getattr(model, 'fit_seconds', np.nan)))
                if truth is not None:
                    truth_errs[(name, size)].append(_truth_rmse(model, test, truth, truth_x))
    for name in factories:
        for size in sizes:
            errs, times = results[(name, size)]
            if not errs:
                continue
            e = np.array(errs)
            rows.append({'model': name, 'size': int(size), 'median': float(np.median(e)),
                         'q25': float(np.percentile(e, 25)), 'q75': float(np.percentile(e, 75)),
                         'mean': float(e.mean()), 'rmse': e.tolist(),
                         'fit_s': float(np.median(times))})
            if truth is not None:
                rows[-1]['truth_rmse'] = truth_errs[(name, size)]
                rows[-1]['truth_median'] = float(np.median(truth_errs[(name, size)]))
    return rows


def _truth_rmse(model, test: Sequence[PokeCurve], truth: Mapping[str, Tuple],
                features: Mapping[str, np.ndarray]) -> float:
    """RMSE (N) of ``model`` against the true forces of the held-out pokes ``test``."""
    return rms(sample_errors(model, [(features[c.poke_id],
                                      *(np.asarray(v, dtype=float) for v in truth[c.poke_id]))
                                     for c in test]))


def draw_learning_rows(ax, rows: Sequence[Mapping]) -> None:
    """Plot each model's median RMSE against training pokes, with its inter-quartile band."""
    for name in dict.fromkeys(r['model'] for r in rows):
        sel = sorted((r for r in rows if r['model'] == name), key=lambda r: r['size'])
        x = [r['size'] for r in sel]
        ax.plot(x, [r['median'] for r in sel], marker='o', label=name)
        ax.fill_between(x, [r['q25'] for r in sel], [r['q75'] for r in sel], alpha=0.2)


def plot_learning_curve(rows: Sequence[Mapping], path, title: str = 'Held-out RMSE') -> None:
    """Write a PNG of median RMSE (with the inter-quartile band) against training pokes."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5.0, 3.6), dpi=120)
    draw_learning_rows(ax, rows)
    ax.set_xlabel('training pokes')
    ax.set_ylabel('held-out RMSE [N]')
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv=None) -> None:
    """Learning curves of ours, ET and Auto-ET on the synthetic object; JSON + PNG in ``--out``.

    ``python -m pointforce_ros.lab.evaluate --out out/learn`` reproduces the figures quoted
    for this module (held-out RMSE, median of 10 random training subsets of a 40-poke pool).
    """
    import argparse
    import json
    from pathlib import Path

    parser = argparse.ArgumentParser(description='learning curves on the synthetic object')
    parser.add_argument('--out', default='out/learn', help='output directory')
    parser.add_argument('--repeats', type=int, default=10)
    parser.add_argument('--auto-budget', type=float, default=3.0, help='Auto-ET budget, s')
    parser.add_argument('--nonrigid', action='store_true',
                        help='camera bias as a smooth non-rigid field instead of an extrinsic '
                             'error (the harder case for ours)')
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    kw = dict(camera_shift=(0.0, 0.0, 0.0), camera_tilt=(0.0, 0.0, 0.0),
              bias_amplitude=0.003) if args.nonrigid else {}
    obj = SyntheticObject(**kw)
    surface = obj.surface(0.002)
    rng = np.random.default_rng(0)
    curves = obj.curves(surface, spread_indices(surface, 40, rng), rng)
    factories = {'ours': ContactGpModel, 'et': EtBaseline,
                 'auto_et': lambda: AutoEtBaseline(budget_s=args.auto_budget)}
    rows = learning_curve(curves, surface, factories, sizes=(2, 3, 5, 10, 20),
                          repeats=args.repeats, seed=1)
    plot_learning_curve(rows, out / 'learning_curve.png',
                        title='synthetic dome, held-out RMSE (contact region)')
    avr = active_vs_random_curve(curves, surface, ContactGpModel, start=2, max_pokes=14,
                                 repeats=args.repeats, seed=1)
    plot_active_vs_random(avr, out / 'active_vs_random.png')
    table = [{k: r[k] for k in ('model', 'size', 'median', 'q25', 'q75', 'fit_s')}
             for r in rows]
    (out / 'learning_curve.json').write_text(json.dumps({'rows': table, 'active_vs_random': {
        k: avr[k]['median'] for k in ('active', 'random')}, 'sizes': avr['sizes']}, indent=1))
    for r in table:
        print(f"{r['model']:8s} {r['size']:3d} pokes: {r['median']:.3f} N "
              f"[{r['q25']:.3f}, {r['q75']:.3f}]  fit {r['fit_s']:.2f} s")


if __name__ == '__main__':
    main()
