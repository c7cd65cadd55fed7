#!/usr/bin/env python3
"""Regenerate the FEM fixtures of test/data/fem/ (live-path caches and validation data).

Usage::

    python data/fem/make_fem_cache.py                 # everything (about an hour)
    python data/fem/make_fem_cache.py --object lamb   # one object's live cache
    python data/fem/make_fem_cache.py --object vest --holdout 4   # vest, lamb, thin_layer
                                        # as committed (dome, plush: the default 2)
    python data/fem/make_fem_cache.py --mesh-noise --object dome  # FE noise, no files
    python data/fem/make_fem_cache.py --validation    # Hertz + refinement fixtures only
    python data/fem/make_fem_cache.py --validation --part hertz   # one of the two

Scenario of each file:
- ``live_<object>.npz``: the live point-probe table of ``config/objects/<object>.yaml``
  (nonlinear neo-Hookean pokes along the surface normal on ``live.grid`` locations, probe
  :data:`pointforce_ros.sim.fem.live.POINT_PROBE`, element size ``mesh.live`` near the probe)
  plus held-out full solves at seeded random locations and the live path's error on them.
- ``hertz_fine.npz``: rigid sphere R = 10 mm on a homogeneous quarter block (600 x 600 x 300 mm,
  bonded base, symmetry planes), E = 100 kPa, nu = 0.45, small-strain, depths 0.3 and 0.5 mm,
  at 0.7 / 0.5 / 0.35 mm elements at the contact, plus nu = 0.3 at 0.35 mm
  (:data:`pointforce_ros.sim.fem.validation.HERTZ`, ``HERTZ_H_FINE``); about 17 min.
- ``refine_fine.npz``: point probe on a homogeneous 60 x 60 x 40 mm block (E = 100 kPa,
  nu = 0.45), neo-Hookean, to 2 and 5 mm at 3 / 1.5 / 1 / 0.75 mm elements (``REFINE_H``).

Measured on the shared 2-core machine (heavily loaded, times are wall clock): lamb (4 x 5 grid)
2199 s (4 x 5; 7 x 7 with 4 held-out solves: 614 s on a quieter machine), plush (5 x 4)
414 s, thin_layer 1295 s (4 x 3; 7 x 7 with 4 held-out solves: 367 s), vest 1144 s (4 x 3;
7 x 7 with 4 held-out solves: 525 s), dome 1640 s, foam_block (7 x 7, 4 held-out solves)
1100 s;
validation: Hertz 669 s (0.35 mm runs 266-282 s), refinement about 95 min (the 1 mm run
1032 s, the 0.75 mm run 4488 s).

Runs with ``nice`` friendliness in mind: one process, progress on stdout, timings at the end.
"""

import argparse
import os
import sys
import time

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    # one BLAS thread: on a shared, loaded machine threaded BLAS spins and runs ~2x slower
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..')))

from pointforce_ros.sim.fem import validation  # noqa: E402
from pointforce_ros.sim.fem.live import (cache_path, LiveContact,  # noqa: E402
                                         nonlinear_point_poke, uv_to_xy)
from pointforce_ros.sim.objects import list_objects, load_object  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def say(msg):
    """Print a progress line at once."""
    print(msg, flush=True)


def holdout_locations(live, count, seed=7):
    """(x, y) of ``count`` held-out pokes, uniform in the grid's reference coordinates."""
    rng = np.random.default_rng(seed)
    tb = live.table
    out = []
    for _ in range(count):
        u = rng.uniform(tb.u[0], tb.u[-1])
        v = rng.uniform(tb.v[0], tb.v[-1])
        out.append(tuple(float(a) for a in uv_to_xy(live.spec, u, v)))
    return out


