"""``pointforce bench streams``: both listeners get every message of the talker's streams."""

import math

import pytest

from pointforce_ros.bringup.bench_streams import bench_streams, TOPICS

pytestmark = pytest.mark.ros


def test_both_modes_count_every_message_and_the_ratio_is_their_quotient():
    out = bench_streams(seconds=2.0, rounds=1, rate=100.0)
    expected = len(TOPICS) * 100.0 * 2.0   # two topics at 100 Hz over a 2 s window
    for mode in ('executor', 'loop'):
        assert out[f'{mode}_lost'] == 0, out
        assert abs(out[f'{mode}_messages'] - expected) <= 0.1 * expected, out
        per_message = out[f'{mode}_us_per_message']
        assert math.isfinite(per_message) and per_message > 0.0
        # the core share is the same CPU over wall time, not per message
        share = per_message * 1e-6 * out[f'{mode}_messages'] / 2.0
        assert share == pytest.approx(out[f'{mode}_core_share'], rel=0.05)
    assert out['executor_over_loop'] == pytest.approx(
        out['executor_us_per_message'] / out['loop_us_per_message'])
    # the poke server's side: both rotation paths timed over the same samples
    assert out['publish_samples'] > 0
    for key in ('publish_us_per_sample', 'publish_scipy_us_per_sample'):
        assert math.isfinite(out[key]) and out[key] > 0.0, out
    assert out['scipy_over_closed_form'] == pytest.approx(
        out['publish_scipy_us_per_sample'] / out['publish_us_per_sample'])
