"""Run-time parameters take effect or are refused (issue 21): never accepted and ignored.

Each parameter set here is checked by what the node then does, not by the stored value.
"""

import time

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped, WrenchStamped
from pointforce_interfaces.action import Poke
from rcl_interfaces.srv import SetParameters
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from msg_adapters.interfaces import poke_goal_to_msg
from msg_adapters.pointcloud2 import msg_from_cloud
from pointforce_ros.errors import DeviceFault
from pointforce_ros.nodes.cloud_capture import CloudCaptureNode
from pointforce_ros.nodes.common import declare, live
from pointforce_ros.nodes.deformation_force import DeformationForceNode, STREAM
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.nodes.stiffness_learner import LATCHED
from pointforce_ros.types import PokeGoal

from test_cell_graph import _learner_with_model  # noqa: I100 - the same learner fixture
from idle_arm import IdleArm  # noqa: I100 - the test helper beside this file

pytestmark = pytest.mark.ros


class Setter:
    """``ros2 param set`` over the node's ``set_parameters`` service."""

    def __init__(self, graph, probe, node_name):
        self.graph = graph
        self.client = probe.create_client(SetParameters, f'/{node_name}/set_parameters')
        assert self.client.wait_for_service(timeout_sec=30.0)

    def __call__(self, name, value):
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()])
        return self.graph.wait_future(self.client.call_async(request), 20, name).results[0]


def _capture(graph, client):
    assert client.wait_for_service(timeout_sec=30.0)
    result = graph.wait_future(client.call_async(Trigger.Request()), 30, 'capture')
    assert result.success, result.message


def test_cloud_capture_roi_voxel_and_camera_pose_apply_to_the_next_capture(ros_graph, tmp_path):
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 'surface.npz'))]))
    probe = ros_graph.add(Node('live_probe', context=ros_graph.context))
    camera = probe.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    g = np.arange(-0.03, 0.03 + 1e-9, 0.002)
    xs, ys = np.meshgrid(g, g)
    cloud = msg_from_cloud(np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.46)]),
                           frame_id='camera_depth_optical_frame')

    def published():
        camera.publish(cloud)
        return node._latest is not None
    ros_graph.wait_for(published, 10, 'a cloud', period=0.1)
    capture = probe.create_client(Trigger, '/cloud_capture/capture')
    setter = Setter(ros_graph, probe, 'cloud_capture')
    _capture(ros_graph, capture)
    first = node.surface
    assert first.points[:, 0].max() > 0.525 and np.allclose(first.points[:, 2], 0.04, atol=1e-3)
    # a smaller box: the next surface is cut at x = 0.5
    assert setter('roi', [0.35, -0.15, 0.0, 0.5, 0.15, 0.2]).successful
    _capture(ros_graph, capture)
    assert node.surface.points[:, 0].max() <= 0.5 + 1e-9
    # an empty box is refused with the reason, and the box in use stays
    bad = setter('roi', [0.6, -0.15, 0.0, 0.5, 0.15, 0.2])
    assert not bad.successful and 'roi' in bad.reason and 'empty' in bad.reason
    assert not setter('roi', [0.35, 0.0]).successful
    _capture(ros_graph, capture)
    assert node.surface.points[:, 0].max() <= 0.5 + 1e-9
    # the camera 0.1 m higher: the same cloud lands 0.1 m higher in base
    assert setter('camera_pose', [0.5, 0.0, 0.6, 1.0, 0.0, 0.0, 0.0]).successful
    assert not setter('camera_pose', [0.5, 0.0, 0.6, 0.5, 0.0, 0.0, 0.0]).successful
    _capture(ros_graph, capture)
    assert np.allclose(node.surface.points[:, 2], 0.14, atol=1e-3)
    # a coarser voxel grid: fewer points
    before = len(node.surface)
    assert setter('voxel_size', 0.006).successful
    _capture(ros_graph, capture)
    assert len(node.surface) < 0.5 * before
    assert not setter('normal_orientation', 'sideways').successful
    # what cannot change at run time says so
    for name, value in (('cloud_topic', '/other'), ('surface_file', 'x.npz'),
                        ('frame_id', 'world')):
        result = setter(name, value)
        assert not result.successful and 'read-only' in result.reason, name


