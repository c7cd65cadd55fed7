"""poke_server end to end: action over DDS -> UrArm -> real ur_rtde -> loopback RTDE emulator.

Every test starts its own emulator process (a flat elastic top at z = 0.04 m, k = 1000 N/m) on
its own loopback address and its own ROS graph.
"""

import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pointforce_interfaces.action import Poke
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from msg_adapters.interfaces import poke_goal_to_msg
from msg_adapters.pointcloud2 import surface_to_msg
from pointforce_ros.drivers.ur_arm import missing_slots, unreported_runs
from pointforce_ros.nodes.poke_server import LATCHED, PokeServerNode, STREAM
from pointforce_ros.pokes.store import PokeStore, read_poke_bag
from pointforce_ros.types import PokeGoal, Surface

pytestmark = [pytest.mark.e2e, pytest.mark.ros]
SPRING = {'z0': 0.04, 'k': 1000.0}
START = [0.5, 0.0, 0.1, np.pi, 0.0, 0.0]


@pytest.fixture
def cell(ros_graph, start_emulator, tmp_path):
    emulator = start_emulator(force_model='pointforce_ros.sim.rtde.forces:HalfSpaceSpring',
                              force_model_kwargs=SPRING, initial_pose=START)
    server = ros_graph.add(PokeServerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('robot_ip', value=emulator.host),
        Parameter('store_dir', value=str(tmp_path / 'pokes'))]))
    client_node = ros_graph.add(Node('poke_client', context=ros_graph.context))
    client = ActionClient(client_node, Poke, '/poke_server/poke')
    # one fresh-clone run of the whole suite missed it in 15 s (not reproduced in 45 set-ups
    # in three runs of this file): the busiest processes are shown if it happens again
    assert client.wait_for_server(timeout_sec=30.0), _busiest()
    return ros_graph, emulator, server, client_node, client, tmp_path


def _busiest() -> str:
    """The ten processes with the most CPU since they started (a hint on a failure)."""
    out = subprocess.run(['ps', '-eo', 'pid,cls,pcpu,etime,args', '--sort=-pcpu'],
                         capture_output=True, text=True).stdout
    return '/poke_server/poke did not appear in 30 s; busiest processes:\n' + '\n'.join(
        line[:160] for line in out.splitlines()[:11])


def _goal(**overrides):
    values = dict(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0], force_limit=3.0,
                  depth_limit=0.008, speed=0.005, standoff=0.008)
    values.update(overrides)
    return poke_goal_to_msg(PokeGoal(**values))


def _send(graph, client, goal, feedback=None):
    handle = graph.wait_future(client.send_goal_async(goal, feedback_callback=feedback), 10,
                               'goal response')
    return handle


def test_poke_end_to_end_with_feedback_and_a_250hz_bag(cell):
    graph, emulator, server, client_node, client, tmp_path = cell
    before = emulator.control.state()
    landed = []
    client_node.create_subscription(String, '/poke_server/poke_landed',
                                    lambda m: landed.append(m.data), STREAM)
    feedback = []
    handle = _send(graph, client, _goal(), lambda m: feedback.append(m.feedback))
    assert handle.accepted
    result = graph.wait_future(handle.get_result_async(), 40, 'poke result').result
    assert result.outcome == 'force_limit', result.message
    assert 3.0 <= result.peak_force < 3.6
    assert result.max_depth == pytest.approx(0.003, abs=0.0006)  # F = k d
    assert len(feedback) >= 10 and max(f.normal_force for f in feedback) > 1.0
    graph.wait_for(lambda: landed == [result.poke_id], 5, 'poke_landed')
    starved = emulator.control.starved_share(before, emulator.control.state())
    record = read_poke_bag(tmp_path / 'pokes' / result.poke_id)
    assert len(record) == result.samples
    dt = np.diff(record.t_controller)
    rate = 1.0 / np.median(dt)
    assert rate == pytest.approx(250.0, rel=0.05)
    # as in the driver's own stream test (test_ur_arm_driver.py): every run of empty slots is
    # in the poke's meta, at the sample after it, with its size
    losses = record.meta['stream_losses']
    assert not unreported_runs(record.t_controller, losses)
    gaps = {round(float(record.t_controller[k]), 6) for k in missing_slots(record.t_controller)[0]}
    extra = [x for x in losses if round(x[0], 6) not in gaps]
    assert not extra, f'losses reported where the record has no gap: {extra}'
    if starved <= 0.05:
        assert dt.max() <= 0.05, f'gap of {1e3 * dt.max():.1f} ms in the 250 Hz stream'
    assert np.all(dt > 0)
    # force against depth in the bag is the spring the emulator simulates
    d, f = record.displacement(), record.normal_force()
    loaded = (d > 0.0008) & (d < 0.0028) & (np.gradient(d) > 0)
    slope = np.polyfit(d[loaded], f[loaded], 1)[0]
    assert slope == pytest.approx(SPRING['k'], rel=0.1)


