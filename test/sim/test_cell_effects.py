"""Signature tests of the simulated cell's effects, the F/T sensor and the scenarios.

The clean physics is an analytic stand-in: a flat elastic top at ``z = Z0`` (normal +z) with a
Hertz-like response ``f = k(x, y) d**1.5`` (or a linear spring) and a stiffness field over x, y.
The probe points down (TCP rotation vector ``(pi, 0, 0)``: tool z = -z of base).
"""

import time

import numpy as np
import pytest

from pointforce_ros.sim.disturbances import (DelayLine, EFFECTS, Friction, Hysteresis, PlasticSet,
                                             SeriesCompliance, solve_series_compliance, TimeOffset,
                                             ViscoelasticRelaxation)
from pointforce_ros.sim.ft_sensor import FtSensor, GRAVITY
from pointforce_ros.sim.scenario import (CellForceModel, HalfSpaceContact, list_scenarios,
                                         load_scenario, make_force_model, Scenario,
                                         scenario_from_dict)
from pointforce_ros.errors import DataError, InvalidInput, NotConverged

Z0 = 0.04
RATE = 500.0
DOWN_ROTVEC = np.array([np.pi, 0.0, 0.0])


def stiffness_field(x, y):
    """Hertz-like stiffness over the top, N/m^1.5 (about 10 N at 8 mm)."""
    return 1.4e4 * (1.0 + 0.5 * np.sin(40.0 * x) * np.cos(30.0 * y))


def hertz_clean(tip, axis):
    depth = max(Z0 - tip[2], 0.0)
    return np.array([0.0, 0.0, stiffness_field(tip[0], tip[1]) * depth ** 1.5]), np.zeros(3)


def linear_clean(k):
    def clean(tip, axis):
        return np.array([0.0, 0.0, k * max(Z0 - tip[2], 0.0)]), np.zeros(3)
    return clean


def pose_at(depth, x=0.5, y=0.0):
    """TCP pose with the tip ``depth`` below the clean top at (x, y), probe pointing down."""
    return np.concatenate([[x, y, Z0 - depth], DOWN_ROTVEC])


def run(model, depths, t0=0.0, x=0.5, y=0.0):
    """Feed a depth trajectory at 500 Hz; return reported (T, 6) and the per-sample truth."""
    out, truth = [], []
    for i, d in enumerate(depths):
        out.append(model.wrench(pose_at(d, x, y), t0 + i / RATE))
        truth.append(model.last)
    return np.array(out), truth


def ramp(d_max, speed=0.002, start=-0.002):
    """Depths from ``start`` to ``d_max`` and back at ``speed`` m/s, sampled at 500 Hz."""
    n = int(round((d_max - start) / speed * RATE))
    down = np.linspace(start, d_max, n + 1)
    return np.concatenate([down, down[-2::-1]])


# --------------------------------------------------------------------------- F/T sensor


def test_ft_tare_removes_bias_and_drift_only_at_tare_time():
    bias = np.array([0.8, -0.5, 1.2, 0.02, -0.01, 0.005])
    drift = np.array([0.01, -0.008, 0.02, 2e-4, -2e-4, 1e-4])
    sensor = FtSensor(bias=bias, drift_rate=drift)
    true = np.array([0.1, 0.2, 3.0, 0.0, 0.01, 0.0])
    np.testing.assert_allclose(sensor.read(true, 4.0), true + bias + 4.0 * drift, atol=1e-12)
    load_at_tare = np.array([0.0, 0.0, 0.5, 0.0, 0.0, 0.0])
    sensor.tare(load_at_tare, 10.0)
    np.testing.assert_allclose(sensor.read(load_at_tare, 10.0), 0.0, atol=1e-12)
    np.testing.assert_allclose(sensor.read(true, 15.0), true - load_at_tare + 5.0 * drift,
                               atol=1e-12)


def test_ft_noise_std_and_seed():
    std = np.array([0.03, 0.03, 0.03, 0.0015, 0.0015, 0.0015])
    a, b = FtSensor(noise_std=std, seed=4), FtSensor(noise_std=std, seed=4)
    ra = np.array([a.read(np.zeros(6), i / RATE) for i in range(4000)])
    rb = np.array([b.read(np.zeros(6), i / RATE) for i in range(4000)])
    np.testing.assert_array_equal(ra, rb)
    np.testing.assert_allclose(ra.std(axis=0), std, rtol=0.05)
    assert np.all(np.abs(ra.mean(axis=0)) < 4 * std / np.sqrt(4000))


