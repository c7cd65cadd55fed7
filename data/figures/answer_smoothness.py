#!/usr/bin/env python3
"""How smooth the contact answer is along a planner's moves (a study, session 43).

A planner that takes finite differences of the wrench (a push or grasp optimiser) needs to know
over what step the answer is smooth. Ours (fitted on all 30 pokes of a figure fixture, baked on
its surface as the learner bakes) drives the contact simulator (``c`` = 4 mm, the default
rigid-sample spacing of 3 mm); a sphere (20 mm radius), a flat box (30 x 30 mm) and a
cylinder (10 mm radius, 60 mm long, axis along x) are placed over the middle of the object,
3 mm past its top, and moved:

- sideways over 10 mm in 2 um steps (along x; the cylinder across its axis, along y): ``jumps``
  counts the steps whose change in ``Fz`` is over 20 times the median step's, with the largest
  as a share of the force; the finite-difference slope error is the median of
  ``|central difference - slope of a degree-5 fit over the 10 mm|`` over the median fitted
  slope, for steps ``h`` of 0.01, 0.1, 0.5 and 1 mm;
- along the approach over 6 mm in 1 um steps: the same, and how many steps the force falls
  as the body goes deeper.

Each rigid sample's estimated contact point and nominal displacement average its three
nearest surface points with equal weights (seed 000, eq. 1), so the answer steps where the
third and fourth nearest of a sample swap; with some 50 samples in contact that is every few
tens of microns of sideways travel. For the sphere's sideways sweep each jump is put down to
its cause (:func:`attribute`): a kept sample's neighbour triple changed, or the kept samples
themselves (one per surface point and per triple; a sample entering contact).

Session 43, lamb (record ``answer_smoothness.log``): sideways 21-45 steps per mm, each at
most 0.3-1.0 % of the force, and the slope error 260-430 % at 0.01 mm, 87-228 % at 0.1 mm,
22-64 % at 0.5 mm and 9-34 % at 1 mm; along the approach no step over 20 times the median,
slope error 0.2-1.7 % at every ``h``, and one step in 18 000 where the force fell (0.25 mN at
11.3 N, the LCP's tolerance). So: finite differences along the approach at any step; sideways
at 1 mm or more, and even then with the sideways slope known to some 10-30 %. Of the
sphere's 384 sideways jumps, 339 are a kept sample's neighbour triple changing alone (the
largest, 0.99 %, among them), 15 the kept samples changing and 30 both: neighbour weights that
vanish where a sample's third and fourth nearest swap would take out most of them.

Session 44 (``--neighbours smooth``, the simulator's weights that vanish where a point leaves
a sample's three): sideways 12 steps over 20 times the median one for the sphere (384 with
equal weights), 31 for the box (453), 74 for the cylinder (212); the largest 0.35, 0.17 and
0.49 % of the force; none is a neighbour triple changing alone any more (the sphere's 12: 9
the kept samples, 3 both). The slope error at 1 mm 25, 10 and 15 % (34, 9 and 17 %): what is
left are the kept samples changing and the kinks of the weights. Squared weights ``(r_4 -
r_k)^2``, whose slope vanishes too where a point leaves the three, do no better (9, 25 and 73
steps, slope error at 1 mm 35, 11 and 15 %; not kept).

Usage: python data/figures/answer_smoothness.py [--object lamb] [--neighbours equal|smooth]
(about 2 min on one core; set OPENBLAS_NUM_THREADS=1).
"""

import argparse
import time

import numpy as np

from pointforce_ros.contact.sampling import sample_mesh_surface
from pointforce_ros.contact.simulator import ContactSimulator, NEIGHBOUR_RULES, NEIGHBOURS
from pointforce_ros.lab.figures import bake_depths, load_poke_fixture
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.shapes import box, cylinder, icosphere

BODIES = {'sphere': (lambda: icosphere(0.02, 2), 0.02, 0),
          'box': (lambda: box((0.03, 0.03, 0.02)), 0.0, 0),
          'cylinder': (lambda: cylinder(0.01, 0.06), 0.0, 1)}
"""Name: (mesh, height of its lowest point below the mesh origin, sideways axis)."""
STEPS = (1e-5, 1e-4, 5e-4, 1e-3)
DEPTH = 0.003


def sweep(sim, mesh, poses):
    """``Fz`` (N) at each pose, the body moving along -z."""
    return np.asarray(sim.query_batch(mesh, poses, [0.0, 0.0, -1.0], poses[:, :3]).wrenches)[:, 2]


