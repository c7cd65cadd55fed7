"""The fused camera force (issue 18): point model magnitude, FEM direction, inverse variance."""

from types import SimpleNamespace

import numpy as np
import pytest

from pointforce_ros.deformation import cell_check
from pointforce_ros.deformation.cell_check import (CameraForceCheck, cross_site_error,
                                                   fused_from_views, point_calibration)
from pointforce_ros.deformation.fused import (between_site_spread, depth_calibration,
                                              fuse_force, indentation_depth, point_model_force,
                                              small_sample_factor)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Surface

STIFFNESS = 4.0e4
"""``k`` of the synthetic point law ``f = k max(d - onset, 0) ** 1.5``, N/m^1.5."""
ONSET = -0.0012
"""Where the synthetic law's contact starts on the scan's depth axis, metres (a camera bias
puts the scanned surface 1.2 mm below the true one)."""


def _law(d, onset=ONSET):
    return STIFFNESS * np.clip(np.asarray(d) - onset, 0.0, None) ** 1.5


def _scan(seed=0, noise=2e-4, z=0.04 - 0.0012, tilt=(0.0, 0.0)):
    """A scanned flat top (2 mm grid, 60 x 60 mm, seeded noise) and its outward normals."""
    rng = np.random.default_rng(seed)
    g = np.arange(-0.03, 0.0301, 0.002)
    xy = np.stack(np.meshgrid(g, g, indexing='ij'), -1).reshape(-1, 2) + [0.5, 0.0]
    height = z + tilt[0] * (xy[:, 0] - 0.5) + tilt[1] * xy[:, 1]
    points = np.column_stack([xy, height + rng.normal(0.0, noise, len(xy))])
    n = np.array([-tilt[0], -tilt[1], 1.0])
    return points, np.tile(n / np.linalg.norm(n), (len(xy), 1))


def _point_model(points, normals, relative_std=0.05):
    """A point model baked from the synthetic law on the scan (every row the same)."""
    depths = np.linspace(-0.004, 0.012, 65)
    row = _law(depths)
    forces = np.tile(row, (len(points), 1))
    slope = 1.5 * STIFFNESS * (depths[-1] - ONSET) ** 0.5
    response = BakedResponse(depths=depths, forces=forces, slopes=np.full(len(points), slope),
                             std=relative_std * forces + 1e-3)
    return SimpleNamespace(surface=Surface(points, normals), response=response)


def _check(force, std, truth):
    return CameraForceCheck(camera_force=np.asarray(force, float), camera_std=std,
                            ft_force=np.asarray(truth, float),
                            contact_point=np.array([0.5, 0.0, 0.04]), depth=0.004, young=5e4,
                            poisson=0.3, seconds=1.0, estimate_seconds=0.1)


def test_depth_below_a_noisy_tilted_scan_is_read_by_the_plane_fit():
    points, normals = _scan(seed=1, noise=5e-4, tilt=(0.1, -0.05))
    tip = np.array([0.501, 0.0005, 0.0])
    surface_z = 0.04 - 0.0012 + 0.1 * 0.001 - 0.05 * 0.0005
    tip[2] = surface_z - 0.004 / normals[0, 2]   # straight down, 4 mm below along the normal
    d = indentation_depth(points, normals, tip, radius=0.006)
    want = (surface_z - tip[2]) * normals[0, 2]
    assert d.points >= 20
    np.testing.assert_allclose(d.depth, want, atol=3 * d.std + 5e-5)
    assert 0 < d.std < 2e-4          # 0.5 mm noise over ~28 points: about 0.1 mm
    np.testing.assert_allclose(d.normal, normals[0], atol=1e-9)
    np.testing.assert_allclose(points[d.index, :2], [0.5, 0.0], atol=0.0015)


def test_depth_needs_scan_points_about_the_probe_line():
    points, normals = _scan()
    with pytest.raises(InvalidInput, match='scan points within'):
        indentation_depth(points, normals, [0.7, 0.0, 0.03])
    with pytest.raises(InvalidInput, match='need points and normals'):
        indentation_depth(points, normals[:5], [0.5, 0.0, 0.03])


