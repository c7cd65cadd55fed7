"""Benchmark of the cell's object physics (wired into ``pointforce bench cell --json``)."""

import time

import numpy as np

from pointforce_ros.sim.fem.live import (cache_path, LiveContact, nonlinear_point_poke,
                                         uv_to_xy)
from pointforce_ros.sim.objects import list_objects
from pointforce_ros.errors import DataError


def bench_cell(object_name: str = 'plush', queries: int = 2000, full_solve: bool = True,
               seed: int = 0) -> dict:
    """Time the full nonlinear solve and the live path; report the live path's error.

    Args:
        object_name: object whose live cache and FE model are timed.
        queries: number of random live queries timed.
        full_solve: also time a 4-step full nonlinear poke (tens of seconds).
        seed: RNG seed of the query locations.

    Returns:
        dict with ``full_solve_seconds_per_step``, ``live_query_seconds_median`` / ``_p99``,
        ``live_error_vs_full`` (per object: max and mean relative error of the held-out full
        solves stored in the caches, depths >= 2 mm), ``live_error_vs_full_max`` and
        ``live_speedup`` (full-solve step time / live query time).

    Raises:
        DataError: a live cache is missing (build it with make_fem_cache.py).

    """
    rng = np.random.default_rng(seed)
    live = LiveContact.load(object_name, build=False)
    tb = live.table
    u = rng.uniform(tb.u[0], tb.u[-1], queries)
    v = rng.uniform(tb.v[0], tb.v[-1], queries)
    x, y = uv_to_xy(live.spec, u, v)
    tips = live.spec.top_point(x, y) - np.array([0.0, 0.0, 1.0]) * rng.uniform(
        0.0, live.spec.max_depth, queries)[:, None]
    times = np.empty(queries)
    axis = np.array([0.0, 0.0, -1.0])
    for k in range(queries):
        t0 = time.perf_counter()
        live.point_probe_wrench(tips[k], axis)
        times[k] = time.perf_counter() - t0
    out = dict(object=object_name, live_query_seconds_median=float(np.median(times)),
               live_query_seconds_p99=float(np.percentile(times, 99)))
    errors = {}
    for name in list_objects():
        try:
            with np.load(cache_path(name)) as data:
                rows = data['holdout']
            other = LiveContact.load(name, build=False)
        except (OSError, KeyError, DataError):
            continue
        xs, ys, d, full, _ = rows.T
        pred = np.array([other.normal_force(a, b, c) for a, b, c in zip(xs, ys, d)])
        use = d >= 0.002
        rel = np.abs(pred[use] - full[use]) / np.abs(full[use])
        errors[name] = dict(max=float(rel.max()), mean=float(rel.mean()))
    out['live_error_vs_full'] = errors
    out['live_error_vs_full_max'] = max((e['max'] for e in errors.values()), default=None)
    if full_solve:
        depths = np.array([1.0, 2.0, 3.5, 5.0]) * 1e-3
        t0 = time.perf_counter()
        nonlinear_point_poke(live.spec, live.spec.centre[0], live.spec.centre[1], depths)
        step = (time.perf_counter() - t0) / len(depths)
        out['full_solve_seconds_per_step'] = step
        out['live_speedup'] = step / out['live_query_seconds_median']
    return out
