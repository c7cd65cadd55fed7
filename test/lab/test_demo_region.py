"""The demo's region of interest is where its probes will touch the captured surface."""

import numpy as np

from pointforce_ros.bringup.demo import (calibration_rod_push, demo_query_set, planner_region,
                                         ROD_LENGTH)
from pointforce_ros.model.learner import region_candidates
from pointforce_ros.sim.objects import load_object
from pointforce_ros.types import Surface


def _flat_surface(spec):
    """A 1 mm grid over the object's top, at its true height (normals up)."""
    cx, cy = spec.centre
    xs, ys = np.meshgrid(np.arange(cx - 0.04, cx + 0.04, 0.001),
                         np.arange(cy - 0.03, cy + 0.03, 0.001))
    z = np.array([spec.top_height(x, y) for x, y in zip(xs.ravel(), ys.ravel())])
    points = np.column_stack([xs.ravel(), ys.ravel(), z])
    return Surface(points=points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))


def test_the_rods_footprint_is_a_strip_along_its_axis_not_a_disc_round_its_tip():
    spec = load_object('lamb')
    surface = _flat_surface(spec)
    mesh, poses, _ = calibration_rod_push(spec)
    rod = [(None, mesh, poses[-1], None, None)]
    rows = planner_region(rod, surface=surface)
    tip = poses[-1].position
    along = np.abs(rows[:, 1] - tip[1])           # the rod's axis is along y
    across = np.abs(rows[:, 0] - tip[0])
    assert along.max() > 0.4 * ROD_LENGTH and across.max() < 0.012
    discs = planner_region(rod)                   # without a surface: one disc at the tip
    assert discs.shape == (1, 4)
    everything = np.arange(len(surface))
    in_strip = region_candidates(surface.points, everything, rows)
    far = np.abs(surface.points[in_strip, 1] - tip[1]) > 0.018
    assert np.any(far)                            # the rod's ends are in, a 12 mm disc's not


def test_every_demo_query_touches_the_region():
    spec = load_object('lamb')
    surface = _flat_surface(spec)
    queries = demo_query_set(spec)
    rows = planner_region(queries, surface=surface)
    for _, _, pose, _, _ in queries:
        gap = np.hypot(rows[:, 0] - pose.position[0], rows[:, 1] - pose.position[1])
        assert gap.min() < 0.004
