"""Offline cell sessions: the poke server's tip path, sampling, tare, limits and campaigns.

Closed-form checks on the analytic half-space (flat top at z0, push-back k d**p along +z).
"""

import numpy as np
import pytest

from pointforce_ros.sim.disturbances import CameraDepthBias, FtBias, FtNoise, PlasticSet
from pointforce_ros.sim.scenario import HalfSpaceContact, Scenario
from pointforce_ros.sim.session import (CellObject, halfspace_object, simulate_campaign,
                                        simulate_poke)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.rotations import rotvec_aligning_z, rotvec_to_matrix

Z0 = 0.04
K0 = 1.4e4


def _model(*effects, contact=None):
    contact = contact if contact is not None else HalfSpaceContact(z0=Z0, k0=K0)
    return Scenario('t', effects=tuple(effects)).force_model(contact)


def test_rotvec_aligning_z_maps_ez_onto_axis():
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(20, 3))
    axes = np.vstack([axes / np.linalg.norm(axes, axis=1, keepdims=True),
                      [[0, 0, 1.0], [0, 0, -1.0]]])
    for axis in axes:
        rot = rotvec_to_matrix(rotvec_aligning_z(axis))
        np.testing.assert_allclose(rot[:, 2], axis, atol=1e-12)


def test_poke_path_timing_and_force_follow_the_server():
    speed, rate, standoff, limit = 0.004, 250.0, 0.003, 3.0
    point = np.array([0.01, -0.02, Z0])
    rec = simulate_poke(_model(), point, [0, 0, 1.0], poke_id='poke-000001', speed=speed,
                        standoff=standoff, force_limit=limit, depth_limit=0.02, rate=rate,
                        t0=5.0, hold=0.2, pre_hold=0.1)
    d = rec.displacement()
    np.testing.assert_allclose(np.diff(rec.t_controller), 1.0 / rate, rtol=1e-9)
    assert rec.t_controller[0] == 5.0
    # TCP z axis is the push direction -n (what the cell force model expects)
    axes = rotvec_to_matrix(rec.tcp_pose[:, 3:])[:, :, 2]
    np.testing.assert_allclose(axes, np.tile([0, 0, -1.0], (len(rec), 1)), atol=1e-12)
    # constant-speed push from the stand-off, hold, retract to the stand-off
    steps = np.diff(d)
    assert d[0] == pytest.approx(-standoff) and d[-1] == pytest.approx(-standoff)
    moving = steps[np.abs(steps) > 0]
    np.testing.assert_allclose(np.abs(moving), speed / rate, rtol=1e-6)
    peak = int(np.argmax(d))
    assert np.all(steps[:peak] >= 0) and np.all(steps[peak + 50:] <= 0)
    held = np.count_nonzero(d == d.max())
    assert held == 1 + int(round(0.2 * rate))
    # force limit: the first sample at or above the limit ends the push
    f = rec.normal_force()
    assert rec.outcome == 'force_limit'
    assert f[peak] >= limit and np.all(f[:peak] < limit)
    # closed form: k d**1.5 at the commanded depth (tared at rest, no effects)
    np.testing.assert_allclose(f, K0 * np.maximum(d, 0.0) ** 1.5, atol=1e-12)
    assert rec.meta['tare_time'] == pytest.approx(5.0 + (round(0.1 * rate) - 1) / rate)


def test_depth_limit_and_oblique_axis():
    tilt = np.radians(20.0)
    normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    point = np.array([0.0, 0.0, Z0])
    rec = simulate_poke(_model(), point, normal, poke_id='poke-000002', speed=0.002,
                        standoff=0.002, force_limit=1e3, depth_limit=0.003, rate=200.0)
    assert rec.outcome == 'depth_limit'
    assert rec.displacement().max() == pytest.approx(0.003)
    # the half-space sees depth d cos(tilt) and pushes along +z only
    d = rec.displacement()
    expected = K0 * np.maximum(d * np.cos(tilt), 0.0) ** 1.5
    np.testing.assert_allclose(rec.wrench[:, 2], expected, atol=1e-10)
    np.testing.assert_allclose(rec.wrench[:, :2], 0.0, atol=1e-12)