def test_learner_marker_settings_redraw_and_its_paths_are_read_only(ros_graph, tmp_path):
    _learner_with_model(ros_graph, tmp_path, marker_suggestions=2)
    probe = ros_graph.add(Node('live_learner_probe', context=ros_graph.context))
    arrays = []
    probe.create_subscription(MarkerArray, '/stiffness_learner/markers', arrays.append, LATCHED)
    ros_graph.wait_for(lambda: arrays, 30, 'markers of the first model')
    setter = Setter(ros_graph, probe, 'stiffness_learner')

    def legend():
        return next(m.text for m in arrays[-1].markers if m.ns == 'legend')

    def arrows():
        return sum(m.ns == 'suggested_pokes' for m in arrays[-1].markers)
    assert '5.0 mm' in legend() and arrows() == 2
    count = len(arrays)
    assert setter('marker_depth', 0.008).successful
    ros_graph.wait_for(lambda: len(arrays) > count, 10, 'markers redrawn')
    assert '8.0 mm' in legend()
    count = len(arrays)
    assert setter('marker_suggestions', 4).successful
    ros_graph.wait_for(lambda: len(arrays) > count, 10, 'markers redrawn')
    assert arrows() == 4
    for name, value in (('store_dir', '/tmp/elsewhere'), ('model_dir', '/tmp/elsewhere'),
                        ('record_topics', True), ('poll_period', 1.0),
                        ('min_peak_force', 1.0), ('effects_file', 'e.json')):
        result = setter(name, value)
        assert not result.successful and 'read-only' in result.reason, name


class RecordingArm(IdleArm):
    """A connected arm whose push takes 0.8 s and records the limits it was given."""

    def __init__(self, host):
        super().__init__(host)
        self.pushes = []

    def push_until(self, standoff, direction, **kwargs):
        self.pushes.append(kwargs)
        time.sleep(0.8)
        raise DeviceFault('scripted: no samples')   # ends the poke quickly, aborted


def test_poke_limits_apply_to_the_next_goal_never_to_the_running_one(ros_graph, tmp_path):
    arms = []

    def factory(host):
        arms.append(RecordingArm(host))
        return arms[-1]
    ros_graph.add(PokeServerNode(arm_factory=factory, context=ros_graph.context,
                                 parameter_overrides=[
                                     Parameter('store_dir', value=str(tmp_path / 'pokes'))]))
    probe = ros_graph.add(Node('poke_live_probe', context=ros_graph.context))
    client = ActionClient(probe, Poke, '/poke_server/poke')
    assert client.wait_for_server(timeout_sec=30.0)
    setter = Setter(ros_graph, probe, 'poke_server')

    def goal(force):
        return poke_goal_to_msg(PokeGoal(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0],
                                         force_limit=force, depth_limit=0.008, speed=0.005,
                                         standoff=0.008))
    running = ros_graph.wait_future(client.send_goal_async(goal(10.0)), 15, 'goal')
    assert running.accepted
    ros_graph.wait_for(lambda: arms and arms[-1].pushes, 10, 'the push started')
    assert setter('max_force', 5.0).successful          # during the push
    assert setter('approach_speed', 0.02).successful
    ros_graph.wait_future(running.get_result_async(), 20, 'first poke')
    assert arms[-1].pushes[0]['max_force'] == 15.0       # the running poke kept its limit
    assert arms[-1].pushes[0]['approach_speed'] == 0.05
    refused = ros_graph.wait_future(client.send_goal_async(goal(10.0)), 15, 'goal over 5 N')
    assert not refused.accepted                          # the next goal sees 5 N
    second = ros_graph.wait_future(client.send_goal_async(goal(4.0)), 15, 'goal under 5 N')
    assert second.accepted
    ros_graph.wait_future(second.get_result_async(), 20, 'second poke')
    assert arms[-1].pushes[-1]['max_force'] == 5.0
    assert arms[-1].pushes[-1]['approach_speed'] == 0.02
    assert not setter('max_force', 0.0).successful       # outside the declared bounds
    for name, value in (('robot_ip', '10.0.0.1'), ('store_dir', '/tmp/elsewhere')):
        result = setter(name, value)
        assert not result.successful and 'read-only' in result.reason, name


