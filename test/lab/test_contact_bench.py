"""Contact benchmarks on a small scene: the report is complete and ours agrees with the paper."""

import json

from pointforce_ros.lab.bench_contact import bench_batch, bench_contact


def test_bench_contact_small_scene():
    out = bench_contact(n_ours=30, n_paper=4, n_grid=81, half=0.05, regressor='analytic')
    json.dumps(out)  # JSON-serialisable for `pointforce bench --json`
    assert out['surface_points'] == 81 * 81 and out['rigid_points'] == 150
    assert out['contacts_median'] >= 3
    # Same model, same poses: only the 3-neighbour averaging of a non-affine k(x) differs.
    assert out['max_force_difference_rel'] < 1e-3
    assert out['paper_analytic_lcp_failures'] == 0
    assert out['figure'] == out['speedup_vs_paper_analytic'] > 2.0


def test_bench_batch_small_grid():
    out = bench_batch(n_xy=6, n_z=5, n_paper=2, n_grid=81, half=0.05)
    json.dumps(out)
    assert out['poses'] == 180
    assert 0.2 < out['in_contact_fraction'] < 1.0
    assert out['figure'] > 2.0