def test_ft_payload_error_leaves_its_weight_and_torque():
    sensor = FtSensor(payload_error=0.1, payload_cog=(0.0, 0.0, 0.05))
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # tool z -> base -y
    out = sensor.read(np.zeros(6), 0.0, tilt)
    weight = 0.1 * GRAVITY
    np.testing.assert_allclose(out[:3], [0.0, 0.0, weight], atol=1e-12)
    np.testing.assert_allclose(out[3:], np.cross([0.0, -0.05, 0.0], [0.0, 0.0, weight]),
                               atol=1e-12)
    with pytest.raises(InvalidInput):
        FtSensor(noise_std=-0.1)
    with pytest.raises(InvalidInput):
        sensor.read(np.full(6, np.nan), 0.0)


# --------------------------------------------------------------------------- time offset


def test_time_offset_cross_correlation_peaks_at_the_offset():
    rng = np.random.default_rng(21)
    n = 3000
    # band-limited random depth around 4 mm
    white = rng.standard_normal(n + 200)
    depth = 0.004 + 0.001 * np.convolve(white, np.hanning(25) / 6.0, mode='same')[100:-100]
    model = load_scenario('time_offset').force_model(linear_clean(2000.0))
    reported, truth = run(model, depth)
    clean = np.array([s.clean[2] for s in truth])
    a, b = clean - clean.mean(), reported[:, 2] - reported[:, 2].mean()
    lags = np.arange(-10, 11)
    corr = [np.dot(a[20:-20], np.roll(b, -lag)[20:-20]) for lag in lags]
    assert lags[int(np.argmax(corr))] == round(0.008 * RATE)
    np.testing.assert_allclose(reported[4:, 2], clean[:-4], atol=1e-9)


def test_delay_line_interpolates_fractional_offsets():
    line = DelayLine(0.003)  # 1.5 samples at 500 Hz
    t = np.arange(50) / RATE
    out = np.array([line(ti, np.full(6, 2.0 * ti + 1.0)) for ti in t])
    np.testing.assert_allclose(out[2:, 0], 2.0 * (t[2:] - 0.003) + 1.0, atol=1e-12)
    with pytest.raises(InvalidInput):
        TimeOffset(offset=-0.001)


# --------------------------------------------------------------------------- viscoelastic


def test_relaxation_decays_with_tau_to_g_inf_at_constant_depth():
    visco = ViscoelasticRelaxation(g=(0.3,), tau=(0.4,))
    model = CellForceModel(linear_clean(2000.0), [visco])
    hold_depth = 0.005
    depths = np.concatenate([np.linspace(0.0, hold_depth, 51), np.full(1500, hold_depth)])
    reported, _ = run(model, depths)
    f = reported[:, 2]
    f_e = 2000.0 * hold_depth
    t_ramp = 50 / RATE
    # ramp with constant force rate r: f = g_inf r t + g r tau (1 - exp(-t / tau))
    r = f_e / t_ramp
    expect_peak = 0.7 * r * t_ramp + 0.3 * r * 0.4 * (1.0 - np.exp(-t_ramp / 0.4))
    assert f[50] == pytest.approx(expect_peak, rel=1e-9)
    hold = f[50:] - visco.g_inf * f_e
    t = np.arange(len(hold)) / RATE
    slope = np.polyfit(t, np.log(hold), 1)[0]
    assert -1.0 / slope == pytest.approx(0.4, rel=1e-6)
    assert f[-1] == pytest.approx(0.7 * f_e, rel=1e-3)


def test_relaxation_never_pulls_after_fast_unloading():
    model = CellForceModel(linear_clean(2000.0), [ViscoelasticRelaxation(g=(0.5,), tau=(2.0,))])
    depths = np.concatenate([np.linspace(0.0, 0.006, 301), np.linspace(0.006, 0.003, 4),
                             np.full(50, 0.003), np.full(20, -0.001)])
    reported, _ = run(model, depths)
    assert np.all(reported[:, 2] >= 0.0)
    assert np.all(reported[-20:] == 0.0)
    # right after the fast partial unload the force has dropped below the elastic value
    assert reported[305, 2] < 2000.0 * 0.003


