#!/usr/bin/env python3
"""Does a calibrated force scale on the point response help figure 2's wide contacts? (a study)

``probe_family_floor.py`` found, with the TRUE point response, that the simulator family scaled
by one force factor ``s`` (chosen with ``(c, L)``) fits every object's line and cylinder trials
far better than ``(c, L)`` alone: with the answers known 3.1-4.4 % of the peak against
5.3-10.6 %, and under figure 2's protocol (each trial from the object's other trials) vest 14.6
-> 5.9 % and lamb 9.7 -> 5.7 %. The best members have a small ``c`` (0.5-2 mm, contacts barely
coupled) and ``s`` 0.2-0.45: the point responses summed over the contact, scaled down.

This study asks the same with the LEARNED point response, in figure 2's protocol
(:func:`~pointforce_ros.lab.figures.figure_probes`): ``(c, L)`` -- and here ``s``, least
squares at each grid member -- are chosen on the object's other trials with the point model
fitted on every poke of the fixture, and each trial is then scored with point models trained on
10 random pokes (the figure's draws: ``default_rng([seed, 2])``). ``(c, L)`` come from a grid
here (:data:`C_GRID` x :data:`L_GRID`), not the figure's continuous fit of ``c``, so the
unscaled column is close to, not equal to, figure 2's ``ours``.

Result (session 23, 10 draws, median force RMSE, % of the object's peak; ``probe_scale.log``,
44 s in all): ``(c, L)`` -> ``(c, L, s)``: plush 7.1 -> 5.3 %, vest 16.3 -> 14.3 %, lamb 7.0 ->
7.1 %, dome 3.9 -> 3.6 %, thin_layer 7.4 -> 5.8 %; the other trials choose ``c`` 0.5-2 mm and
``s`` 0.16-0.55. Vest stays over figure 2's 10 %: with the scale in, its remaining error is the
point model (the 30-poke model itself scores 12.5 % scaled; the true response 5.9 %,
``probe_family_floor.py``). On the demo, whose calibration has two pushes, ``(c, L, s)``
over-fits them (``data/fem/demo_floor_law.py --scale``: 9.2-13.6 % and 8-9 of 9 below on the
17 stored lamb runs, against 6.9-8.8 % without; calibration error 0.9-4.1 %). Not in the
product: two pushes cannot carry a third parameter, and where four trials can, the goal the
scale was tried for (vest under 10 %) stays out of reach.

Usage: python data/figures/probe_scale.py [--objects vest lamb] [--draws 10] [--data FOLDER]
"""

import argparse
import time
from pathlib import Path

import numpy as np

from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.lab.figures import (bake_depths, DEFAULT_C, load_poke_fixture,
                                        load_probe_fixture, PROBE_TRAIN_POKES, trial_poses)
from pointforce_ros.response.ours import ContactGpModel

HERE = Path(__file__).resolve().parent
OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
C_GRID = (0.0002, 0.0005, 0.001, 0.002, 0.004, 0.008, 0.012, 0.02)
L_GRID = (np.inf, 0.032, 0.016, 0.008, 0.004)


def _forces(sim, trial) -> np.ndarray:
    return sim.query_batch(trial['mesh'], trial_poses(trial), trial['direction'],
                           trial['torque_centre']).wrenches[:, :3]


def _picks(cal, trials):
    """Per trial: the grid's best ``(c, L)`` and best ``(c, L, s)`` on the other trials."""
    grid = {(c, d): [_forces(cal.with_shape_constant(c, d), t) for t in trials]
            for c in C_GRID for d in L_GRID}
    picks = []
    for j in range(len(trials)):
        others = [i for i in range(len(trials)) if i != j]
        truth = np.vstack([trials[i]['force'] for i in others])

        def fit(key, scaled):
            p = np.vstack([grid[key][i] for i in others])
            s = float(np.sum(p * truth) / max(np.sum(p * p), 1e-30)) if scaled else 1.0
            return float(np.sum((s * p - truth) ** 2)), s

        plain = min(grid, key=lambda k: fit(k, False)[0])
        scaled = min(grid, key=lambda k: fit(k, True)[0])
        picks.append((plain, scaled, fit(scaled, True)[1]))
    return picks


def object_scale(name: str, draws: int, data, seed: int = 0) -> dict:
    """Figure 2's protocol on one object with and without the force scale (see module)."""
    surface, curves, _ = load_poke_fixture(name, data, say=lambda s: None)
    trials, _, _ = load_probe_fixture(name, data, say=lambda s: None)
    depths = bake_depths(curves)
    everything = ContactGpModel().fit(list(curves), surface).bake(surface, depths)
    picks = _picks(ContactSimulator(surface, everything, DEFAULT_C), trials)
    for j, (plain, scaled, s) in enumerate(picks):
        print(f'[scale] {name} trial {j} ({trials[j]["kind"]}): (c, L) {plain}, '
              f'(c, L, s) {scaled}, {s:.3f}', flush=True)
    peak = max(float(np.linalg.norm(t['force'], axis=1).max()) for t in trials)
    rng = np.random.default_rng([int(seed), 2])
    rmse = {'plain': [], 'scaled': []}
    for rep in range(int(draws)):
        pick = rng.choice(len(curves), size=PROBE_TRAIN_POKES, replace=False)
        model = ContactGpModel().fit([curves[i] for i in pick], surface)
        sim = ContactSimulator(surface, model.bake(surface, depths), DEFAULT_C)
        sq = {'plain': [], 'scaled': []}
        for t, (plain, scaled, s) in zip(trials, picks):
            for key, (cl, k) in (('plain', (plain, 1.0)), ('scaled', (scaled, s))):
                sq[key].append(np.sum((k * _forces(sim.with_shape_constant(*cl), t)
                                       - t['force']) ** 2, axis=1))
        for key in rmse:
            rmse[key].append(float(np.sqrt(np.mean(np.concatenate(sq[key])))))
        print(f'[scale] {name} draw {rep + 1}/{draws}: (c, L) {rmse["plain"][-1]:.3f} N, '
              f'(c, L, s) {rmse["scaled"][-1]:.3f} N', flush=True)
    out = {key: float(np.median(v)) for key, v in rmse.items()}
    print(f'[scale] {name}: median (c, L) {out["plain"]:.3f} N ({100 * out["plain"] / peak:.1f} '
          f'% of {peak:.1f} N), (c, L, s) {out["scaled"]:.3f} N '
          f'({100 * out["scaled"] / peak:.1f} %)', flush=True)
    return out


def main(argv=None) -> int:
    """Run the study on the chosen objects and print per draw and per object."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS), choices=OBJECTS)
    parser.add_argument('--draws', type=int, default=10)
    parser.add_argument('--data', default=str(HERE), help='folder of the cached fixtures')
    args = parser.parse_args(argv)
    started = time.monotonic()
    for name in args.objects:
        object_scale(name, args.draws, args.data)
    print(f'[scale] done in {time.monotonic() - started:.0f} s')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
