"""Contact-query benchmarks: ours against the paper's algorithm, measured in the same run.

Scene (seed 000's packing example): a 40 mm sphere of 150 surface points pushed 1-8 mm into a
~40 000-point equilibrium surface (a 200 x 200 mm sphere cap sampled 1 mm apart) with a
heterogeneous stiffness field ``k(x, y) = 800 (1 + 0.5 sin(40 x) cos(30 y))`` N/m.

* :func:`bench_contact`: median single-query time of :class:`ContactSimulator` and of
  :class:`PaperContactSimulator` with the regressor queried per call (scikit-learn
  ``ExtraTreesRegressor``, the paper's model family, trained on 10 synthetic pokes), plus the
  paper's algorithm with an analytic ``predict`` to isolate the algorithmic gain.
* :func:`bench_batch`: 10 000 poses of one sphere (a packing grid search) through
  :meth:`ContactSimulator.query_batch`, against the paper's per-query time from the same run.

Both return a JSON-serialisable dict whose ``figure`` is the speed-up ratio to the baseline.
"""

import time
from typing import Dict

import numpy as np

from pointforce_ros.lab.paper_contact import PaperContactSimulator
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.lab.synthetic_contact import (dome_surface, fibonacci_sphere_mesh,
                                                  linear_response)
from pointforce_ros.types import Pose

DOWN = np.array([0.0, 0.0, -1.0])
SPHERE_RADIUS = 0.02
SPACING = 0.01  # longer than the sphere mesh's edges: exactly its 150 vertices are sampled
C = 0.005


def _stiffness(points: np.ndarray) -> np.ndarray:
    return 800.0 * (1.0 + 0.5 * np.sin(40.0 * points[:, 0]) * np.cos(30.0 * points[:, 1]))


def _scene(n_grid: int, half: float):
    surface = dome_surface(n=n_grid, half=half, radius=0.3)
    response = linear_response(_stiffness(surface.points))
    return surface, response, fibonacci_sphere_mesh(150, SPHERE_RADIUS)


def _dome_height(xy: np.ndarray, radius: float = 0.3) -> np.ndarray:
    return np.sqrt(radius ** 2 - (xy ** 2).sum(axis=-1)) - radius


def _extra_trees_predict(surface, seed: int):
    """Fit the paper's regressor family on 10 synthetic pokes; return ``predict(features, d)``."""
    from sklearn.ensemble import ExtraTreesRegressor

    rng = np.random.default_rng(seed)
    pick = rng.choice(len(surface), 10, replace=False)
    depth = np.linspace(0.0, 0.012, 60)
    feats = np.repeat(surface.features[pick], len(depth), axis=0)
    d = np.tile(depth, len(pick))
    force = np.repeat(_stiffness(surface.points[pick]), len(depth)) * d
    model = ExtraTreesRegressor(n_estimators=100, random_state=seed, n_jobs=1)
    model.fit(np.column_stack([feats, d]), force)
    return lambda features, dd: model.predict(np.column_stack([features, dd]))


def _analytic_predict(features: np.ndarray, d: np.ndarray) -> np.ndarray:
    return _stiffness(features[:, :3]) * np.clip(d, 0.0, None)