# --------------------------------------------------------------------------- hysteresis


def loop_area(model_factory):
    depths = ramp(0.008)
    reported, truth = run(model_factory(), depths)
    d = np.array([Z0 - s.actual_tip[2] for s in truth])
    # closed loop integral of f dd: loading work minus the work given back on unloading
    trapezoid = getattr(np, 'trapezoid', None) or np.trapz
    return trapezoid(reported[:, 2], d), d, reported[:, 2]


def test_hysteresis_unloading_below_loading_and_area_proportional_to_eta():
    area1, d, f1 = loop_area(lambda: CellForceModel(hertz_clean, [Hysteresis(0.1, 0.0005)]))
    area2, _, _ = loop_area(lambda: CellForceModel(hertz_clean, [Hysteresis(0.2, 0.0005)]))
    area0, _, _ = loop_area(lambda: CellForceModel(hertz_clean, []))
    assert abs(area0) < 1e-12
    assert area1 > 1e-3  # joules: about 0.1 of the loading work
    assert area2 / area1 == pytest.approx(2.0, rel=1e-9)
    half = len(d) // 2
    probe = np.array([0.002, 0.004, 0.006])
    loading = np.interp(probe, d[:half + 1], f1[:half + 1])
    unloading = np.interp(probe, d[half:][::-1], f1[half:][::-1])
    assert np.all(unloading < 0.95 * loading)


def test_hysteresis_is_rate_independent():
    slow = run(CellForceModel(hertz_clean, [Hysteresis(0.15, 0.0005)]), ramp(0.006, 0.002))[0]
    fast_depths = ramp(0.006, 0.004)
    fast = run(CellForceModel(hertz_clean, [Hysteresis(0.15, 0.0005)]), fast_depths)[0]
    np.testing.assert_allclose(slow[::2, 2], fast[:, 2], atol=1e-12)


# --------------------------------------------------------------------------- series compliance


def test_series_compliance_apparent_stiffness_on_a_linear_spring():
    k, k_s = 3000.0, 20000.0
    model = CellForceModel(linear_clean(k), [SeriesCompliance(k_s)])
    depths = np.linspace(0.001, 0.008, 200)
    reported, truth = run(model, depths)
    slope = np.polyfit(depths, reported[:, 2], 1)[0]
    assert slope == pytest.approx(k * k_s / (k + k_s), rel=1e-9)
    assert max(s.evaluations for s in truth) <= 3


def test_series_compliance_fixed_point_on_hertz():
    k_s = 20000.0
    model = CellForceModel(hertz_clean, [SeriesCompliance(k_s)])
    reported, truth = run(model, ramp(0.009))
    commanded = np.array([Z0 - s.commanded_tip[2] for s in truth])
    actual = np.array([Z0 - s.actual_tip[2] for s in truth])
    np.testing.assert_allclose(actual, commanded - reported[:, 2] / k_s, atol=2e-9)
    assert np.max(commanded - actual) > 4e-4  # the effect is visible: > 0.4 mm at ~10 N
    assert np.mean([s.evaluations for s in truth]) < 4.0


def test_series_compliance_solver_reports_non_convergence():
    # a "force" that grows as the tip retracts has no fixed point
    with pytest.raises(NotConverged):
        solve_series_compliance(lambda u: 1.0 + 4e4 * u, 2e4, max_iter=20)
    u, _, _ = solve_series_compliance(lambda u: max(500.0 * (0.01 - u), 0.0), 1000.0)
    assert u == pytest.approx(500.0 * 0.01 / 1500.0, abs=1e-9)


# --------------------------------------------------------------------------- friction


