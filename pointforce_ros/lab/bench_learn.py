"""Benchmark ``learn``: model update after a new poke, ours against the seed's Auto-ET.

What a live cell waits for after each poke, on a 40 000-point surface: ours as the product
uses it (:func:`~pointforce_ros.response.ours.product_model`) refits (one curve fit per law,
small GP fits and the trees' forests) and bakes the force table; the paper's learner
retrains Auto-ET (a time-boxed hyperparameter search, 30 s in the paper, ``auto_budget_s``
here) and must then be baked the same way for the contact solver. Both are measured in the
same run on the same synthetic object (:mod:`.synthetic`), and the figure is the ratio of
their median times.
Held-out accuracy of both on the same training pokes is reported alongside, so a speed-up that
costs accuracy shows.

Run: ``python -m pointforce_ros.lab.bench_learn [--quick]`` (prints one JSON line).
"""

import argparse
import json
import time
from typing import Dict

import numpy as np

from pointforce_ros.lab.baseline import AutoEtBaseline, EtBaseline
from pointforce_ros.lab.evaluate import rmse
from pointforce_ros.response.ours import product_model
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject


def bench_learn(n_points: int = 40000, n_pokes: int = 10, repeats: int = 5,
                baseline_repeats: int = 2, auto_budget_s: float = 10.0, n_depths: int = 32,
                n_test: int = 20, seed: int = 0, quick: bool = False) -> Dict:
    """Measure refit + bake after one new poke; return medians (s) and ratios.

    Args:
        n_points: surface size (a grid on the synthetic dome).
        n_pokes: pokes already in the model before the new one.
        repeats: timed updates of ours (each adds a different new poke).
        baseline_repeats: timed Auto-ET retrains and bakes (each takes ``auto_budget_s``+).
        auto_budget_s: Auto-ET search budget, seconds (the paper used 30).
        n_depths: depth grid of the baked table.
        n_test: held-out pokes for the accuracy columns.
        seed: RNG seed of the pokes.
        quick: smoke-run sizes (4 000 points, 3 repeats, one 2 s Auto-ET search).

    Returns:
        A dict; ``ratio_update`` = median(Auto-ET fit + bake) / median(ours refit + bake) is
        the figure (wall clock); ``ratio_update_vs_et`` uses plain default-ET fit + bake
        instead (no search); ``ratio_fit`` compares training only; ``ours_update_cpu_s`` is
        the process CPU time of ours (robust to a busy machine); ``*_rmse`` are held-out RMSE
        (N) of the three models trained on the same pokes.

    """
    if quick:
        n_points, repeats, baseline_repeats, auto_budget_s, n_test = 4000, 3, 1, 2.0, 10
    obj = SyntheticObject()
    area = obj.size[0] * obj.size[1]
    spacing = float(np.sqrt(area / n_points))
    surface = obj.surface(spacing)
    rng = np.random.default_rng(seed)
    idx = spread_indices(surface, n_pokes + repeats + n_test, rng)
    rng.shuffle(idx)
    curves = obj.curves(surface, idx, rng)
    base, new, test = (curves[:n_pokes], curves[n_pokes:n_pokes + repeats],
                       curves[n_pokes + repeats:])
    depths = np.linspace(-0.006, 0.014, n_depths)

    refit, bake, total, cpu = [], [], [], []
    ours = None
    for c in new:
        ours = product_model().fit(base, surface)
        c0 = time.process_time()
        t0 = time.perf_counter()
        ours.partial_fit(c, surface)
        t1 = time.perf_counter()
        ours.bake(surface, depths)
        t2 = time.perf_counter()
        cpu.append(time.process_time() - c0)
        refit.append(t1 - t0)
        bake.append(t2 - t1)
        total.append(t2 - t0)
    train = base + new[:1]
    ours = product_model().fit(train, surface)

    auto_fit, auto_bake, auto_total = [], [], []
    auto = None
    for r in range(baseline_repeats):
        t0 = time.perf_counter()
        auto = AutoEtBaseline(budget_s=auto_budget_s, search_seed=r).fit(train, surface)
        t1 = time.perf_counter()
        auto.bake(surface, depths)
        t2 = time.perf_counter()
        auto_fit.append(t1 - t0)
        auto_bake.append(t2 - t1)
        auto_total.append(t2 - t0)
    t0 = time.perf_counter()
    et = EtBaseline().fit(train, surface)
    t1 = time.perf_counter()
    et.bake(surface, depths)
    t2 = time.perf_counter()

    med = float(np.median(total))
    return {
        'name': 'learn', 'n_points': len(surface), 'n_pokes': n_pokes + 1,
        'n_depths': n_depths, 'repeats': repeats, 'baseline_repeats': baseline_repeats,
        'auto_budget_s': auto_budget_s,
        'ours_refit_s': float(np.median(refit)), 'ours_bake_s': float(np.median(bake)),
        'ours_update_s': med, 'ours_update_cpu_s': float(np.median(cpu)),
        'auto_et_fit_s': float(np.median(auto_fit)), 'auto_et_bake_s': float(np.median(auto_bake)),
        'auto_et_update_s': float(np.median(auto_total)),
        'auto_et_configs': len(auto.search_log),
        'et_fit_s': t1 - t0, 'et_bake_s': t2 - t1,
        'ours_rmse': rmse(ours, test, surface), 'auto_et_rmse': rmse(auto, test, surface),
        'et_rmse': rmse(et, test, surface),
        'ratio_fit': float(np.median(auto_fit)) / float(np.median(refit)),
        'ratio_update': float(np.median(auto_total)) / med,
        'ratio_update_vs_et': (t2 - t0) / med,
    }


def main(argv=None) -> None:
    """Command line: print the benchmark as one JSON line."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='4 000 points, 2 s Auto-ET budget, fewer repeats (smoke run)')
    parser.add_argument('--budget', type=float, default=10.0, help='Auto-ET budget, s')
    args = parser.parse_args(argv)
    out = bench_learn(quick=True) if args.quick else bench_learn(auto_budget_s=args.budget)
    print(json.dumps(out))


if __name__ == '__main__':
    main()
