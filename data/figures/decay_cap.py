#!/usr/bin/env python3
"""Figure 2 with the tail decay length capped by the object's thickness (a study, session 26).

Figure 2's ``ours`` column (:func:`~pointforce_ros.lab.figures.figure_probes`): every line and
cylinder trial is scored with ``(c, L)`` identified on the object's other trials
(``shape_fits_from_probes`` over the decay grid, the point model fitted on every poke), with
point models trained on 10 random pokes (the figure's draws, ``default_rng([seed, 2])``); force
RMSE, median over the draws, as a share of the object's peak force. Here the decay grid is
also offered capped at ``k`` times the object's thickness ``h`` above the table (``z = 0`` in
``base``; ``h`` the median height of the captured surface's upward-facing points, what the
product's cloud gives): the surface displacement of an elastic layer bonded to a rigid table
under a point load dies out within about its thickness (the layer's Green's function decays
exponentially, over a length of the order of ``h``), so an infinite tail is not physics for an
object on a table, and the other trials of the vest pick one (``probe_scale.py``).

Result (session 26, record ``decay_cap.log``, 15 min on one core): the caps 1.5 and 2 change
the picks of one trial on one object, the vest's first line (3.7 mm / inf -> 12.6 mm / 32 mm;
``h`` = 30.4 mm), which goes from 28.3 % to 12.6 % of the vest's peak; the vest from 16.7 % to
11.7 % (every trial now 6.8-13.5 %); plush 9.7 %, lamb 7.5 %, dome 4.5 %, thin_layer 8.3 %
unchanged (every pick the same). The figure, the coverage study, the wide-contact comparison
and the demo's calibration now offer decay lengths up to 1.5 thicknesses
(:func:`~pointforce_ros.contact.identify.decay_grid`, ``DECAY_CAP``); the ``grid`` column here
is the figure before that.

Session 27: ``--near flat`` puts the flat-topped near field ``(1 + r / c) exp(-r / c)`` on every
trial; figure 2 itself now chooses the near field per trial from the other trials
(:func:`~pointforce_ros.contact.identify.choose_near`; its numbers in ``docs/STATUS.md``).

Usage: python data/figures/decay_cap.py [--objects vest lamb] [--caps 1.5 2] [--draws 10] [--fine]
       [--law fixed] [--near flat]
"""

import argparse
import time
from pathlib import Path

import numpy as np

from pointforce_ros.contact.identify import DECAY_GRID, shape_fits_from_probes
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.errors import NotConverged
from pointforce_ros.lab.figures import (_score, _simulate_ours, bake_depths, DEFAULT_C,
                                        load_poke_fixture, load_probe_fixture,
                                        PROBE_TRAIN_POKES, trial_poses)
from pointforce_ros.response.ours import ContactGpModel

HERE = Path(__file__).resolve().parent
OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')


def thickness(surface) -> float:
    """Median height above the table of the surface's upward-facing points, metres."""
    up = surface.normals[:, 2] > np.cos(np.radians(45.0))
    return float(np.median(surface.points[up, 2]))


def picks(calibration, trials, decays):
    """Per trial, the best ``(c, L)`` on the other trials over ``decays``."""
    out = []
    for j in range(len(trials)):
        others = [(t['mesh'], trial_poses(t), t['direction'], t['force'])
                  for i, t in enumerate(trials) if i != j]
        try:
            fits = shape_fits_from_probes(calibration, others, c_bounds=(1e-4, 0.1),
                                          decays=decays)
        except NotConverged:    # c wants the bound at every capped L: offer up to 1 m
            fits = shape_fits_from_probes(calibration, others, c_bounds=(1e-4, 1.0),
                                          decays=decays)
        best = min(fits, key=lambda f: f.rmse)
        out.append((float(best.c), float(best.decay)))
    return out