def test_friction_opposes_oblique_slip_with_mu_times_normal_force():
    mu = 0.4
    model = CellForceModel(hertz_clean, [Friction(mu=mu, stick_velocity=1e-4)])
    n = 1500
    s = np.arange(n) * 0.002 / RATE  # 2 mm/s along the path
    direction = np.array([np.sin(np.radians(30)), 0.0, -np.cos(np.radians(30))])
    reported = []
    for i in range(n):
        tip = np.array([0.5, 0.0, Z0 + 0.001]) + s[i] * direction
        reported.append(model.wrench(np.concatenate([tip, DOWN_ROTVEC]), i / RATE))
    reported = np.array(reported)
    contact = reported[:, 2] > 0.05
    assert np.count_nonzero(contact) > 500
    ratio = -reported[contact, 0] / reported[contact, 2]  # slip is +x, friction -x
    np.testing.assert_allclose(ratio[1:], mu, rtol=1e-9)
    np.testing.assert_allclose(reported[:, 1], 0.0, atol=1e-12)


def test_friction_is_silent_on_a_normal_push_and_proportional_below_stick():
    model = CellForceModel(hertz_clean, [Friction(mu=0.5, stick_velocity=1e-3)])
    reported, _ = run(model, np.linspace(0.0, 0.006, 300))
    np.testing.assert_allclose(reported[:, :2], 0.0, atol=1e-12)
    model = CellForceModel(hertz_clean, [Friction(mu=0.5, stick_velocity=1e-3)])
    for i in range(10):  # slide sideways at 0.25 mm/s at 5 mm depth
        out = model.wrench(pose_at(0.005, x=0.5 + i * 0.00025 / RATE), i / RATE)
    assert -out[0] / out[2] == pytest.approx(0.5 * 0.25, rel=1e-6)


# --------------------------------------------------------------------------- plastic set


def onset_depth(model, x=0.5):
    """Poke to 5 mm and back; return the commanded depth where contact starts (> 0.05 N)."""
    depths = ramp(0.005, 0.004)
    reported, _ = run(model, depths, t0=model.last.t + 1.0 if model.last else 0.0, x=x)
    model.reset_poke()
    first = int(np.argmax(reported[:, 2] > 0.05))
    # interpolate the depth where f = 0.05 N on the linear spring used here
    return depths[first] - (reported[first, 2] - 0.05) / 2000.0


def test_plastic_set_shifts_onset_with_repeated_pokes():
    effect = PlasticSet(max_set=0.0008, n0=3.0, radius=0.004, min_force=1.0)
    model = CellForceModel(linear_clean(2000.0), [effect])
    base_onset = 0.05 / 2000.0
    onsets = [onset_depth(model) for _ in range(5)]
    expect = base_onset + effect.set_depth(np.arange(5))
    np.testing.assert_allclose(onsets, expect, atol=1e-7)
    # a spot 10 mm away is untouched; a light touch leaves no set
    assert onset_depth(model, x=0.51) == pytest.approx(base_onset, abs=1e-7)
    light = CellForceModel(linear_clean(2000.0), [effect])
    run(light, ramp(0.0003))
    light.reset_poke()
    assert onset_depth(light) == pytest.approx(base_onset, abs=1e-7)


# --------------------------------------------------------------------------- scenarios + model


def test_every_effect_has_a_scenario_file_and_all_files_load():
    names = list_scenarios()
    assert {'clean', 'realistic'} <= set(names)
    single = {}
    for name in names:
        scenario = load_scenario(name)
        assert scenario.name == name
        assert scenario_from_dict(scenario.to_dict(), scenario.source) == scenario
        if len(scenario.effects) == 1:
            single[scenario.effects[0].name] = name
    assert set(EFFECTS) <= set(single)
    assert load_scenario('clean').effects == ()


def test_realistic_scenario_has_the_specified_sizes():
    real = load_scenario('realistic')
    assert real.camera_kwargs()['depth_bias'] == pytest.approx(0.002)
    assert real.camera_kwargs(0)['seed'] != real.camera_kwargs(1)['seed']
    sensor = real.ft_sensor()
    np.testing.assert_allclose(sensor.noise_std[:3], 0.03)
    assert 0 < np.max(np.abs(sensor.drift_rate[:3])) <= 0.005


