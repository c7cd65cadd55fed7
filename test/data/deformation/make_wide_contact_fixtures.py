#!/usr/bin/env python3
"""Regenerate ``wide_foam_block.npz``: figure-2 style probe trials on the homogeneous foam block.

Usage::

    nice -n 10 python test/data/deformation/make_wide_contact_fixtures.py

The five cell objects' line and cylinder trials live in ``data/figures/probes_<name>.npz``;
the figure objects are not homogeneous. This makes the same kind of data for the cell object
``foam_block`` (``config/objects/foam_block.yaml``: E 50 kPa, nu 0.30; these fixtures predate
its live-path cache and do not use it):

- ``trialNN_*``, ``trial_kinds``: 2 line and 1 cylinder trials drawn and solved exactly as
  :func:`pointforce_ros.lab.figures.make_probe_fixture` does (:func:`pointforce_ros.sim.generate.
  probe_trials`, seeds 0 and 1, full neo-Hookean solve at the object's live mesh size), same
  keys.
- ``curve_*`` (:func:`pointforce_ros.lab.figures.curves_to_arrays`): ``POKES`` point pokes of the
  cell's point probe along the inward normal at seeded random locations, full nonlinear solves
  at the same mesh size, to the object's depth limit in ``POKE_STEPS`` steps, stopped past the
  force cap. They stand in for a recorded campaign: noise-free truth, contact onset at 0.
- ``surface_*``: the equilibrium surface scanned by the cell's camera (``realistic`` scenario,
  seed 0), as ``data/figures/pokes_<name>.npz`` holds it.

Measured here (2 shared cores, load 6-9): about 25 min in all.
"""

import os
import sys
import time

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..')))

from pointforce_ros.errors import NotConverged  # noqa: E402
from pointforce_ros.lab.figures import _scan_surface, _trial_arrays, curves_to_arrays  # noqa
from pointforce_ros.pokes.curves import PokeCurve  # noqa: E402
from pointforce_ros.sim.fem.indentation import solve_indentation  # noqa: E402
from pointforce_ros.sim.fem.live import POINT_PROBE  # noqa: E402
from pointforce_ros.sim.fem.probes import point_probe, pose_for_push  # noqa: E402
from pointforce_ros.sim.generate import probe_trials  # noqa: E402
from pointforce_ros.sim.objects import load_object  # noqa: E402
from pointforce_ros.sim.scenario import load_scenario  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(HERE, 'wide_foam_block.npz')
POKES = 10
POKE_STEPS = 10


def say(msg):
    """Print a progress line at once."""
    print(msg, flush=True)


def point_pokes(spec, count=POKES, steps=POKE_STEPS, seed=0):
    """Full-solve point pokes at seeded locations; returns a list of :class:`PokeCurve`."""
    rng = np.random.default_rng([seed, 11])
    probe = point_probe(**POINT_PROBE)
    depths = np.linspace(0.0, spec.max_depth, steps + 1)[1:]
    curves = []
    for k in range(count):
        x = spec.centre[0] + rng.uniform(-0.3, 0.3) * spec.size[0]
        y = spec.centre[1] + rng.uniform(-0.3, 0.3) * spec.size[1]
        q = np.asarray(spec.top_point(x, y), dtype=float)
        n = np.asarray(spec.top_normal(x, y), dtype=float)
        t0 = time.monotonic()
        try:
            res = solve_indentation(spec, probe, pose_for_push(q, -n), -n, depths,
                                    torque_centre=q, h=spec.mesh_live,
                                    stop_force=1.5 * spec.force_cap, keep_solved=True)
        except NotConverged as exc:
            say(f'poke {k}: skipped ({exc})')
            continue
        f = -(res.force @ -n)
        d = np.concatenate([[0.0], res.depths])
        f = np.concatenate([[0.0], f])
        curves.append(PokeCurve(poke_id=f'foam_block_{k:02d}', point=q, normal=n, d=d, f=f,
                                onset_d=0.0, t=d / 0.002))
        say(f'poke {k}: {f[-1]:.2f} N at {1e3 * d[-1]:.1f} mm, {time.monotonic() - t0:.0f} s')
    return curves


def main():
    """Build the fixture (about 25 min on the shared machine)."""
    t0 = time.monotonic()
    spec = load_object('foam_block')
    surface = _scan_surface(spec, load_scenario('realistic'), seed=0)
    say(f'surface: {len(surface.points)} points')
    trials = []
    for kind, count, kind_seed in (('line', 2, 0), ('cylinder', 1, 1)):
        trials += probe_trials(spec, [kind], count, kind_seed, progress=say)
    arrays = _trial_arrays('trial', trials)
    arrays.update(curves_to_arrays(point_pokes(spec)))
    arrays.update(surface_points=surface.points.astype(np.float32),
                  surface_normals=surface.normals.astype(np.float32),
                  surface_colors=surface.colors.astype(np.float32),
                  seconds=np.asarray(time.monotonic() - t0))
    np.savez_compressed(OUT, **arrays)
    say(f'wrote {OUT} in {time.monotonic() - t0:.0f} s')


if __name__ == '__main__':
    main()
