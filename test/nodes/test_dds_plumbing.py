"""The generated interfaces work over real DDS (Fast DDS) between two nodes in one process.

The Poke action server here is a minimal stand-in for poke_server (which needs the arm); the
point is the transport: goal, feedback stream, result and rejection go over the wire.
"""

import os
import subprocess
import sys
import threading
import time

import pytest
import rclpy
from pointforce_interfaces.action import Poke
from rclpy.action import ActionClient, ActionServer, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

pytestmark = pytest.mark.ros


def _wait(future, timeout, what):
    deadline = time.monotonic() + timeout
    while not future.done():
        if time.monotonic() > deadline:
            raise RuntimeError(f'timed out after {timeout} s waiting for {what}')
        time.sleep(0.01)
    return future.result()


class CountingPokeServer(Node):
    """Emits one feedback per millimetre of a fake push, rejects non-positive force limits."""

    def __init__(self, context):
        super().__init__('plumbing_poke_server', context=context)
        self._server = ActionServer(self, Poke, '~/poke', self._execute,
                                    goal_callback=self._on_goal,
                                    callback_group=ReentrantCallbackGroup())

    def _on_goal(self, goal):
        return GoalResponse.ACCEPT if goal.force_limit > 0 else GoalResponse.REJECT

    def _execute(self, handle):
        depth_mm = int(round(handle.request.depth_limit * 1000))
        for i in range(depth_mm):
            handle.publish_feedback(Poke.Feedback(depth=(i + 1) / 1000.0,
                                                  normal_force=0.5 * (i + 1),
                                                  samples=(i + 1) * 125, phase='push'))
            time.sleep(0.01)
        handle.succeed()
        return Poke.Result(poke_id='poke-000001', samples=depth_mm * 125,
                           peak_force=0.5 * depth_mm, max_depth=depth_mm / 1000.0,
                           outcome='depth_limit')


def test_poke_action_goal_feedback_result_and_rejection_over_dds(ros_graph):
    ros_graph.add(CountingPokeServer(ros_graph.context))
    client_node = ros_graph.add(Node('plumbing_client', context=ros_graph.context))
    client = ActionClient(client_node, Poke, '/plumbing_poke_server/poke')
    assert client.wait_for_server(timeout_sec=30.0), 'poke action server not discovered'
    feedback = []
    lock = threading.Lock()

    def on_feedback(msg):
        with lock:
            feedback.append(msg.feedback)

    goal = Poke.Goal(force_limit=4.0, depth_limit=0.006)
    handle = _wait(client.send_goal_async(goal, feedback_callback=on_feedback), 10, 'goal')
    assert handle.accepted
    result = _wait(handle.get_result_async(), 15, 'result').result
    assert result.outcome == 'depth_limit' and result.samples == 750
    assert result.peak_force == pytest.approx(3.0)
    time.sleep(0.2)
    with lock:
        depths = [f.depth for f in feedback]
    assert len(depths) >= 4 and depths == sorted(depths)
    assert depths[-1] == pytest.approx(0.006)
    rejected = _wait(client.send_goal_async(Poke.Goal(force_limit=-1.0)), 10, 'rejection')
    assert not rejected.accepted


FOREIGN = (
    'import rclpy, time\n'
    'rclpy.init()\n'
    'n = rclpy.create_node("foreign_node")\n'
    'print("up", flush=True)\n'
    'time.sleep(4.0)\n'
    'n.destroy_node(); rclpy.shutdown()\n'
)


@pytest.mark.parametrize('same_domain', [True, False])
def test_graph_sees_only_its_own_domain(ros_graph, same_domain):
    """A node in another process shows up only when it shares this test's domain id."""
    domain = int(os.environ['ROS_DOMAIN_ID'])
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain if same_domain else (domain % 100) + 1))
    proc = subprocess.Popen([sys.executable, '-c', FOREIGN], env=env, stdout=subprocess.PIPE,
                            text=True)
    try:
        assert proc.stdout.readline().strip() == 'up'
        node = ros_graph.add(Node('watcher', context=ros_graph.context))
        seen = False
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline and not seen:
            seen = 'foreign_node' in {n for n, _ in node.get_node_names_and_namespaces()}
            time.sleep(0.1)
        assert seen == same_domain
        assert rclpy.ok(context=ros_graph.context)
    finally:
        proc.kill()
        proc.wait()