def test_tare_removes_bias_unless_disabled():
    bias = FtBias(force=(0.3, -0.2, 0.5))
    tared = simulate_poke(_model(), [0, 0, Z0], [0, 0, 1.0], poke_id='p-1', rate=100.0,
                          standoff=0.002, force_limit=2.0)
    model = Scenario('b', effects=(bias,))
    sensor_model = model.force_model(HalfSpaceContact(z0=Z0, k0=K0),
                                     ft_sensor=model.ft_sensor())
    raw = simulate_poke(sensor_model, [0, 0, Z0], [0, 0, 1.0], poke_id='p-2', rate=100.0,
                        standoff=0.002, force_limit=2.0, tare=False)
    assert raw.meta['tared'] is False and raw.meta['tare_time'] is None
    free = raw.displacement() < 0
    np.testing.assert_allclose(raw.wrench[free, :3], np.tile([0.3, -0.2, 0.5],
                                                             (free.sum(), 1)), atol=1e-12)
    np.testing.assert_allclose(tared.wrench[tared.displacement() < 0, :3], 0.0, atol=1e-12)


@pytest.mark.parametrize('kwargs', [dict(speed=0.0), dict(rate=-1.0), dict(standoff=-0.1),
                                    dict(hold=float('nan')), dict(force_limit=0.0)])
def test_poke_rejects_bad_settings(kwargs):
    with pytest.raises(InvalidInput):
        simulate_poke(_model(), [0, 0, Z0], [0, 0, 1.0], poke_id='p', **kwargs)


def test_poke_rejects_non_unit_normal():
    with pytest.raises(InvalidInput):
        simulate_poke(_model(), [0, 0, Z0], [0, 0, 2.0], poke_id='p')


def _campaign(seed, **kwargs):
    scenario = Scenario('c', seed=3, effects=(FtNoise(force_std=0.01),
                                              CameraDepthBias(bias=0.001)))
    args = dict(count=4, seed=seed, speed=(0.002, 0.004), standoff=0.002, force_limit=2.0,
                rate=100.0, hold=0.1, gap=1.5, repeats=2)
    args.update(kwargs)
    return simulate_campaign(HalfSpaceContact(z0=Z0, k0=K0, ripple=0.3), scenario, **args)


def test_campaign_is_deterministic_and_seeded():
    a, b, c = _campaign(5), _campaign(5), _campaign(6)
    assert [r.poke_id for r in a] == [f'poke-{k:06d}' for k in range(1, 9)]
    for ra, rb in zip(a, b):
        for name in ('t', 't_controller', 'tcp_pose', 'wrench', 'point', 'normal'):
            np.testing.assert_array_equal(getattr(ra, name), getattr(rb, name))
    assert not np.array_equal(a[0].wrench, c[0].wrench)
    assert not np.array_equal(a[0].point, c[0].point)


def test_campaign_geometry_timing_and_camera_bias():
    recs = _campaign(7)
    # interleaved repeats: location k is poked at positions k and k + 4
    for k in range(4):
        np.testing.assert_array_equal(recs[k].point, recs[k + 4].point)
    # the camera reads 1 mm too far: commanded points sit 1 mm below the true top
    for rec in recs:
        assert rec.point[2] == pytest.approx(Z0 - 0.001, abs=1e-12)
        assert -0.03 <= rec.point[0] <= 0.03 and -0.03 <= rec.point[1] <= 0.03
        assert 0.002 <= rec.speed <= 0.004
    # one controller clock, 1.5 s gaps, sequence numbers in the metadata
    for prev, nxt in zip(recs[:-1], recs[1:]):
        assert nxt.t_controller[0] - prev.t_controller[-1] == pytest.approx(1.5)
    assert [r.meta['sequence'] for r in recs] == list(range(8))
    # contact starts 1 mm before the commanded point: where the force first exceeds 0.1 N
    # (10 noise sigma) the tip is (0.1 / k)**(2/3) past the true top, k the local stiffness
    w = 2 * np.pi / 0.05
    for rec in recs[:4]:
        k_local = K0 * (1 + 0.3 * np.sin(w * rec.point[0]) * np.sin(w * rec.point[1]))
        first = int(np.argmax(rec.normal_force() > 0.1))
        onset = rec.displacement()[first] - (0.1 / k_local) ** (2 / 3)
        assert onset == pytest.approx(-0.001, abs=1e-4)