def build_object(name, holdout=2, seed=7):
    """Build the live cache of ``name`` and measure its error on held-out full solves."""
    t0 = time.time()
    spec = load_object(name)
    live = LiveContact.build(spec, progress=say)
    errs, rows = [], []
    for k, (x, y) in enumerate(holdout_locations(live, holdout, seed)):
        depths, f, n, _ = nonlinear_point_poke(spec, x, y, force_stop=spec.force_cap)
        solved = np.isfinite(f[:, 0])  # steps past the force cap may fail: left out
        depths, full = depths[solved], f[solved] @ n
        pred = np.array([live.normal_force(x, y, d) for d in depths])
        use = depths >= 0.002
        rel = np.abs(pred[use] - full[use]) / np.abs(full[use])
        errs.append(rel)
        rows.append(np.column_stack([np.full(len(depths), x), np.full(len(depths), y), depths,
                                     full, pred]))
        say(f'{name}: held-out {k + 1}/{holdout} at ({x:.4f}, {y:.4f}): max error '
            f'{rel.max() * 100:.2f} % (full {full[-1]:.2f} N, live {pred[-1]:.2f} N at '
            f'{depths[-1] * 1e3:.1f} mm)')
    allerr = np.concatenate(errs)
    live.meta.update(build_seconds=time.time() - t0,
                     holdout_max_rel_error=float(allerr.max()),
                     holdout_mean_rel_error=float(allerr.mean()))
    live.meta['holdout_rows'] = 0  # scalar meta only; rows go in their own array below
    path = cache_path(name)
    live.save(path)
    with np.load(path) as data:
        payload = dict(data)
    payload['holdout'] = np.concatenate(rows)  # (R, 5): x, y, depth, full N, live N
    tmp = path + '.tmp.npz'
    np.savez_compressed(tmp, **payload)
    os.replace(tmp, path)
    say(f'{name}: done in {time.time() - t0:.0f} s, held-out max error '
        f'{allerr.max() * 100:.2f} %, mean {allerr.mean() * 100:.2f} % -> {path}')


def mesh_noise(name, seed=7):
    """Print the full solve's spread over mesh shifts at the first held-out location."""
    live = LiveContact.load(name, build=False)
    (x, y), = holdout_locations(live, 1, seed)
    t0 = time.time()
    r = validation.mesh_shift_case(live.spec, x, y)
    for dx, f in zip(r['shifts'], r['force']):
        say(f'{name} at ({x:.4f}, {y:.4f}), mesh refined {dx * 1e3:.1f} mm off: '
            f'{np.round(f, 3)} N at {np.round(r["depths"] * 1e3, 1)} mm')
    use = r['depths'] >= 0.002
    say(f'{name}: spread over the shifts at >= 2 mm: {np.round(100 * r["spread"][use], 1)} %, '
        f'{time.time() - t0:.0f} s')


def main(argv=None):
    """Parse the command line and build the requested fixtures."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--object', action='append', help='object name (repeatable); default all')
    ap.add_argument('--holdout', type=int, default=2,
                    help='held-out full solves per object that measure the live path (default 2)')
    ap.add_argument('--mesh-noise', action='store_true',
                    help='only print, per object, the live-path poke at its first held-out '
                         'location on meshes refined 0 / 1 / 2 mm off it (the full solve\'s '
                         'own discretisation noise); writes nothing')
    ap.add_argument('--validation', action='store_true', help='only the validation fixtures')
    ap.add_argument('--no-validation', action='store_true', help='skip validation fixtures')
    ap.add_argument('--part', choices=('hertz', 'refine'), action='append',
                    help='with --validation: only this fixture (repeatable)')
    args = ap.parse_args(argv)
    t0 = time.time()
    if args.mesh_noise:
        for name in args.object or list_objects():
            mesh_noise(name)
        return
    if not args.validation:
        names = args.object or sorted(list_objects(), key=lambda n: n == 'dome')
        for name in names:
            build_object(name, holdout=args.holdout)
    if args.validation or (not args.object and not args.no_validation):
        t1 = time.time()
        validation.make_fixtures(HERE, progress=say, parts=args.part or ('hertz', 'refine'))
        say(f'validation fixtures: {time.time() - t1:.0f} s')
    say(f'total {time.time() - t0:.0f} s')


if __name__ == '__main__':
    main()
