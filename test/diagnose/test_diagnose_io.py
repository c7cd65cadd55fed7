"""Data in and out of diagnose: tables, stores, bags, corrections, stored effects, report, CLI."""

import dataclasses
import functools
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.sim import disturbances as ce
from pointforce_ros.sim.scenario import HalfSpaceContact, Scenario
from pointforce_ros.sim.session import simulate_campaign, simulate_poke
from pointforce_ros.diagnose import diagnose, run_diagnose
from pointforce_ros.effects.accepted import correct_surface, effects_from_dict, effects_to_dict
from pointforce_ros.effects.correct import (apply_series_compliance, correct_curve,
                                            correct_records, predict_measured, relaxed_fraction)
from pointforce_ros.pokes.table import load_pokes, read_poke_table, write_poke_table
from pointforce_ros.diagnose.batch import make_batch
from pointforce_ros.diagnose.model import fit_global
from pointforce_ros.diagnose.report import write_report
from pointforce_ros.diagnose.run import stream_loss_note
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.model.files import ContactModel, load_model, save_model
from pointforce_ros.pokes.curves import extract_curve
from pointforce_ros.pokes.store import PokeStore, write_poke_bag
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import PokeRecord, Surface

DATA = Path(__file__).resolve().parents[1] / 'data' / 'diagnose' / 'datasets.py'
_spec = importlib.util.spec_from_file_location('diagnose_datasets_io', DATA)
datasets = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(datasets)


@functools.lru_cache(maxsize=None)
def records(name):
    return tuple(datasets.make(name, seed=4))


# --------------------------------------------------------------------------- tables


