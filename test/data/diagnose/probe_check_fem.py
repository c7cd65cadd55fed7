"""Score the demo's FEM planner queries as one-step probe trials (real FEM ground truth).

``data/fem/demo_queries_<object>.npz`` holds the full nonlinear FEM wrench of the 9 demo
queries (sphere, paddle, cylinder at three poses; ``make_demo_queries.py``). This script learns
the point model from the pokes of a ``pointforce cell generate`` folder of the same object, as
the nodes do, on that folder's ``surface.npz``, answers the queries through the contact service
and tests the spatial coupling (shape constant) on them::

    nice -n 10 pointforce cell generate --object lamb --scenario realistic --pokes 8
        --probes point --seed 1 --out /tmp/lamb_realistic     (one line)
    nice -n 10 python test/data/diagnose/probe_check_fem.py /tmp/lamb_realistic
"""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]  # test/


def main(folder: str, shape_constant: float = 0.004) -> int:
    """Print the probe score of the queries against the model learned from ``folder``."""
    from pointforce_ros.sim.objects import load_object
    from pointforce_ros.pokes.table import load_pokes
    from pointforce_ros.diagnose.probes import (learn_contact_model, ProbeTrial,
                                                score_probe_trials, trial_errors)
    from pointforce_ros.model.files import load_surface
    from pointforce_ros.bringup.demo import demo_query_set
    folder = Path(folder)
    spec = load_object(json.loads((folder / 'manifest.json').read_text())['object'])
    with np.load(ROOT / 'data' / 'fem' / f'demo_queries_{spec.name}.npz') as z:
        truth = {str(n): (f, t) for n, f, t in zip(z['names'], z['force'], z['torque'])}
    trials = [ProbeTrial(kind=name.split()[0], mesh=mesh, start=pose,
                         direction=np.asarray(approach, dtype=np.float64),
                         torque_centre=np.asarray(centre, dtype=np.float64),
                         depths=np.zeros(1), force=truth[name][0][None],
                         torque=truth[name][1][None])
              for name, mesh, pose, approach, centre in demo_query_set(spec)]
    score = score_probe_trials(load_pokes(folder), trials, load_surface(folder / 'surface.npz'),
                               {}, shape_constant=shape_constant)
    print(score.describe())
    model = learn_contact_model(load_pokes(folder), load_surface(folder / 'surface.npz'), {},
                                shape_constant)
    fitted = dataclasses.replace(model, shape_constant=score.coupling.fitted)
    errors = trial_errors(model, trials)[0]
    refit = trial_errors(fitted, trials)[0]
    for trial, err, err_c in zip(trials, errors, refit):
        true = float(np.linalg.norm(trial.force))
        print(f'  {trial.kind:9s} |F| true {true:6.2f} N, model '
              f'{np.linalg.norm(trial.force + err):6.2f} N, with the fitted c '
              f'{np.linalg.norm(trial.force + err_c):6.2f} N')
    return 0


if __name__ == '__main__':
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    sys.exit(main(sys.argv[1]))
