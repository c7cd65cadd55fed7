"""Live point-probe path: cache freshness, query speed, geometry, and error vs full solves.

The caches (data/fem/live_<object>.npz) come from
``python data/fem/make_fem_cache.py``; each holds held-out full nonlinear pokes at seeded
random locations, which these tests compare with the live path.
"""

import time

import numpy as np
import pytest

from pointforce_ros.sim.fem import live as live_module
from pointforce_ros.sim.fem.live import LiveContact, uv_to_xy
from pointforce_ros.sim.objects import list_objects
from pointforce_ros.errors import DataError, InvalidInput

OBJECTS = list_objects()


@pytest.fixture(scope='module', params=OBJECTS)
def live(request):
    return LiveContact.load(request.param, build=False)


def test_cache_reproduces_its_grid_pokes(live):
    tb = live.table
    for i, j in ((0, 0), (len(tb.u) - 1, len(tb.v) - 1), (len(tb.u) // 2, len(tb.v) // 2)):
        x, y = uv_to_xy(live.spec, tb.u[i], tb.v[j])
        n = live.spec.top_normal(x, y)
        for k in (2, len(tb.depths) - 1):
            want = tb.forces[i, j, k] @ n
            # exact up to the dense depth resampling of the monotone cubic (2e-5 relative)
            assert live.normal_force(x, y, tb.depths[k]) == pytest.approx(want, rel=1e-4)


def test_held_out_full_solves_are_matched(live):
    if live.spec.name == 'dome':
        pytest.xfail('dome: a 3 mm full solve itself moves 5-17 % at 2-5 mm depth when its '
                     'mesh is refined 1-2 mm off the poke, so no table can match it to 3 % '
                     '(docs/STATUS.md, FEM ground truth: mean 9.6 %)')
    rows = np.load(_path(live), allow_pickle=False)['holdout']
    x, y, depth, full, _ = rows.T
    pred = np.array([live.normal_force(a, b, d) for a, b, d in zip(x, y, depth)])
    use = depth >= 0.002
    rel = np.abs(pred[use] - full[use]) / full[use]
    # target 3 % mean: plush 2.1, lamb 2.1, vest 1.8, thin_layer 2.0 % (7 x 7 grids but
    # plush); per-object figures: pointforce bench cell --json
    assert np.mean(rel) < 0.04 and rel.max() < 0.10, rel


def _path(live):
    from pointforce_ros.sim.fem.live import cache_path

    return cache_path(live.spec.name)


def test_wrench_geometry(live):
    spec = live.spec
    rng = np.random.default_rng(0)
    tb = live.table
    for _ in range(5):
        x, y = uv_to_xy(spec, rng.uniform(tb.u[0], tb.u[-1]), rng.uniform(tb.v[0], tb.v[-1]))
        q, n = spec.top_point(x, y), spec.top_normal(x, y)
        above, _ = live.point_probe_wrench(q + 0.002 * n, -n)
        assert np.all(above == 0)
        forces = [live.point_probe_wrench(q - d * n, -n)[0] @ n for d in (0.001, 0.003, 0.006)]
        assert 0 < forces[0] < forces[1] < forces[2]
        tip = q - 0.004 * n
        f, t_tip = live.point_probe_wrench(tip, -n)
        np.testing.assert_allclose(t_tip, 0.0, atol=1e-12)
        centre = tip + np.array([0.0, 0.0, 0.2])
        _, t_c = live.point_probe_wrench(tip, -n, torque_centre=centre)
        np.testing.assert_allclose(t_c, np.cross(tip - centre, f), atol=1e-12)
    off, _ = live.point_probe_wrench([0.9, 0.5, 0.01], [0, 0, -1])
    assert np.all(off == 0)


def test_no_point_of_the_top_lies_above_its_bound_and_the_answer_there_is_unchanged(
        live, monkeypatch):
    spec = live.spec
    rng = np.random.default_rng(2)
    x = spec.centre[0] + spec.size[0] * rng.uniform(-0.5, 0.5, 20000)
    y = spec.centre[1] + spec.size[1] * rng.uniform(-0.5, 0.5, 20000)
    top = spec.top_height(x, y)
    assert np.max(top) <= spec.top_bound < np.max(top) + 0.002
    # tips around the bound, moving down (some tilted): the quick "nothing above" answer is
    # the surface search's (a bound too low would cut off real contact)
    tips = np.column_stack([x[:200], y[:200], spec.top_bound + rng.uniform(-0.004, 0.004, 200)])
    axes = np.column_stack([rng.uniform(-0.3, 0.3, (200, 2)), -np.ones(200)])
    quick = [live.point_probe_wrench(t, a) for t, a in zip(tips, axes)]
    above = np.sum(tips[:, 2] > spec.top_bound + live_module.ABOVE_MARGIN)
    monkeypatch.setattr(live_module, 'ABOVE_MARGIN', np.inf)
    full = [live.point_probe_wrench(t, a) for t, a in zip(tips, axes)]
    for (fq, tq), (ff, tf) in zip(quick, full):
        np.testing.assert_array_equal(fq, ff)
        np.testing.assert_array_equal(tq, tf)
    assert sum(np.any(f != 0) for f, _ in full) >= 3         # the band reaches into contact
    assert above > 50                                        # and above it


def test_emulator_force_model_uses_the_tcp_z_axis():
    from pointforce_ros.sim.fem.live import force_model

    model = force_model('lamb')
    live = model.live
    q = live.spec.top_point(0.5, 0.0)
    down = np.array([q[0], q[1], q[2] - 0.004, np.pi, 0.0, 0.0])  # TCP z axis = -z (base)
    w = model.wrench(down, 0.0)
    f, t = live.point_probe_wrench(down[:3], [0.0, 0.0, -1.0])
    np.testing.assert_allclose(w, np.concatenate([f, t]), atol=1e-12)
    assert w[2] > 0.1  # the object pushes the tool up
    up = down.copy()
    up[3] = 0.0  # TCP z axis = +z: pointing away from the object
    assert np.all(model.wrench(up, 0.0) == 0)


def test_bad_inputs_are_rejected():
    live = LiveContact.load('lamb', build=False)
    with pytest.raises(InvalidInput):
        live.point_probe_wrench([np.nan, 0, 0], [0, 0, -1])
    with pytest.raises(InvalidInput):
        live.point_probe_wrench([0.5, 0, 0.03], [0, 0, 0])
    with pytest.raises(DataError, match='make_fem_cache'):
        LiveContact.load('lamb', cache_dir='/nonexistent', build=False)


def test_query_is_fast_enough_for_250_hz():
    live = LiveContact.load('lamb', build=False)
    rng = np.random.default_rng(1)
    tips = np.column_stack([rng.uniform(0.47, 0.53, 400), rng.uniform(-0.02, 0.02, 400),
                            rng.uniform(0.03, 0.045, 400)])
    times = []
    for tip in tips:
        t0 = time.perf_counter()
        live.point_probe_wrench(tip, [0.0, 0.0, -1.0])
        times.append(time.perf_counter() - t0)
    assert np.median(times) < 0.004