def object_caps(name, caps, draws, seed=0, data=HERE, fine=False, law=None, near='paper'):
    """Figure 2's ``ours`` for the full grid and each cap; prints and returns the medians.

    ``fine``: the grid with its geometric midpoints added (steps of sqrt 2); ``law``: the
    simulator's decay law (``None``: its default); ``near``: the shape function's near field
    (``'paper'`` or ``'flat'``, every trial; figure 2 chooses it per trial).
    """
    surface, curves, _ = load_poke_fixture(name, data, say=lambda s: None)
    trials, _, _ = load_probe_fixture(name, data, say=lambda s: None)
    h = thickness(surface)
    depths = bake_depths(curves)
    calibration = ContactSimulator(
        surface, ContactGpModel().fit(list(curves), surface).bake(surface, depths), DEFAULT_C,
        decay_law=law, near=near)
    full = tuple(DECAY_GRID)
    if fine:
        finite = sorted(L for L in DECAY_GRID if np.isfinite(L))
        middles = {float(np.sqrt(a * b)) for a, b in zip(finite[:-1], finite[1:])}
        full = tuple(sorted(set(full) | middles, reverse=True))
    grids = {'grid': full}
    for k in caps:
        grids[f'L <= {k:g} h'] = tuple(L for L in full if L <= k * h + 1e-9)
    shapes = {key: picks(calibration, trials, g) for key, g in grids.items()}
    for key, sh in shapes.items():
        print(f'[cap] {name} (h = {1e3 * h:.1f} mm) {key}: (c, L) per trial [mm] '
              + ', '.join(f'{1e3 * c:.1f}/{1e3 * L:.0f}' for c, L in sh), flush=True)
    peak = max(float(np.linalg.norm(t['force'], axis=1).max()) for t in trials)
    rng = np.random.default_rng([int(seed), 2])
    rmse = {key: [] for key in shapes}
    per_trial = {key: [] for key in shapes}
    every = list(range(len(trials)))
    for _ in range(int(draws)):
        pick = rng.choice(len(curves), size=PROBE_TRAIN_POKES, replace=False)
        model = ContactGpModel().fit([curves[i] for i in pick], surface)
        sim = ContactSimulator(surface, model.bake(surface, depths), DEFAULT_C, decay_law=law,
                               near=near)
        for key, sh in shapes.items():
            pred = [_simulate_ours(sim.with_shape_constant(c, L), [t])[0]
                    for (c, L), t in zip(sh, trials)]
            rmse[key].append(_score(pred, trials, every)[0])
            per_trial[key].append([_score(pred, trials, [j])[0] for j in every])
    out = {key: float(np.median(v)) for key, v in rmse.items()}
    for key, v in per_trial.items():
        print(f'[cap] {name} {key}: per trial ' + ', '.join(
            f'{t["kind"]} {100 * e / peak:.1f} %' for t, e in zip(trials, np.median(v, axis=0))))
    print(f'[cap] {name}: force RMSE, median of {draws} draws, % of the {peak:.1f} N peak: '
          + ', '.join(f'{key} {v:.3f} N ({100 * v / peak:.1f} %)' for key, v in out.items()),
          flush=True)
    return out


def main():
    """Run the study on the chosen objects."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS), choices=OBJECTS)
    parser.add_argument('--caps', nargs='+', type=float, default=[1.5, 2.0])
    parser.add_argument('--draws', type=int, default=10)
    parser.add_argument('--fine', action='store_true', help='decay grid in steps of sqrt 2')
    parser.add_argument('--law', choices=('fixed', 'penetration'), default=None,
                        help="the simulator's decay law (default: its own)")
    parser.add_argument('--near', choices=('paper', 'flat'), default='paper',
                        help="the shape function's near field on every trial")
    args = parser.parse_args()
    started = time.monotonic()
    for name in args.objects:
        object_caps(name, args.caps, args.draws, fine=args.fine, law=args.law, near=args.near)
    print(f'[cap] done in {time.monotonic() - started:.0f} s')


if __name__ == '__main__':
    main()
