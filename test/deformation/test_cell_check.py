"""The demo's camera-only force check: ray registration, a coarse run on the cell's truth."""

from types import SimpleNamespace

import numpy as np
import pytest

from pointforce_ros.bringup import camera_check
from pointforce_ros.deformation.cell_check import (CameraForceCheck, contact_on_scan,
                                                   direction_std_deg, seeded_field)
from pointforce_ros.deformation.identify import Poke
from pointforce_ros.deformation.mesh import block_mesh
from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints
from pointforce_ros.sim.objects import load_object
from pointforce_ros.types import Surface


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
    # coarse meshes (5 mm truth, 6 mm model, about 10 s), a 2 mm depth bias: the estimate
    # pushes into the object with about the F/T's magnitude (the README's figure uses 2 / 4 mm)
    spec = load_object('foam_block')
    camera = DepthCamera(noise_a=1e-4, noise_b=2e-3, depth_unit=1e-4, depth_bias=0.002, seed=3)
    poses = ring_viewpoints([spec.centre[0], spec.centre[1], 0.02], 0.25, count=2,
                            azimuth0_deg=200.0)
    check = _glue().camera_force_check_on(spec, camera, poses, depth=0.004, element_size=0.006,
                                          truth_h=0.005)
    assert np.linalg.norm(check.ft_force) > 0.5
    assert check.camera_force[2] < 0 and check.ft_force[2] < 0
    # measured: 4.2 % and 6.0 deg; with the merged two-view scan as the residual's reference
    # (before issue 18's fix) 10.6 % and 25.0 deg: the 2 mm bias tilts the estimate
    assert check.magnitude_error < 0.12
    assert check.direction_error_deg < 15.0
    assert check.inside and check.direction_std_deg > 0
    assert check.young > 0 and 0.0 <= check.poisson < 0.5
    assert 'camera-only force' in check.line()


def test_a_cell_without_a_simulated_camera_is_refused():
    class RealCell:
        spec = None
        camera = None

    with pytest.raises(InvalidInput, match='simulated object and camera'):
        _glue().camera_force_check(RealCell())


def test_the_demo_check_prints_the_fused_force_against_the_ft_with_a_point_model():
    # a flat scanned top and a point law that says 1.0 N at the tip; the FEM says 2.0 N
    g = np.arange(-0.02, 0.0201, 0.002)
    xy = np.stack(np.meshgrid(g, g, indexing='ij'), -1).reshape(-1, 2) + [0.5, 0.0]
    surface = Surface(np.column_stack([xy, np.full(len(xy), 0.04)]),
                      np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
    depths = np.linspace(-0.002, 0.01, 25)
    forces = np.tile(250.0 * np.clip(depths, 0.0, None), (len(xy), 1))    # 1 N at 4 mm
    response = BakedResponse(depths=depths, forces=forces, slopes=np.full(len(xy), 250.0),
                             std=0.05 * forces + 1e-3)
    model = SimpleNamespace(surface=surface, response=response, version=4)
    check = CameraForceCheck(camera_force=np.array([0.0, 0.0, -2.0]), camera_std=0.1,
                             ft_force=np.array([0.0, 0.0, -1.0]),
                             contact_point=np.array([0.5, 0.0, 0.04]), depth=0.004,
                             young=5e4, poisson=0.3, seconds=1.0, estimate_seconds=0.1)
    tip = np.array([0.5, 0.0, 0.036])
    checks = _glue().fuse_check(check, tip, model)
    assert checks.fused.magnitude_error < 0.15 < checks.fem.magnitude_error
    lines = checks.lines()
    assert lines[0].startswith('fused camera force [') and 'FEM alone 2.00' in lines[1]
    assert 'point model v4, uncalibrated' in lines[1]
    assert _glue().fuse_check(check, tip, None).lines() == [
        check.line(), '(no fused force: no point model held by deformation_force)']
    refused = _glue().fuse_check(check, tip + [0.0, 0.0, 0.02], model)
    assert refused.fused is None and 'above the scanned surface' in refused.note


def test_direction_std_of_an_isotropic_covariance_is_sigma_over_the_force():
    f = np.array([0.0, 0.0, -2.0])
    # sigma 0.1 N in every direction: about 0.05 rad across a 2 N force
    assert direction_std_deg(f, 0.01 * np.eye(3)) == pytest.approx(np.degrees(0.05), rel=1e-9)
    # uncertainty along the force only: no direction uncertainty
    assert direction_std_deg(f, np.diag([0.0, 0.0, 0.04])) == pytest.approx(0.0, abs=1e-12)


def test_a_point_model_seed_gives_its_contrast_or_a_power_fitted_to_the_pokes():
    # point-model stiffness doubles from -x to +x; the pokes' own moduli rise by sqrt(2) only:
    # the field takes the seed's contrast to the power 0.5
    mesh = block_mesh((0.06, 0.05, 0.03), 0.005, 3, corner=(0.47, -0.025))
    gx, gy = np.meshgrid(np.linspace(0.47, 0.53, 13), np.linspace(-0.025, 0.025, 11))
    xy = np.column_stack([gx.ravel(), gy.ravel()])
    stiffness = 2.0 ** ((xy[:, 0] - 0.47) / 0.06)
    cloud = np.zeros((1, 3))
    pokes = [Poke([x, 0.0, 0.03], [0.0, 0.0, -1.0], cloud) for x in (0.48, 0.50, 0.52)]
    seed_at = 2.0 ** ((np.array([0.48, 0.50, 0.52]) - 0.47) / 0.06)
    fit = SimpleNamespace(local_young=tuple(4e4 * np.sqrt(seed_at)))
    field, exponent = seeded_field(mesh, pokes, fit, (xy, stiffness), length=0.004,
                                   exponent=None)
    assert exponent == pytest.approx(0.5, abs=0.05)
    x = mesh.nodes[mesh.tets].mean(axis=1)[:, 0]
    contrast = field[x > 0.52].mean() / field[x < 0.48].mean()
    assert 1.2 < contrast < 1.45   # sqrt(2 ** (0.8)) about 1.32; the full seed gives ~1.74
    # by default the seed's full contrast; without samples the pokes' own moduli
    full, one = seeded_field(mesh, pokes, fit, (xy, stiffness), length=0.004)
    assert one == 1.0 and full[x > 0.52].mean() / full[x < 0.48].mean() > 1.6
    assert seeded_field(mesh, pokes, fit)[1] == 1.0
    with pytest.raises(InvalidInput, match='no finite positive'):
        seeded_field(mesh, pokes, fit, (xy, -stiffness))
