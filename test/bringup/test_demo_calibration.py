"""The demo's calibration pushes, its error and coverage summary and its wrench figure (no ROS)."""

import numpy as np
import pytest

from pointforce_ros.bringup import demo, plots
from pointforce_ros.contact.uncertainty import Z90
from pointforce_ros.sim.objects import load_object


def test_two_calibration_pushes_with_different_tools_at_one_site():
    spec = load_object('lamb')
    pokes = demo._calibration_pokes(spec)
    assert set(pokes) == {'sphere', 'rod'}
    sphere, rod = pokes['sphere'], pokes['rod']
    # the same site (where the first poke lands), different tools: the rod is wide along x
    np.testing.assert_allclose(sphere[1][0].position[:2], rod[1][0].position[:2])
    extent = np.ptp(rod[0].vertices, axis=0)
    assert extent[0] == pytest.approx(demo.ROD_LENGTH, rel=1e-6)
    assert np.ptp(sphere[0].vertices, axis=0)[0] == pytest.approx(0.04, rel=1e-3)
    # measured push-back grows with depth for both (the fixtures are FEM full solves)
    for _, poses, approach, force in (sphere, rod):
        assert len(poses) == 2 and np.all(np.diff(force) > 0) and np.all(force > 1.0)


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
