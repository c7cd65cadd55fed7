#!/usr/bin/env python3
"""Does the point model's standard deviation cover its force past the depth the pokes reached?

The contact service answers a query that presses deeper than any poke (the learned table's
extrapolation; ``WrenchServer.depth_note`` says so in the answer's message), and its
``wrench_std`` takes the response's part from the baked table's ``std``. This study measures
whether that ``std`` covers the true force there, on every object of the simulated cell:

For each object, ``repeats`` random draws (seeded) of ``size`` training pokes from its committed
30-poke fixture; each training curve is cut at ``cut`` metres of nominal displacement (the
pokes "reached" ``cut``); the model (:class:`~pointforce_ros.response.ours.ContactGpModel`)
predicts every held-out poke's TRUE force (the object's FEM live path at the poked point,
:func:`~pointforce_ros.lab.figures.full_depth_truth`, to the cell's 10 mm depth limit) with
its mean and ``predict_std``. Samples are binned by how far past the learned depth they lie,
``(d - D) / D`` with ``D`` the deepest training sample, and each bin reports the share of true
forces inside the nominal 90 % interval ``mean +- 1.645 std`` and the median ``|err| / F``.
The point-level interval covers less than 90 % within the pokes too (the wrench's other parts,
:mod:`pointforce_ros.contact.uncertainty`, hold the rest), so the aim is that past ``D`` it
covers as much as within ``D``.

With ``--kappa K`` the interval adds :func:`~pointforce_ros.response.baked.extrapolation_std`
(``K |F| (d - D) / D`` past ``D``) in variance, what the learner bakes into the table; the
script reports that coverage beside the model's own. ``--fit`` picks ``K`` on all objects but
one (the smallest whose coverage past the learned depth reaches their coverage within
it) and scores it on the one left out (leave one object out), so no object's coverage is
judged with a ``K`` it chose.

With ``--spread S`` each training poke is cut at ``cut`` plus a uniform draw in ``[0, S]`` (pokes
that stopped at different depths, as the force cap stops them), and with ``--local`` ``D`` is
the depth the nearest training poke reached instead of the deepest of all.

Usage: python data/figures/extrapolation_std.py [--objects lamb dome] [--cut 0.005]
       [--size 10] [--repeats 4] [--kappa 0.3] [--fit] [--spread 0.004] [--local]
(about 20 s per object and draw on one core; set OPENBLAS_NUM_THREADS=1.)
"""

import argparse
import json
from pathlib import Path

import numpy as np

from pointforce_ros.lab.coverage import cut_curve
from pointforce_ros.lab.figures import full_depth_truth, load_poke_fixture, OBJECTS
from pointforce_ros.pokes.curves import learned_depth
from pointforce_ros.response.baked import extrapolation_std
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel

Z90 = 1.6448536269514722
BINS = (-np.inf, 0.0, 0.25, 0.5, 1.0, np.inf)
"""Edges of ``(d - D) / D``: inside the learned depth, then past it."""
HERE = Path(__file__).resolve().parent


def samples(name, cut, size, repeats, seed=0, spread=0.0, local=False):
    """Per held-out true sample: ``(x, F, err, std, D, d, mean)`` over every draw of ``name``.

    ``spread``: each training poke is cut at ``cut`` plus a uniform draw in ``[0, spread]``
    (pokes stopped by the force cap at different depths); ``local``: ``D`` is the depth the
    nearest training poke (by position) reached, not the deepest of all.
    """
    surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
    truth = full_depth_truth(name, curves)
    feats = dict(zip((c.poke_id for c in curves), curve_features(curves, surface)))
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(repeats):
        pick = rng.choice(len(curves), size=size, replace=False)
        cuts = cut + spread * rng.random(len(pick))
        train = [cut_curve(curves[i], at) for i, at in zip(pick, cuts)]
        train = [c for c in train if c is not None]
        model = ContactGpModel().fit(train, surface)
        learned = learned_depth(train)
        where = np.stack([c.point for c in train])
        reached = np.array([learned_depth([c]) for c in train])
        for c in (curves[i] for i in range(len(curves)) if i not in set(pick)):
            d, f = truth[c.poke_id]
            on = f > 0.05
            d, f = d[on], f[on]
            if not len(d):
                continue
            x = np.repeat(feats[c.poke_id][None], len(d), axis=0)
            mean = model.predict(x, d)
            std = model.predict_std(x, d)
            D = float(reached[np.argmin(np.linalg.norm(where - c.point, axis=1))]) if local \
                else learned
            rows.append(np.stack([(d - D) / D, f, mean - f, std, np.full(len(d), D), d, mean],
                                 axis=1))
        print(f'  {name} draw {k + 1}/{repeats}: learned depth {1e3 * learned:.1f} mm',
              flush=True)
    return np.concatenate(rows)


