#!/usr/bin/env python3
"""Ours with its laws spread by Extra Trees (``ContactGpModel(spread='trees')``) against ET (a study).

Ours fits a contact law to each training poke and spreads the laws' parameters over the
features; the default spreads them with Gaussian processes, ``spread='trees'`` with Extra
Trees over the same nine features (:mod:`pointforce_ros.response.trees`). Three data sets,
each held out (median RMSE over 10 draws, newtons, and the ratio to ET):

- ``--part figure1`` (default): figure 1's draws (seed 0, 10 random training subsets per size
  of the committed 30-poke fixtures, sizes in order; every held-out poke scored on its
  measured contact samples), as ``python -m pointforce_ros.lab.figures --learning-only``;
- ``--part steps``: step tables of :mod:`pointforce_ros.lab.step_data` (another generator, as
  ``nugget_floor.py --part steps``), held-out pokes scored against the noise-free force;
- ``--part coverage``: figure 1's draws again, the share of the held-out samples whose measured
  force lies inside ``+- Z90`` times the model's ``predict_std`` (nominal 90 %; the spread of
  the force curve at the point, not F/T noise) for ours and ``ours_trees``;
- ``--part probes``: figure 2 (``figure_probes`` of :mod:`pointforce_ros.lab.figures`: line
  and cylinder probe trials, ``(c, L)`` from each object's other trials, 10-poke point models,
  10 draws) with ours' point model under each spread, ``--objects``; about 2-5 min per
  object and spread on one core;
- ``--part synthetic``: the unit tests' synthetic dome (:class:`~pointforce_ros.lab.
  synthetic_response.SyntheticObject`: a smooth stiffness field, a stiff inclusion, camera
  bias; 30 pokes, draws of seed 7), held-out pokes scored on their samples.

Session 46 (record ``tree_laws.log``). Figure 1: the trees 1.02-1.17 of ET at 5 pokes and
1.08-1.18 at 10, the processes 1.00-1.77 and 1.10-1.45 (better on 7 of 10 cells, mean 1.11
against 1.24); the step tables: better on 8 of 12 cells (mean 1.11 against 1.23); held-out
samples inside the nominal 90 %: 68-94 % against 42-77 %. Worse on the synthetic dome (1.30 |
1.05 against 0.82 | 0.69), whose smooth field a process over position interpolates and trees
cut into steps, and under figure 2's probes on lamb (1.064 against 0.814 N: 0.73x the paper's
simulator, the 0.7x goal fails) and plush (0.730 against 0.629 N: 10.1 % of the peak); better
there on thin_layer, vest and the dome. None reaches 0.9x ET on every object. Per fit the two are not told apart by leave-one-poke-out error with
5-10 pokes (an ``auto`` choice kept the processes on thin_layer and lamb at 10 pokes), so
``spread`` is a setting, the processes the default.

Usage: python data/figures/tree_laws.py [--part figure1|steps|synthetic] [--objects ...]
[--sizes 5 10] (set OPENBLAS_NUM_THREADS=1; figure 1 about 12 min on one core).
"""

import argparse
import time

import numpy as np
from nugget_floor import figure1_sets, STEP_OBJECTS, step_sets   # this folder is on sys.path

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.evaluate import learning_curve
from pointforce_ros.lab.figures import (DATA_DIR, figure_probes, load_poke_fixture,
                                        load_probe_fixture, probe_goals)
from pointforce_ros.contact.uncertainty import Z90
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject
from pointforce_ros.response.ours import ContactGpModel

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
MODELS = {'et': EtBaseline, 'ours': ContactGpModel,
          'ours_trees': lambda: ContactGpModel(spread='trees')}


def draw_rmse(train, surface, queries, models=MODELS):
    """``{model: RMSE}`` of one draw over ``queries`` (feature rows, depths, forces)."""
    fitted = {k: make().fit(train, surface) for k, make in models.items()}
    return {k: float(np.sqrt(np.mean(np.concatenate(
        [m.predict(x, d) - f for x, d, f in queries]) ** 2))) for k, m in fitted.items()}


