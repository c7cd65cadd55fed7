"""diagnose on FEM lamb pokes whose curves are not power laws: no wrong effect is accepted.

Fixture: ``test/data/diagnose/lamb_realistic.npz`` (8 pokes, scenario ``realistic``: 2 mm
camera depth bias; see ``make_lamb_fixture.py``). The curves stiffen sharply over the bone; an
offset of about 5 mm with the exponent on its bound fitted them better than the true bias, and
diagnose accepted it.
"""

import functools
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.diagnose import diagnose

HERE = Path(__file__).resolve().parents[1] / 'data' / 'diagnose'
_spec = importlib.util.spec_from_file_location('lamb_fixture', HERE / 'make_lamb_fixture.py')
fixture = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fixture)


@functools.lru_cache(maxsize=None)
def lamb_report():
    records, truth = fixture.load()
    return diagnose(records, seed=0, bootstrap=0, log=lambda line: None), truth


def test_stiffening_curves_do_not_make_a_wrong_surface_offset():
    report, truth = lamb_report()
    assert np.mean(truth) == pytest.approx(0.0019, abs=2e-4)  # the camera bias, per point
    fitted = report.effects().get('surface_offset')
    # nothing accepted, or an offset that is the camera bias (within 0.5 mm)
    assert fitted is None or abs(fitted['offset'] - np.mean(truth)) < 5e-4
    assert set(report.accepted_names) <= {'surface_offset'}
    # the offset candidate passes the statistics but is refused, and the report says why
    first = {c.name: c for c in report.rounds[0].candidates}['surface_offset']
    assert first.p_value < 0.01 and first.improvement > 0.03 and first.delta_score < 0
    assert not first.significant
    assert 'bound' in first.rejected and 'exponent' in first.rejected
    assert 'not accepted: surface_offset' in report.summary()
    # what is left is reported as unexplained, with the bias estimated by the onsets
    assert report.unexplained
    assert report.onset.offset == pytest.approx(np.mean(truth), abs=1e-3)


def test_offset_that_contradicts_the_onset_estimate_is_refused():
    # the onset check alone: interior fits, an offset 3 mm away from the onset estimate
    from pointforce_ros.diagnose.run import _plausibility, OnsetOffset
    from pointforce_ros.diagnose.model import Fit, Layout
    layout = Layout.of(['surface_offset'])
    values = {'base': {'exponent': 2.0, 'curvature': 0.0}, 'surface_offset': {'offset': 0.005}}
    fit = Fit(layout, layout.coordinates(values), layout.values(layout.coordinates(values)),
              0.0, 1)
    base = Layout.of([])
    base_fit = Fit(base, base.coordinates(values), base.values(base.coordinates(values)), 0.0, 1)
    onset = OnsetOffset(offset=0.002, sem=1e-4, spread=3e-4, count=9)
    why = _plausibility('surface_offset', [(None, fit)], [(None, base_fit)], onset, 0.001)
    assert 'contradicts the onset estimate' in why
    close = OnsetOffset(offset=0.0042, sem=1e-4, spread=3e-4, count=9)
    assert _plausibility('surface_offset', [(None, fit)], [(None, base_fit)], close,
                         0.001) == ''
