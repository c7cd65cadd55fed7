"""diagnose on too few pokes: says it cannot test, accepts nothing, names the best candidate."""

from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.diagnose.run import diagnose, UNDERPOWERED

BAGS = Path(__file__).resolve().parents[1] / 'data' / 'bags' / 'pokes'


def test_four_pokes_are_too_few_for_the_test_and_the_report_says_so():
    # the committed store: 4 pokes, scenario 'realistic' (camera bias 2 mm, F/T noise)
    report = diagnose(BAGS, seed=0, log=lambda line: None)
    assert report.accepted == []
    assert any(note.startswith(UNDERPOWERED) for note in report.notes)
    summary = report.summary()
    assert 'strongest candidate was surface_offset' in summary
    best = min(report.rounds[0].candidates, key=lambda c: c.rmse)
    assert best.rmse < 0.8 * report.rmse_before  # the bias is there, only untestable


def test_camera_bias_absorbed_by_the_onset_is_reported():
    # diagnose cannot test the bias on 4 pokes, the learner's onset absorbs it: the report
    # must still state it. The half-space top is at z = 0.04 m, so the true offset of each
    # poke is 0.04 - its observed z (2 mm bias plus camera noise).
    report = diagnose(BAGS, seed=0, bootstrap=0, log=lambda line: None)
    truth = float(np.mean(0.04 - report.points[:, 2]))
    assert truth == pytest.approx(0.002, abs=5e-4)
    onset = report.onset
    assert onset.count == 4
    assert onset.offset == pytest.approx(truth, abs=1e-4)
    assert 0 < onset.sem < 5e-4
    assert f'surface offset {onset.offset * 1e3:.2f} +- {onset.sem * 1e3:.2f} mm absorbed by ' \
           'the onset' in report.summary()
    assert report.offset_disagreement() == ''  # no surface offset was accepted
