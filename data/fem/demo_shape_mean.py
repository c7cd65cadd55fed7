#!/usr/bin/env python3
"""Would the predictive mean over the shape function's spread lift the demo's answers? (a study)

The service answers at the identified ``(c, L)``; the calibration also stores their spread
(``shape_cov``, the covariance of ``(log c, 1/L)``), which only widens ``wrench_std``. The
force is not linear in ``log c`` and ``1/L``, so the mean over that spread differs from the
answer at its centre: the retransformation issue 17 names for the point model's parameters.
This replays stored ``pointforce demo --out DIR`` runs: each run's last model, the 9 planner
queries at the served ``(c, L)`` and averaged over ``N((log c, 1/L), shape_cov)`` by a 5 x 5
Gauss-Hermite rule (a tail length past infinity, ``1/L <= 0``, is no tail), each scored
against the FEM truth (Fz RMSE as a share of the largest true Fz, queries below the truth).

Result (session 29, twelve lamb runs of sessions 25-28, ``demo_shape_mean.log``): the mean is
0.5-1.7 % above the centre on every query (spheres a little more than paddles), RMSE 0.1-0.3
points lower on all twelve, queries below the truth unchanged on eleven (7 -> 6 on one). The
spread is not what keeps cylinder #2 at 0.73-0.81 of the truth. Not kept: 25 solves per
query (4 with the unscented rule) for a lift of about 1 %.

Usage: python data/fem/demo_shape_mean.py DEMO_OUT [DEMO_OUT ...]
"""

from pathlib import Path

import numpy as np

from demo_floor_setup import demo_runs_arguments  # this folder
from pointforce_ros.model.serving import WrenchServer

NODES, WEIGHTS = np.polynomial.hermite_e.hermegauss(5)
WEIGHTS = WEIGHTS / WEIGHTS.sum()


def query_fz(simulator, queries) -> np.ndarray:
    """Fz (N, base z) of each planner query under ``simulator``."""
    return np.array([float(simulator.query(mesh, pose, approach, tip).wrench.force[2])
                     for _, mesh, pose, approach, tip in queries])


def score(pred: np.ndarray, true: np.ndarray):
    """RMSE as a share of the largest true force (%), and the number below the truth."""
    r = pred - true
    return 100 * np.sqrt(np.mean(r ** 2)) / np.abs(true).max(), int((r < 0).sum())


def main():
    """Print one line per run: the served answer's score, the mean's, their ratio."""
    args, demo = demo_runs_arguments(__doc__.splitlines()[0])
    true = demo.gt['force'][:, 2]
    for out in args.demo_out:
        server = WrenchServer()
        model = server.load(sorted((Path(out) / 'cell' / 'models').glob('model-v*.npz'))[-1])
        sim = server.simulator()
        cov = np.asarray(model.meta['shape_cov'], dtype=float)
        c, decay = model.shape_constant, model.shape_decay
        inv = 1.0 / decay if np.isfinite(decay) else 0.0
        root = np.linalg.cholesky(cov + 1e-12 * np.eye(2))
        centre = query_fz(sim, demo.queries)
        mean = np.zeros_like(centre)
        for wi, xi in zip(WEIGHTS, NODES):
            for wj, xj in zip(WEIGHTS, NODES):
                z = root @ np.array([xi, xj])
                tail = 1.0 / (inv + z[1]) if inv + z[1] > 0 else np.inf
                mean += wi * wj * query_fz(sim.with_shape_constant(c * np.exp(z[0]), tail),
                                           demo.queries)
        print(f'{out}: c {1e3 * c:.2f} mm, L {1e3 * decay:.0f} mm, std of log c '
              f'{np.sqrt(cov[0, 0]):.2f}; at the centre %.1f %% (%d below), the mean %.1f %% '
              f'(%d below); mean / centre {np.round(mean / centre, 3).tolist()}'
              % (score(centre, true) + score(mean, true)), flush=True)


if __name__ == '__main__':
    main()