def test_realistic_model_tare_zeroes_out_of_contact_reading():
    model = load_scenario('realistic').force_model(hertz_clean)
    free = pose_at(-0.01)
    before = np.array([model.wrench(free, 100.0 + i / RATE) for i in range(500)])
    model.tare()
    after = np.array([model.wrench(free, 101.0 + i / RATE) for i in range(500)])
    assert abs(before[:, 2].mean()) > 0.5  # bias 0.5 N plus 0.3 N of drift
    assert abs(after[:, 2].mean()) < 4 * 0.03 / np.sqrt(500) + 0.003
    reference = model.last
    assert reference.reported is not None and np.all(reference.clean == 0.0)


def test_force_model_reads_the_probe_axis_from_the_tcp_rotation():
    seen = []

    def recording(tip, axis):
        seen.append(np.array(axis))
        return np.zeros(3), np.zeros(3)

    model = CellForceModel(recording)
    model.wrench(pose_at(0.0), 0.0)
    np.testing.assert_allclose(seen[-1], [0.0, 0.0, -1.0], atol=1e-12)
    tilt = np.radians(20.0)
    model.wrench([0.5, 0.0, 0.05, 0.0, tilt, 0.0], 0.1)
    np.testing.assert_allclose(seen[-1], [np.sin(tilt), 0.0, np.cos(tilt)], atol=1e-12)
    with pytest.raises(InvalidInput):
        model.wrench(pose_at(0.0), 0.05)  # time went backwards
    with pytest.raises(InvalidInput):
        model.wrench([np.nan] * 6, 1.0)


def test_invalid_scenarios_are_rejected(tmp_path):
    with pytest.raises(InvalidInput, match='known'):
        load_scenario('no_such_scenario')
    with pytest.raises(InvalidInput, match='unknown effect'):
        scenario_from_dict({'name': 'x', 'effects': [{'effect': 'magic'}]})
    with pytest.raises(InvalidInput, match='unknown parameter'):
        scenario_from_dict({'name': 'x', 'effects': [{'effect': 'ft_noise', 'sigma': 1}]})
    with pytest.raises(InvalidInput, match='more than once'):
        scenario_from_dict({'name': 'x', 'effects': [{'effect': 'ft_noise'}] * 2})
    with pytest.raises(InvalidInput):
        ViscoelasticRelaxation(g=(0.6, 0.5), tau=(1.0, 2.0))
    with pytest.raises(InvalidInput):
        Hysteresis(eta=1.2)
    bad = tmp_path / 'broken.yaml'
    bad.write_text('name: [unclosed\n')
    with pytest.raises(DataError):
        load_scenario(str(bad))


def test_all_effects_model_call_is_well_under_a_millisecond():
    scenario = Scenario('all', seed=1, effects=(
        ViscoelasticRelaxation(g=(0.15, 0.1), tau=(0.5, 5.0)), Hysteresis(0.15, 0.0005),
        Friction(0.4), SeriesCompliance(2e4), PlasticSet(), TimeOffset(0.008)))
    model = scenario.force_model(hertz_clean)
    depths = ramp(0.008)
    times = []
    for i, d in enumerate(depths):
        pose = pose_at(d, x=0.5 + 1e-4 * np.sin(i / 50.0))
        start = time.perf_counter()
        model.wrench(pose, i / RATE)
        times.append(time.perf_counter() - start)
    assert np.median(times) < 0.5e-3


def test_emulator_factory_with_an_analytic_half_space():
    model = make_force_model('series_compliance', halfspace={'z0': Z0, 'k0': 3000.0,
                                                             'exponent': 1.0})
    depths = np.linspace(0.001, 0.006, 50)
    reported, _ = run(model, depths)
    np.testing.assert_allclose(reported[:, 2], 3000.0 * 2e4 / 2.3e4 * depths, rtol=1e-9)
    ripple = HalfSpaceContact(z0=Z0, k0=1000.0, exponent=1.0, ripple=0.5, wavelength=0.04)
    stiff, _ = ripple(np.array([0.01, 0.01, Z0 - 0.002]), np.array([0.0, 0.0, -1.0]))
    soft, _ = ripple(np.array([0.01, -0.01, Z0 - 0.002]), np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose([stiff[2], soft[2]], [3.0, 1.0], rtol=1e-12)
    with pytest.raises(InvalidInput):
        make_force_model('clean', halfspace={'stiffness': 1.0})