def smoothness(fz, step, span):
    """``(jumps, largest jump / F, slope errors per STEPS, steps where F fell, largest fall)``."""
    change = np.diff(fz)
    big = np.abs(change) > 20.0 * max(np.median(np.abs(change)), 1e-9)
    largest = float(np.max(np.abs(change[big]) / np.abs(fz[1:][big]))) if big.any() else 0.0
    x = np.linspace(0.0, 1.0, len(fz))
    slope = np.polyval(np.polyder(np.polyfit(x, fz, 5)), x) / span
    errors = []
    for h in STEPS:
        k = max(1, int(round(h / step)))
        central = (fz[2 * k:] - fz[:-2 * k]) / (2 * k * step)
        errors.append(float(np.median(np.abs(central - slope[k:-k]))
                            / np.median(np.abs(slope[k:-k]))))
    fell = change < -1e-12
    return (int(big.sum()), largest, errors, int(fell.sum()),
            float(-change[fell].min()) if fell.any() else 0.0)


def attribute(sim, mesh, poses, fz):
    """``{cause: (count, largest jump / F)}`` of the sideways jumps (identity rotations only).

    Between the two poses of each jump the contact candidates (steps 1-3 of the simulator:
    each rigid sample's neighbour triple, one sample kept per surface point and per triple)
    are compared: ``triple`` a kept sample's three nearest surface points changed, ``samples``
    the kept samples changed, ``both``, or ``neither``.
    """
    local, _ = sample_mesh_surface(mesh, sim.spacing)
    change = np.diff(fz)
    big = np.flatnonzero(np.abs(change) > 20.0 * max(np.median(np.abs(change)), 1e-9))

    def kept(i):
        cand = sim._candidates(local, np.eye(3)[None], poses[i:i + 1, :3],
                               np.array([0.0, 0.0, -1.0]))
        ids = np.argmin(np.linalg.norm((cand['p'] - poses[i, :3])[:, None, :] - local[None],
                                       axis=2), axis=1)
        return {int(k): tuple(sorted(t)) for k, t in zip(ids, cand['nbr'])}

    out = {k: [] for k in ('triple', 'samples', 'both', 'neither')}
    for j in big:
        before, after = kept(j), kept(j + 1)
        moved = set(before) != set(after)
        triple = any(before[k] != after[k] for k in set(before) & set(after))
        cause = 'both' if moved and triple else 'triple' if triple else \
            'samples' if moved else 'neither'
        out[cause].append(abs(change[j]) / abs(fz[j + 1]))
    return {k: (len(v), max(v, default=0.0)) for k, v in out.items()}


def main(argv=None):
    """Print one line per body and direction."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--object', default='lamb')
    parser.add_argument('--neighbours', choices=NEIGHBOUR_RULES, default=NEIGHBOURS,
                        help="step 2's neighbour weights (default %(default)s)")
    args = parser.parse_args(argv)
    surface, curves, _ = load_poke_fixture(args.object, say=lambda line: None)
    sim = ContactSimulator(surface, ContactGpModel().fit(curves, surface).bake(
        surface, bake_depths(curves)), c=0.004, neighbours=args.neighbours)
    middle = np.median(surface.points, axis=0)
    top = surface.points[np.linalg.norm(surface.points[:, :2] - middle[:2], axis=1) < 0.003,
                         2].max()
    for name, (make, low, side) in BODIES.items():
        mesh = make()
        for direction, span, step in (('sideways', 0.01, 2e-6), ('approach', 0.006, 1e-6)):
            start = time.monotonic()
            n = int(round(span / step)) + 1
            poses = np.zeros((n, 7))
            poses[:, 6] = 1.0
            poses[:, :3] = middle
            travel = np.linspace(0.0, span, n)
            if direction == 'sideways':
                poses[:, side] += travel - span / 2
                poses[:, 2] = top + low - DEPTH
            else:
                poses[:, 2] = top + low - travel
            fz = sweep(sim, mesh, poses)
            jumps, largest, errors, fell, drop = smoothness(fz, step, span)
            causes = attribute(sim, mesh, poses, fz) if (
                name == 'sphere' and direction == 'sideways') else None
            print(f'{args.object} {args.neighbours} {name} {direction} over {span * 1e3:.0f} mm: Fz '
                  f'{fz.min():.2f}-{fz.max():.2f} N; {jumps} jumps (largest '
                  f'{largest * 100:.2f} % of the force); slope error at h = 0.01 / 0.1 / 0.5 / '
                  f'1 mm: ' + ' / '.join(f'{e * 100:.1f} %' for e in errors)
                  + f'; steps where the force fell: {fell} of {n - 1} (largest '
                  f'{drop * 1e3:.3g} mN)'
                  + (''.join(f'; {k} {n} (largest {v * 100:.2f} %)'
                             for k, (n, v) in causes.items()) if causes else '')
                  + f'   [{time.monotonic() - start:.0f} s]', flush=True)


if __name__ == '__main__':
    main()
