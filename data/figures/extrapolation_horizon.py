#!/usr/bin/env python3
"""How far may a baked table follow its law past the depth the pokes reached?

The learner bakes the point model on a grid to 25 mm; past the pokes' deepest nominal
displacement ``D`` the table is the fitted law continued, and a steep law fitted on shallow
pokes ran to absurd finite forces (1e26 N at 25 mm from pokes to 1 mm).
:meth:`~pointforce_ros.response.baked.BakedResponse.with_extrapolation` caps each row past
``horizon * D`` at its tangent there (``EXTRAPOLATION_HORIZON``). This study measures what the
cap costs where the truth is known, on every object of the simulated cell: ``repeats`` seeded
draws of ``size`` training pokes from the object's committed 30-poke fixture, each training
curve cut at ``cut`` metres; every held-out poke's row is baked on the learner's grid and capped
at each horizon (the same code as the learner's tables), then read at the poke's TRUE forces
(the FEM live path, :func:`~pointforce_ros.lab.figures.full_depth_truth`, to the cell's 10 mm
depth limit). Per horizon and band of ``d / D`` it prints the median ``|err| / F``, the
mean signed ``err / F`` (negative: below the truth) and the share of true forces inside the
table's nominal 90 % interval (its capped ``std`` with the learner's extrapolation term,
``EXTRAPOLATION_KAPPA``); ``inf`` is the law continued uncapped.

Usage: python data/figures/extrapolation_horizon.py [--objects lamb dome] [--cut 0.002 0.003]
       [--size 10] [--repeats 4] [--horizons 1 1.5 2 3]
(about 15 s per object, cut and draw on one core; set OPENBLAS_NUM_THREADS=1.)
"""

import argparse

import numpy as np

from pointforce_ros.lab.coverage import cut_curve
from pointforce_ros.lab.figures import full_depth_truth, load_poke_fixture, OBJECTS
from pointforce_ros.model.learner import DEFAULT_DEPTHS
from pointforce_ros.pokes.curves import learned_depth
from pointforce_ros.response.baked import (BakedResponse, EXTRAPOLATION_KAPPA,
                                           extrapolation_std, tangent_cap)
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel

BANDS = ((1.0, 1.5), (1.5, 2.0), (2.0, 3.0), (3.0, np.inf))
Z90 = 1.6448536269514722
"""Bands of ``d / D`` past the learned depth."""


def errors(name, cut, size, repeats, horizons, seed=0):
    """``{horizon: (x, err / F, inside)}`` over the held-out true samples past ``D``."""
    surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
    truth = full_depth_truth(name, curves)
    feats = dict(zip((c.poke_id for c in curves), curve_features(curves, surface)))
    rng = np.random.default_rng(seed)
    grid = np.asarray(DEFAULT_DEPTHS, dtype=float)
    out = {h: [] for h in horizons}
    for k in range(repeats):
        pick = rng.choice(len(curves), size=size, replace=False)
        train = [c for c in (cut_curve(curves[i], cut) for i in pick) if c is not None]
        model = ContactGpModel().fit(train, surface)
        D = learned_depth(train)
        held = [c for i, c in enumerate(curves) if i not in set(pick)]
        x = np.stack([feats[c.poke_id] for c in held])
        rows = np.stack([model.predict(np.repeat(x[i:i + 1], len(grid), axis=0), grid)
                         for i in range(len(held))])
        stds = np.stack([model.predict_std(np.repeat(x[i:i + 1], len(grid), axis=0), grid)
                         for i in range(len(held))])
        slopes = np.maximum((rows[:, -1] - rows[:, -2]) / (grid[-1] - grid[-2]), 0.0)
        for h in horizons:
            f, s, sd = tangent_cap(grid, rows, slopes, stds, h * D)
            sd = np.hypot(sd, extrapolation_std(f, grid[None, :], D, EXTRAPOLATION_KAPPA))
            table = BakedResponse(depths=grid, forces=f, slopes=s)
            spread = BakedResponse(depths=grid, forces=sd, slopes=np.zeros(len(sd)))
            for i, c in enumerate(held):
                d, ft = truth[c.poke_id]
                on = (ft > 0.05) & (d > D)
                if not on.any():
                    continue
                idx = np.full(int(on.sum()), i)
                pred = table.force(idx, d[on])
                std = spread.force(idx, np.minimum(d[on], grid[-1]))
                inside = np.abs(pred - ft[on]) <= Z90 * std
                out[h].append(np.stack([d[on] / D, (pred - ft[on]) / ft[on], inside], axis=1))
        print(f'  {name} cut {1e3 * cut:g} mm draw {k + 1}/{repeats}: learned depth '
              f'{1e3 * D:.1f} mm', flush=True)
    return {h: np.concatenate(v) if v else np.zeros((0, 3)) for h, v in out.items()}


def main():
    """Print, per object, cut and horizon, the error by band of ``d / D``."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--cut', nargs='+', type=float, default=[0.002, 0.003])
    parser.add_argument('--size', type=int, default=10)
    parser.add_argument('--repeats', type=int, default=4)
    parser.add_argument('--horizons', nargs='+', type=float, default=[1.0, 1.5, 2.0, 3.0])
    args = parser.parse_args()
    horizons = list(args.horizons) + [np.inf]
    pooled = {(cut, h): [] for cut in args.cut for h in horizons}
    for name in args.objects:
        for cut in args.cut:
            found = errors(name, cut, args.size, args.repeats, horizons)
            for h in horizons:
                pooled[(cut, h)].append(found[h])
                print(f'{name:10s} cut {1e3 * cut:g} mm horizon {h:4g}: ' + line(found[h]))
    for cut in args.cut:
        for h in horizons:
            print(f'{"pooled":10s} cut {1e3 * cut:g} mm horizon {h:4g}: '
                  + line(np.concatenate(pooled[(cut, h)])))


def line(rows):
    """One band after another: samples, median |err| / F, mean err / F, 90 % coverage."""
    cells = []
    for lo, hi in BANDS:
        m = (rows[:, 0] > lo) & (rows[:, 0] <= hi)
        e = rows[m, 1]
        cells.append(f'{lo:g}-{hi:g} D {int(m.sum()):5d} |e|/F {np.median(np.abs(e)):.3f} '
                     f'mean {np.mean(e):+.3f} in90 {100 * np.mean(rows[m, 2]):3.0f} %'
                     if m.any() else f'{lo:g}-{hi:g} D     0')
    return '  '.join(cells)


if __name__ == '__main__':
    main()
