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

Four columns: ``plain`` the grid's best ``(c, L)``; ``scaled`` the best ``(c, L, s)``;
``averaged`` every ``(c, L, s)`` weighted by its likelihood on the other trials (the members
they cannot tell apart, as ``probe_family_floor.py`` averages the unscaled family); ``gated``
``plain`` or ``averaged``, whichever predicts each of the other trials better from the rest
(what a product would check before trusting a third parameter).

Result (session 23, 10 draws, median force RMSE, % of the object's peak; ``probe_scale.log``,
about 1 min in all), plain -> scaled -> averaged: plush 7.1 -> 5.3 -> 5.2 %, vest 16.3 -> 14.3
-> 11.8 %, lamb 7.0 -> 7.1 -> 6.8 %, dome 3.9 -> 3.6 -> 3.4 %, thin_layer 7.4 -> 5.8 -> 5.8 %;
the other trials choose ``c`` 0.5-2 mm and ``s`` 0.16-0.56. With the vest's side walls left
out as well (``--wall-deg 45``): 16.2 -> 12.9 -> 11.6 %. Vest stays over figure 2's 10 %, and
not because its point model is wrong: the 30-poke model reads within 1-4 % of the true
response under every trial's footprint (0.5-6 mm below the surface), but along the ridge the
other trials cannot resolve it picks ``L`` = none for the first line where the true response
picks 32 mm; with the picks the true response makes, the 30-poke model scores 7.9 %, and the
true response with the learned response's picks 11.5 % (walls out, this grid; the true
response with its own picks 6.5 %; ``--swap``). Averaging over the ridge recovers part of that.
The gate keeps the scale on plush, dome and thin_layer (5.2, 3.4, 5.8 %) but not for the vest's
first line, the trial it helps most (vest 15.1 %), and on lamb it costs (7.0 -> 7.3 %).

