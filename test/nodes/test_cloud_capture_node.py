"""cloud_capture over DDS: rendered scans in, latched outward surface out, bad clouds refused."""

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2, PointField
from std_srvs.srv import Trigger

from msg_adapters.geometry import pose_stamped_to_msg
from msg_adapters.pointcloud2 import msg_from_cloud, surface_from_msg
from pointforce_ros.sim.camera import DepthCamera, look_at
from pointforce_ros.model.files import load_surface
from pointforce_ros.nodes.cloud_capture import CloudCaptureNode, LATCHED
from pointforce_ros.shapes import box
from pointforce_ros.types import Mesh, Pose

pytestmark = pytest.mark.ros


def _block():
    """A 80 x 60 x 40 mm block on the table centred at (0.5, 0), as base-frame triangles."""
    b = box((0.08, 0.06, 0.04))
    return Mesh(vertices=b.vertices + [0.5, 0.0, 0.0], triangles=b.triangles)


def _call(graph, client, what):
    assert client.wait_for_service(timeout_sec=30.0), f'{what} service missing'
    return graph.wait_future(client.call_async(Trigger.Request()), 30, what)


def test_two_views_merge_into_a_latched_outward_surface(ros_graph, tmp_path):
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
        Parameter('roi', value=[0.4, -0.1, 0.01, 0.6, 0.1, 0.1])]))
    test_node = ros_graph.add(Node('camera_driver', context=ros_graph.context))
    cloud_pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    pose_pub = test_node.create_publisher(PoseStamped, '/cloud_capture/camera_pose', 10)
    add = test_node.create_client(Trigger, '/cloud_capture/add_scan')
    capture = test_node.create_client(Trigger, '/cloud_capture/capture')
    camera = DepthCamera(noise_a=0.0003, seed=3)
    mesh = _block()
    for eye in ([0.5, -0.25, 0.35], [0.5, 0.25, 0.35]):
        pose = look_at(eye, [0.5, 0.0, 0.04])
        frame = camera.render(mesh, pose, organised=True)
        pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose)))
        ros_graph.wait_for(lambda: node._camera_pose is not None and np.allclose(
            node._camera_pose.position, eye), 10, 'camera pose')
        cloud_pub.publish(msg_from_cloud(frame.points, frame.rgb,
                                         frame_id='camera_depth_optical_frame'))
        ros_graph.wait_for(lambda: node._latest is not None, 10, 'cloud')
        assert _call(ros_graph, add, 'add_scan').success
        node._latest = None
    result = _call(ros_graph, capture, 'capture')
    assert result.success, result.message
    received = []
    test_node.create_subscription(PointCloud2, '/cloud_capture/surface',
                                  received.append, LATCHED)  # late joiner still gets it
    ros_graph.wait_for(lambda: received, 10, 'latched surface')
    surface = surface_from_msg(received[0])
    top = surface.points[:, 2] > 0.038
    assert top.mean() > 0.3
    # top face normals point up, side faces point away from the block centre
    assert np.median(surface.normals[top, 2]) > 0.98
    side = np.abs(surface.points[:, 1]) > 0.029
    out = np.sign(surface.points[side, 1]) * surface.normals[side, 1]
    assert np.mean(out > 0.5) > 0.9
    stored = load_surface(tmp_path / 'surface.npz')
    np.testing.assert_allclose(stored.points, surface.points, atol=1e-6)
    level, message, values = node.health()               # /diagnostics: captured
    assert level == DiagnosticStatus.OK and f'{len(surface)} points' in message


def test_bad_or_missing_cloud_is_refused_and_node_keeps_serving(ros_graph, tmp_path):
    ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz'))]))
    test_node = ros_graph.add(Node('bad_driver', context=ros_graph.context))
    capture = test_node.create_client(Trigger, '/cloud_capture/capture')
    first = _call(ros_graph, capture, 'capture without cloud')
    assert not first.success and 'no cloud' in first.message
    pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    bad = msg_from_cloud(np.random.default_rng(0).uniform(size=(50, 3)))
    bad.fields = [f for f in bad.fields if f.name != 'z'] + [
        PointField(name='w', offset=8, datatype=PointField.FLOAT32, count=1)]
    pub.publish(bad)
    time.sleep(0.5)
    second = _call(ros_graph, capture, 'capture with a bad cloud')
    assert not second.success and "no 'z' field" in second.message
    assert not (tmp_path / 's.npz').exists()


def test_a_cloud_is_paired_with_the_camera_pose_of_its_own_stamp(ros_graph, tmp_path):
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz'))]))
    test_node = ros_graph.add(Node('stamp_driver', context=ros_graph.context))
    pose_pub = test_node.create_publisher(PoseStamped, '/cloud_capture/camera_pose', 10)
    cloud_pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    pose_a = look_at([0.5, -0.3, 0.3], [0.5, 0.0, 0.0])
    pose_b = look_at([0.5, 0.3, 0.3], [0.5, 0.0, 0.0])
    pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose_a), stamp=10.0))
    pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose_b), stamp=10.5))
    ros_graph.wait_for(lambda: len(node._pose_history) == 2, 10, 'two poses')
    cloud_pub.publish(msg_from_cloud(np.random.default_rng(1).uniform(0.2, 0.3, (100, 3)),
                                     stamp=10.0, frame_id='camera_depth_optical_frame'))
    ros_graph.wait_for(lambda: node._latest is not None, 10, 'cloud')
    np.testing.assert_allclose(node._scan_from_latest().transform, pose_a, atol=1e-9)


