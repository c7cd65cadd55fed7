"""Benchmark ``calibrate``: the kept candidates give the calibration the repeated search gives."""

from pointforce_ros.lab.bench_calibrate import bench_calibrate


def test_kept_candidates_give_the_same_calibration_from_one_search_per_push():
    out = bench_calibrate(quick=True)
    assert out['max_rel_diff'] < 1e-9
    # one search per push for the fit and one per push for the lateral share (force vectors),
    # against one per push for every (c, L) a fit tries
    assert out['searches_ours'] == 2 * out['pushes']
    assert out['searches_baseline'] > 100 * out['searches_ours']
    # the rod's 20 % extra is a share no (c, L) explains, and c is found near 4 mm
    assert 0.05 < out['relative_std'] < 0.5 and 2.0 < out['c_mm'] < 8.0