def coverage(rows, kappa):
    """Per bin of ``(d - D) / D``: ``(samples, inside share, median |err| / F)``."""
    x, f, err, std, learned, d, mean = rows.T
    extra = extrapolation_std(mean, d, learned, kappa)
    total = np.sqrt(std ** 2 + extra ** 2)
    inside = np.abs(err) <= Z90 * total
    out = []
    for lo, hi in zip(BINS[:-1], BINS[1:]):
        m = (x > lo) & (x <= hi)
        out.append((int(m.sum()), float(inside[m].mean()) if m.any() else float('nan'),
                    float(np.median(np.abs(err[m]) / f[m])) if m.any() else float('nan')))
    return out


def past_coverage(rows, kappa):
    """Share of the samples past the learned depth inside the 90 % interval."""
    x, f, err, std, learned, d, mean = rows.T
    m = x > 0
    total = np.sqrt(std[m] ** 2 + extrapolation_std(mean[m], d[m], learned[m], kappa) ** 2)
    return float(np.mean(np.abs(err[m]) <= Z90 * total))


def inside_coverage(rows):
    """Share of the samples within the learned depth inside the model's own 90 % interval."""
    x, f, err, std = rows.T[:4]
    m = x <= 0
    return float(np.mean(np.abs(err[m]) <= Z90 * std[m]))


def fit_kappa(rows):
    """The smallest ``K`` of a grid whose coverage past the learned depth reaches the model's
    own coverage within it (or the grid's largest): past its pokes the model is to be no less
    trustworthy than within them."""
    target = inside_coverage(rows)
    for kappa in np.round(np.arange(0.0, 2.01, 0.05), 2):
        if past_coverage(rows, kappa) >= target:
            return float(kappa)
    return 2.0


def main():
    """Print each object's coverage by bin, without and with the extrapolation term."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--cut', type=float, default=0.005)
    parser.add_argument('--size', type=int, default=10)
    parser.add_argument('--repeats', type=int, default=4)
    parser.add_argument('--kappa', type=float, default=0.0)
    parser.add_argument('--fit', action='store_true')
    parser.add_argument('--spread', type=float, default=0.0)
    parser.add_argument('--local', action='store_true')
    args = parser.parse_args()
    rows = {}
    for name in args.objects:
        rows[name] = samples(name, args.cut, args.size, args.repeats, spread=args.spread,
                             local=args.local)
    labels = ['inside D'] + [f'{lo:g}-{hi:g} D' for lo, hi in zip(BINS[1:-1], BINS[2:])]
    record = {}
    for name, r in rows.items():
        kappas = {'model std': 0.0}
        if args.kappa:
            kappas[f'K {args.kappa:g}'] = args.kappa
        if args.fit and len(rows) > 1:
            rest = np.concatenate([v for k, v in rows.items() if k != name])
            kappas['K fit on the others'] = fit_kappa(rest)
        record[name] = {}
        for label, kappa in kappas.items():
            cov = coverage(r, kappa)
            record[name][label] = {'kappa': kappa, 'bins': dict(zip(labels, cov))}
            cells = '  '.join(f'{lab} {n:5d} {100 * c:5.1f} % (|e|/F {e:.2f})'
                              for lab, (n, c, e) in zip(labels, cov))
            past = past_coverage(r, kappa)
            record[name][label]['past'] = past
            print(f'{name:10s} {label:20s} K {kappa:4.2f}: past D {100 * past:5.1f} %  {cells}')
    pooled = np.concatenate(list(rows.values()))
    if args.fit:
        kappa = fit_kappa(pooled)
        print(f'pooled: K {kappa:.2f} brings the coverage past the learned depth to '
              f'{100 * past_coverage(pooled, kappa):.1f} % (model std alone '
              f'{100 * past_coverage(pooled, 0.0):.1f} %; within it '
              f'{100 * inside_coverage(pooled):.1f} %)')
        record['pooled_kappa'] = kappa
    tag = f'_cut{1e3 * args.cut:g}' + (f'_spread{1e3 * args.spread:g}' if args.spread else '') \
        + ('_local' if args.local else '')
    (HERE / f'extrapolation_std{tag}.json').write_text(json.dumps(record, indent=1))


if __name__ == '__main__':
    main()