def test_table_round_trip_keeps_every_series(tmp_path):
    recs = records('friction')[:5]
    path = write_poke_table(recs, tmp_path / 'pokes.csv')
    back = read_poke_table(path)
    assert [r.poke_id for r in back] == [r.poke_id for r in recs]
    for a, b in zip(recs, back):
        np.testing.assert_array_equal(b.point, a.point)
        np.testing.assert_allclose(b.normal, a.normal, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(b.t_controller, a.t_controller)
        np.testing.assert_allclose(b.displacement(), a.displacement(), rtol=0, atol=1e-15)
        np.testing.assert_allclose(b.wrench[:, :3], a.wrench[:, :3], rtol=0, atol=1e-15)
        np.testing.assert_allclose(b.normal_force(), a.normal_force(), rtol=0, atol=1e-14)
        assert b.speed == pytest.approx(a.speed, rel=1e-6)
    # a second round trip changes nothing beyond the last bit
    again = read_poke_table(write_poke_table(back, tmp_path / 'again.csv'))
    for a, b in zip(back, again):
        np.testing.assert_allclose(b.displacement(), a.displacement(), rtol=0, atol=1e-15)
        np.testing.assert_array_equal(b.wrench, a.wrench)


def test_table_without_force_vector_puts_force_on_the_normal(tmp_path):
    path = tmp_path / 'minimal.csv'
    t = np.arange(30) * 0.01
    depth = -0.001 + 0.002 * t
    force = 100.0 * np.maximum(depth, 0.0)
    rows = ['t,poke_id,px,py,pz,nx,ny,nz,depth,force']
    rows += [f'{ti},p1,0.1,0.2,0.3,0,0.6,0.8,{di},{fi}' for ti, di, fi in zip(t, depth, force)]
    path.write_text('\n'.join(rows) + '\n')
    (rec,) = read_poke_table(path)
    np.testing.assert_allclose(rec.displacement(), depth, atol=1e-15)
    np.testing.assert_allclose(rec.normal_force(), force, atol=1e-12)
    np.testing.assert_allclose(rec.wrench[:, :3], np.outer(force, [0, 0.6, 0.8]), atol=1e-12)
    assert rec.speed == pytest.approx(0.002)


@pytest.mark.parametrize('body, message', [
    ('poke_id,t,px,py,pz,nx,ny,nz,depth\np,0,0,0,0,0,0,1,0\n', 'missing column'),
    ('poke_id,t,px,py,pz,nx,ny,nz,depth,force\np,0,0,0,0,0,0,1,0,x\n', 'non-numeric'),
    ('poke_id,t,px,py,pz,nx,ny,nz,depth,force\np,1,0,0,0,0,0,1,0,0\np,0,0,0,0,0,0,1,0,0\n',
     'strictly increasing'),
    ('poke_id,t,px,py,pz,nx,ny,nz,depth,force\np,0,0,0,0,0,0,1,0,0\np,1,1,0,0,0,0,1,0,0\n',
     'changes between rows'),
])
def test_table_errors_say_what_is_wrong(tmp_path, body, message):
    path = tmp_path / 'bad.csv'
    path.write_text(body)
    with pytest.raises(DataError, match=message):
        read_poke_table(path)


def test_load_pokes_from_store_bag_table_and_records(tmp_path):
    recs = list(records('clean')[:4])
    store = PokeStore(tmp_path / 'store')
    for rec in recs:
        store.add(rec)
    bag = write_poke_bag(recs[0], tmp_path / 'single' / recs[0].poke_id)
    table = write_poke_table(recs, tmp_path / 'pokes.csv')
    for source, count in ((tmp_path / 'store', 4), (bag, 1), (table, 4), (recs, 4)):
        loaded = load_pokes(source)
        assert [r.poke_id for r in loaded] == [r.poke_id for r in recs][:count]
        np.testing.assert_allclose(loaded[0].normal_force(), recs[0].normal_force(),
                                   atol=1e-9)
    with pytest.raises(DataError):
        load_pokes(tmp_path / 'missing')
    (tmp_path / 'x.parquet').write_bytes(b'PAR1')
    with pytest.raises(DataError, match='pyarrow'):
        load_pokes(tmp_path / 'x.parquet')
    with pytest.raises(InvalidInput):
        load_pokes([recs[0], 'not a record'])


def test_diagnose_reads_a_table_like_records(tmp_path):
    recs = records('hysteresis')
    path = write_poke_table(recs, tmp_path / 'hyst.csv')
    kwargs = dict(seed=1, bootstrap=0, candidates=['hysteresis', 'viscoelastic',
                                                   'surface_offset'])
    from_table = diagnose(path, **kwargs)
    from_records = diagnose(list(recs), **kwargs)
    assert from_table.accepted_names == from_records.accepted_names == ['hysteresis']
    assert from_table.rmse_after == pytest.approx(from_records.rmse_after, rel=1e-6)
    assert from_table.effects()['hysteresis']['eta'] == pytest.approx(0.15, rel=0.05)


def test_large_camera_bias_stays_inside_the_analysis_window():
    # contact 4 mm before the observed surface, stand-off 10 mm: the window must follow it
    scenario = Scenario('bias', effects=(ce.FtNoise(force_std=0.005),
                                         ce.CameraDepthBias(bias=0.004)))
    recs = simulate_campaign(HalfSpaceContact(ripple=0.3), scenario, count=8, seed=2,
                             speed=0.004, standoff=0.01, force_limit=3.0, rate=100.0)
    batch, _ = make_batch(recs, window=0.002)
    first = batch.d[batch.starts[:-1]]
    assert np.all(first < -0.005)   # at least 1 mm of free space before the contact
    report = diagnose(recs, bootstrap=0, candidates=['surface_offset'])
    assert report.effects()['surface_offset']['offset'] == pytest.approx(0.004, rel=0.02)


def test_diagnose_rejects_bad_settings_and_too_little_data():
    recs = list(records('clean'))
    with pytest.raises(InvalidInput):
        diagnose(recs, alpha=1.5)
    with pytest.raises(InvalidInput, match='unknown candidate'):
        diagnose(recs, candidates=['gremlins'])
    with pytest.raises(DataError, match='at least 4'):
        diagnose(recs[:3])


# --------------------------------------------------------------------------- stored effects


def test_effects_mapping_round_trips_through_a_model_file(tmp_path):
    report = diagnose(list(records('surface_offset')), seed=0, bootstrap=0,
                      candidates=['surface_offset', 'time_offset'])
    effects = effects_to_dict(report)
    assert list(effects) == ['surface_offset']
    assert effects['surface_offset']['offset'] == pytest.approx(0.0015, rel=0.05)
    surface = Surface(points=np.zeros((2, 3)), normals=np.tile([0, 0, 1.0], (2, 1)))
    table = BakedResponse(depths=[0.0, 0.001], forces=np.zeros((2, 2)), slopes=np.zeros(2))
    path = save_model(ContactModel(surface, table, 0.01, version=3, effects=effects), tmp_path)
    loaded = effects_from_dict(load_model(path).effects)
    assert loaded == effects
    assert json.loads(json.dumps(loaded)) == loaded


@pytest.mark.parametrize('bad, message', [
    ({'gremlins': {}}, 'unknown effect'),
    ({'hysteresis': {'eta': 0.1}}, 'missing'),
    ({'friction': {'mu': 0.1, 'colour': 2}}, 'unknown parameter'),
    ({'viscoelastic': {'g': 0.1, 'tau': -1.0}}, '> 0'),
    ({'time_offset': {'offset': float('nan')}}, 'finite'),
    (['surface_offset'], 'mapping'),
])
def test_effects_from_dict_rejects_bad_entries(bad, message):
    with pytest.raises(InvalidInput, match=message):
        effects_from_dict(bad)


# --------------------------------------------------------------------------- corrections

CORRECTABLE = ['surface_offset', 'ft_bias', 'ft_drift', 'time_offset', 'viscoelastic',
               'hysteresis', 'series_compliance', 'plastic_set', 'friction', 'two_effects']


def _true_effects(name):
    effects = {}
    for effect, params in datasets.TRUTH[name].items():
        full = dict(datasets.FULL_TRUTH.get(effect, params))
        if effect == 'plastic_set':
            full['radius'] = 0.004
        effects[effect] = full
    return effects


def _base_rms(recs):
    batch, _ = make_batch(recs)
    fit = fit_global(batch, [])
    return float(np.sqrt(fit.cost)), fit


def _until_retraction(rec):
    """The record up to the end of the hold (relaxation is not invertible once it unloads)."""
    d = rec.displacement()
    stop = int(np.flatnonzero(d == d.max())[-1]) + 1
    return PokeRecord(poke_id=rec.poke_id, point=rec.point, normal=rec.normal, t=rec.t[:stop],
                      t_controller=rec.t_controller[:stop], tcp_pose=rec.tcp_pose[:stop],
                      wrench=rec.wrench[:stop], speed=rec.speed, meta=rec.meta)


@pytest.mark.parametrize('name', CORRECTABLE)
def test_correcting_with_the_true_effect_leaves_only_noise(name):
    recs = list(records(name))
    before, _ = _base_rms(recs)
    clean, _ = _base_rms(list(records('clean')))
    corrected = correct_records(recs, _true_effects(name))
    if 'viscoelastic' in datasets.TRUTH[name]:
        corrected = [_until_retraction(r) for r in corrected]
        clean, _ = _base_rms([_until_retraction(r) for r in records('clean')])
    after, fit = _base_rms(corrected)
    assert before > 1.5 * clean
    # relaxation: the material's memory of the previous poke (2 s earlier, tau 1 s) is not
    # carried by a per-record correction, so a little more than noise remains
    factor = 2.5 if 'viscoelastic' in datasets.TRUTH[name] else 1.5
    assert after < factor * clean + 1e-3
    # the recovered contact law has the object's Hertz shape over the poked depths
    x = np.linspace(0.3, 1.4, 12)
    base = fit.values['base']
    shape = x ** base['exponent'] * np.exp(base['curvature'] * (x - 1.0))
    np.testing.assert_allclose(shape, x ** 1.5, rtol=0.02 * factor)


def test_correct_curve_moves_the_onset_and_the_depth():
    (rec,) = [r for r in records('surface_offset')[:1]]
    curve = extract_curve(rec)
    assert curve.onset_d == pytest.approx(-0.0015, abs=2e-4)
    fixed = correct_curve(curve, {'surface_offset': {'offset': 0.0015}})
    assert fixed.onset_d == pytest.approx(0.0, abs=2e-4)
    np.testing.assert_allclose(fixed.d - curve.d, 0.0015)
    comp = correct_curve(curve, {'series_compliance': {'compliance': 5e-4}})
    np.testing.assert_allclose(curve.d - comp.d, 5e-4 * np.maximum(curve.f, 0.0))
    set_two = correct_curve(curve, {'plastic_set': {'max_set': 0.001, 'n0': 1.0}},
                            count_before=2)
    np.testing.assert_allclose(curve.d - set_two.d, 0.001 * (1 - np.exp(-2.0)))
    with pytest.raises(InvalidInput):
        correct_curve(curve, {}, count_before=-1)


def test_correct_surface_offset_and_plastic_sink():
    points = np.array([[0.0, 0.0, 0.04], [0.003, 0.0, 0.04], [0.01, 0.0, 0.04]])
    surface = Surface(points=points, normals=np.tile([0, 0, 1.0], (3, 1)))
    moved = correct_surface(surface, {'surface_offset': {'offset': 0.002}})
    np.testing.assert_allclose(moved.points[:, 2], 0.042)
    sunk = correct_surface(surface, {'plastic_set': {'max_set': 0.001, 'n0': 2.0,
                                                     'radius': 0.004}},
                           poke_points=[[0.0, 0.0, 0.04]], poke_counts=[3])
    expected = 0.001 * (1 - np.exp(-1.5))
    np.testing.assert_allclose(sunk.points[:, 2], [0.04 - expected, 0.04 - expected, 0.04])


def test_forward_terms_match_closed_forms_and_the_cell():
    k, c = 3000.0, 2e-4
    depth = np.linspace(-0.001, 0.006, 50)
    force = apply_series_compliance(lambda d: k * np.maximum(d, 0.0), depth,
                                    {'series_compliance': {'compliance': c}})
    np.testing.assert_allclose(force, k * np.maximum(depth, 0.0) / (1 + k * c), rtol=1e-9,
                               atol=1e-12)
    assert relaxed_fraction({'viscoelastic': {'g': 0.25, 'tau': 2.0}}) == pytest.approx(0.75)
    assert relaxed_fraction({}) == 1.0
    # predict_measured reproduces the cell's hysteresis + relaxation + time offset
    truth = {'hysteresis': {'eta': 0.2, 'transition': 4e-4},
             'viscoelastic': {'g': 0.3, 'tau': 0.7}, 'time_offset': {'offset': 0.012}}
    contact = HalfSpaceContact(z0=0.04, k0=1.4e4)
    scenario = Scenario('f', effects=(ce.Hysteresis(eta=0.2, transition=4e-4),
                                      ce.ViscoelasticRelaxation(g=(0.3,), tau=(0.7,)),
                                      ce.TimeOffset(offset=0.012)))
    rec = simulate_poke(scenario.force_model(contact), [0, 0, 0.04], [0, 0, 1.0],
                        poke_id='p', speed=0.003, standoff=0.002, force_limit=3.0,
                        rate=250.0, hold=0.5)
    predicted = predict_measured(lambda d: 1.4e4 * np.maximum(d, 0.0) ** 1.5,
                                 rec.t_controller, rec.displacement(), truth)
    np.testing.assert_allclose(predicted, rec.normal_force(), atol=2e-3 * 3.0)


# --------------------------------------------------------------------------- report and CLI


def test_write_report_and_run_diagnose(tmp_path, capsys):
    report = diagnose(list(records('time_offset')), seed=0, bootstrap=2,
                      candidates=['time_offset', 'hysteresis', 'surface_offset'])
    path = write_report(report, tmp_path / 'out')
    text = path.read_text()
    assert 'time_offset' in text and f'{report.rmse_before:.4g}' in text
    assert f'{report.rmse_after:.4g}' in text
    for png in ('residual_before.png', 'residual_after.png', 'selection.png',
                'worst_poke.png'):
        data = (tmp_path / 'out' / png).read_bytes()
        assert data[:8] == b'\x89PNG\r\n\x1a\n' and len(data) > 5000
    stored = json.loads((tmp_path / 'out' / 'effects.json').read_text())
    assert stored == effects_to_dict(report)
    summary = json.loads((tmp_path / 'out' / 'summary.json').read_text())
    assert summary['rmse']['sample_before'] == pytest.approx(report.rmse_before)
    assert summary['rmse']['model_after'] == pytest.approx(report.model_rmse_after)
    assert summary['halved'] == report.halved and summary['halving_judged_on'] == 'model RMSE'
    assert [a['name'] for a in summary['accepted']] == report.accepted_names
    assert f'{report.model_rmse_before:.4g}' in text and 'model RMSE' in text
    table = write_poke_table(records('clean')[:5], tmp_path / 'clean.csv')
    assert run_diagnose(table, tmp_path / 'cli', seed=0, bootstrap=0,
                        candidates=['surface_offset']) == 0
    out = capsys.readouterr().out
    assert 'no effect accepted' in out and (tmp_path / 'cli' / 'report.md').is_file()
    assert run_diagnose(tmp_path / 'nothing-here', tmp_path / 'cli2') == 2
    assert 'no poke data' in capsys.readouterr().err


# --------------------------------------------------------------------------- forward terms


def test_retreat_solves_the_series_spring_in_closed_form():
    from pointforce_ros.effects.forward import solve_retreat
    rng = np.random.default_rng(5)
    depth = rng.uniform(-0.001, 0.006, 40)          # commanded depths, some out of contact
    k = rng.uniform(500.0, 5000.0, 40)               # contact stiffness, N/m
    compliance = 2e-4                                # m/N

    def push_back(index, shift):                     # a linear contact spring per pose
        return k[index] * np.maximum(depth[index] - shift, 0.0)

    shift, evaluations = solve_retreat(push_back, compliance, len(depth))
    expected = compliance * k * np.maximum(depth, 0.0) / (1.0 + compliance * k)
    np.testing.assert_allclose(shift, expected, rtol=0, atol=1e-8)
    assert evaluations < 20
    # Hertz-like law: the retreat is the fixed point s = c F(d - s)
    shift, _ = solve_retreat(lambda i, s: 3e4 * np.maximum(depth[i] - s, 0) ** 1.5,
                             compliance, len(depth))
    np.testing.assert_allclose(shift, compliance * 3e4 * np.maximum(depth - shift, 0) ** 1.5,
                               rtol=0, atol=1e-8)


def test_forward_terms_say_what_they_apply_and_why_not():
    from pointforce_ros.effects.forward import ForwardTerms, hold_fraction, model_surface
    effects = {'series_compliance': {'compliance': 1e-4}, 'viscoelastic': {'g': 0.3, 'tau': 2.0},
               'time_offset': {'offset': 0.01}, 'surface_offset': {'offset': 0.002}}
    terms = ForwardTerms.of(effects, hold_time=2.0)
    assert terms.compliance == 1e-4
    assert terms.force_scale == pytest.approx(1.0 - 0.3 * (1.0 - np.exp(-1.0)), rel=1e-12)
    assert set(terms.applied) == {'series_compliance', 'viscoelastic', 'surface_offset'}
    assert dict(terms.skipped).keys() == {'time_offset'}
    off = ForwardTerms.of(effects, series_compliance=False)
    assert off.compliance == 0.0 and off.force_scale == 1.0
    assert 'series_compliance' in dict(off.skipped)
    assert hold_fraction({'g': 0.3, 'tau': 2.0}, 1e9) == pytest.approx(0.7)
    with pytest.raises(InvalidInput, match='hold_time'):
        ForwardTerms.of(effects, hold_time=-1.0)
    # a file that has not applied the surface offset gets it at load, one that has does not
    surface = Surface(points=np.zeros((3, 3)) + [[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0]],
                      normals=np.tile([0.0, 0.0, 1.0], (3, 1)))
    table = BakedResponse(depths=np.array([0.0, 0.01]), forces=np.zeros((3, 2)),
                          slopes=np.zeros(3))
    raw = ContactModel(surface=surface, response=table, shape_constant=0.004,
                       effects=effects_to_dict(effects))
    np.testing.assert_allclose(model_surface(raw).points[:, 2], 0.002)
    done = ContactModel(surface=surface, response=table, shape_constant=0.004, effects=effects,
                        meta={'surface_corrected': ['surface_offset']})
    np.testing.assert_allclose(model_surface(done).points[:, 2], 0.0)


def test_pokes_whose_stream_missed_slots_are_named_in_the_report_notes(tmp_path):
    """The poke server stores the runs of 250 Hz slots with no sample in a poke's meta
    (``stream_losses``); diagnose names those pokes, after a round trip through the bags, and
    counts nothing from a malformed entry."""
    recs = simulate_campaign(HalfSpaceContact(ripple=0.3), Scenario('clean', effects=()),
                             count=3, seed=4, speed=0.004, force_limit=2.0, rate=100.0)
    losses = {0: [[1.25, 4, 0.02], [1.5, 1, 0.004]], 2: [[2.0, 15, 0.066]]}
    store = PokeStore(tmp_path / 'pokes')
    for k, record in enumerate(recs):
        meta = dict(record.meta, stream_losses=losses.get(k, []))
        if k == 1:
            meta['stream_losses'] = [['x', 'many'], [1.0], 'garbage', [1.0, float('nan'), 0]]
        store.add(dataclasses.replace(record, meta=meta))
    note = stream_loss_note(load_pokes(tmp_path / 'pokes'))
    assert note.startswith('2 poke(s) have F/T stream slots with no sample (20 slots in 3 runs')
    assert f'{recs[2].poke_id} 15, {recs[0].poke_id} 5' in note
    assert stream_loss_note(recs) == ''
