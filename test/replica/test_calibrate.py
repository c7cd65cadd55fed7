"""The scaling calibrator's objective: the goal's two measures over their bounds, closed form."""

import numpy as np

from pointforce_ros.replica.calibrate import (_goal_error, _scale_fit, AT_MAX_GOAL, CURVE_GOAL,
                                              poke_errors)
from pointforce_ros.replica.data import MeasuredPoke


def _ball_like(seed):
    """A measured curve (Hertz-like) and a prediction of another shape: stiff early, soft deep."""
    rng = np.random.default_rng(seed)
    depth = np.linspace(0.002, 0.030, 15)
    force = 2.0e4 * depth ** 1.5 + rng.normal(0.0, 0.02, len(depth))
    pred = 2.0e4 * depth ** 1.5 * (1.6 - 0.7 * (depth - 0.002) / 0.028)
    return MeasuredPoke(f'p{seed}', np.zeros(2), depth, force, depth / 0.01), pred


def test_scale_minimises_the_squared_error_at_max_plus_over_the_curve():
    pokes, preds = zip(*(_ball_like(s) for s in range(3)))

    def objective(k):
        errs = [poke_errors(p, k * f) for p, f in zip(pokes, preds)]
        return sum((e.at_max / AT_MAX_GOAL) ** 2 + (e.curve / CURVE_GOAL) ** 2
                   for e in errs) / len(errs)

    k = _scale_fit(preds, pokes)
    # the closed form is the minimum of the goal's objective: a grid finds nothing lower
    grid = np.linspace(0.5 * k, 1.5 * k, 2001)
    assert objective(k) <= min(objective(g) for g in grid) + 1e-12
    np.testing.assert_allclose(_goal_error([k * f for f in preds], pokes), objective(k),
                               rtol=1e-9)
    # plain least squares over the curve leaves a larger error at the largest compression
    ls = sum(f @ p.force for f, p in zip(preds, pokes)) / sum(f @ f for f in preds)
    at_max = np.median([poke_errors(p, k * f).at_max for p, f in zip(pokes, preds)])
    at_max_ls = np.median([poke_errors(p, ls * f).at_max for p, f in zip(pokes, preds)])
    assert at_max < 0.5 * at_max_ls
