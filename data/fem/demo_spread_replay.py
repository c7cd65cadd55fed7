#!/usr/bin/env python3
"""Stored demos relearned with the per-poke laws spread by the processes or by trees (a study).

``ContactGpModel(spread='trees')`` (session 46, :mod:`pointforce_ros.response.trees`) spreads
the per-poke laws with Extra Trees instead of Gaussian processes; the learner's
``point_spread`` parameter chooses it. This replays stored ``pointforce demo --out DIR`` runs:
each run's poke store is relearned by the learner under each spread (its shape settings as the
run's last model has them), ``(c, L)`` identified from the demo's three calibration pushes as
the demo does, and the 9 planner queries answered as the contact service answers them
(:func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty`), scored against the FEM
truth: force RMSE as a share of the largest true force, ``Fz`` below the truth, true ``Fz``
inside the nominal 90 % intervals and their mean width. The row of the spread the run served
(``gp`` before session 47, ``mix`` since) reproduces the run's own numbers.

Session 46 (record ``demo_spread_replay.log``, the six fresh clones of ``demo_runs_s45.log``):
the trees 7.44-7.74 % (mean 7.54 %), both demo goals on 6 of 6, against 7.52-8.15 % (7.67 %)
and 5 of 6 with the processes (each run's own numbers); 54 of 54 true ``Fz`` inside either way,
the intervals wider with the trees (6.92 against 4.89 N mean width). On session 46's three
(``demo_runs_s46.log``): the trees 7.17-7.65 %, 3 of 3 meet; the processes 7.34-8.92 %, 2 of 3.
Session 47's four fresh clones of the mix (``demo_runs_s47.log``): the mix 6.81-6.98 % on three
(each run's own numbers) and 9.41 % on 47d, whose eighth poke (at the force cap, its power law's
onset 3 mm before the others') made the mix choose the power law and widened its trees'
scatter (mean width 13.79 N); the processes on the same pokes 6.92-7.21 %, 4 of 4 meet.

Usage: python data/fem/demo_spread_replay.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
(about a minute per run on one core)
"""

import functools
import tempfile
from pathlib import Path

import numpy as np

from demo_floor_setup import (last_model_path, meets_demo_goals,  # this folder
                              query_score, replay_arguments, served_variant)
from pointforce_ros.bringup.demo import _calibration_pokes
from pointforce_ros.contact.uncertainty import Z90
from pointforce_ros.model.files import load_model, load_surface
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.response.ours import ContactGpModel, SPREADS


def relearned(out, spread: str, tmp: Path):
    """``(model file contents, served simulator)`` of ``out``'s pokes learned under ``spread``."""
    last = load_model(last_model_path(out))
    learner = OnlineLearner(Path(out) / 'cell' / 'pokes', tmp / spread,
                            load_surface(Path(out) / 'cell' / 'surface.npz'),
                            shape_constant=last.shape_constant, shape_decay=last.shape_decay,
                            shape_decay_law=last.shape_decay_law, shape_near=last.shape_near,
                            model_factory=functools.partial(ContactGpModel, spread=spread))
    learner.update()
    path = learner.current_model_path()
    server = WrenchServer()
    server.load(path)
    return load_model(path), server.simulator(), len(learner.curves)


def main():
    """Print one line per run and spread, then one per spread."""
    args, demo, pushes, true, largest = replay_arguments(__doc__.splitlines()[0])
    three = pushes + [_calibration_pokes(demo.spec, vectors=True)['streak']]
    rows = {name: [] for name in SPREADS}
    with tempfile.TemporaryDirectory() as tmp:
        for k, out in enumerate(args.demo_out):
            for spread in SPREADS:
                model, sim, pokes = relearned(out, spread, Path(tmp) / str(k))
                cal, pred, std = served_variant(model, sim, three, demo.queries)
                pct, below = query_score(pred, true, largest)
                inside = int(np.sum(np.abs(pred[:, 2] - true[:, 2]) <= Z90 * std))
                width = float(np.mean(2 * Z90 * std))
                rows[spread].append((pct, below, inside, width))
                print(f'{out} {spread:5s}: {pokes} pokes, c {1e3 * cal.fit.c:.2f} mm, L '
                      f'{1e3 * cal.fit.decay:.0f} mm, share {100 * cal.relative_std:.0f} %; '
                      f'queries {pct:.2f} %, {below} of 9 below, {inside} of 9 inside (mean '
                      f'width {width:.2f} N); Fz pred / true '
                      + ' '.join(f'{v:.2f}' for v in pred[:, 2] / true[:, 2]), flush=True)
    for spread, got in rows.items():
        pct = np.array([g[0] for g in got])
        meet = sum(1 for p, b, _, _ in got if meets_demo_goals(p, b))
        print(f'{spread:5s}: {len(got)} runs, RMSE {pct.min():.2f}-{pct.max():.2f} % (mean '
              f'{pct.mean():.2f} %), both goals {meet} of {len(got)}; true Fz inside '
              f'{sum(g[2] for g in got)} of {9 * len(got)}, mean width '
              f'{np.mean([g[3] for g in got]):.2f} N')


if __name__ == '__main__':
    main()