@pytest.mark.parametrize('pinned', ['', 'camera_color_optical_frame'])
def test_a_cloud_is_moved_by_its_frame_and_one_in_an_unknown_frame_is_refused(
        ros_graph, tmp_path, pinned):
    """Session 40: a cloud already in base was moved again by the camera pose, and a cloud in
    any frame at all was taken as the camera's."""
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz')),
        Parameter('camera_frame', value=pinned)]))
    test_node = ros_graph.add(Node('frame_driver', context=ros_graph.context))
    cloud_pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    add = test_node.create_client(Trigger, '/cloud_capture/add_scan')
    camera = look_at([0.5, -0.3, 0.3], [0.5, 0.0, 0.0])
    node._new_camera_pose(list(Pose.from_matrix(camera).position)
                          + list(Pose.from_matrix(camera).orientation))()
    points = np.random.default_rng(4).uniform(0.2, 0.3, (100, 3))
    optical = pinned or 'camera_depth_optical_frame'

    def latest(frame):
        node._latest = None
        cloud_pub.publish(msg_from_cloud(points, frame_id=frame))
        ros_graph.wait_for(lambda: node._latest is not None, 10, f'cloud in {frame!r}')

    level, message, _ = node.health()                    # /diagnostics: nothing yet
    assert level == DiagnosticStatus.WARN and 'no cloud received yet' in message
    latest('base')                                       # taken as it is
    np.testing.assert_allclose(node._scan_from_latest().transform, np.eye(4), atol=0)
    latest(optical)                                      # the camera's: moved with its pose
    np.testing.assert_allclose(node._scan_from_latest().transform, camera, atol=1e-9)
    assert node.camera_frame.camera == optical
    latest('')                                           # unstamped: the camera's, as before
    np.testing.assert_allclose(node._scan_from_latest().transform, camera, atol=1e-9)
    latest('map')                                        # needs tf: refused with the reason
    refused = _call(ros_graph, add, 'add_scan of a cloud in map')
    assert not refused.success, refused.message
    assert "'map'" in refused.message and repr(optical) in refused.message
    assert not node._scans
    level, message, values = node.health()
    assert level == DiagnosticStatus.WARN and 'no surface captured yet' in message
    assert "'map'" in values['last_refusal'] and "'map'" in message
    latest(optical)                                      # and the node goes on
    assert _call(ros_graph, add, 'add_scan in the camera frame').success


def test_hostile_clouds_are_refused_with_a_reason_and_the_node_keeps_serving(ros_graph,
                                                                             tmp_path):
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz')),
        Parameter('roi', value=[-1e9, -1e9, -1e9, 1e9, 1e9, 1e9])]))
    test_node = ros_graph.add(Node('hostile_driver', context=ros_graph.context))
    pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    add = test_node.create_client(Trigger, '/cloud_capture/add_scan')
    capture = test_node.create_client(Trigger, '/cloud_capture/capture')
    rng = np.random.default_rng(5)
    plate = np.c_[rng.uniform(-0.1, 0.1, (3000, 2)), np.full(3000, 0.5)]

    def publish(msg):
        node._latest = None
        pub.publish(msg)
        ros_graph.wait_for(lambda: node._latest is not None, 10, 'cloud')

    counted = msg_from_cloud(plate)
    counted.fields[0].count = 3           # x as a 3-vector: no readable x
    publish(counted)
    refused = _call(ros_graph, add, 'add_scan of a cloud whose x has count 3')
    assert not refused.success and "'x' has count" in refused.message
    publish(msg_from_cloud(np.r_[plate, [[1e7, 0.0, 0.5]]]))   # a stray point 10 000 km out
    refused = _call(ros_graph, capture, 'capture with a stray point')
    assert not refused.success and 'voxel edges' in refused.message
    publish(msg_from_cloud(plate))
    result = _call(ros_graph, capture, 'capture of a good cloud')
    assert result.success, result.message


def test_the_merge_set_is_bounded(ros_graph, tmp_path):
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz'))]))
    node.max_merge_points = 250
    test_node = ros_graph.add(Node('merge_driver', context=ros_graph.context))
    pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    add = test_node.create_client(Trigger, '/cloud_capture/add_scan')
    clear = test_node.create_client(Trigger, '/cloud_capture/clear')
    pub.publish(msg_from_cloud(np.random.default_rng(2).uniform(0.2, 0.3, (100, 3))))
    ros_graph.wait_for(lambda: node._latest is not None, 10, 'cloud')
    assert _call(ros_graph, add, 'first add').success
    assert _call(ros_graph, add, 'second add').success
    third = _call(ros_graph, add, 'third add')
    assert not third.success and 'call ~/capture or ~/clear' in third.message
    assert len(node._scans) == 2
    assert _call(ros_graph, clear, 'clear').success
    assert _call(ros_graph, add, 'add after clear').success