On the demo, whose calibration has two pushes, ``(c, L, s)`` over-fits them
(``data/fem/demo_floor_law.py --scale``: 9.2-13.6 % and 8-9 of 9 below on the 17 stored lamb
runs, against 6.9-8.8 % without; calibration error 0.9-4.1 %). Not in the product: two pushes
cannot carry a third parameter, so the product would have to choose between ``(c, L)`` and
``(c, L, s)`` by leave-one-push-out error where three or more pushes allow it (the model file,
the shape sidecar, the service and the learner's parameters would carry ``s``), and the goal
it was tried for (vest under 10 %) stays out of reach even so.

Usage: python data/figures/probe_scale.py [--objects vest lamb] [--draws 10] [--data FOLDER]
       [--wall-deg 45] [--swap]
"""

import argparse
import time
from pathlib import Path

import numpy as np

from probe_family_floor import least_squares_scale, top_surface  # this folder
from pointforce_ros.bringup.demo import true_point_response
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.lab.figures import (bake_depths, DEFAULT_C, load_poke_fixture,
                                        load_probe_fixture, PROBE_TRAIN_POKES, trial_poses)
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.sim.fem.live import LiveContact
from pointforce_ros.sim.objects import load_object

HERE = Path(__file__).resolve().parent
OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
C_GRID = (0.0002, 0.0005, 0.001, 0.002, 0.004, 0.008, 0.012, 0.02)
L_GRID = (np.inf, 0.032, 0.016, 0.008, 0.004)


def _forces(sim, trial) -> np.ndarray:
    return sim.query_batch(trial['mesh'], trial_poses(trial), trial['direction'],
                           trial['torque_centre']).wrenches[:, :3]


def _fit_on(grid, trials, pick):
    """Members fitted on the trials ``pick``: ``(plain key, [(key, s)], [(w, key, s)])``.

    The best ``(c, L)``, the best ``(c, L, s)`` and every ``(c, L, s)`` weighted by
    ``exp(-SSE / (2 s2))`` (``s2`` the best member's mean square; weights under 1e-3 left out).
    """
    truth = np.vstack([trials[i]['force'] for i in pick])

    def fit(key, scaled):
        p = np.vstack([grid[key][i] for i in pick])
        s = least_squares_scale(p, truth) if scaled else 1.0
        return float(np.sum((s * p - truth) ** 2)), s

    fits = {key: fit(key, True) for key in grid}
    sse = np.array([f[0] for f in fits.values()])
    weight = np.exp(-0.5 * (sse - sse.min()) / max(sse.min() / len(truth), 1e-30))
    weight /= weight.sum()
    best = min(fits, key=lambda k: fits[k][0])
    return (min(grid, key=lambda k: fit(k, False)[0]), [(best, fits[best][1])],
            [(w, key, fits[key][1]) for w, key in zip(weight, fits) if w > 1e-3])


def _members(cal, trials):
    """Per trial, the grid's members fitted on the other trials.

    Returns per trial ``{'plain': [(1, key, 1)], 'scaled': [(1, key, s)], 'averaged': [(w,
    key, s)], 'gated': ...}`` (:func:`_fit_on` on the other trials); ``gated`` is ``plain`` or
    ``averaged``, whichever predicts each of the other trials better from the rest (leave one
    out within them: what a product would check before it trusts a third parameter).
    """
    grid = {(c, d): [_forces(cal.with_shape_constant(c, d), t) for t in trials]
            for c in C_GRID for d in L_GRID}
    out = []
    for j in range(len(trials)):
        others = [i for i in range(len(trials)) if i != j]
        plain, scaled, averaged = _fit_on(grid, trials, others)
        inner = {'plain': 0.0, 'averaged': 0.0}
        for k in others:
            p_key, _, p_avg = _fit_on(grid, trials, [i for i in others if i != k])
            pred = {'plain': grid[p_key][k],
                    'averaged': sum(w * s * grid[key][k] for w, key, s in p_avg)
                    / sum(w for w, _, _ in p_avg)}
            for name, value in pred.items():
                inner[name] += float(np.sum((value - trials[k]['force']) ** 2))
        members = {'plain': [(1.0, plain, 1.0)],
                   'scaled': [(1.0, key, k) for key, k in scaled], 'averaged': averaged}
        members['gated'] = members[min(inner, key=inner.get)]
        members['gate'] = min(inner, key=inner.get)
        out.append(members)
    return out


def object_scale(name: str, draws: int, data, seed: int = 0, wall_deg: float = 0.0) -> dict:
    """Figure 2's protocol on one object with and without the force scale (see module)."""
    surface, curves, _ = load_poke_fixture(name, data, say=lambda s: None)
    trials, _, _ = load_probe_fixture(name, data, say=lambda s: None)
    if wall_deg:
        surface = top_surface(surface, wall_deg)
    depths = bake_depths(curves)
    everything = ContactGpModel().fit(list(curves), surface).bake(surface, depths)
    members = _members(ContactSimulator(surface, everything, DEFAULT_C), trials)
    for j, m in enumerate(members):
        print(f'[scale] {name} trial {j} ({trials[j]["kind"]}): (c, L) {m["plain"][0][1]}, '
              f'(c, L, s) {m["scaled"][0][1]}, {m["scaled"][0][2]:.3f}; '
              f'{len(m["averaged"])} members averaged; gate: {m["gate"]}', flush=True)
    peak = max(float(np.linalg.norm(t['force'], axis=1).max()) for t in trials)
    rng = np.random.default_rng([int(seed), 2])
    rmse = {'plain': [], 'scaled': [], 'averaged': [], 'gated': []}
    for rep in range(int(draws)):
        pick = rng.choice(len(curves), size=PROBE_TRAIN_POKES, replace=False)
        model = ContactGpModel().fit([curves[i] for i in pick], surface)
        sim = ContactSimulator(surface, model.bake(surface, depths), DEFAULT_C)
        sq = {key: [] for key in rmse}
        for t, m in zip(trials, members):
            for key, parts in ((key, m[key]) for key in rmse):
                pred = sum(w * k * _forces(sim.with_shape_constant(*cl), t) for w, cl, k in parts)
                pred = pred / sum(w for w, _, _ in parts)
                sq[key].append(np.sum((pred - t['force']) ** 2, axis=1))
        for key in rmse:
            rmse[key].append(float(np.sqrt(np.mean(np.concatenate(sq[key])))))
        print(f'[scale] {name} draw {rep + 1}/{draws}: '
              + ', '.join(f'{key} {v[-1]:.3f} N' for key, v in rmse.items()), flush=True)
    out = {key: float(np.median(v)) for key, v in rmse.items()}
    print(f'[scale] {name}: median over the draws, % of the {peak:.1f} N peak: '
          + ', '.join(f'{key} {v:.3f} N ({100 * v / peak:.1f} %)' for key, v in out.items()),
          flush=True)
    return out


def swap_check(name: str, data, wall_deg: float = 45.0) -> None:
    """Whose picks, whose response: the 30-poke model and the true response, crossed.

    On the top surface (side walls beyond ``wall_deg`` left out: the true response is a
    vertical poke) each response picks its best ``(c, L, s)`` per trial on the other trials;
    every trial is then scored with either response under either's picks, and the point
    forces of both are compared under each trial's footprint (surface points under the last
    pose's probe, within 12 mm of its lowest point) at 0.5-6 mm below the surface.
    """
    captured, curves, _ = load_poke_fixture(name, data, say=lambda s: None)
    trials, _, _ = load_probe_fixture(name, data, say=lambda s: None)
    surface = top_surface(captured, wall_deg)
    depths = bake_depths(curves)
    spec = load_object(name)
    responses = {'learned': ContactGpModel().fit(list(curves), surface).bake(surface, depths),
                 'true': true_point_response(spec, LiveContact.load(spec.name, build=False),
                                             surface.points, depths)}
    index = np.arange(len(surface))
    for depth in (0.0005, 0.002, 0.006):
        force = {k: np.asarray(r.force(index, np.full(len(index), depth)))
                 for k, r in responses.items()}
        for j, t in enumerate(trials):
            pose = trial_poses(t)[-1]
            v = t['mesh'].vertices @ pose.rotation().T + pose.position
            inside = (np.all((surface.points[:, :2] >= v[:, :2].min(0) - 0.002)
                             & (surface.points[:, :2] <= v[:, :2].max(0) + 0.002), axis=1)
                      & (np.abs(surface.points[:, 2] - v[:, 2].min() - 0.0055) < 0.0065)
                      & (force['true'] > 0.05))
            print(f'[scale] {name} trial {j} ({t["kind"]}), {int(inside.sum())} points at '
                  f'{1e3 * depth:g} mm: learned / true point force, median '
                  f'{np.median(force["learned"][inside] / force["true"][inside]):.2f}')
    sims = {k: ContactSimulator(surface, r, DEFAULT_C) for k, r in responses.items()}
    picks = {k: _members(sim, trials) for k, sim in sims.items()}
    for j, t in enumerate(trials):
        print(f'[scale] {name} trial {j} ({t["kind"]}): (c, L, s) picked with the '
              + ', '.join(f'{k} response {m[j]["scaled"][0][1]}, {m[j]["scaled"][0][2]:.3f}'
                          for k, m in picks.items()))
    peak = max(float(np.linalg.norm(t['force'], axis=1).max()) for t in trials)
    for by, members in picks.items():
        for scored, sim in sims.items():
            sq = [np.sum((k * _forces(sim.with_shape_constant(*key), t) - t['force']) ** 2,
                         axis=1) for t, m in zip(trials, members) for _, key, k in m['scaled']]
            err = float(np.sqrt(np.mean(np.concatenate(sq))))
            print(f'[scale] {name}: picks of the {by} response, scored with the {scored} '
                  f'one: {err:.3f} N ({100 * err / peak:.1f} %)', flush=True)


def main(argv=None) -> int:
    """Run the study on the chosen objects and print per draw and per object."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS), choices=OBJECTS)
    parser.add_argument('--draws', type=int, default=10)
    parser.add_argument('--data', default=str(HERE), help='folder of the cached fixtures')
    parser.add_argument('--swap', action='store_true', help='only the crossed check of '
                        'swap_check (30-poke model against the true response)')
    parser.add_argument('--wall-deg', type=float, default=0.0, help='leave out surface points '
                        'whose normal is further than this from vertical (0: keep all)')
    args = parser.parse_args(argv)
    started = time.monotonic()
    for name in args.objects:
        if args.swap:
            swap_check(name, args.data, args.wall_deg or 45.0)
            continue
        object_scale(name, args.draws, args.data, wall_deg=args.wall_deg)
    print(f'[scale] done in {time.monotonic() - started:.0f} s')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
