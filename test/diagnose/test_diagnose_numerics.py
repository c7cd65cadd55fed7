"""Numerics that cannot fail on strong effects (issue 20).

Stable relaxation recursions, guarded exponentials, a finite model at every corner of every
effect's search box, no warning text, and per-poke times that restart at 0 (as the import
format allows) keep each poke's relaxation history independent. One fit per library effect
on tables of the independent generator (:mod:`pointforce_ros.lab.effect_generator`) at ten
times the size of its cell scenario (``config/scenarios``; capped where the physics caps it).
"""

import itertools
import warnings

import numpy as np
import pytest

from pointforce_ros.diagnose.batch import make_batch, time_order
from pointforce_ros.diagnose.model import carried_links, fit_global, forward, Layout
from pointforce_ros.effects.library import LIBRARY, PRONY_TAUS
from pointforce_ros.effects.relaxation import hereditary, prony_filter, prony_inverse
from pointforce_ros.lab import effect_generator as eg

TEN_X = {
    # generator effect: (level giving 10x the scenario default, library parameter, truth)
    'camera_bias': 0.02 / eg.BASE['camera_bias'],                 # 2 mm -> 20 mm
    'ft_bias': 10 * np.linalg.norm([0.8, -0.5, 1.2]) / eg.BASE['ft_bias'],
    'ft_drift': 10 * np.linalg.norm([0.01, -0.008, 0.02]) / eg.BASE['ft_drift'],
    'time_offset': 0.08 / eg.BASE['time_offset'],                 # 8 ms -> 80 ms
    'viscoelastic': 0.77 / eg.BASE['viscoelastic'],             # relaxed modulus 1/3 -> 10/3
    'hysteresis': 0.9 / eg.BASE['hysteresis'],                  # eta 0.15 -> 0.9 (cap: < 1)
    'series_compliance': 1 / 2000.0 / eg.BASE['series_compliance'],   # 20 -> 2 N/mm
    'plastic_set': 0.0008 / eg.BASE['plastic_set'],              # a 0.8 mm step per repeat
    'friction': 4.0 / eg.BASE['friction'],                          # mu 0.4 -> 4
}


@pytest.fixture(scope='module')
def batches(tmp_path_factory):
    folder = tmp_path_factory.mktemp('ten_x')
    out = {}
    for effect, level in TEN_X.items():
        shape = eg.SHAPES.get(effect, ('',))[-1]
        case = eg.Case(effect, level, shape, seed=3, pokes=12, restart=True)
        out[effect] = (case, make_batch(eg.records(case, folder), max_rate=50.0)[0])
    return out


def test_prony_filter_is_stable_from_milliseconds_to_hours():
    dt = 0.01
    t = np.arange(0, 60, dt)
    f_e = np.minimum(t, 2.0) * (t < 40)
    g = np.array([0.2, 0.2, 0.2, 0.2, 0.15])
    tau = np.array([1e-3, 0.05, 1.0, 30.0, 3600.0])
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        f = prony_filter(f_e, dt, g, tau)
        back = prony_inverse(f, dt, g, tau)
    assert np.all(np.isfinite(f))
    assert np.all(f <= f_e.max() + 1e-12) and np.all(f >= -f_e.max())
    # the inverse is one polynomial filter: precision 1e-5 of the peak over 5 decades of tau
    np.testing.assert_allclose(back, f_e, atol=2e-5 * f_e.max())
    # each term is the exact hereditary integral of a ramp: tau (1 - exp(-t / tau)) per unit
    ramp = np.arange(0, 5, dt)
    np.testing.assert_allclose(hereditary(ramp, dt, 0.5), 0.5 * -np.expm1(-ramp / 0.5),
                               rtol=0, atol=1e-12)


def test_library_spans_milliseconds_to_tens_of_seconds():
    assert min(PRONY_TAUS) <= 0.03 and max(PRONY_TAUS) >= 30.0
    sharp = {p.name: p for p in LIBRARY['hysteresis'].params}['transition']
    assert sharp.limit_ok and sharp.to_value(sharp.lower) <= 1e-5


@pytest.mark.parametrize('effect', list(LIBRARY))
def test_model_is_finite_at_every_corner_of_the_search_box(batches, effect):
    _, batch = batches['viscoelastic']
    layout = Layout.of([effect])
    corners = [(p.lower, p.upper) for _, p in layout.entries]
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        with np.errstate(all='ignore'):
            for x in itertools.islice(itertools.product(*corners), 64):
                pred, _ = forward(batch, layout.values(np.asarray(x)))
                assert np.all(np.isfinite(pred)), (effect, x)


def test_restarted_times_keep_every_poke_independent(batches):
    case, batch = batches['viscoelastic']
    assert case.restart and not np.any(carried_links(batch))
    # the same table on one increasing clock: only pokes at the same spot would link
    records = eg.records(eg.Case('plastic_set', 3.0, 'equal', seed=3, pokes=8), '/tmp')
    ordered, one_clock = time_order(records)
    assert one_clock and [r.poke_id for r in ordered] == [r.poke_id for r in records]
    joined, _ = make_batch(records)
    links = carried_links(joined)
    same_spot = np.linalg.norm(np.diff(joined.point, axis=0), axis=1) < 1e-9
    np.testing.assert_array_equal(links, same_spot)


def test_restarted_times_keep_the_table_order():
    records = eg.records(eg.Case('clean', seed=5, pokes=6, restart=True), '/tmp')
    ordered, one_clock = time_order(records)
    assert not one_clock
    assert [r.poke_id for r in ordered] == [r.poke_id for r in records]
    _, notes = make_batch(records)
    assert any('restart' in n for n in notes)


@pytest.mark.parametrize('effect', list(TEN_X))
def test_each_effect_at_ten_times_the_scenario_fits_without_a_warning(batches, effect):
    case, batch = batches[effect]
    name = eg.library_name(effect)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        fit = fit_global(batch, [name], max_nfev=40)
    assert np.isfinite(fit.cost)
    base = fit_global(batch, [], max_nfev=40)
    assert fit.cost <= base.cost * (1 + 1e-9)
    if base.cost > 4 * eg.NOISE ** 2:
        # the effect explains most of what the base model leaves (10x: far above the noise)
        assert fit.cost < 0.5 * base.cost, (effect, fit.cost, base.cost)
    else:
        # a 2 N/mm arm only reparametrises each point poke's curve: nothing is left to
        # explain, and the fit still finds the compliance
        assert effect == 'series_compliance'
        assert fit.values[name]['compliance'] == pytest.approx(1 / 2000.0, rel=0.2)
