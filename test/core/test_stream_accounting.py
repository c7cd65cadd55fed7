"""The 250 Hz stream's loss accounting: runs of empty slots and the losses that report them."""

import numpy as np

from pointforce_ros.drivers.ur_arm import missing_slots, StreamLoss, unreported_runs


def _stream(drop):
    """Controller times of a 500 Hz controller read once per 4 ms slot, slots ``drop`` unread."""
    t = np.round(np.arange(40) * 0.004 + 0.002 * (np.arange(40) % 3 == 0), 6)   # odd ticks too
    return t[[k for k in range(40) if k not in drop]]


def test_runs_of_empty_slots_are_found_with_their_size():
    t = _stream({5, 6, 7, 20})
    after, count = missing_slots(t)
    np.testing.assert_array_equal(t[after], [0.032, 0.086])
    np.testing.assert_array_equal(count, [3, 1])
    assert missing_slots(_stream(set()))[0].size == 0


def test_a_run_is_unreported_unless_a_loss_of_its_size_names_the_sample_after_it():
    t = _stream({5, 6, 7, 20})
    both = [StreamLoss(0.032, 3, 0.013), StreamLoss(0.086, 1, 0.004)]
    assert unreported_runs(t, both) == []
    assert unreported_runs(t, [[0.032, 3, 0.013], [0.086, 1, 0.004]]) == []  # poke meta rows
    assert unreported_runs(t, both[:1]) == [(0.086, 1, None)]
    assert unreported_runs(t, [StreamLoss(0.032, 2, 0.01), both[1]]) == [(0.032, 3, 2)]
    assert unreported_runs(t, []) == [(0.032, 3, None), (0.086, 1, None)]
