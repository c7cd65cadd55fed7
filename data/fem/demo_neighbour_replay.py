#!/usr/bin/env python3
"""Stored demo models under each neighbour rule of the contact simulator (a study, session 44).

Step 2 of the simulator averages a rigid sample's three nearest surface points. The paper
weighs them equally, so the answer steps each time a sample's third and fourth nearest swap
(``data/figures/answer_smoothness.py``); session 44 made the default weights vanish where a
point leaves the three (``neighbours='smooth'``,
:func:`~pointforce_ros.contact.single_pose.neighbour_weights`). This replays ``pointforce demo
--out DIR`` runs as the contact service answers them (:func:`served_variant`: ``(c, L)`` from the
sphere and rod pushes, then each query through
:func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty`) under three set-ups:

- ``equal``: identified and served with equal weights (the code before session 44);
- ``smooth``: identified and served with smooth weights (the code after);
- ``mixed``: ``(c, L)`` identified with equal weights, served with smooth ones (a model file
  calibrated before session 44, served after).

Per run and set-up: ``(c, L)``, the queries' force RMSE as a share of the largest true force,
how many ``Fz`` lie below the truth and inside their 90 % intervals; per set-up the summary.

Usage: python data/fem/demo_neighbour_replay.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
"""

from contextlib import contextmanager
from dataclasses import replace

import numpy as np

from demo_floor_setup import (last_model_path, meets_demo_goals,  # this folder
                              query_score, replay_arguments, served_last_model, served_variant)
from pointforce_ros.contact import simulator as simulator_module
from pointforce_ros.contact.identify import calibrate_shape, decay_grid
from pointforce_ros.contact.uncertainty import wrench_uncertainty, Z90
from pointforce_ros.model.files import load_model

SETUPS = ('equal', 'smooth', 'mixed')


@contextmanager
def rule(name):
    """Build every simulator inside with the neighbour rule ``name`` (the module's default)."""
    before = simulator_module.NEIGHBOURS
    simulator_module.NEIGHBOURS = name
    try:
        yield
    finally:
        simulator_module.NEIGHBOURS = before


def mixed(model, pushes, queries, out):
    """:func:`served_variant` with ``(c, L)`` identified under equal weights, served smooth."""
    with rule('equal'):
        sim = served_last_model(out)
        cal = calibrate_shape(sim, pushes, decays=decay_grid(sim.surface))
    served = replace(model, shape_constant=cal.fit.c, shape_decay=cal.fit.decay,
                     shape_near=cal.near, meta={**model.meta, **cal.sources()})
    with rule('smooth'):
        answers = [wrench_uncertainty(served, mesh, [pose], a, centre)
                   for _, mesh, pose, a, centre in queries]
    return (cal, np.array([u.wrench[0, :3] for u in answers]),
            np.array([u.std[0, 2] for u in answers]))


def main():
    """Print one line per run and set-up, then one per set-up."""
    args, demo, pushes, true, largest = replay_arguments(__doc__.splitlines()[0])
    scores = {name: [] for name in SETUPS}
    for out in args.demo_out:
        model = load_model(last_model_path(out))
        for name in SETUPS:
            if name == 'mixed':
                cal, pred, std = mixed(model, pushes, demo.queries, out)
            else:
                with rule(name):
                    cal, pred, std = served_variant(model, served_last_model(out), pushes,
                                                    demo.queries)
            pct, below = query_score(pred, true, largest)
            inside = int(np.sum(np.abs(pred[:, 2] - true[:, 2]) <= Z90 * std))
            scores[name].append((pct, below, inside))
            print(f'{out} {name:6s}: c {1e3 * cal.fit.c:.2f} mm, L {1e3 * cal.fit.decay:.0f} mm; '
                  f'queries {pct:.2f} %, {below} of 9 below, {inside} of 9 inside; Fz pred / '
                  f'true ' + ' '.join(f'{v:.3f}' for v in pred[:, 2] / true[:, 2]), flush=True)
    for name, rows in scores.items():
        pct = np.array([r[0] for r in rows])
        meet = sum(1 for p, b, _ in rows if meets_demo_goals(p, b))
        print(f'{name:6s}: {len(rows)} runs, RMSE {pct.min():.2f}-{pct.max():.2f} % (mean '
              f'{pct.mean():.2f} %), both goals {meet} of {len(rows)}; true Fz inside '
              f'{sum(r[2] for r in rows)} of {9 * len(rows)}')


if __name__ == '__main__':
    main()
