"""The demo's camera-only force check: ray registration, a coarse run on the cell's truth."""

import os

import numpy as np
import pytest

from pointforce_ros.bringup import camera_check
from pointforce_ros.deformation.cell_check import contact_on_scan, direction_std_deg
from pointforce_ros.errors import InvalidInput
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints
from pointforce_ros.sim.objects import load_object

DATA = os.path.join(os.path.dirname(__file__), '..', 'data', 'deformation')
BLOCK = os.path.join(DATA, 'foam_block.yaml')


def _glue():
    """The bringup glue of the camera-only check."""
    return camera_check


def test_contact_moves_along_the_line_of_sight_by_the_depth_bias():
    # a flat top at z = 0.04 seen with a 2 mm depth bias: every point 2 mm farther on its ray
    origin = np.array([0.3, -0.1, 0.25])
    xy = np.stack(np.meshgrid(np.linspace(0.48, 0.52, 81), np.linspace(-0.02, 0.02, 81)),
                  -1).reshape(-1, 2)
    true = np.column_stack([xy, np.full(len(xy), 0.04)])
    ray = true - origin
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    scan = true + 0.002 * ray
    q = np.array([0.5, 0.0, 0.04])
    want = q + 0.002 * (q - origin) / np.linalg.norm(q - origin)
    np.testing.assert_allclose(contact_on_scan(q, scan, origin, radius=0.001), want, atol=1e-4)
    far = np.array([0.9, 0.5, 0.04])
    np.testing.assert_array_equal(contact_on_scan(far, scan, origin), far)


def test_camera_estimate_of_a_held_out_push_on_coarse_meshes():
    # plumbing on coarse meshes (5 mm truth, 6 mm model, about 10 s): the estimate pushes
    # into the object with about the F/T's magnitude (the README's figure uses 2 mm / 4 mm)
    spec = load_object(BLOCK)
    camera = DepthCamera(noise_a=1e-4, noise_b=2e-3, depth_unit=1e-4, depth_bias=0.002, seed=3)
    poses = ring_viewpoints([spec.centre[0], spec.centre[1], 0.02], 0.25, count=2,
                            azimuth0_deg=200.0)
    check = _glue().camera_force_check_on(spec, camera, poses, depth=0.004, element_size=0.006,
                                          truth_h=0.005)
    assert np.linalg.norm(check.ft_force) > 0.5
    assert check.camera_force[2] < 0 and check.ft_force[2] < 0
    assert check.magnitude_error < 0.35
    assert check.young > 0 and 0.0 <= check.poisson < 0.5
    assert 'camera-only force' in check.line()


def test_a_cell_without_a_simulated_camera_is_refused():
    class RealCell:
        spec = None
        camera = None

    with pytest.raises(InvalidInput, match='simulated object and camera'):
        _glue().camera_force_check(RealCell())


def test_direction_std_of_an_isotropic_covariance_is_sigma_over_the_force():
    f = np.array([0.0, 0.0, -2.0])
    # sigma 0.1 N in every direction: about 0.05 rad across a 2 N force
    assert direction_std_deg(f, 0.01 * np.eye(3)) == pytest.approx(np.degrees(0.05), rel=1e-9)
    # uncertainty along the force only: no direction uncertainty
    assert direction_std_deg(f, np.diag([0.0, 0.0, 0.04])) == pytest.approx(0.0, abs=1e-12)