def test_point_force_is_the_law_at_the_measured_depth_with_its_spread():
    points, normals = _scan(noise=0.0)
    model = _point_model(points, normals)
    tip = np.array([0.5, 0.0, 0.04 - 0.004])          # 4 mm into the true surface
    d = indentation_depth(points, normals, tip)
    np.testing.assert_allclose(d.depth, 0.004 + ONSET, atol=1e-9)
    p = point_model_force(model.response, d)
    np.testing.assert_allclose(p.magnitude, _law(0.004 + ONSET), rtol=2e-3)
    np.testing.assert_allclose(p.model_std, 0.05 * p.magnitude + 1e-3, rtol=2e-3)
    np.testing.assert_allclose(p.slope, 1.5 * STIFFNESS * 0.004 ** 0.5, rtol=0.02)
    without = BakedResponse(depths=model.response.depths, forces=model.response.forces,
                            slopes=model.response.slopes)
    with pytest.raises(InvalidInput, match='no predictive std'):
        point_model_force(without, d)


def test_fem_off_by_two_is_corrected_by_the_point_model():
    # the lamb's case: the FEM's modulus, read from a far field a buried bone shields, is 2x
    # off; its sites disagree (spread 0.5, as the lamb's sites do); the point model is right
    points, normals = _scan(seed=2)
    model = _point_model(points, normals)
    tip = np.array([0.5, 0.0, 0.04 - 0.005])
    truth = _law(0.005 + ONSET) * np.array([0.1, 0.0, -1.0]) / np.hypot(0.1, 1.0)
    direction = np.array([0.15, 0.02, -1.0])
    fem = 2.0 * np.linalg.norm(truth) * direction / np.linalg.norm(direction)
    check = _check(fem, 0.05 * np.linalg.norm(fem), truth)
    assert check.magnitude_error > 0.9                     # the FEM alone: +100 %
    fused, info = fused_from_views(check, 0.5, tip, model)
    assert fused.magnitude_error < 0.05
    assert info.point_weight > 0.9
    np.testing.assert_allclose(fused.camera_force / np.linalg.norm(fused.camera_force),
                               fem / np.linalg.norm(fem), atol=1e-12)   # the FEM's direction
    assert fused.inside
    # without the sites' spread the FEM's own 5 % keeps a fifth of the weight and pulls the
    # magnitude 20 % off; the two disagree far beyond their spreads, so the std is scaled up
    alone, info = fused_from_views(check, float('nan'), tip, model)
    assert alone.magnitude_error > 0.15 and info.point_weight < 0.85
    assert info.scale > 5.0 and alone.inside


def test_a_good_fem_on_a_homogeneous_block_keeps_dominating():
    # the foam block: sites agree (spread 0.05), the FEM is 4 % off with a 6 % std and the
    # point model is noisier (15 %) and 20 % off: the fused estimate stays near the FEM
    points, normals = _scan(seed=3)
    model = _point_model(points, normals, relative_std=0.15)
    tip = np.array([0.5, 0.0, 0.04 - 0.005])
    magnitude = _law(0.005 + ONSET) / 1.2               # the point model reads 20 % high
    truth = np.array([0.0, 0.0, -magnitude])
    check = _check(1.04 * truth, 0.06 * magnitude, truth)
    fused, info = fused_from_views(check, 0.05, tip, model)
    assert info.point_weight < 0.25
    assert fused.magnitude_error < 0.09


def test_fuse_force_is_the_inverse_variance_mean_and_scales_its_std_by_disagreement():
    f = fuse_force([0.0, 0.0, -2.0], 0.2, 1.0, 0.1)
    w = (1 / 0.01) / (1 / 0.01 + 1 / 0.04)
    assert f.point_weight == pytest.approx(w)
    np.testing.assert_allclose(f.force, [0.0, 0.0, -(w * 1.0 + (1 - w) * 2.0)])
    chi = 1.0 / np.hypot(0.2, 0.1)
    assert f.scale == pytest.approx(chi)
    assert f.std == pytest.approx(chi / np.sqrt(1 / 0.04 + 1 / 0.01))
    agree = fuse_force([0.0, 0.0, -1.0], 0.2, 1.05, 0.1)
    assert agree.scale == 1.0
    assert fuse_force([1.0, 0.0, 0.0], np.inf, 3.0, 0.5).force[0] == pytest.approx(3.0)
    with pytest.raises(InvalidInput, match='direction'):
        fuse_force([0.0, 0.0, 0.0], 0.1, 1.0, 0.1)
    with pytest.raises(InvalidInput, match='stds'):
        fuse_force([0.0, 0.0, -1.0], float('nan'), 1.0, 0.1)
    with pytest.raises(InvalidInput, match='both'):
        fuse_force([0.0, 0.0, -1.0], np.inf, 1.0, np.inf)