def print_row(label, rows, start, models=MODELS):
    med = {k: float(np.median([r[k] for r in rows])) for k in models}
    print(f'{label} | ' + ' | '.join(f'{med[k]:.3f} ({med[k] / med["et"]:.2f})'
                                     for k in models)
          + f'   [{time.monotonic() - start:.0f} s]', flush=True)


def figure1(objects, sizes, models=MODELS):
    for label, start, draws in figure1_sets(objects, sizes):
        print_row(label, [draw_rmse(*draw, models) for draw in draws], start, models)


def coverage(objects, sizes, models=MODELS):
    for label, start, draws in figure1_sets(objects, sizes):
        hits = {k: [] for k in models if k != 'et'}
        for train, surface, queries in draws:
            for k in hits:
                model = models[k]().fit(train, surface)
                for x, d, f in queries:
                    hits[k].append(np.abs(model.predict(x, d) - f)
                                   <= Z90 * model.predict_std(x, d))
        print(f'{label} coverage | ' + ' | '.join(
            f'{k} {100 * np.mean(np.concatenate(v)):.0f} %' for k, v in hits.items())
            + f'   [{time.monotonic() - start:.0f} s]', flush=True)


def probes(objects, spreads=('gp', 'trees')):
    for name in objects:
        surface, curves, _ = load_poke_fixture(name, DATA_DIR, lambda line: None)
        trials, dent, _ = load_probe_fixture(name, DATA_DIR, lambda line: None)
        for spread in spreads:
            start = time.monotonic()
            res = figure_probes(curves, surface, trials, dent, say=lambda line: None,
                                point_model=lambda: ContactGpModel(spread=spread))
            ours, paper = res['rmse']['ours']['force'], res['rmse']['baseline']['force']
            goals = probe_goals(res)
            print(f'{name} probes {spread}: ours {ours:.3f} N, the paper\'s simulator '
                  f'{paper:.3f} N ({ours / paper:.2f}x, goal met: {goals["ratio_met"]}), '
                  f'{100 * ours / res["peak_force"]:.1f} % of the peak {res["peak_force"]:.2f} '
                  f'N (met: {goals["peak_met"]})   [{time.monotonic() - start:.0f} s]',
                  flush=True)


def steps(objects, sizes, models=MODELS):
    for label, start, draws in step_sets(objects, sizes):
        print_row(f'{label} steps', [draw_rmse(*draw, models) for draw in draws], start,
                  models)


def synthetic(sizes, models=MODELS):
    start = time.monotonic()
    obj = SyntheticObject()
    surface = obj.surface(0.002)
    rng = np.random.default_rng(2024)
    curves = obj.curves(surface, spread_indices(surface, 30, rng), rng, rate=100.0,
                        ft_noise=0.03, ft_bias=0.05)
    rows = learning_curve(curves, surface, models, sizes=sizes, repeats=10, seed=7)
    med = {(r['model'], r['size']): r['median'] for r in rows}
    for size in sizes:
        print(f'synthetic {size} | ' + ' | '.join(
            f'{med[(k, size)]:.3f} ({med[(k, size)] / med[("et", size)]:.2f})' for k in models)
            + f'   [{time.monotonic() - start:.0f} s]', flush=True)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--part', choices=('figure1', 'steps', 'synthetic', 'coverage',
                                           'probes'),
                        default='figure1')
    parser.add_argument('--objects', nargs='+')
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args = parser.parse_args(argv)
    print('object pokes | ' + ' | '.join(MODELS))
    if args.part == 'figure1':
        figure1(args.objects or OBJECTS, args.sizes)
    elif args.part == 'steps':
        steps(args.objects or STEP_OBJECTS, args.sizes)
    elif args.part == 'coverage':
        coverage(args.objects or OBJECTS, args.sizes)
    elif args.part == 'probes':
        probes(args.objects or OBJECTS)
    else:
        synthetic(args.sizes)


if __name__ == '__main__':
    main()
