"""The demo's calibration pushes, its error and coverage summary and its wrench figure (no ROS)."""

import numpy as np
import pytest

from pointforce_ros.bringup import demo, plots
from pointforce_ros.contact.uncertainty import lateral_share, Z90
from pointforce_ros.sim.objects import load_object


def test_calibration_pushes_with_different_tools_and_on_both_looks_of_the_lamb():
    spec = load_object('lamb')
    pokes = demo._calibration_pokes(spec)
    assert set(pokes) == {'sphere', 'rod', 'streak'}
    sphere, rod, streak = pokes['sphere'], pokes['rod'], pokes['streak']
    # the sphere where the first poke lands, the rod at its own site with its axis along y
    np.testing.assert_allclose(sphere[1][0].position[:2],
                               np.asarray(spec.centre) + demo.CALIBRATION_OFFSET)
    np.testing.assert_allclose(rod[1][0].position[:2], np.asarray(spec.centre) + demo.ROD_SITE)
    world = rod[0].vertices @ rod[1][0].rotation().T
    assert np.ptp(world[:, 1]) == pytest.approx(demo.ROD_LENGTH, rel=1e-6)
    assert np.ptp(sphere[0].vertices, axis=0)[0] == pytest.approx(0.04, rel=1e-3)
    # the third: the rod again, across the paler streak the camera sees over the bone
    np.testing.assert_allclose(streak[1][0].position[:2],
                               np.asarray(spec.centre) + demo.STREAK_SITE)
    top = streak[1][0].position + [0.0, 0.0, demo.ROD_DEPTHS[0]]
    pale, red = spec.colour_at(np.array([top, rod[1][0].position + [0, 0, 0.002]]))
    assert pale.mean() > red.mean() + 0.2     # the streak is pale, the muscle red
    np.testing.assert_allclose(streak[1][0].orientation, rod[1][0].orientation)
    # measured push-back grows with depth for all (the fixtures are FEM full solves), and
    # over the bone the same rod meets more than 1.5 times the muscle's push-back
    for _, poses, approach, force in (sphere, rod, streak):
        assert len(poses) == 2 and np.all(np.diff(force) > 0) and np.all(force > 1.0)
    assert np.all(streak[3] > 1.5 * rod[3])
    vectors = demo._calibration_pokes(spec, vectors=True)
    np.testing.assert_allclose(vectors['rod'][3][:, 2], rod[3])
    # an object without the streak's fixture keeps two pushes
    assert set(demo._calibration_pokes(load_object('foam_block'))) == {'sphere', 'rod'}


def test_a_calibration_file_for_another_probe_pose_is_not_used(tmp_path, monkeypatch, capsys):
    spec = load_object('lamb')
    for name in ('demo_calibration_lamb.npz', 'demo_calibration_rod_lamb.npz'):
        with np.load(demo.DATA / name, allow_pickle=False) as z:
            data = dict(z)
        if 'rod' in name:
            data['positions'] = data['positions'] + [0.01, 0, 0, 0, 0, 0, 0]   # moved 10 mm
        np.savez(tmp_path / name, **data)
    monkeypatch.setattr(demo, 'DATA', tmp_path)
    assert set(demo._calibration_pokes(spec)) == {'sphere'}
    assert 'for another probe pose: not used' in capsys.readouterr().out


def test_lateral_share_is_the_unpredicted_force_across_the_push():
    class Flat:
        """Predicts the measured normal force and no lateral force."""

        def query_batch(self, mesh, poses, a, centre):
            class R:
                wrenches = np.array([[0.0, 0.0, 4.0, 0, 0, 0], [0.0, 0.0, 8.0, 0, 0, 0]])
            return R()

    measured = np.array([[0.3, -0.4, 4.0], [0.6, -0.8, 8.0]])
    pokes = {'p': (None, [None, None], [0.0, 0.0, -1.0], measured)}
    # lateral RMS per component sqrt((0.25 + 1.0) / 4) over RMS normal sqrt((16 + 64) / 2)
    expected = np.sqrt(1.25 / 4) / np.sqrt(40.0)
    assert lateral_share(Flat(), pokes) == pytest.approx(expected)


