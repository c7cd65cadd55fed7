"""``pointforce bench ros`` times round trips with an event-driven client (issue 21).

It used to wait on each future with a 10 ms sleep loop, so no round trip could read below the
poll period; it now reports single queries, small batches and a trivial Trigger service's round
trip from the same run, with the services in their own processes (as deployed), and a load test
of client processes (issue 16).
"""

import threading
import time

import pytest
from rclpy.node import Node
from std_srvs.srv import Trigger

from pointforce_ros.bringup.bench_ros import _trigger_node, bench_ros, round_trip, warm_up_call

pytestmark = pytest.mark.ros

POLL_PERIOD = 0.010     # the old bench's sleep between looks at a future, s


def test_round_trip_is_event_driven_and_below_a_poll_period(ros_graph):
    ros_graph.add(_trigger_node(ros_graph.context), isolated=True)
    client = ros_graph.add(Node('rtt_client', context=ros_graph.context)).create_client(
        Trigger, '/bench_trigger/trigger')
    assert client.wait_for_service(timeout_sec=30.0)
    times = sorted(round_trip(client, Trigger.Request(), 10.0, 'trigger')[0]
                   for _ in range(60))
    polled = sorted(_polled_round_trip(client, Trigger.Request()) for _ in range(20))
    # a client that sleeps 10 ms before each look at the future (the old bench) can never read
    # below its poll period, however fast the service; the event-driven median stays under it
    # with room for a busy machine (it read 5.6 ms beside another test worker, 1-3 ms alone)
    assert polled[0] >= POLL_PERIOD
    assert times[len(times) // 2] < POLL_PERIOD


def _polled_round_trip(client, request) -> float:
    """Time one call the way the old bench did: sleep a poll period, then look."""
    start = time.perf_counter()
    future = client.call_async(request)
    while True:
        time.sleep(POLL_PERIOD)
        if future.done():
            return time.perf_counter() - start
        if time.perf_counter() - start > 10.0:
            raise RuntimeError('no reply to a polled trigger call in 10 s')


def test_round_trip_names_the_service_on_time_out(ros_graph):
    client = ros_graph.add(Node('lonely', context=ros_graph.context)).create_client(
        Trigger, '/nobody/trigger')
    with pytest.raises(RuntimeError, match='nobody trigger.*0.2 s|0.2 s.*nobody trigger'):
        round_trip(client, Trigger.Request(), 0.2, 'nobody trigger')


def test_a_warm_up_call_asks_again_when_its_reply_does_not_come(ros_graph):
    # the service's first reply comes too late for the attempt that asked (as a reply lost
    # while discovery completes): the next attempts are answered
    first = threading.Event()

    def answer(request, response):
        if not first.is_set():
            first.set()
            time.sleep(0.5)
        response.success = True
        return response
    server = ros_graph.add(Node('late_first', context=ros_graph.context), isolated=True)
    server.create_service(Trigger, '/late_first/trigger', answer)
    client = ros_graph.add(Node('warm_client', context=ros_graph.context)).create_client(
        Trigger, '/late_first/trigger')
    assert client.wait_for_service(timeout_sec=30.0)
    assert warm_up_call(client, Trigger.Request(), 'late trigger', tries=8, timeout=0.2).success
    assert first.is_set()
    lonely = ros_graph.add(Node('lonely_warm', context=ros_graph.context)).create_client(
        Trigger, '/nobody_warm/trigger')
    with pytest.raises(RuntimeError, match='no reply from nobody to 2 warm-up calls of 0.1 s'):
        warm_up_call(lonely, Trigger.Request(), 'nobody', tries=2, timeout=0.1)


def test_bench_ros_reports_round_trips_beside_core_and_trigger():
    out = bench_ros(quick=True, campaign=False, load_clients=2, load_calls=20)
    assert out['services'].endswith('each in its own process')
    assert out['load_failures'] == 0 and out['load_clients'] == 2
    assert out['load_rtt_p99_ms'] >= out['load_rtt_p50_ms'] > 0
    # the same load with each client on a service lane of its own (client_lanes)
    assert out['load_lanes_failures'] == 0 and out['load_lanes_clients'] == 2
    assert out['load_lanes_rtt_p99_ms'] >= out['load_lanes_rtt_p50_ms'] > 0
    # and with the package's executor-free client, on one and on two service processes
    for prefix in ('load_direct_', 'load_procs_'):
        assert out[prefix + 'failures'] == 0 and out[prefix + 'clients'] == 2
        assert out[prefix + 'rtt_p99_ms'] >= out[prefix + 'rtt_p50_ms'] > 0
    for prefix in ('load_', 'load_lanes_', 'load_direct_', 'load_procs_'):   # CPU per call
        assert out[prefix + 'service_cpu_per_call_ms'] > 0
        assert out[prefix + 'client_cpu_per_call_ms'] > 0
    assert 50 < out['service_peak_rss_mb'] < 600    # issue 16: the service stays under 600 MB
    for key in ('single_rtt_p50_ms', 'single_rtt_p99_ms', 'core_query_p50_ms',
                'ros_overhead_p50_ms', 'trigger_rtt_p50_ms', 'trigger_rtt_p99_ms',
                'small_batch_rtt_p50_ms', 'small_batch_rtt_p99_ms', 'small_batch_core_p50_ms',
                'single_rtt_mesh_msg_p50_ms', 'single_rtt_with_std_p50_ms',
                'single_rtt_mt_client_p50_ms', 'trigger_rtt_mt_client_p50_ms',
                'single_rtt_direct_client_p50_ms', 'trigger_rtt_direct_p50_ms',
                'single_rtt_after_idle_p50_ms', 'batch_ros_poses_per_s'):
        assert out[key] > 0, key
    # a round trip holds the core's work, but the two are timed in separate loops on a shared
    # machine (a 100-pose batch: 71 ms round trip against 64 ms core), so allow their noise
    assert out['single_rtt_p50_ms'] > 0.8 * out['core_query_p50_ms']
    assert out['single_rtt_mt_client_p50_ms'] > 0.8 * out['core_query_p50_ms']
    assert out['single_rtt_direct_client_p50_ms'] > 0.8 * out['core_query_p50_ms']
    assert out['single_rtt_after_idle_p50_ms'] > 0.8 * out['core_query_p50_ms']
    assert out['single_rtt_p99_ms'] >= out['single_rtt_p50_ms']
    # the service's own account of the DirectClient lane: each stage is a part of the trip.
    # The lane's timing window holds both of its series, the bursts and the calls after idle
    # (slower on a VM), and medians do not add up: the stages' medians summed passed the
    # bursts' median in two fresh clones of session 41 (0.7387 against 0.7384 ms, 1.025
    # against 0.917 ms). So the sum is held to the slower series' median within 10 % (a
    # stage timed twice would double it)
    stages = [out[f'service_{stage}_p50_ms'] for stage in ('take', 'callback', 'send')]
    slower = max(out['single_rtt_direct_client_p50_ms'], out['single_rtt_after_idle_p50_ms'])
    assert min(stages) > 0 and sum(stages) < 1.1 * slower
    assert out['service_callback_p50_ms'] > max(out['service_take_p50_ms'],
                                                out['service_send_p50_ms'])
    # no such bound for the batch: the service solves a batch's chunks on its worker threads,
    # the core figure in one (at load 20: 22 ms round trip against 34 ms core, fastest of each)
    # the wrench's spread takes four more solves; the latency series skip it
    assert out['single_rtt_with_std_p50_ms'] > out['single_rtt_p50_ms']
    assert 'ft_stream_rate_hz' not in out