def test_between_site_spread_of_log_moduli():
    q = [[0.0, 0.0, 0.04], [0.0, 0.0, 0.04], [0.01, 0.0, 0.04], [0.02, 0.0, 0.04]]
    e = [1e5, 1e5, 2e5, 4e5]
    s = np.std(np.log([1e5, 2e5, 4e5]), ddof=1) * np.sqrt(1 + 1 / 3)
    assert between_site_spread(q, e) == pytest.approx(s)
    assert np.isnan(between_site_spread(q[:2], e[:2]))
    with pytest.raises(InvalidInput, match='positive modulus'):
        between_site_spread(q, [1e5, 0.0, 1.0, 1.0])


def test_depth_calibration_recovers_the_point_models_onset_error():
    # the model believes contact starts 0.6 mm later than it does: a constant depth offset
    points, normals = _scan(seed=4, noise=1e-4)
    model = _point_model(points, normals)
    states = []
    for x in (0.49, 0.51):
        for depth in (0.003, 0.005):
            q = np.array([x, 0.0, 0.04])
            tip = q - [0.0, 0.0, depth]
            states.append((q, tip, [0.0, 0.0, -_law(depth + ONSET, onset=ONSET - 6e-4)]))
    cal = point_calibration(model, states)
    np.testing.assert_allclose(cal.offset, 6e-4, atol=1e-4)
    assert len(cal.site_offsets) == 2 and cal.std < 2e-4
    with pytest.raises(InvalidInput, match='two sites'):
        point_calibration(model, states[:2])
    with pytest.raises(InvalidInput, match='positive force'):
        depth_calibration(model.response, [None, None], [0.0, 1.0], [0, 1])
    with pytest.raises(InvalidInput, match='one site per depth'):
        depth_calibration(model.response, [None, None], [1.0, 1.0], [0, 1, 2])


def test_small_sample_factor_is_the_t_interval_over_the_normal_one():
    assert small_sample_factor(2) == pytest.approx(12.706 / 1.960, rel=1e-3)
    assert small_sample_factor(5) == pytest.approx(2.776 / 1.960, rel=1e-3)
    assert 1.0 < small_sample_factor(200) < 1.01
    with pytest.raises(InvalidInput, match='>= 2 sites'):
        small_sample_factor(1)


def test_cross_site_error_leaves_each_site_out(monkeypatch):
    # a stand-in FEM that reads forces 2x high at x = 0.51 when identified without it and
    # exact elsewhere: the error of each left-out site is read by a model that never saw it
    seen = []

    def identify(rest, normals, states, origin, **kwargs):
        seen.append(sorted({round(float(q[0]), 3) for q, _, _ in states}))
        assert kwargs == {'view_rest': 'frames'}
        return seen[-1]

    def estimate(model, state):
        q, force, _ = state
        gain = 2.0 if (round(float(q[0]), 3) == 0.51 and 0.51 not in model) else 1.0
        return SimpleNamespace(camera_force=gain * np.asarray(force), ft_force=force)

    monkeypatch.setattr(cell_check, 'identify_from_views', identify)
    monkeypatch.setattr(cell_check, 'estimate_from_views', estimate)
    states = [(np.array([x, 0.0, 0.04]), np.array([0.0, 0.0, -f]), None)
              for x in (0.49, 0.51, 0.53) for f in (1.0, 2.0)]
    rms, errors = cross_site_error(None, None, states, None, view_rest='frames')
    assert seen == [[0.51, 0.53], [0.49, 0.53], [0.49, 0.51]]
    np.testing.assert_allclose(errors, [0, 0, np.log(2), np.log(2), 0, 0], atol=1e-12)
    assert rms == pytest.approx(np.log(2) / np.sqrt(3))
    with pytest.raises(InvalidInput, match='two sites'):
        cross_site_error(None, None, states[:2], None)
