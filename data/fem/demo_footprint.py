#!/usr/bin/env python3
"""Each demo query's error split into the point model's share and the contact family's (s35).

A planner query's predicted ``Fz`` over its FEM truth mixes two errors: the learned point
response under the query's contacts, and how the contact family (shape function, ``(c, L)``,
LCP) turns point responses into a wrench. For the last served model of each ``pointforce demo
--out DIR`` run, with ``(c, L)`` from the demo's calibration pushes as the demo identifies them
(:func:`~pointforce_ros.contact.identify.calibrate_shape`, the capped decay grid), this answers
every query and prints three ratios:

* ``query``: the predicted ``Fz`` over the true one (what the demo prints);
* ``point``: under that answer's contacts, the learned point force at each contact's own
  displacement over the true point-probe force there
  (:func:`~pointforce_ros.bringup.demo.true_force_below_observed`), both weighted by the
  contact forces: the point model's error where this query touches;
* ``family``: ``query / point``, what is left for the contact family.

Usage: python data/fem/demo_footprint.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
(about 20 s per run)
"""

from pathlib import Path

import numpy as np

from demo_floor_setup import demo_runs_arguments, served_last_model  # this folder
from pointforce_ros.bringup.demo import (_calibration_pokes, CALIBRATIONS,
                                         true_force_below_observed)
from pointforce_ros.contact.identify import calibrate_shape, decay_grid


def split(sim, fitted, demo, query, true_fz: float) -> tuple:
    """``(query, point, family)`` ratios of one query (see the module)."""
    _, mesh, pose, approach, centre = query
    result = fitted.query(mesh, pose, approach, centre)
    index = result.displaced_indices
    depth = result.actual_displacements
    weight = result.contact_forces / max(float(np.sum(result.contact_forces)), 1e-12)
    learned = sim.response.force(index, depth)
    true = np.array([true_force_below_observed(demo.spec, demo.live, sim.surface.points[i:i + 1],
                                               d)[0] for i, d in zip(index, depth)])
    ratio = float(result.wrench.force[2]) / true_fz
    point = float(np.sum(weight * learned)) / max(float(np.sum(weight * true)), 1e-12)
    return ratio, point, ratio / point


def main() -> None:
    """Print one block per run and the family's ratio per query over all runs."""
    args, demo = demo_runs_arguments(__doc__.splitlines()[0])
    vectors = _calibration_pokes(demo.spec, vectors=True)
    pushes = [vectors[name] for name in CALIBRATIONS if name in vectors]
    true = np.asarray(demo.gt['force'], dtype=float)
    family = {name: [] for name, *_ in demo.queries}
    for out in args.demo_out:
        sim = served_last_model(out)
        cal = calibrate_shape(sim, pushes, decays=decay_grid(sim.surface))
        fitted = sim.with_shape_constant(cal.fit.c, cal.fit.decay)
        print(f'{out}: c {1e3 * cal.fit.c:.2f} mm, L {1e3 * cal.fit.decay:.0f} mm '
              f'({len(pushes)} pushes); query / point / family', flush=True)
        for query, t in zip(demo.queries, true):
            ratio, point, rest = split(sim, fitted, demo, query, float(t[2]))
            family[query[0]].append(rest)
            print(f'  {query[0]:<18} {ratio:5.2f} {point:5.2f} {rest:5.2f}', flush=True)
    print(f'family (query / point) over {len(args.demo_out)} runs, min-max:')
    for name, values in family.items():
        print(f'  {name:<18} {min(values):.2f}-{max(values):.2f}')
    print('runs: ' + ' '.join(Path(out).as_posix() for out in args.demo_out))


if __name__ == '__main__':
    main()
