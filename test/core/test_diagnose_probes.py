"""Probe trials in diagnose: before/after errors of the served model, and spatial coupling.

The trials (``test/data/diagnose/probe_trials.py``) press a paddle and a cylinder into the
analytic half-space of the diagnose data sets; their ground truth uses the true point law and a
chosen true shape constant ``c_true``. The point model is learned from the pokes as the nodes
learn it and answered through the contact service.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.effects import diagnose
from pointforce_ros.effects.probes import generated_files, score_probe_trials

HERE = Path(__file__).resolve().parents[1] / 'data' / 'diagnose'
_spec = importlib.util.spec_from_file_location('diagnose_probe_trials', HERE / 'probe_trials.py')
probe_data = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(probe_data)
datasets = probe_data.datasets


def test_probe_trials_are_scored_before_and_after_through_diagnose(tmp_path):
    # pokes through a compliant arm (0.5 mm/N), probes with the learner's own coupling: diagnose
    # accepts the compliance on the pokes and the model learned with it answers the probes far
    # better; the coupling, right already, is not changed
    from pointforce_ros.effects.report import write_report
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
    from pointforce_ros.cell.generate import save_probe_trials
    from pointforce_ros.effects.probes import load_probe_trials
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
