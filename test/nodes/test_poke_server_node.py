"""poke_server over DDS with a scripted arm: atomic busy check, no poke lost when storing fails.

Issue 16: of 20 simultaneous goals, 3 were accepted and then aborted (the busy check ran before
the lock); when storing failed after the arm moved, the data was gone and the client got ABORTED
with an empty message.
"""

import dataclasses
import json
import time

import numpy as np
import pytest
import rclpy
from geometry_msgs.msg import WrenchStamped
from pointforce_interfaces.action import Poke
from rclpy.action import ActionClient
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from scipy.spatial.transform import Rotation
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import transform_to_msg
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.drivers.ur_arm import ArmSample, PushResult
from pointforce_ros.errors import DataError
from pointforce_ros.nodes.common import destroy_node, TF_STATIC_QOS
from pointforce_ros.nodes.poke_server import PokeServerNode, REQUESTS, stream_messages
from pointforce_ros.pokes.store import load_recovery, PokeStore
from pointforce_ros.rotations import quaternion_to_matrix, rotvec_to_matrix
from pointforce_ros.types import PokeGoal

from idle_arm import IdleArm  # noqa: I100 - the test helper beside this file

pytestmark = pytest.mark.ros


def test_stream_messages_carry_the_pose_in_base_and_the_wrench_in_the_tool_frame():
    rng = np.random.default_rng(3)
    for _ in range(20):
        rotvec = rng.normal(size=3)
        pose6 = np.r_[rng.uniform(-0.6, 0.6, 3), rotvec]
        wrench6 = rng.normal(scale=5.0, size=6)
        t_wall = 1.7e9 + rng.uniform(0.0, 1e6)
        pose, wrench = stream_messages(ArmSample(t_wall, 12.5, pose6, wrench6))
        assert pose.header.frame_id == 'base' and wrench.header.frame_id == 'tool0_controller'
        assert pose.header.stamp == wrench.header.stamp
        stamp = pose.header.stamp.sec + 1e-9 * pose.header.stamp.nanosec
        assert stamp == pytest.approx(t_wall, abs=2e-9 * t_wall)
        p, o = pose.pose.position, pose.pose.orientation
        np.testing.assert_allclose([p.x, p.y, p.z], pose6[:3])
        matrix = rotvec_to_matrix(rotvec)
        assert o.w >= 0.0
        np.testing.assert_allclose(quaternion_to_matrix([o.x, o.y, o.z, o.w]), matrix,
                                   atol=1e-12)
        f, t = wrench.wrench.force, wrench.wrench.torque
        # rotated back into base, the tool-frame wrench is the controller's base-oriented one
        np.testing.assert_allclose(matrix @ [f.x, f.y, f.z], wrench6[:3], atol=1e-12)
        np.testing.assert_allclose(matrix @ [t.x, t.y, t.z], wrench6[3:], atol=1e-12)


class ScriptedArm(IdleArm):
    """Stands in for UrArm: ``samples`` samples into a 1000 N/m spring over ``duration`` s."""

    def __init__(self, host, duration=0.6, samples=150):
        super().__init__(host)
        self.duration, self.samples = duration, samples
        self.pushes = 0
        self.tares = 0

    def tare(self):
        self.tares += 1

    def push_until(self, standoff, direction, *, force_limit, travel_limit, speed,
                   approach_speed, retract_speed, cancel, max_force, max_travel, phase=None):
        self.pushes += 1
        self.last_push = (np.array(standoff, float), np.array(direction, float))
        deadline = time.monotonic() + self.duration
        while time.monotonic() < deadline:
            if cancel():
                break
            time.sleep(0.01)
        n = self.samples
        travel = np.linspace(0.0, travel_limit, n)
        direction = np.asarray(direction, float)
        pose = np.tile(np.asarray(standoff, float), (n, 1))
        pose[:, :3] += travel[:, None] * direction
        force = 1000.0 * np.maximum(travel - 0.008, 0.0)
        wrench = np.zeros((n, 6))
        wrench[:, :3] = -force[:, None] * direction
        t = 1000.0 + np.arange(n) * 0.004
        return PushResult(t_wall=t, t_controller=t - 990.0, tcp_pose=pose, wrench=wrench,
                          outcome='force_limit', peak_force=float(force.max()),
                          max_travel=float(travel.max()), standoff=np.asarray(standoff, float),
                          direction=direction)