def test_campaign_aims_at_the_scanned_surface_when_given_one():
    # a scanned surface 1.3 mm low with a tilted normal at one spot: the commanded point and
    # normal are the scan's nearest upward point, and the contact onset moves with it
    from pointforce_ros.types import Surface
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.03, 0.03, (400, 2))
    pts = np.column_stack([xy, np.full(400, Z0 - 0.0013)])
    normals = np.tile([0.0, 0.0, 1.0], (400, 1))
    normals[0] = [0.0, 0.1, 1.0] / np.linalg.norm([0.0, 0.1, 1.0])
    side = Surface(points=np.vstack([pts, [[0.0, 0.0, Z0 - 0.01]]]),
                   normals=np.vstack([normals, [[1.0, 0.0, 0.0]]]))
    recs = _campaign(7, surface=side)
    plain = _campaign(7)
    for rec, ref in zip(recs[:4], plain[:4]):
        near = np.argmin(np.linalg.norm(pts[:, :2] - ref.point[:2], axis=1))
        np.testing.assert_array_equal(rec.point, pts[near])
        np.testing.assert_array_equal(rec.normal, normals[near])
        if near:
            first = int(np.argmax(rec.normal_force() > 0.1))
            w = 2 * np.pi / 0.05
            k_local = K0 * (1 + 0.3 * np.sin(w * rec.point[0]) * np.sin(w * rec.point[1]))
            onset = rec.displacement()[first] - (0.1 / k_local) ** (2 / 3)
            assert onset == pytest.approx(-0.0013, abs=1e-4)


def test_campaign_tilt_and_plastic_memory():
    recs = simulate_campaign(halfspace_object(HalfSpaceContact(z0=Z0, k0=K0)),
                             Scenario('p', effects=(PlasticSet(max_set=0.001, n0=1.0,
                                                               radius=0.003),)),
                             points=[[0.0, 0.0, Z0]], normals=[[0.0, 0.0, 1.0]], repeats=3,
                             standoff=0.002, force_limit=2.0, rate=100.0,
                             normal_tilt_deg=10.0, seed=1)
    tilt = np.degrees(np.arccos(recs[0].normal[2]))
    assert tilt == pytest.approx(10.0)
    # each repeat starts touching deeper: set(n) = 1 mm (1 - exp(-n))
    onsets = []
    for rec in recs:
        onsets.append(rec.displacement()[np.argmax(rec.normal_force() > 1e-9)])
    sets = np.array(onsets) * np.cos(np.radians(10.0))
    np.testing.assert_allclose(sets, [0.0, 0.001 * (1 - np.exp(-1)), 0.001 * (1 - np.exp(-2))],
                               atol=3e-5)


def test_campaign_rejects_bad_requests():
    scenario = Scenario('c')
    with pytest.raises(InvalidInput):
        simulate_campaign(HalfSpaceContact(), scenario)                   # neither
    with pytest.raises(InvalidInput):
        simulate_campaign(HalfSpaceContact(), scenario, count=2, points=[[0, 0, Z0]],
                          normals=[[0, 0, 1.0]])                          # both
    with pytest.raises(InvalidInput):
        simulate_campaign(object(), scenario, count=2)
    with pytest.raises(InvalidInput):
        simulate_campaign(HalfSpaceContact(), scenario, count=2, speed=(0.001, 0.002, 0.003))
    with pytest.raises(InvalidInput):
        simulate_campaign(HalfSpaceContact(), scenario, count=2, repeats=0)
    assert isinstance(halfspace_object(), CellObject)


def test_fem_object_wraps_the_live_contact_or_says_how_to_build_it():
    from pointforce_ros.sim.objects import load_object
    from pointforce_ros.sim.session import fem_object
    from pointforce_ros.errors import DataError
    try:
        obj = fem_object('plush')
    except DataError as exc:
        assert 'make_fem_cache.py' in str(exc)
        return
    spec = load_object('plush')
    (x0, x1), (y0, y1) = obj.region
    xy = np.array([[x0, y0], [x1, y1], [(x0 + x1) / 2, (y0 + y1) / 2]])
    points, normals = obj.surface_at(xy)
    assert np.all(spec.footprint_mask(xy[:, 0], xy[:, 1]))
    np.testing.assert_allclose(points[:, 2], spec.top_height(xy[:, 0], xy[:, 1]))
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)
    force, _ = obj.clean(points[2] - 0.002 * normals[2], -normals[2])
    assert force @ normals[2] > 0