def test_summary_counts_signs_coverage_and_error():
    true = np.zeros((4, 6))
    true[:, 2] = [4.0, 6.0, 8.0, 10.0]
    pred = true.copy()
    pred[:, 2] += [-0.5, 0.2, -0.1, 3.0]
    std = np.full((4, 6), 0.2)
    s = demo.summarise(pred, std, true)
    assert (s['below'], s['above']) == (2, 2)
    # |err| <= 1.645 * 0.2 = 0.329 for 0.2 and 0.1 only
    assert s['coverage_fz'] == pytest.approx(0.5)
    assert s['coverage_all'] == pytest.approx((4 * 5 + 2) / 24)
    assert s['coverage_force'] == pytest.approx((4 * 2 + 2) / 12)
    assert s['coverage_torque'] == pytest.approx(1.0)
    assert s['rmse'] == pytest.approx(np.sqrt(np.mean(np.array([0.5, 0.2, 0.1, 3.0]) ** 2)))
    assert s['peak'] == pytest.approx(10.0)
    assert s['width_fz'] == pytest.approx(2 * Z90 * 0.2)


def test_wrench_figure_is_written(tmp_path):
    names = ['sphere r20 #1', 'sphere r20 #2', 'paddle 60 mm #1']
    true = np.zeros((3, 6))
    true[:, 2] = [5.0, 6.0, 9.0]
    pred = true + 0.3
    path = plots.plot_wrench_pred_vs_true(names, pred, np.full((3, 6), 0.2), true,
                                          tmp_path / 'w.png')
    assert path.exists() and path.stat().st_size > 10_000


def test_point_model_check_reads_the_ratio_at_each_site():
    from pointforce_ros.lab.synthetic_contact import linear_response
    from pointforce_ros.types import Surface

    spec = load_object('lamb')
    cx, cy = spec.centre
    xs, ys = np.meshgrid(np.linspace(cx - 0.03, cx + 0.03, 31),
                         np.linspace(cy - 0.025, cy + 0.025, 26))
    x, y = xs.ravel(), ys.ravel()
    z = np.array([spec.top_height(a, b) for a, b in zip(x, y)]) + 0.001   # camera 1 mm high
    surface = Surface(points=np.column_stack([x, y, z]),
                      normals=np.tile([0.0, 0.0, 1.0], (len(x), 1)))
    # learned: k (d - 1 mm)_+ with k 1.2x the truth left of x = cx - 8 mm, 0.9x right of it
    k = np.where(x < cx - 0.008, 1.2, 0.9) * 2000.0
    depths = np.linspace(-0.002, 0.01, 49)
    baked = linear_response(k, depths=depths)
    shifted = type(baked)(depths=depths, forces=np.array([np.interp(depths - 0.001, depths, row)
                                                         for row in baked.forces]),
                          slopes=baked.slopes)

    class Truth:
        def normal_force(self, x, y, d):
            return 2000.0 * max(d, 0.0)

    ratios = demo.point_model_check(spec, Truth(), surface, shifted)
    assert ratios['calibration'] == pytest.approx(1.2, rel=1e-6)      # x = cx - 20 mm
    assert ratios['query site #1'] == pytest.approx(0.9, rel=1e-6)    # the centre
    assert ratios['query site #3'] == pytest.approx(1.2, rel=1e-6)    # x = cx - 15 mm


def test_the_stiffness_maps_truth_puts_the_tip_where_the_learned_map_does():
    spec = load_object('lamb')
    cx, cy = spec.centre
    pts = np.array([[cx, cy, spec.top_height(cx, cy) + 0.002],          # camera 2 mm high
                    [cx + 0.01, cy, spec.top_height(cx + 0.01, cy) - 0.001]])  # 1 mm low

    class Truth:
        def normal_force(self, x, y, d):
            return 1000.0 * d

    got = demo.true_force_below_observed(spec, Truth(), pts, 0.003)
    np.testing.assert_allclose(got, [1.0, 4.0], rtol=1e-9)   # tips 1 and 4 mm deep
    assert demo.true_force_below_observed(spec, Truth(), pts[:1], 0.0015)[0] == 0.0  # outside