def _goal():
    return poke_goal_to_msg(PokeGoal(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0],
                                     force_limit=3.0, depth_limit=0.008, speed=0.005,
                                     standoff=0.008))


def _server(ros_graph, tmp_path, arm_class):
    """``(poke server on the graph, the arms it made)``: each arm an ``arm_class(host)``."""
    arms = []

    def factory(host):
        arms.append(arm_class(host))
        return arms[-1]
    server = ros_graph.add(PokeServerNode(
        arm_factory=factory, context=ros_graph.context,
        parameter_overrides=[Parameter('store_dir', value=str(tmp_path / 'pokes'))]))
    return server, arms


@pytest.fixture
def scripted(ros_graph, tmp_path):
    server, arms = _server(ros_graph, tmp_path, ScriptedArm)
    client_node = ros_graph.add(Node('scripted_client', context=ros_graph.context))
    client = ActionClient(client_node, Poke, '/poke_server/poke')
    assert client.wait_for_server(timeout_sec=30.0)
    return ros_graph, server, client, arms, tmp_path


class Burst:
    """A client in its own, not yet spinning, context: goals sent together reach the server
    together, and no goal response can arrive before rclpy registers its future (its
    ActionClient has no lock between sending and registering).
    """

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node('burst_client', context=self.context)
        self.client = ActionClient(self.node, Poke, '/poke_server/poke',
                                   goal_service_qos_profile=REQUESTS)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def wait(self, futures, timeout, what):
        deadline = time.monotonic() + timeout
        while not all(f.done() for f in futures):
            if time.monotonic() > deadline:
                raise RuntimeError(f'timed out after {timeout} s waiting for {what}')
            self.executor.spin_once(timeout_sec=0.05)
        return [f.result() for f in futures]

    def close(self):
        self.executor.shutdown(timeout_sec=5.0)
        destroy_node(self.node)
        rclpy.try_shutdown(context=self.context)
        self.context.destroy()


def test_twenty_simultaneous_goals_one_accepted_none_accepted_then_aborted(scripted):
    graph, server, _, arms, tmp_path = scripted
    burst = Burst()
    try:
        assert burst.client.wait_for_server(timeout_sec=30.0)
        handles = burst.wait([burst.client.send_goal_async(_goal()) for _ in range(20)], 30,
                             'goal responses')
        accepted = [h for h in handles if h.accepted]
        assert len(accepted) == 1, f'{len(accepted)} of 20 accepted'
        result, = burst.wait([accepted[0].get_result_async()], 30, 'result')
    finally:
        burst.close()
    assert result.status == 4 and result.result.outcome == 'force_limit'   # SUCCEEDED
    assert arms[0].pushes == 1
    # the lock is free again: the next goal is accepted and runs
    again = graph.wait_future(scripted[2].send_goal_async(_goal()), 20, 'next goal')
    assert again.accepted
    assert graph.wait_future(again.get_result_async(), 30, 'next result').status == 4
    assert PokeStore(tmp_path / 'pokes').ids() == ['poke-000001', 'poke-000002']


class StreamingArm(IdleArm):
    """An idle arm whose stream the test drives: ``emit(sample)`` calls every subscriber."""

    def __init__(self, host):
        super().__init__(host)
        self.callbacks = []

    def add_sample_callback(self, callback):
        self.callbacks.append(callback)

    def emit(self, sample):
        for callback in self.callbacks:
            callback(sample)


