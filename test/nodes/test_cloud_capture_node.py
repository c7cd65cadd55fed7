"""cloud_capture over DDS: rendered scans in, latched outward surface out, bad clouds refused."""

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2, PointField
from scipy.spatial.transform import Rotation, Slerp
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import pose_stamped_to_msg, stamp_to_sec, transform_to_msg
from msg_adapters.pointcloud2 import msg_from_cloud, surface_from_msg
from pointforce_ros.sim.camera import DepthCamera, look_at
from pointforce_ros import frames
from pointforce_ros.model.files import load_surface
from pointforce_ros.rotations import pose_to_matrix
from pointforce_ros.nodes.cloud_capture import CloudCaptureNode, LATCHED
from pointforce_ros.nodes.common import TF_QOS, TF_STATIC_QOS
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


def _random_pose(rng, reach=0.3):
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    m[:3, 3] = rng.uniform(-reach, reach, 3)
    return m


@pytest.mark.parametrize('via', ['camera_pose', 'tf'])
def test_two_views_merge_into_a_latched_outward_surface(ros_graph, tmp_path, via):
    """``via``: the camera placed by the camera pose topic, or (session 41) by a wrist mount
    on /tf_static and the arm's pose on /tf at each cloud's stamp, as a real cell does."""
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
        Parameter('roi', value=[0.4, -0.1, 0.01, 0.6, 0.1, 0.1])]))
    test_node = ros_graph.add(Node('camera_driver', context=ros_graph.context))
    cloud_pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    pose_pub = test_node.create_publisher(PoseStamped, '/cloud_capture/camera_pose', 10)
    tf_pub = test_node.create_publisher(TFMessage, '/tf', TF_QOS)
    static_pub = test_node.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS)
    mount = _random_pose(np.random.default_rng(5), 0.1)    # tool0 <- optical frame
    static_pub.publish(TFMessage(transforms=[
        transform_to_msg(mount, 'tool0', 'camera_depth_optical_frame')]))
    add = test_node.create_client(Trigger, '/cloud_capture/add_scan')
    capture = test_node.create_client(Trigger, '/cloud_capture/capture')
    camera = DepthCamera(noise_a=0.0003, seed=3)
    mesh = _block()
    for k, eye in enumerate(([0.5, -0.25, 0.35], [0.5, 0.25, 0.35])):
        pose = look_at(eye, [0.5, 0.0, 0.04])
        frame = camera.render(mesh, pose, organised=True)
        stamp = 100.0 + k
        if via == 'tf':     # the arm carries the camera: base <- tool0 at the cloud's stamp
            tf_pub.publish(TFMessage(transforms=[
                transform_to_msg(pose @ np.linalg.inv(mount), 'base', 'tool0', stamp)]))
            ros_graph.wait_for(lambda: node.tf_listener.received == 2 + k, 10, 'arm on /tf')
        else:
            pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose)))
            ros_graph.wait_for(lambda: node._camera_pose is not None and np.allclose(
                node._camera_pose.position, eye), 10, 'camera pose')
        cloud_pub.publish(msg_from_cloud(frame.points, frame.rgb, stamp=stamp,
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


def test_clouds_are_moved_through_the_tf_tree_at_their_own_stamp(ros_graph, tmp_path):
    """Session 41: without tf a real cell's camera (on the arm's wrist through /tf_static, the
    arm on /tf) could be placed only by a hand-published pose; now the tree is looked up at
    each cloud's stamp, interpolated between the arm's samples, and refused with the reason
    where it cannot be."""
    rng = np.random.default_rng(11)
    test_node = ros_graph.add(Node('robot_state', context=ros_graph.context))
    tf_pub = test_node.create_publisher(TFMessage, '/tf', TF_QOS)
    static_pub = test_node.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS)
    link, optical = _random_pose(rng, 0.1), _random_pose(rng, 0.05)
    static_pub.publish(TFMessage(transforms=[                      # before the node starts
        transform_to_msg(link, 'tool0', 'camera_link'),
        transform_to_msg(optical, 'camera_link', 'camera_depth_optical_frame')]))
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz'))]))
    ros_graph.wait_for(lambda: node.tf.knows('camera_depth_optical_frame'), 10,
                       'the static mounts, published before the node (transient local)')
    cloud_pub = test_node.create_publisher(PointCloud2, '/camera/camera/depth/color/points', 10)
    add = test_node.create_client(Trigger, '/cloud_capture/add_scan')
    arm = [_random_pose(rng) for _ in range(3)]                    # base <- tool0
    bad = transform_to_msg(arm[0], 'base', 'tool0', 10.2)
    bad.transform.translation.x = float('nan')
    tf_pub.publish(TFMessage(transforms=[transform_to_msg(arm[0], 'base', 'tool0', 10.0),
                                         bad]))
    tf_pub.publish(TFMessage(transforms=[transform_to_msg(arm[1], 'base', 'tool0', 10.5)]))
    ros_graph.wait_for(lambda: node.tf_listener.received == 4, 10, 'the arm on /tf')
    assert 'non-finite' in node.tf_listener.last_refusal      # and the others were taken
    # a camera pose published by hand does not override the tree for a frame it holds
    node._new_camera_pose([0.5, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0])()
    points = rng.uniform(0.2, 0.3, (100, 3))

    def latest(stamp, frame='camera_depth_optical_frame'):
        node._latest = None
        cloud_pub.publish(msg_from_cloud(points, frame_id=frame, stamp=stamp))
        ros_graph.wait_for(lambda: node._latest is not None, 10, f'cloud at {stamp}')

    def expected(a, b, s):
        rot = Slerp([0.0, 1.0], Rotation.from_matrix([a[:3, :3], b[:3, :3]]))([s]).as_matrix()
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = rot[0], (1 - s) * a[:3, 3] + s * b[:3, 3]
        return m @ link @ optical

    latest(10.25)
    np.testing.assert_allclose(node._scan_from_latest().transform,
                               expected(arm[0], arm[1], 0.5), atol=1e-9)
    latest(10.75)                     # after the arm's newest sample: refused until it comes
    refused = _call(ros_graph, add, 'add_scan before its transform')
    assert not refused.success and 'not arrived yet' in refused.message, refused.message
    tf_pub.publish(TFMessage(transforms=[transform_to_msg(arm[2], 'base', 'tool0', 11.0)]))
    ros_graph.wait_for(lambda: node.tf_listener.received == 5, 10, 'the arm at 11 s')
    assert _call(ros_graph, add, 'add_scan after its transform').success
    np.testing.assert_allclose(node._scans[-1].transform, expected(arm[1], arm[2], 0.5),
                               atol=1e-9)
    # a camera of another tree (not connected to base) is refused, naming both roots
    tf_pub.publish(TFMessage(transforms=[
        transform_to_msg(arm[0], 'world', 'camera2_optical', 11.0)]))
    ros_graph.wait_for(lambda: node.tf.knows('camera2_optical'), 10, 'a second tree')
    latest(11.0, 'camera2_optical')
    refused = _call(ros_graph, add, 'add_scan of a cloud in another tree')
    assert not refused.success and 'not connected' in refused.message, refused.message
    assert "'world'" in refused.message and "'base'" in refused.message
    assert len(node._scans) == 1
    values = node.health()[2]
    assert int(values['tf_frames']) == 6 and int(values['tf_refused']) == 1
    # a hostile flood: 12 000 new frames in one message, then NaN; the tree stops at its
    # bound, says why, and the node goes on placing clouds
    flood = [transform_to_msg(arm[0], 'base', f'junk{k}', 11.0) for k in range(12_000)]
    tf_pub.publish(TFMessage(transforms=flood))
    ros_graph.wait_for(lambda: node.tf.refused > 1, 30, 'the flood refused past the bound')
    ros_graph.wait_for(lambda: node.tf_listener.received + node.tf.refused >= 12_006, 30,
                       'the whole flood taken')
    assert len(node.tf.frames()) == frames.MAX_FRAMES
    assert 'frames, at most' in node.tf_listener.last_refusal
    latest(10.25)
    assert _call(ros_graph, add, 'add_scan after the flood').success


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
    # session 42: a pose in a frame /tf has not reached yet waits; a cloud of its instant that
    # came meanwhile is paired with it once it is placed (it took the newest pose, b)
    node.tf.set_transform('base', 'odom', 11.0, [0.0, 0.0, 0.0], [0, 0, 0, 1], static=False)
    pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose_a, frame='odom'), stamp=12.0))
    ros_graph.wait_for(lambda: len(node._pose_waiting) == 1, 10, 'pose held for /tf')
    cloud_pub.publish(msg_from_cloud(np.random.default_rng(2).uniform(0.2, 0.3, (100, 3)),
                                     stamp=12.0, frame_id='camera_depth_optical_frame'))
    ros_graph.wait_for(lambda: stamp_to_sec(node._latest[0].header.stamp) == 12.0, 10, 'cloud')
    np.testing.assert_allclose(node._scan_from_latest().transform, pose_b, atol=1e-9)
    node.tf.set_transform('base', 'odom', 13.0, [0.2, 0.0, 0.0], [0, 0, 0, 1], static=False)
    pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose_b, frame='odom'), stamp=13.5))
    ros_graph.wait_for(lambda: len(node._pose_history) == 3, 10, 'held pose placed')
    shifted = pose_a.copy()
    shifted[:3, 3] += [0.1, 0.0, 0.0]       # base <- odom at 12.0: halfway from 0 to 0.2 m
    np.testing.assert_allclose(node._scan_from_latest().transform, shifted, atol=1e-9)