def bench_contact(n_ours: int = 300, n_paper: int = 15, n_grid: int = 201, half: float = 0.1,
                  regressor: str = 'extra_trees', seed: int = 0, quick: bool = False) -> Dict:
    """Time one wrench query, ours against the paper's algorithm (module docstring).

    Args:
        n_ours: queries timed for :class:`ContactSimulator`.
        n_paper: queries timed for each paper variant (the first ``n_paper`` of the same poses).
        n_grid, half: surface of ``n_grid`` x ``n_grid`` points over ``+-half`` metres.
        regressor: ``'extra_trees'`` (the paper's model family, needs scikit-learn) or
            ``'analytic'`` (skip the regressor variant).
        seed: pose and regressor seed.
        quick: 60 of our queries and 3 of each paper variant (same scene), for CI.

    Returns:
        dict with medians in seconds (wall clock, and ``*_cpu_s`` process CPU time, which a
        loaded machine inflates less), ``figure`` = paper median / ours median, the paper's
        time breakdown, the largest wrench difference to the analytic paper variant (which
        computes the same model) and the paper LCP scheme's failures.

    """
    if quick:
        n_ours, n_paper = min(n_ours, 60), min(n_paper, 3)
    surface, response, mesh = _scene(n_grid, half)
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-0.4 * half, 0.4 * half, (n_ours, 2))
    depth = rng.uniform(0.001, 0.008, n_ours)
    z = _dome_height(xy) + SPHERE_RADIUS - depth
    poses = [Pose(position=[*p, h]) for p, h in zip(xy, z)]
    t0 = time.perf_counter()
    ours = ContactSimulator(surface, response, c=C, spacing=SPACING)
    ours.query(mesh, poses[0], DOWN, poses[0].position)
    setup = time.perf_counter() - t0
    ours_times, ours_cpu, ours_results = [], [], []
    for pose in poses:
        t0, c0 = time.perf_counter(), time.process_time()
        res = ours.query(mesh, pose, DOWN, pose.position)
        ours_cpu.append(time.process_time() - c0)
        ours_times.append(time.perf_counter() - t0)
        ours_results.append(res)
    variants = {'analytic': _analytic_predict}
    if regressor == 'extra_trees':
        variants['extra_trees'] = _extra_trees_predict(surface, seed)
    out = dict(surface_points=len(surface), rigid_points=150, contacts_median=float(
        np.median([r.contact_count for r in ours_results])), setup_s=setup,
        ours_median_s=float(np.median(ours_times)),
        ours_median_cpu_s=float(np.median(ours_cpu)),
        ours_p90_s=float(np.percentile(ours_times, 90)))
    for name, predict in variants.items():
        paper = PaperContactSimulator(surface, predict, c=C, spacing=SPACING)
        times, cpu, parts, worst, failures = [], [], [], 0.0, 0
        for i, pose in enumerate(poses[:n_paper]):
            t0, c0 = time.perf_counter(), time.process_time()
            res = paper.query(mesh, pose, DOWN, pose.position)
            cpu.append(time.process_time() - c0)
            times.append(time.perf_counter() - t0)
            parts.append([paper.last_timing[k] for k in ('collision', 'lcp', 'model')])
            scale = max(res.nominal_displacements.max(initial=0.0), 1e-3)
            failures += int(res.lcp_residual > 1e-9 * scale)
            if name == 'analytic':
                ref = np.linalg.norm(res.wrench.force) + 1e-9
                diff = ours_results[i].wrench.as_vector() - res.wrench.as_vector()
                worst = max(worst, float(np.abs(diff[:3]).max() / ref))
        med = np.median(parts, axis=0)
        out[f'paper_{name}_median_s'] = float(np.median(times))
        out[f'paper_{name}_median_cpu_s'] = float(np.median(cpu))
        out[f'paper_{name}_breakdown_s'] = dict(zip(('collision', 'lcp', 'model'),
                                                    map(float, med)))
        out[f'paper_{name}_lcp_failures'] = failures
        out[f'speedup_vs_paper_{name}'] = float(np.median(times) / out['ours_median_s'])
        if name == 'analytic':
            out['max_force_difference_rel'] = worst
    headline = 'extra_trees' if 'extra_trees' in variants else 'analytic'
    out['baseline'] = f'PaperContactSimulator ({headline} predict)'
    out['figure'] = out[f'speedup_vs_paper_{headline}']
    out['goal_met'] = bool(out['ours_median_s'] < 1e-3 and out['figure'] >= 50.0)
    return out


def bench_batch(n_xy: int = 25, n_z: int = 16, n_paper: int = 5,
                n_grid: int = 201, half: float = 0.1, seed: int = 0,
                quick: bool = False) -> Dict:
    """Time :meth:`ContactSimulator.query_batch` on a packing-style grid of sphere poses.

    The grid is ``n_xy`` x ``n_xy`` positions over +-40 % of the surface and ``n_z`` heights
    from 5 mm above the cap's top to 10 mm below it (``25 * 25 * 16 = 10 000`` poses);
    ``quick`` uses 10 x 10 x 10 poses and 2 paper queries.

    Returns:
        dict with the batch time, time per pose, the fraction of poses in contact and
        ``figure`` = (paper median query time x poses) / batch time, the paper's time being
        measured on ``n_paper`` of the same poses in this run.

    """
    if quick:
        n_xy, n_z, n_paper = min(n_xy, 10), min(n_z, 10), min(n_paper, 2)
    surface, response, mesh = _scene(n_grid, half)
    ticks = np.linspace(-0.4 * half, 0.4 * half, n_xy)
    heights = np.linspace(0.005, -0.010, n_z) + SPHERE_RADIUS
    gx, gy, gz = np.meshgrid(ticks, ticks, heights, indexing='ij')
    poses = np.column_stack([gx.ravel(), gy.ravel(), gz.ravel(),
                             np.zeros((gx.size, 3)), np.ones(gx.size)])
    sim = ContactSimulator(surface, response, c=C, spacing=SPACING)
    t0 = time.perf_counter()
    sim.projection(DOWN)
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    batch = sim.query_batch(mesh, poses, DOWN, np.zeros(3))
    seconds = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    touching = np.flatnonzero(batch.contact_count > 0)
    sample = rng.choice(touching, min(n_paper, len(touching)), replace=False)
    paper = PaperContactSimulator(surface, _analytic_predict, c=C, spacing=SPACING)
    times = []
    for i in sample:
        pose = Pose(position=poses[i, :3])
        t1 = time.perf_counter()
        paper.query(mesh, pose, DOWN, np.zeros(3))
        times.append(time.perf_counter() - t1)
    paper_total = float(np.median(times)) * len(poses) if times else float('nan')
    return dict(poses=len(poses), seconds=seconds, setup_s=setup,
                per_pose_us=1e6 * seconds / len(poses),
                in_contact_fraction=float(np.mean(batch.contact_count > 0)),
                max_contacts=int(batch.contact_count.max()),
                paper_median_s=float(np.median(times)) if times else float('nan'),
                baseline='PaperContactSimulator (analytic predict) x poses',
                figure=paper_total / seconds, goal_met=bool(seconds < 2.0))
