"""diagnose on too few pokes: says it cannot test, accepts nothing, names the best candidate."""

from pathlib import Path

from pointforce_ros.effects.diagnose import diagnose, UNDERPOWERED

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