def test_a_camera_pose_in_another_frame_is_moved_through_tf_or_ignored(ros_graph, tmp_path):
    """Session 41: a camera pose stamped in 'map' was taken as a pose in base."""
    node = ros_graph.add(CloudCaptureNode(context=ros_graph.context, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 's.npz'))]))
    pose = look_at([0.5, -0.3, 0.3], [0.5, 0.0, 0.0])
    in_map = pose_stamped_to_msg(Pose.from_matrix(pose, frame='map'), stamp=5.0)
    node._on_pose(in_map)                                  # no tf: ignored
    assert node._camera_pose is None and not node._pose_history
    base_from_map = _random_pose(np.random.default_rng(12))
    node.tf.set_transform('base', 'map', 0.0, base_from_map[:3, 3],
                          Rotation.from_matrix(base_from_map[:3, :3]).as_quat(), static=True)
    node._on_pose(in_map)
    np.testing.assert_allclose(pose_to_matrix(node._camera_pose), base_from_map @ pose,
                               atol=1e-9)
    assert node._camera_pose.frame == 'base' and len(node._pose_history) == 1
    # session 42: a pose newer than a dynamic frame's newest /tf sample waits for it (it
    # was refused as extrapolation), then takes the transform of its own stamp
    node.tf.set_transform('base', 'odom', 5.0, [0.0, 0.0, 0.0], [0, 0, 0, 1], static=False)
    node._on_pose(pose_stamped_to_msg(Pose.from_matrix(pose, frame='odom'), stamp=5.5))
    assert len(node._pose_history) == 1 and len(node._pose_waiting) == 1
    node.tf.set_transform('base', 'odom', 6.0, [0.2, 0.0, 0.0], [0, 0, 0, 1], static=False)
    node._on_pose(pose_stamped_to_msg(Pose.from_matrix(pose, frame='odom'), stamp=6.5))
    assert [t for t, _ in node._pose_history] == [5.0, 5.5] and len(node._pose_waiting) == 1
    np.testing.assert_allclose(node._camera_pose.position, pose[:3, 3] + [0.1, 0.0, 0.0],
                               atol=1e-12)


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