@pytest.mark.parametrize('overrides, reason', [
    ({'force_limit': 50.0}, 'force above max_force'),
    ({'speed': 0.05}, 'speed above max_speed'),
    ({'depth_limit': -0.001}, 'negative depth'),
    ({'point': [0.5, 0.0, 0.07]}, 'point 30 mm above the surface'),
    # issue 16: accepted; the inverted one tared the sensor 6 mm inside the object
    ({'normal': [0.0, 0.0, -1.0]}, 'inverted normal'),
    ({'normal': [1.0, 0.0, 0.0]}, 'horizontal normal'),
    ({'surface_index': -2}, 'surface_index below -1'),
    ({'surface_index': 30}, 'surface_index past the last point'),
])
def test_bad_goals_are_rejected_and_nothing_moves(cell, overrides, reason):
    graph, emulator, server, client_node, client, _ = cell
    pts = np.column_stack([np.linspace(0.45, 0.55, 30), np.zeros(30), np.full(30, 0.04)])
    pub = client_node.create_publisher(PointCloud2, '/cloud_capture/surface', LATCHED)
    pub.publish(surface_to_msg(Surface(points=pts, normals=np.tile([0, 0, 1.0], (30, 1)))))
    graph.wait_for(lambda: server.surface is not None, 10, 'surface at the server')
    before = server._connect().tcp_pose()
    handle = _send(graph, client, _goal(**overrides))
    assert not handle.accepted, reason
    time.sleep(0.3)
    np.testing.assert_allclose(server._connect().tcp_pose(), before, atol=1e-6)


def test_non_unit_normal_is_rejected(cell):
    graph, _, _, _, client, _ = cell
    goal = _goal()
    goal.normal.z = 0.5
    assert not _send(graph, client, goal).accepted


def _push_then(graph, client, action, depth=0.001):
    """Send a deep goal and call ``action()`` once the feedback shows ``depth`` reached."""
    fired = threading.Event()

    def on_feedback(msg):
        if msg.feedback.depth > depth and not fired.is_set():
            fired.set()
            action()
    handle = _send(graph, client, _goal(force_limit=8.0, depth_limit=0.012, speed=0.004),
                   on_feedback)
    assert handle.accepted
    return handle, fired


def test_protective_stop_mid_push_aborts_and_keeps_the_samples(cell):
    graph, emulator, server, _, client, tmp_path = cell
    handle, fired = _push_then(graph, client, emulator.control.protective_stop)
    result = graph.wait_future(handle.get_result_async(), 40, 'result').result
    assert fired.is_set()
    assert result.outcome == 'aborted' and 'protective' in result.message.lower()
    record = PokeStore(tmp_path / 'pokes').get(result.poke_id)
    assert record.outcome.startswith('aborted') and len(record) == result.samples > 50
    assert record.displacement().max() > 0.001


def test_ft_stall_mid_push_aborts_and_keeps_the_samples(cell):
    graph, emulator, server, _, client, tmp_path = cell
    handle, fired = _push_then(graph, client, lambda: emulator.control.stall('force', 5.0))
    result = graph.wait_future(handle.get_result_async(), 40, 'result').result
    assert fired.is_set() and result.outcome == 'aborted'
    assert 'stall' in result.message.lower() or 'frozen' in result.message.lower()
    assert PokeStore(tmp_path / 'pokes').get(result.poke_id).outcome.startswith('aborted')


