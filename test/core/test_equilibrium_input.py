"""Hostile clouds into the equilibrium surface: refused with a reason, never a foreign error."""

import numpy as np
import pytest

from pointforce_ros.errors import InvalidInput
from pointforce_ros.surface.equilibrium import build_equilibrium_surface, Scan, SurfaceConfig


def _plate(rng, n=3000):
    """A flat 200 x 200 mm plate 0.5 m in front of the camera, camera frame, metres."""
    return np.c_[rng.uniform(-0.1, 0.1, (n, 2)), np.full(n, 0.5)]


def test_a_far_stray_point_in_a_wide_roi_is_refused_with_a_reason():
    rng = np.random.default_rng(3)
    points = np.r_[_plate(rng), [[1e7, 0.0, 0.5]]]   # one garbage depth 10 000 km away
    config = SurfaceConfig(roi_min=[-1e9] * 3, roi_max=[1e9] * 3)
    with pytest.raises(InvalidInput, match='voxel edges'):
        build_equilibrium_surface(Scan(points), config)
    # the same plate without the stray point still builds
    surface, _ = build_equilibrium_surface(Scan(points[:-1]), config)
    assert np.all(np.isfinite(surface.points)) and len(surface) > 100


@pytest.mark.parametrize('shape', ['identical', 'collinear'])
def test_degenerate_clouds_are_refused_with_a_reason(shape):
    n = 2000
    if shape == 'identical':
        points = np.tile([0.1, 0.1, 0.5], (n, 1))
    else:
        points = np.c_[np.linspace(0.0, 0.2, n), np.zeros(n), np.full(n, 0.5)]
    config = SurfaceConfig(roi_min=[-1.0] * 3, roi_max=[1.0] * 3)
    with pytest.raises(InvalidInput, match='points left'):
        build_equilibrium_surface(Scan(points), config)
