"""Probe trials in diagnose: before/after errors of the served model, and spatial coupling.

The trials (``test/data/diagnose/probe_trials.py``) press a paddle and a cylinder into the
analytic half-space of the diagnose data sets; their ground truth uses the true point law and a
chosen true shape constant ``c_true``. The point model is learned from the pokes as the nodes
learn it and answered through the contact service.
"""

import dataclasses
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.diagnose import diagnose
from pointforce_ros.diagnose.probes import (compliance_corrected, CouplingResult,
                                            fit_series_compliance, generated_files,
                                            learn_contact_model, ProbeScore, score_probe_trials)
from pointforce_ros.diagnose.report import write_report
from pointforce_ros.diagnose.run import _probe_accepted
from pointforce_ros.effects.accepted import effects_from_dict, effects_to_dict
from pointforce_ros.effects.forward import ForwardTerms
from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.trials import load_probe_trials, save_probe_trials
from pointforce_ros.response.baked import BakedResponse

HERE = Path(__file__).resolve().parents[1] / 'data' / 'diagnose'
_spec = importlib.util.spec_from_file_location('diagnose_probe_trials', HERE / 'probe_trials.py')
probe_data = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(probe_data)
datasets = probe_data.datasets


def test_probe_trials_are_scored_before_and_after_through_diagnose(tmp_path):
    # pokes through a compliant arm (0.5 mm/N), probes with the learner's own coupling: diagnose
    # accepts the compliance on the pokes and the model learned with it answers the probes far
    # better; the coupling, right already, is not changed
    trials = probe_data.make_trials(0.004)
    report = diagnose(datasets.make('series_compliance'), seed=0, bootstrap=0,
                      probes=trials, surface=probe_data.top_surface(), shape_constant=0.004,
                      log=lambda line: None)
    assert report.accepted_names == ['series_compliance']
    probe = report.probe
    assert probe.effects == report.effects() and len(probe.kinds) == len(trials) == 8
    assert probe.force_rmse_after <= 0.5 * probe.force_rmse_before
    assert probe.torque_rmse_after <= 0.5 * probe.torque_rmse_before
    assert np.all(probe.force_after < probe.force_before)
    # pooled RMSE is the RMS of the per-trial figures weighted by their steps
    assert probe.force_rmse_after == pytest.approx(
        np.sqrt(np.sum(probe.force_after ** 2 * probe.steps) / probe.steps.sum()))
    coupling = probe.coupling
    assert not coupling.accepted
    assert coupling.fitted == pytest.approx(0.004, rel=0.2)
    summary = report.summary()
    assert 'probe trials (8' in summary and 'spatial_coupling (probe trials)' in summary
    text = write_report(report, tmp_path).read_text()
    assert '## Probe trials' in text and (tmp_path / 'probe_trials.png').is_file()
    assert f'| RMSE, probe trials: force (N) | {probe.force_rmse_before:.4g} | ' \
           f'{probe.force_rmse_after:.4g} |' in text


def test_spatial_coupling_beyond_the_shape_function_is_found_on_probe_trials():
    # true coupling 12 mm against the learner's 4 mm; the point pokes cannot tell
    trials = probe_data.make_trials(0.012)
    score = score_probe_trials(datasets.make('clean'), trials, probe_data.top_surface(), {},
                               shape_constant=0.004)
    assert score.force_rmse_after == score.force_rmse_before  # no effect: the same model
    coupling = score.coupling
    assert coupling.accepted and coupling.rejected == ''
    assert coupling.fitted == pytest.approx(0.012, rel=0.2)
    assert coupling.std < 0.25 * coupling.fitted
    assert coupling.rmse_after <= 0.5 * coupling.rmse_before
    assert coupling.p_value < 0.01 and coupling.improved >= 7
    assert 'accepted' in coupling.describe()


def test_generate_folder_files_are_found_from_the_folder_or_its_pokes(tmp_path):
    (tmp_path / 'pokes').mkdir()
    assert generated_files(tmp_path) == {}
    (tmp_path / 'probes.npz').write_bytes(b'')
    (tmp_path / 'surface.npz').write_bytes(b'')
    expected = {'probes': tmp_path / 'probes.npz', 'surface': tmp_path / 'surface.npz'}
    assert generated_files(tmp_path) == expected
    assert generated_files(tmp_path / 'pokes') == expected
    assert generated_files([]) == {}


def test_generated_probe_file_round_trips_into_trials(tmp_path):
    trials = probe_data.make_trials(0.004, count=1)
    save_probe_trials([{'kind': t.kind, 'vertices': t.mesh.vertices,
                        'triangles': t.mesh.triangles, 'start_position': t.start.position,
                        'orientation': t.start.orientation, 'direction': t.direction,
                        'torque_centre': t.torque_centre, 'depths': t.depths, 'force': t.force,
                        'torque': t.torque, 'seconds': 0.0} for t in trials], tmp_path)
    loaded = load_probe_trials(tmp_path)
    assert [t.kind for t in loaded] == ['line', 'cylinder']
    for a, b in zip(trials, loaded):
        np.testing.assert_array_equal(a.force, b.force)
        np.testing.assert_array_equal(a.mesh.triangles, b.mesh.triangles)
        poses_a, poses_b = a.poses(), b.poses()
        np.testing.assert_allclose([p.position for p in poses_a],
                                   [p.position for p in poses_b], atol=0)


