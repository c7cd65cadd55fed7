#!/usr/bin/env python3
"""A floor on the per-poke scatter (the nugget) of ours' processes: figure 1, figure 2, step data.

A study (session 43). Each process of :class:`~pointforce_ros.response.ours.ContactGpModel`
chooses its nugget (a new poke's scatter about the smooth field, as a share of the process
variance) from ``1e-4 ... 1`` by the restricted likelihood; with 5-10 pokes it mostly takes
1e-4-1e-2 and so interpolates each poke's parameters, scatter and all. On thin_layer's
uniform part (the 23 pokes off the stepped end, 10-poke draws, held-out pokes of that part)
ours scores 0.162 N where the mean force of the training pokes' own laws scores 0.140 and ET
0.095-0.119. Variants here (``GpGrid.nugget``): ``n05`` (0.05, 0.2, 1), ``n2`` (0.2, 1),
``n1_3`` (0.1, 0.3, 1), ``nprior`` (the full grid, the nugget's prior median 0.2 instead of
0.01) and ``n05_long`` (``n05`` with the position length scale's prior median at the object
size instead of 0.3 of it).

Three data sets, each held out:

- ``--part figure1`` (default): figure 1's draws and table (``spread_variants.py``'s output:
  median and mean RMSE over 10 draws, ratio to ET);
- ``--part steps``: step tables of :mod:`pointforce_ros.lab.step_data` (another generator:
  40 pokes of 10 quasi-static steps, each poke's surface offset drawn on its own, seed 7; 10
  random 5- and 10-poke training sets, seed 3), held-out pokes scored against the noise-free
  force; ours, ``n05`` and ET;
- ``--part figure2``: figure 2's line and cylinder trials of one object (``--objects``), ours
  and ``n05`` (the paper's simulator on one draw only: its number is the figure's order of
  magnitude, not its value).

Session 43 (record ``nugget_floor.log``). Figure 1, ``n05`` against ours (medians, ratio to
ET at 5 | 10 pokes): thin_layer 1.00 | 1.36 (1.00 | 1.43), lamb 1.08 | 1.16 (1.06 | 1.45),
dome 1.64 | 1.24 (1.77 | 1.23), plush 1.04 | 1.09 (1.22 | 1.13), vest 1.01 | 1.07 (1.00 |
1.10): better on 6 of 10 cells, none at 0.9x. Figure 2: lamb 7.2 -> 6.9 % of the peak, vest
8.4 -> 7.9 %, plush 8.7 -> 8.6 %. The step tables, which figure 1 did not choose the variant
on: as good as ours on the whole and no better (``n05`` / ours per cell 0.95-1.10, lamb at
10 pokes 0.320 -> 0.353 N, plush at 5 0.666 -> 0.630 N). Not the product's default: the gain
is figure 1's data's, not the method's.

Usage: python data/figures/nugget_floor.py [--part figure1|steps|figure2] [--objects ...]
[--sizes 5 10] (figure 1 about 35 s per object, steps 15 s, figure 2 2-4 min per object
and setting; set OPENBLAS_NUM_THREADS=1).
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from spread_variants import OBJECTS, print_table   # this script's folder is on sys.path

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.figures import figure_probes, load_poke_fixture, load_probe_fixture
from pointforce_ros.lab.step_data import make_step_table
from pointforce_ros.pokes.curves import extract_curve
from pointforce_ros.pokes.table import load_pokes, surface_from_records
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.gp import GpGrid
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.response.scoring import CONTACT_MARGIN
import pointforce_ros.response.ours as ours_module

FLOOR = (0.05, 0.2, 1.0)
VARIANTS = {
    'ours': ContactGpModel,
    'et': EtBaseline,
    'n05': lambda: ContactGpModel(grid=GpGrid(nugget=FLOOR)),
    'n2': lambda: ContactGpModel(grid=GpGrid(nugget=(0.2, 1.0))),
    'n1_3': lambda: ContactGpModel(grid=GpGrid(nugget=(0.1, 0.3, 1.0))),
    'nprior': lambda: ContactGpModel(grid=GpGrid(nugget_prior=(0.2, 1.0))),
    'n05_long': lambda: ContactGpModel(grid=GpGrid(nugget=FLOOR, position_prior=(1.0, 0.7))),
}
STEP_OBJECTS = ('foam_block', 'lamb', 'plush', 'vest', 'dome', 'thin_layer')


def figure1_sets(objects, sizes):
    """Yield ``(label, start, draws)`` per object and size of figure 1's held-out draws.

    As :func:`step_sets`: each draw is ``(train, surface, queries)``, the queries each held-out
    poke's ``(feature rows, depths, measured forces)`` on its contact samples (seed 0, 10
    random training subsets per size of the committed 30-poke fixtures, sizes in order: the
    draws of ``python -m pointforce_ros.lab.figures --learning-only``). Also used by
    ``curve_average.py`` and ``tree_laws.py``.
    """
    for name in objects:
        start = time.monotonic()
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        features = curve_features(curves, surface)
        queries = []
        for c, x in zip(curves, features):
            sel = c.d >= c.onset_d - CONTACT_MARGIN
            queries.append((np.repeat(x[None], sel.sum(), 0), c.d[sel], c.f[sel]))
        rng = np.random.default_rng(0)
        for size in sizes:
            draws = []
            for _ in range(10):
                idx = rng.choice(len(curves), size=size, replace=False)
                draws.append(([curves[i] for i in idx], surface,
                              [queries[i] for i in np.setdiff1d(np.arange(len(curves)), idx)]))
            yield f'{name} {size}', start, draws


def step_sets(objects, sizes):
    """Yield ``(label, start, draws)`` per object and size of the step tables' held-out draws.

    Each draw is ``(train, surface, queries)``: the training curves and, per held-out poke,
    ``(feature rows, depths, noise-free forces)`` (40 pokes of 10 steps, seed 7; 10 random
    training sets per size, seed 3). Also used by ``curve_average.py``.
    """
    with tempfile.TemporaryDirectory() as tmp:
        for name in objects:
            start = time.monotonic()
            made = make_step_table(Path(tmp) / f'{name}.csv', name, pokes=40, per_poke=10,
                                   seed=7)
            records = load_pokes(made['path'])
            surface = surface_from_records(records)
            curves = [extract_curve(r) for r in records]
            feats = curve_features(curves, surface)
            rng = np.random.default_rng(3)
            for size in sizes:
                draws = []
                for _ in range(10):
                    train = rng.choice(len(curves), size=size, replace=False)
                    queries = [(np.repeat(feats[i][None], len(made['depth'][i]), axis=0),
                                made['depth'][i], made['force_true'][i])
                               for i in np.setdiff1d(np.arange(len(curves)), train)]
                    draws.append(([curves[i] for i in train], surface, queries))
                yield f'{name} {size}', start, draws


def steps(objects, sizes):
    """Print ours, ``n05`` and ET on each object's step table (median and mean over draws)."""
    models = {k: VARIANTS[k] for k in ('et', 'ours', 'n05')}
    for label, start, draws in step_sets(objects, sizes):
        rows = []
        for train, surface, queries in draws:
            fitted = {k: make().fit(train, surface) for k, make in models.items()}
            rows.append({k: float(np.sqrt(np.mean(np.concatenate(
                [model.predict(x, d) - f for x, d, f in queries]) ** 2)))
                for k, model in fitted.items()})
        med = {k: float(np.median([r[k] for r in rows])) for k in models}
        mean = {k: float(np.mean([r[k] for r in rows])) for k in models}
        print(f'{label} median | ' + ' | '.join(
            f'{k} {med[k]:.3f} ({med[k] / med["et"]:.2f})' for k in models)
            + '  mean | ' + ' | '.join(f'{k} {mean[k]:.3f}' for k in models)
            + f'   [{time.monotonic() - start:.0f} s]', flush=True)


