"""The coverage summary of the service's 90 % intervals on probe trials (issue 17)."""

import numpy as np
import pytest

from pointforce_ros.contact.uncertainty import Z90
from pointforce_ros.errors import InvalidInput
from pointforce_ros.lab.coverage import probe_coverage, summary


def test_summary_counts_what_lies_inside_the_nominal_interval():
    rng = np.random.default_rng(5)
    normal = rng.standard_normal(4000)
    force = rng.standard_normal((4000, 3))
    pred = np.tile([0.0, 0.0, 4.0], (4000, 1))
    std = np.tile([0.1, 0.1, 0.5], (4000, 1))
    out = summary({'normal': normal, 'force': force, 'pred': pred, 'std': std,
                   'true': pred + 0.1})
    # standard normal errors: the nominal 90 % interval holds 90 % of them
    assert out['coverage_normal'] == pytest.approx(0.90, abs=0.015)
    assert out['coverage_force'] == pytest.approx(0.90, abs=0.015)
    assert out['below'] + out['above'] == 4000 and abs(out['below'] - 2000) < 150
    width = 2 * Z90 * np.linalg.norm([0.1, 0.1, 0.5]) / np.linalg.norm([0.1, 0.1, 4.1])
    assert out['width_over_force'] == pytest.approx(width)
    doubled = summary({'normal': 2 * normal, 'force': 2 * force, 'pred': pred, 'std': std,
                       'true': pred})
    assert doubled['coverage_normal'] < 0.65     # intervals half as wide as the errors
    # torque components are counted on their own (here: inside only within half a std)
    torque = summary({'normal': normal, 'force': force, 'torque': 4 * force, 'pred': pred,
                      'std': std, 'true': pred})
    assert torque['coverage_torque'] == pytest.approx(np.mean(np.abs(force) <= Z90 / 4))
    assert torque['coverage_torque'] < 0.4 and np.isnan(out['coverage_torque'])


def test_probe_coverage_needs_other_trials_to_calibrate():
    with pytest.raises(InvalidInput, match='2 trials'):
        probe_coverage([], None, [{}])


def test_probe_coverage_refuses_unknown_sources():
    with pytest.raises(InvalidInput, match='sources'):
        probe_coverage([], None, [{}, {}], sources='leave_one_step_out')