def test_an_aborted_ur_rtde_process_costs_one_poke_and_loses_none_of_its_samples(cell):
    """CI, session 17: a throwing ur_rtde destructor aborted the process that held the arm.
    The interfaces now live in their own process: its death aborts this poke, whose samples
    are kept, and the next goal reconnects.
    """
    graph, emulator, server, _, client, tmp_path = cell
    arm = server._connect()
    handle, fired = _push_then(graph, client, lambda: os.kill(arm.host_pid, signal.SIGABRT))
    result = graph.wait_future(handle.get_result_async(), 40, 'result').result
    assert fired.is_set() and result.outcome == 'aborted'
    assert 'host process is gone' in result.message, result.message
    record = PokeStore(tmp_path / 'pokes').get(result.poke_id)
    assert record.outcome.startswith('aborted') and len(record) == result.samples > 50
    again = graph.wait_future(_send(graph, client, _goal()).get_result_async(), 40,
                              'second result').result
    assert again.outcome == 'force_limit', again.message
    assert server._connect() is not arm


def test_cancel_stops_the_arm_and_retracts(cell):
    graph, emulator, server, _, client, tmp_path = cell
    box = {}
    handle, fired = _push_then(graph, client,
                               lambda: box.setdefault('cancel', box['h'].cancel_goal_async()),
                               depth=0.0015)
    box['h'] = handle
    result = graph.wait_future(handle.get_result_async(), 40, 'result').result
    assert fired.is_set() and result.outcome == 'canceled'
    assert result.max_depth < 0.006  # stopped well before the 12 mm depth limit
    pose = server._connect().tcp_pose()
    assert pose[2] == pytest.approx(0.04 + 0.008, abs=0.001)  # back at the stand-off


def test_second_goal_while_busy_is_rejected(cell):
    graph, _, _, _, client, _ = cell
    first = _send(graph, client, _goal(force_limit=8.0, depth_limit=0.012, speed=0.004))
    assert first.accepted
    time.sleep(0.3)
    assert not _send(graph, client, _goal()).accepted
    graph.wait_future(first.get_result_async(), 40, 'first result')


def test_diagnostics_report_the_arm_and_stream_health_over_dds(cell):
    """``/diagnostics`` (the diagnostic_updater convention, 1 Hz): OK while the stream flows,
    WARN for the slots a held-up stream worker missed, ERROR on a protective stop and, once it
    is released, for the control program it stopped."""
    graph, emulator, server, client_node, client, tmp_path = cell
    got = []
    client_node.create_subscription(DiagnosticArray, '/diagnostics',
                                    lambda m: got.extend(m.status), 10)

    def next_report(what, timeout=10.0):
        got.clear()
        graph.wait_for(lambda: got, timeout, what)
        status = got[-1]
        return status, {v.key: v.value for v in status.values}

    status, values = next_report('a report')
    assert status.name == 'poke_server: arm and F/T stream'
    assert status.hardware_id == emulator.host
    # steady streaming (in the first seconds of a node and its graph the emulator's clock may
    # slow or a few slots go: a WARN, named)
    graph.wait_for(lambda: got and got[-1].level == DiagnosticStatus.OK, 15, 'an OK report')
    values = {v.key: v.value for v in got[-1].values}
    assert 200.0 <= float(values['sample_rate_hz']) < 300.0, values
    assert 'streaming at' in got[-1].message
    # the stream worker held 60 ms: its missed slots make the next report a warning
    pid = server._arm.stream_pid
    got.clear()
    os.kill(pid, signal.SIGSTOP)
    time.sleep(0.06)
    os.kill(pid, signal.SIGCONT)
    graph.wait_for(lambda: any(s.level == DiagnosticStatus.WARN for s in got), 5,
                   'a WARN report after the hold')
    status = next(s for s in got if s.level == DiagnosticStatus.WARN)
    values = {v.key: v.value for v in status.values}
    assert 'slots missed' in status.message, status.message
    assert int(values['slots_missed_since_last']) >= 10
    assert int(values['slots_missed']) == server._arm.lost_samples
    # a protective stop is an error, named
    emulator.control.protective_stop()
    graph.wait_for(lambda: got and got[-1].level == DiagnosticStatus.ERROR, 10,
                   'an ERROR report')
    assert 'protective' in got[-1].message, got[-1].message
    # released, the stop is no longer named; the control script it ended still is (a UR's
    # protective stop ends the program; the arm is not ready until it runs again)
    assert emulator.control.unlock()
    graph.wait_for(lambda: got and 'protective' not in got[-1].message, 10, 'stop released')
    assert got[-1].level == DiagnosticStatus.ERROR
    assert 'control program' in got[-1].message, got[-1].message