def test_a_non_finite_arm_sample_is_counted_and_not_published_and_the_stream_goes_on(
        ros_graph, tmp_path):
    server, arms = _server(ros_graph, tmp_path, StreamingArm)
    listener = ros_graph.add(Node('stream_listener', context=ros_graph.context))
    got = []
    listener.create_subscription(WrenchStamped, '/poke_server/wrench',
                                 lambda msg: got.append(msg.wrench.force.z), 10)
    ros_graph.wait_for(lambda: server.count_subscribers('/poke_server/wrench') > 0, 30.0,
                       'the wrench subscriber')
    good = np.array([0.3, 0.0, 0.3, np.pi, 0.0, 0.0])
    bad_pose, bad_wrench = good.copy(), np.zeros(6)
    bad_pose[4] = np.nan
    bad_wrench[2] = np.inf
    samples = [ArmSample(1.7e9, 1.0, bad_pose, np.zeros(6)),
               ArmSample(1.7e9 + 0.004, 1.004, good, bad_wrench),
               ArmSample(1.7e9 + 0.008, 1.008, good, np.r_[0.0, 0.0, 2.5, 0.0, 0.0, 0.0])]
    for sample in samples:   # as the driver's stream thread calls it: nothing may raise
        arms[0].emit(sample)
    ros_graph.wait_for(lambda: got, 30.0, 'the published wrench')
    time.sleep(0.3)   # the refused two would have arrived before the good one
    # the tool's z axis points down (a half turn about x): +2.5 N along base z is -2.5 N in it
    assert got == [pytest.approx(-2.5)]
    assert server.samples_refused == 2 and server.samples_streamed == 3


@pytest.mark.parametrize('error', [OSError(28, 'No space left on device'),
                                   DataError('poke ids must be unique')])
def test_a_storing_failure_after_the_arm_moved_keeps_the_samples_and_says_where(
        scripted, monkeypatch, error):
    graph, server, client, arms, tmp_path = scripted

    def refuse(record):
        raise error
    monkeypatch.setattr(server.store, 'add', refuse)
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal')
    assert handle.accepted
    got = graph.wait_future(handle.get_result_async(), 30, 'result')
    result = got.result
    assert got.status == 6 and arms[0].pushes == 1        # ABORTED, after the arm moved
    path = tmp_path / 'pokes' / 'recovery' / 'poke-000001.npz'
    assert str(path) in result.message and type(error).__name__ in result.message
    record = load_recovery(path)
    assert len(record) == arms[0].samples == result.samples
    assert record.outcome == 'force_limit' and result.peak_force > 0.0
    monkeypatch.undo()
    # the recovered id is not handed out again
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal after')
    after = graph.wait_future(handle.get_result_async(), 30, 'result after').result
    assert after.poke_id == 'poke-000002'


def test_a_store_that_cannot_take_a_new_poke_aborts_before_the_arm_moves(scripted, monkeypatch):
    graph, server, client, arms, tmp_path = scripted

    def full(*args, **kwargs):
        raise OSError(28, 'No space left on device')
    monkeypatch.setattr(server.store, '_write_json', full)   # the id counter's write
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal')
    got = graph.wait_future(handle.get_result_async(), 30, 'result')
    assert got.status == 6 and arms[0].pushes == 0            # ABORTED, the arm never moved
    assert (f'poke store {tmp_path / "pokes"} cannot take a new poke (OSError: [Errno 28] No '
            'space left on device); the arm did not move') in got.result.message
    monkeypatch.undo()
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal after')
    after = graph.wait_future(handle.get_result_async(), 30, 'result after')
    assert after.status == 4 and arms[0].pushes == 1


def test_an_unexpected_error_in_execution_aborts_with_a_message_and_frees_the_lock(
        scripted, monkeypatch):
    graph, server, client, arms, _ = scripted
    monkeypatch.setattr(server, '_run_poke', lambda handle: 1 / 0)
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal')
    got = graph.wait_future(handle.get_result_async(), 30, 'result')
    assert got.status == 6 and 'ZeroDivisionError' in got.result.message
    monkeypatch.undo()
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal after')
    assert handle.accepted
    assert graph.wait_future(handle.get_result_async(), 30, 'result after').status == 4