def figure2(objects):
    """Print figure 2's force RMSE of ours and of ``n05`` per object."""
    for name in objects:
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        trials, dent, _ = load_probe_fixture(name, say=lambda line: None)
        for setting in ('ours', 'n05'):
            if setting == 'n05':
                ours_module.GpGrid = lambda **kw: GpGrid(**{'nugget': FLOOR, **kw})
            try:
                figure2_line(f'{name} {setting}', surface, curves, trials, dent)
            finally:
                ours_module.GpGrid = GpGrid


def figure2_line(label, surface, curves, trials, dent):
    """Score figure 2's trials of one object (ours, the paper's simulator on one draw); print."""
    start = time.monotonic()
    res = figure_probes(curves, surface, trials, dent, paper_draws=1, say=lambda line: None)
    ours, base = res['rmse']['ours']['force'], res['rmse']['baseline']['force']
    print(f'{label}: ours {ours:.3f} N ({100 * ours / res["peak_force"]:.1f} % of the peak '
          f'{res["peak_force"]:.2f} N), the paper\'s simulator on one draw {base:.3f} N (ratio '
          f'{ours / base:.2f})   [{time.monotonic() - start:.0f} s]', flush=True)


def main(argv=None):
    """Run the part asked for."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--part', choices=('figure1', 'steps', 'figure2'), default='figure1')
    parser.add_argument('--objects', nargs='+')
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args, rest = parser.parse_known_args(argv)
    if args.part == 'figure1':
        print_table(VARIANTS, __doc__.splitlines()[0],
                    rest + ['--sizes', *map(str, args.sizes)]
                    + (['--objects', *args.objects] if args.objects else []))
    elif args.part == 'steps':
        steps(args.objects or STEP_OBJECTS, args.sizes)
    else:
        figure2(args.objects or OBJECTS)


if __name__ == '__main__':
    main(sys.argv[1:])