def test_deformation_force_contact_threshold_applies_to_the_next_sample(ros_graph, tmp_path):
    """The deformation node's thresholds are live; its paths, topic and mesh are read-only."""
    node = ros_graph.add(DeformationForceNode(context=ros_graph.context, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'deformation'))]))
    probe = ros_graph.add(Node('deformation_param_probe', context=ros_graph.context))
    tcp = probe.create_publisher(PoseStamped, '/poke_server/tcp_pose', STREAM)
    wrench = probe.create_publisher(WrenchStamped, '/poke_server/wrench', STREAM)
    ros_graph.wait_for(lambda: wrench.get_subscription_count() > 0, 10, 'subscriptions')
    pose = PoseStamped()
    pose.pose.orientation.w = 1.0
    tcp.publish(pose)
    ros_graph.wait_for(lambda: node._tcp is not None, 10, 'the TCP pose')

    def push(newtons):
        msg = WrenchStamped()
        msg.wrench.force.z = -float(newtons)    # reaction on the tool: +z on the object
        wrench.publish(msg)
        ros_graph.wait_for(lambda: node._ft is not None and np.isclose(node._ft[2], newtons),
                           10, f'{newtons} N at the node')

    set_param = Setter(ros_graph, probe, 'deformation_force')
    push(1.0)
    assert node._contact is not None            # 1 N > 0.2 N (default): a poke runs
    push(0.0)
    assert node._contact is None
    assert set_param('contact_force', 2.0).successful
    push(1.0)
    assert node._contact is None                # 1 N < 2 N: no poke now
    push(3.0)
    assert node._contact is not None
    assert not set_param('contact_force', 500.0).successful          # above its bound
    for name, value in [('model_dir', str(tmp_path / 'other')), ('cloud_topic', '/x'),
                        ('element_size', 0.01), ('layers', 3), ('frame_id', 'world')]:
        assert not set_param(name, value).successful, name           # read-only


def test_an_applier_or_action_that_raises_refuses_the_set_and_the_node_keeps_its_parameters(
        ros_graph):
    """No exception leaves the on-set callback (session 38): it ran outside any fault boundary.

    An applier may raise more than ``PointforceError``/``ValueError`` (a ``TypeError`` from
    a value it did not expect) and an action may run out of memory (the learner's refit);
    either escaped into rclpy's ``set_parameters`` service. Now the set is refused with the
    reason and the next good set applies.
    """
    node = ros_graph.add(Node('live_faults', context=ros_graph.context))
    applied = []
    declare(node, 'gain', 1.0, 'a test gain', bounds=(0.0, 10.0))

    def applier(value):
        if value == 2.0:
            raise TypeError('an applier bug')
        if value == 3.0:
            return lambda: (_ for _ in ()).throw(MemoryError())
        return lambda: applied.append(value)

    live(node, {'gain': applier})
    for value, reason in ((2.0, 'TypeError: an applier bug'), (3.0, 'not enough memory')):
        result = node.set_parameters([Parameter('gain', value=value)])[0]
        assert not result.successful and reason in result.reason
        assert node.get_parameter('gain').value == 1.0
    assert node.set_parameters([Parameter('gain', value=4.0)])[0].successful
    assert applied == [4.0] and node.get_parameter('gain').value == 4.0