def test_stiff_arm_missed_on_pokes_is_found_on_probe_trials_through_the_arm(tmp_path):
    # 20 N/mm: on point pokes it only reparametrises each curve (d_meas = d + C f) and is
    # absorbed; a paddle or cylinder deflects the arm by the total force of all its contacts
    trials = probe_data.make_trials(0.004, count=6, compliance=datasets.STIFF_ARM)
    assert all(t.compliant for t in trials)
    report = diagnose(datasets.make('stiff_arm'), seed=0, bootstrap=0, probes=trials,
                      surface=probe_data.top_surface(), shape_constant=0.004,
                      log=lambda line: None)
    on_pokes = {c.name: c for c in report.rounds[0].candidates}['series_compliance']
    assert not on_pokes.significant and report.rounds[0].chosen is None
    probe = report.probe
    found = probe.compliance
    assert found.accepted and found.name == 'series_compliance'
    assert found.fitted == pytest.approx(datasets.STIFF_ARM, rel=0.2)
    assert 0 < found.std < found.fitted        # jackknife with the force-scale nuisance
    assert found.rmse_after <= 0.5 * found.rmse_before and found.p_value < 0.01
    # it joins the accepted effects, the model answering the trials and effects.json
    assert report.accepted_names == ['series_compliance']
    assert probe.effects == report.effects()
    assert probe.force_rmse_after <= 0.5 * probe.force_rmse_before
    # with the compliance in, the learner's shape constant is right and stays
    assert not probe.coupling.accepted
    assert probe.coupling.fitted == pytest.approx(0.004, rel=0.2)
    write_report(report, tmp_path)
    stored = json.loads((tmp_path / 'effects.json').read_text())
    assert stored['series_compliance']['compliance'] == pytest.approx(found.fitted)
    assert 'Series compliance:' in (tmp_path / 'report.md').read_text()


def test_compliance_correction_of_a_baked_table_is_the_series_spring():
    # a row learned through a compliance C has 1/k_m = 1/k + C; the correction returns k
    depths = np.linspace(0.0, 0.01, 41)
    k_true = np.array([500.0, 2000.0, 8000.0])
    c = 1e-4
    k_meas = 1.0 / (1.0 / k_true + c)
    table = BakedResponse(depths=depths, forces=k_meas[:, None] * depths[None, :],
                          slopes=k_meas)
    fixed = compliance_corrected(table, c)
    np.testing.assert_allclose(fixed.slopes, k_true, rtol=1e-9)
    np.testing.assert_allclose(fixed.forces, k_true[:, None] * depths[None, :], rtol=1e-6,
                               atol=1e-9)
    assert compliance_corrected(table, 0.0) is table
    with pytest.raises(InvalidInput):
        compliance_corrected(table, -1e-5)


def test_effects_accepted_on_probe_trials_are_written_for_the_learner():
    # spatial_coupling's c goes into effects.json; the service says who applies it
    coupling = CouplingResult(assumed=0.004, fitted=0.012, std=0.001, rmse_before=2.0,
                              rmse_after=0.3, improvement=0.85, p_value=0.004,
                              delta_score=-20.0, improved=8, accepted=True, trials=8)
    refused = dataclasses.replace(coupling, name='series_compliance', fitted=5e-5,
                                  accepted=False, rejected='on a bound')
    score = ProbeScore(kinds=('line',), steps=np.array([5]), effects={}, shape_constant=0.004,
                       force_before=np.ones(1), force_after=np.ones(1),
                       torque_before=np.ones(1), torque_after=np.ones(1),
                       force_rmse_before=1.0, force_rmse_after=1.0, torque_rmse_before=1.0,
                       torque_rmse_after=1.0, peak_force=1.0, coupling=coupling,
                       compliance=refused)
    (accepted,) = _probe_accepted(score)
    stored = json.loads(json.dumps(effects_to_dict([accepted])))
    assert stored == {'spatial_coupling': {'shape_constant': 0.012}}
    assert accepted.low['shape_constant'] == pytest.approx(0.010)
    assert effects_from_dict(stored) == stored
    terms = ForwardTerms.of(stored)
    assert terms.identity and 'shape_constant' in dict(terms.skipped)['spatial_coupling']
    with pytest.raises(InvalidInput, match='unknown parameter'):
        effects_from_dict({'spatial_coupling': {'c': 0.01}})


def test_no_arm_compliance_is_made_up_from_a_point_model_uniformly_too_stiff():
    # a point model uniformly too stiff (here by 12 %; noisy pokes once did that to ours) makes
    # rigid-arm trials look compliant: a compliance would soak the error up (33 N/mm at
    # p = 0.05 without the force-scale nuisance)
    spec = importlib.util.spec_from_file_location('diagnose_effect_table_probes',
                                                  HERE / 'effect_table.py')
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    obj, common = table.cell_object('analytic')
    records = table.records_for(obj, common, 'clean', 16, 1)
    model = learn_contact_model(records, probe_data.top_surface(), {}, 0.004)
    response = model.response
    model = dataclasses.replace(model, response=dataclasses.replace(
        response, forces=1.12 * response.forces, slopes=1.12 * response.slopes))
    trials = [dataclasses.replace(t, compliant=True)
              for t in probe_data.make_trials(0.004, count=4)]
    # at alpha 0.05 the plain test passes on the stiffness error alone; the nuisance refuses it
    result = fit_series_compliance(model, trials, grid=9, alpha=0.05)
    assert result.trials == 8 and result.name == 'series_compliance'
    assert result.p_value < 0.05 and result.improvement > 0.3 and result.delta_score < 0
    assert not result.accepted and 'uniform stiffness error' in result.rejected
    with pytest.raises(InvalidInput, match='compliant'):
        fit_series_compliance(model, probe_data.make_trials(0.004, count=1))
