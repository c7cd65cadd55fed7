"""The node's side of the fused force (issue 18): fusion data, calibration, the fused estimate."""

from types import SimpleNamespace

import numpy as np
import pytest

from pointforce_ros.deformation import fusion
from pointforce_ros.deformation.force import ForceEstimate
from pointforce_ros.deformation.fusion import (DEFAULT_FEM_SPREAD, fem_cross_site_error,
                                               fuse_estimate, fused_covariance, fusion_data,
                                               point_calibration, site_labels)
from pointforce_ros.deformation.identify import Poke
from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Surface

STIFFNESS = 4.0e4
ONSET = -0.0012


def _law(d, onset=ONSET):
    return STIFFNESS * np.clip(np.asarray(d) - onset, 0.0, None) ** 1.5


def _point_model():
    """A flat scanned top at z = 0.04 - 1.2 mm (2 mm grid) and the synthetic law on it."""
    g = np.arange(-0.03, 0.0301, 0.002)
    xy = np.stack(np.meshgrid(g, g, indexing='ij'), -1).reshape(-1, 2) + [0.5, 0.0]
    points = np.column_stack([xy, np.full(len(xy), 0.04 - 0.0012)])
    normals = np.tile([0.0, 0.0, 1.0], (len(xy), 1))
    depths = np.linspace(-0.004, 0.012, 65)
    forces = np.tile(_law(depths), (len(points), 1))
    response = BakedResponse(depths=depths, forces=forces,
                             slopes=np.full(len(points), 1.5 * STIFFNESS * 0.0132 ** 0.5),
                             std=0.05 * forces + 1e-3)
    return SimpleNamespace(surface=Surface(points, normals), response=response)


def _estimate(force, std=0.02):
    return ForceEstimate(force=np.asarray(force, float), covariance=std ** 2 * np.eye(3),
                         residual_rms=1e-4, points=500, iterations=3, seconds=0.1,
                         displacement=np.zeros(3))


def _pokes(xs=(0.49, 0.51), depths=(0.003, 0.005), onset=ONSET):
    cloud = np.zeros((4, 3))
    return [Poke([x, 0.0, 0.04], [0.0, 0.0, -_law(d + onset)], cloud,
                 tip=[x, 0.0, 0.04 - d]) for x in xs for d in depths]


def test_sites_group_contact_points_within_two_millimetres():
    labels = site_labels([[0.5, 0.0, 0.04], [0.5005, 0.0, 0.04], [0.51, 0.0, 0.04],
                          [0.5, 0.001, 0.04]])
    np.testing.assert_array_equal(labels, [0, 0, 1, 0])


def test_one_site_gets_the_default_spread_and_keeps_the_tips():
    pokes = _pokes(xs=(0.5,))
    data, note = fusion_data(None, pokes, SimpleNamespace(local_young=(5e4, 5e4)))
    assert data.spread_source == 'default' and data.fem_spread == DEFAULT_FEM_SPREAD
    assert 'one identification site' in note and data.site_count == 1
    np.testing.assert_allclose(data.tips, [p.tip for p in pokes])
    np.testing.assert_allclose(data.forces, [np.linalg.norm(p.force) for p in pokes])


def test_cross_site_error_skips_a_site_the_others_cannot_identify(monkeypatch):
    # sites at x 0.49, 0.51, 0.53; the FEM identified without 0.51 reads it 2x high; the
    # other two sites alone (0.49 left out) are refused
    def identify(mesh, pokes, config, rest_offset=None):
        xs = {round(float(p.contact_point[0]), 3) for p in pokes}
        if xs == {0.51, 0.53}:
            raise InvalidInput('identify: the clouds do not move with the measured forces')
        return None, xs

    def estimate(fem, contact, cloud, config, rest_offset=None):
        x = round(float(contact[0]), 3)
        gain = 2.0 if x == 0.51 and 0.51 not in fem else 1.0
        return SimpleNamespace(force=gain * np.array([0.0, 0.0, -1.0]))

    monkeypatch.setattr(fusion, 'identify_elasticity', identify)
    monkeypatch.setattr(fusion, 'estimate_force', estimate)
    pokes = [Poke([x, 0.0, 0.04], [0.0, 0.0, -1.0], np.zeros((4, 3)))
             for x in (0.49, 0.51, 0.53)]
    sites = site_labels([p.contact_point for p in pokes])
    rms, errors = fem_cross_site_error(None, pokes, sites)
    np.testing.assert_allclose(errors, [np.log(2.0), 0.0], atol=1e-12)
    assert rms == pytest.approx(np.log(2.0) / np.sqrt(2))
    data, note = fusion_data(None, pokes, SimpleNamespace(local_young=()))
    assert data.spread_source == 'cross-site' and data.fem_spread == pytest.approx(rms)
    with pytest.raises(InvalidInput, match='two sites'):
        fem_cross_site_error(None, pokes[:1], [0])


def test_the_sites_moduli_when_no_site_can_be_left_out(monkeypatch):
    def refuse(*args, **kwargs):
        raise InvalidInput('identify: refused')

    monkeypatch.setattr(fusion, 'identify_elasticity', refuse)
    pokes = _pokes()
    data, note = fusion_data(None, pokes, SimpleNamespace(local_young=(1e5, 1e5, 2e5, 2e5)))
    assert data.spread_source == 'between-site' and 'no cross-site' in note
    assert data.fem_spread == pytest.approx(np.log(2) / np.sqrt(2) * np.sqrt(1.5))
    bad, note = fusion_data(None, pokes, SimpleNamespace(local_young=(1e5, 0.0, 2e5, 2e5)))
    assert bad.spread_source == 'default', note


def test_point_calibration_reads_the_onset_at_the_stored_tips():
    # the object's contact starts 0.6 mm before the point model believes it does
    data, _ = fusion_data(None, _pokes(onset=ONSET + 6e-4), SimpleNamespace(local_young=()),
                          cross=False)
    cal = point_calibration(_point_model(), data)
    np.testing.assert_allclose(cal.offset, 6e-4, atol=1e-4)
    one, _ = fusion_data(None, _pokes(xs=(0.5,)), SimpleNamespace(local_young=()))
    with pytest.raises(InvalidInput, match='two sites'):
        point_calibration(_point_model(), one)


def test_the_fused_estimate_takes_the_point_model_where_the_fem_is_spread():
    model = _point_model()
    tip = np.array([0.5, 0.0, 0.04 - 0.005])
    truth = _law(0.005 + ONSET)
    est = _estimate([0.0, 0.1 * truth, -2.0 * truth])     # the FEM 2x off
    fused = fuse_estimate(est, tip, model, fem_spread=0.8)
    assert fused.point_weight > 0.9
    assert np.linalg.norm(fused.force) == pytest.approx(truth, rel=0.06)
    np.testing.assert_allclose(fused.force / np.linalg.norm(fused.force),
                               est.force / np.linalg.norm(est.force), atol=1e-12)
    cov = fused_covariance(est, fused)
    d = fused.force / np.linalg.norm(fused.force)
    assert d @ cov @ d == pytest.approx(fused.std ** 2)
    for bad, reason in (([np.nan, 0.0, 0.04], 'finite'),
                        (tip + [0.0, 0.0, 0.012], 'above the scanned surface'),
                        (tip + [0.2, 0.0, 0.0], 'scan points within')):
        with pytest.raises(InvalidInput, match=reason):
            fuse_estimate(est, bad, model, fem_spread=0.8)
