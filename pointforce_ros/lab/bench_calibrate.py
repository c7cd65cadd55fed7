"""Benchmark ``calibrate``: a fit of ``(c, L)`` to calibration pushes, candidates kept or not.

:func:`~pointforce_ros.contact.identify.calibrate_shape` solves each push's poses under some
1300 values of ``(c, L)`` (a scan and a refinement per decay length, for the joint fit, each
push held out and each push alone). Which rigid samples touch where, and how deep, does not
depend on ``(c, L)``: since session 32 each push's contact candidates are found once
(:meth:`~pointforce_ros.contact.simulator.ContactSimulator.prepare_batch`). The baseline, in the
same run on the same pushes, is the path before: the simulator without ``prepare_batch``, so
that every ``(c, L)`` searches the candidates again (``query_batch``). Both must give the same
calibration; the figure is the ratio of their times, with the number of candidate searches
each made.

Scene: the analytic patch (:func:`~pointforce_ros.lab.synthetic_contact.patch_contact_model`,
a stiff inclusion under a 60 x 60 mm patch) under the ``'penetration'`` decay law (the
learner's default), pushed at two depths each by the demo's probes (a 20 mm sphere, a 50 mm
rod of radius 10 mm across the inclusion's edge, a 40 mm paddle), measured with ``(c, L)`` =
(4 mm, 20 mm) and the rod 20 % stiffer than any ``(c, L)`` explains (so the held-out share is
not zero).

Run: ``pointforce bench calibrate [--quick] [--json]``.
"""

import time
from typing import Dict, List

import numpy as np

from pointforce_ros.contact import simulator as simulator_module
from pointforce_ros.contact.identify import calibrate_shape, DECAY_GRID
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.sim.fem.probes import cylinder_probe, paddle_probe, pose_for_push, sphere_probe

DOWN = np.array([0.0, 0.0, -1.0])
AT = np.array([0.505, 0.004, 0.04])


class _SearchEveryTime:
    """A simulator without ``prepare_batch``: each ``(c, L)`` searches the candidates again."""

    def __init__(self, simulator: ContactSimulator):
        self._simulator = simulator

    def __getattr__(self, name):
        if name == 'prepare_batch':
            raise AttributeError(name)
        return getattr(self._simulator, name)


def _pushes(spacing: float) -> tuple:
    """Return ``(start simulator, pushes)`` on the patch (see the module docstring)."""
    model = patch_contact_model(spacing=spacing)
    truth = ContactSimulator(model.surface, model.response, 0.004, decay=0.02,
                             decay_law='penetration')
    pushes = []
    for mesh, at, depths, roll, gain in (
            (sphere_probe(0.02), AT, (0.003, 0.005), 0.0, 1.0),
            (cylinder_probe(0.01, 0.05), AT + [0.012, 0, 0], (0.002, 0.004), np.pi / 2, 1.2),
            (paddle_probe(0.04), AT - [0.01, 0, 0], (0.001, 0.002), 0.0, 1.0)):
        poses = [pose_for_push(at + d * DOWN, DOWN, roll) for d in depths]
        force = truth.query_batch(mesh, poses, DOWN, AT).wrenches[:, :3]
        pushes.append((mesh, poses, DOWN, gain * force))
    return truth.with_shape_constant(0.01, np.inf), pushes


def _timed(simulator, pushes: List[tuple], decays, repeats: int) -> tuple:
    """Return (median wall s, median CPU s, candidate searches per fit, the last calibration)."""
    searches = [0]
    original = simulator_module.ContactSimulator._candidates

    def counted(self, *args):
        searches[0] += 1
        return original(self, *args)

    walls, cpus, cal = [], [], None
    simulator_module.ContactSimulator._candidates = counted
    try:
        for _ in range(repeats):
            searches[0] = 0
            c0, t0 = time.process_time(), time.perf_counter()
            cal = calibrate_shape(simulator, pushes, decays=decays)
            walls.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
    finally:
        simulator_module.ContactSimulator._candidates = original
    return float(np.median(walls)), float(np.median(cpus)), searches[0], cal


def bench_calibrate(repeats: int = 3, spacing: float = 0.002, quick: bool = False) -> Dict:
    """Time :func:`calibrate_shape` with the candidates kept and searched every time.

    Args:
        repeats: timed fits of each (the medians are reported).
        spacing: surface spacing of the patch, metres.
        quick: one fit each over three decay lengths, on a 3 mm patch.

    Returns:
        A dict: ``ratio`` = median baseline wall time / median ours (the figure),
        ``ratio_cpu`` the same in process CPU time, the candidate searches of one fit each
        (``searches_*``), and how far the two calibrations differ (``max_rel_diff``, over
        ``c``, ``L``, the held-out share and the covariance; round-off only).

    """
    decays = DECAY_GRID
    if quick:
        repeats, spacing, decays = 1, 0.003, (0.008, 0.016, 0.032)
    start, pushes = _pushes(spacing)
    ours = _timed(start, pushes, decays, repeats)
    base = _timed(_SearchEveryTime(start), pushes, decays, repeats)
    a, b = ours[3], base[3]
    pairs = [(a.fit.c, b.fit.c), (a.fit.decay, b.fit.decay), (a.relative_std, b.relative_std)]
    pairs += list(zip(a.shape_cov.ravel(), b.shape_cov.ravel()))
    diff = max(abs(x - y) / max(abs(y), 1e-300) for x, y in pairs if np.isfinite(y))
    return {'pushes': len(pushes), 'poses': sum(len(p[1]) for p in pushes),
            'surface_points': len(start.surface.points), 'decay_lengths': len(decays),
            'ours_s': round(ours[0], 3), 'baseline_s': round(base[0], 3),
            'ratio': round(base[0] / ours[0], 2), 'ratio_cpu': round(base[1] / ours[1], 2),
            'searches_ours': ours[2], 'searches_baseline': base[2],
            'c_mm': round(1e3 * a.fit.c, 4), 'decay_mm': round(1e3 * a.fit.decay, 1),
            'relative_std': round(a.relative_std, 4), 'max_rel_diff': float(f'{diff:.3g}')}