def test_samples_a_record_refuses_are_kept_raw_and_the_message_says_where(scripted):
    """A controller clock that stepped back: PokeRecord refuses the series, the file keeps it."""
    graph, server, client, arms, tmp_path = scripted
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'warm-up goal')
    graph.wait_future(handle.get_result_async(), 30, 'warm-up result')
    arm = arms[0]
    original = arm.push_until

    def stepped_back(*args, **kwargs):
        result = original(*args, **kwargs)
        t_controller = result.t_controller.copy()
        t_controller[50] = t_controller[10]
        return dataclasses.replace(result, t_controller=t_controller)
    arm.push_until = stepped_back
    handle = graph.wait_future(client.send_goal_async(_goal()), 20, 'goal')
    got = graph.wait_future(handle.get_result_async(), 30, 'result')
    path = tmp_path / 'pokes' / 'recovery' / 'poke-000002.npz'
    assert got.status == 6 and str(path) in got.result.message
    assert 'InvalidInput' in got.result.message
    with np.load(path) as z:
        assert len(z['t_controller']) == arm.samples and z['t_controller'][50] == z[
            't_controller'][10]
        assert 'strictly increasing' in json.loads(bytes(z['header']).decode())['error']


def test_a_goal_in_a_frame_tf_places_pokes_the_same_point_in_base(scripted):
    """Session 41: a planner's goal in ``world`` was rejected; with ``world <- base`` on
    /tf_static the point and normal are moved into ``base``."""
    graph, server, client, arms, _ = scripted
    world_from_base = np.eye(4)
    world_from_base[:3, :3] = Rotation.random(random_state=3).as_matrix()
    world_from_base[:3, 3] = [2.0, -1.0, 0.8]
    probe = graph.add(Node('world_publisher', context=graph.context))
    probe.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS).publish(
        TFMessage(transforms=[transform_to_msg(world_from_base, 'world', 'base')]))
    graph.wait_for(lambda: server.tf.knows('world'), 10, 'world <- base on /tf_static')
    point, normal = np.array([0.5, 0.0, 0.04]), np.array([0.0, 0.6, 0.8])
    goal = poke_goal_to_msg(PokeGoal(point=world_from_base[:3, :3] @ point
                                     + world_from_base[:3, 3],
                                     normal=world_from_base[:3, :3] @ normal, force_limit=3.0,
                                     depth_limit=0.008, speed=0.005, standoff=0.008))
    goal.header.frame_id = 'world'
    handle = graph.wait_future(client.send_goal_async(goal), 20, 'goal response')
    assert handle.accepted, server.last_rejection
    assert graph.wait_future(handle.get_result_async(), 30, 'result').status == 4
    standoff, direction = arms[0].last_push
    np.testing.assert_allclose(standoff[:3], point + 0.008 * normal, atol=1e-9)
    np.testing.assert_allclose(direction, -normal, atol=1e-9)


@pytest.mark.parametrize('frame, accepted', [('', True), ('base', True), ('tool0', False),
                                             ('camera_depth_optical_frame', False)])
def test_a_goal_in_another_frame_is_rejected_with_the_reason(scripted, frame, accepted):
    """Issue 21: the goal's point and normal had ``base`` implied; a frame mistake was silent."""
    graph, server, client, arms, _ = scripted
    goal = _goal()
    assert goal.header.frame_id == 'base'     # the adapter stamps what it converts
    goal.header.frame_id = frame
    handle = graph.wait_future(client.send_goal_async(goal), 20, 'goal response')
    assert handle.accepted == accepted, server.last_rejection
    if accepted:
        assert graph.wait_future(handle.get_result_async(), 30, 'result').status == 4
        assert arms[0].pushes == 1
    else:
        assert 'header.frame_id' in server.last_rejection
        assert repr(frame) in server.last_rejection and "'base'" in server.last_rejection
        assert not arms or arms[0].pushes == 0
