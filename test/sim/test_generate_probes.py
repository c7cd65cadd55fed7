"""Probe trials of the cell generator keep what was solved when a full solve fails."""

import numpy as np

from pointforce_ros.sim import generate
from pointforce_ros.sim.objects import load_object
from pointforce_ros.errors import NotConverged


def test_a_trial_that_does_not_converge_is_skipped_and_the_others_kept(monkeypatch):
    spec = load_object('plush')
    calls = []

    class Result:
        def __init__(self, depths):
            self.depths = np.asarray(depths)
            self.force = np.outer(np.arange(1, len(depths) + 1), [0.0, 0.0, 1.0])
            self.torque = np.zeros((len(depths), 3))

    def solve(spec_, mesh, start, direction, depths, torque_centre=None, h=None,
              stop_force=None, keep_solved=False):
        calls.append(len(calls))
        if len(calls) == 2:            # the second pose is the hard one
            raise NotConverged('step 3 (depth 7.760 mm) failed after 5 bisections')
        return Result(depths)

    monkeypatch.setattr(generate, 'solve_indentation', solve)
    lines = []
    trials = generate.probe_trials(spec, ['line'], 3, seed=0, progress=lines.append, steps=4)
    assert len(calls) == 3 and len(trials) == 2
    assert any('skipped' in line and 'did not converge' in line for line in lines)
    assert all(t['kind'] == 'line' and len(t['depths']) >= 1 for t in trials)


def test_an_interrupted_run_resumes_without_solving_again_and_gives_the_same_trials(monkeypatch):
    spec = load_object('plush')
    solved = []

    class Result:
        def __init__(self, start, depths):
            self.depths = np.asarray(depths)[:3]
            self.force = -np.outer(np.arange(1, 4), start.position)   # depends on the pose
            self.torque = np.zeros((3, 3))

    def solve(spec_, mesh, start, direction, depths, torque_centre=None, h=None,
              stop_force=None, keep_solved=False):
        assert stop_force == 1.5 * spec.force_cap
        solved.append(start.position.copy())
        return Result(start, depths)

    monkeypatch.setattr(generate, 'solve_indentation', solve)
    whole = generate.probe_trials(spec, ['line'], 3, seed=4, progress=lambda _: None)
    saved = []
    generate.probe_trials(spec, ['line'], 2, seed=4, progress=lambda _: None,
                          on_trial=lambda so_far: saved.append(list(so_far)))
    assert [len(s) for s in saved] == [1, 2]
    solved.clear()
    resumed = generate.probe_trials(spec, ['line'], 3, seed=4, progress=lambda _: None,
                                    done=saved[-1])
    assert len(solved) == 1                 # only the third trial is solved again
    for a, b in zip(whole, resumed):
        np.testing.assert_array_equal(a['start_position'], b['start_position'])
        np.testing.assert_array_equal(a['force'], b['force'])


def test_a_push_that_fails_deep_keeps_its_solved_steps_and_a_shallow_failure_is_skipped(
        monkeypatch):
    spec = load_object('thin_layer')
    solved_steps = iter([5, 2, 8])         # steps the solver got through, per trial

    class Result:
        def __init__(self, depths, k):
            self.depths = np.asarray(depths)[:k]
            self.force = -np.outer(np.linspace(0.5, 2.0, k), [0.0, 0.0, 1.0])
            self.torque = np.zeros((k, 3))

    def solve(spec_, mesh, start, direction, depths, torque_centre=None, h=None,
              stop_force=None, keep_solved=False):
        assert keep_solved
        return Result(depths, next(solved_steps))

    monkeypatch.setattr(generate, 'solve_indentation', solve)
    lines = []
    trials = generate.probe_trials(spec, ['line'], 3, seed=1, progress=lines.append, steps=8)
    assert [len(t['depths']) for t in trials] == [5, 8]
    cut = [line for line in lines if 'kept its 5 steps' in line]
    assert len(cut) == 1 and 'did not converge past' in cut[0]
    assert any('skipped' in line and 'only 2 of 8 steps' in line for line in lines)
