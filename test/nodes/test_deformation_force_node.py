"""deformation_force node over real DDS, on the foam block fixtures of the cell's ground truth.

The fixtures (test/data/deformation/, ``make_deformation_fixtures.py``): the rest cloud of a
homogeneous foam block (E 50 kPa, nu 0.30) and static point-probe pushes of the cell's
independent FEM with their F/T truth, rendered by the cell's depth camera. The test plays the
cell: it publishes the rest surface, the poke server's TCP pose and F/T wrench streams and the
camera's clouds, and calls the node's services. A coarse mesh keeps it fast.

The fused force (issue 18) is checked on the lamb (``fused_lamb.npz``,
``make_fused_fixtures.py``): a buried bone under two identification sites, a held-out site off
it, the realistic camera, and the learner's point model (cropped) in the node's
``point_model_dir``.
"""

import os

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped, WrenchStamped
from pointforce_interfaces.srv import EstimateForce, IdentifyDeformation
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import sec_to_stamp, to_point, transform_to_msg
from msg_adapters.pointcloud2 import msg_from_cloud
from pointforce_ros.bringup.camera_check import render_view
from pointforce_ros.deformation.identify import Poke
from pointforce_ros.deformation.store import load_latest, model_versions
from pointforce_ros.model.files import ContactModel, QUARANTINE, save_model
from pointforce_ros.nodes import deformation_force
from pointforce_ros.nodes.common import TF_QOS, TF_STATIC_QOS
from pointforce_ros.nodes.deformation_force import DeformationForceNode, LATCHED, STREAM
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.errors import InvalidInput
from pointforce_ros.rotations import matrix_to_quaternion, pose_to_matrix, quaternion_to_matrix
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints
from pointforce_ros.sim.objects import load_object
from pointforce_ros.types import Surface

pytestmark = pytest.mark.ros
DATA = os.path.join(os.path.dirname(__file__), '..', 'data', 'deformation')
TOPIC = '/test_camera/points'
TOOL_Q = np.array([1.0, 0.0, 0.0, 0.0])  # tool z pointing down, as in a poke along -z
TOOL_R = quaternion_to_matrix(TOOL_Q)


def _fixture(name):
    with np.load(os.path.join(DATA, f'{name}.npz')) as data:
        return dict(data)


def _cloud(push, k, bias=0.0):
    """Cloud of static state k; ``bias`` m added to its depths (along the camera's rays)."""
    s = push['cloud_start']
    points = push['cloud'][s[k]:s[k + 1]].astype(float)
    origin, axis = push['camera_pose'][:3, 3], push['camera_pose'][:3, 2]
    z = (points - origin) @ axis
    return origin + (points - origin) * ((z + bias) / z)[:, None]


def _rest_views(bias=0.0, frames=4):
    """The foam block at rest as the fixtures' camera sees it (their scenario, plus ``bias``).

    Returns ``(merged points, merged normals, [rest frame (P, 3)] * frames)``: the two-view
    scan cloud_capture would publish, and frames of the first view (the one that films the
    pushes, ``camera_pose`` of the push fixtures), all in ``base`` (seeded).
    """
    spec = load_object('foam_block')
    mesh = spec.build_mesh(0.002, h_z=spec.size[2] / 8)
    faces = mesh.boundary_faces
    tris = np.concatenate([faces[:, [0, 1, 2]], faces[:, [0, 2, 3]]])
    poses = ring_viewpoints([spec.centre[0], spec.centre[1], 0.02], 0.25, count=2,
                            elevation_deg=55.0, azimuth0_deg=200.0)
    kw = dict(noise_a=1e-4, noise_b=2e-3, depth_unit=1e-4, depth_bias=bias)
    scan = [render_view(DepthCamera(seed=1, **kw), p, mesh.nodes, tris) for p in poses]
    camera = DepthCamera(seed=2, **kw)
    rest = [render_view(camera, poses[0], mesh.nodes, tris)[0] for _ in range(frames)]
    return (np.concatenate([v[0] for v in scan]), np.concatenate([v[1] for v in scan]), rest)


class Cell:
    """The test's side of the graph: streams, clouds, service clients, collected outputs."""

    def __init__(self, graph, node):
        self.graph, self.node = graph, node
        self.io = graph.add(Node('test_cell', context=graph.context))
        io = self.io
        self.surface_pub = io.create_publisher(PointCloud2, '/cloud_capture/surface', LATCHED)
        self.camera_pub = io.create_publisher(PoseStamped, '/cloud_capture/camera_pose', 10)
        self.cloud_pub = io.create_publisher(PointCloud2, TOPIC, 10)
        self.tcp_pub = io.create_publisher(PoseStamped, '/poke_server/tcp_pose', STREAM)
        self.wrench_pub = io.create_publisher(WrenchStamped, '/poke_server/wrench', STREAM)
        self.landed_pub = io.create_publisher(String, '/poke_server/poke_landed', STREAM)
        self.forces, self.reports = [], []
        io.create_subscription(WrenchStamped, '/deformation_force/force', self.forces.append, 10)
        io.create_subscription(DiagnosticStatus, '/deformation_force/ft_consistency',
                               self.reports.append, 10)
        self.identify = io.create_client(IdentifyDeformation, '/deformation_force/identify')
        self.estimate = io.create_client(EstimateForce, '/deformation_force/estimate_force')
        self.observe = io.create_client(Trigger, '/deformation_force/observe')
        for client in (self.identify, self.estimate, self.observe):
            assert client.wait_for_service(timeout_sec=30.0), client.srv_name
        self.stamp = 0.0

    def call(self, client, request, what, timeout=60.0):
        return self.graph.wait_future(client.call_async(request), timeout, what)

    def estimate_at(self, point, tip=None):
        request = EstimateForce.Request(contact_point=to_point(point))
        if tip is not None:
            request.use_tip, request.tip = True, to_point(tip)
        return self.call(self.estimate, request, 'estimate_force')

    def send_cloud(self, points, frame='base'):
        """Publish until the node has taken this cloud (held it, or refused it)."""
        self.stamp += 1.0
        msg = msg_from_cloud(points, frame_id=frame, stamp=self.stamp)
        before = self.node.clouds_received

        def held():
            if self.node.clouds_received > before:
                return True
            self.cloud_pub.publish(msg)
            return False

        self.graph.wait_for(held, 20.0, 'cloud held by the node', period=0.1)

    def tcp(self, position):
        msg = PoseStamped()
        msg.header.frame_id = 'base'
        msg.pose.position = to_point(position)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = (float(v) for v in TOOL_Q)
        self.tcp_pub.publish(msg)
        self.graph.wait_for(lambda: self.node._tcp is not None
                            and np.allclose(self.node._tcp[0], position), 10.0, 'TCP pose')

    def wrench(self, force_on_object):
        """Publish the F/T reading that a force on the object gives (tool frame, reaction)."""
        f = TOOL_R.T @ -np.asarray(force_on_object, dtype=float)
        msg = WrenchStamped()
        msg.header.frame_id = 'tool0_controller'
        msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = (float(v) for v in f)
        self.wrench_pub.publish(msg)
        self.graph.wait_for(lambda: self.node._ft is not None
                            and np.allclose(self.node._ft, force_on_object, atol=1e-9),
                            10.0, 'F/T sample')

    def poke(self, push, k, ft_force=None, end=True, bias=0.0):
        """One push of the fixtures: touch, press to depth k with its cloud, release."""
        force = push['force'][k] if ft_force is None else np.asarray(ft_force)
        self.press(push['contact_point'], push['probe_position'][k], force,
                   _cloud(push, k, bias), end)

    def press(self, contact, tip, force, cloud, end=True):
        """Touch at ``contact``, press the tip to ``tip`` with ``force`` and ``cloud``."""
        self.tcp(contact)
        self.wrench(0.5 * force / np.linalg.norm(force))  # first touch: 0.5 N
        self.graph.wait_for(lambda: self.node._contact is not None, 10.0, 'contact')
        np.testing.assert_allclose(self.node._contact, contact)
        self.tcp(tip)
        self.wrench(force)
        self.send_cloud(cloud)
        if end:
            self.wrench(np.zeros(3))
            self.graph.wait_for(lambda: self.node._contact is None, 10.0, 'poke ended')


@pytest.fixture
def cell(ros_graph, tmp_path):
    node = ros_graph.add(DeformationForceNode(
        context=ros_graph.context,
        parameter_overrides=[Parameter('model_dir', value=str(tmp_path / 'models')),
                             Parameter('point_model_dir', value=str(tmp_path / 'learner')),
                             Parameter('cloud_topic', value=TOPIC),
                             Parameter('element_size', value=0.006),
                             Parameter('layers', value=4)]))
    cell = Cell(ros_graph, node)
    rest = _fixture('rest_foam_block')
    cell.surface_pub.publish(msg_from_cloud(rest['points'], normals=rest['normals'],
                                            frame_id='base'))
    ros_graph.wait_for(lambda: node._rest is not None, 30.0, 'rest mesh')
    return cell


def test_identify_then_camera_only_force_on_a_held_out_push(cell, tmp_path):
    node = cell.node
    pushes = [_fixture(f'push_foam_block_{k}') for k in range(6)]
    # nothing to work from yet: refused with a reason
    refused = cell.estimate_at(pushes[3]['contact_point'])
    assert not refused.success and 'no deformation model' in refused.message
    refused = cell.call(cell.identify, IdentifyDeformation.Request(), 'identify')
    assert not refused.success and 'no observations' in refused.message
    refused = cell.call(cell.observe, Trigger.Request(), 'observe')
    assert not refused.success and 'no cloud' in refused.message
    # three identification pokes at 3 mm; the poke server names the first one
    for i, push in enumerate(p for p in pushes if str(p['role']) == 'identify'):
        cell.poke(push, 0)
        if i == 0:
            cell.landed_pub.publish(String(data='poke-000001'))
            cell.graph.wait_for(lambda: 'poke-000001' in node._observations, 10.0, 'renamed')
    assert list(node._observations) == ['poke-000001', 'contact-2', 'contact-3']
    np.testing.assert_allclose(node._observations['contact-2'].force, pushes[1]['force'][0])
    assert cell.forces == []  # no model while those pokes ran: no camera estimate
    refused = cell.call(cell.identify, IdentifyDeformation.Request(poke_ids=['poke-9']),
                        'identify')
    assert not refused.success and "no observation ['poke-9']" in refused.message
    fit = cell.call(cell.identify, IdentifyDeformation.Request(), 'identify')
    assert fit.success, fit.message
    # it started from the model factorised when the surface arrived (one factorisation
    # fewer); that model now serves the estimates, so a second identification starts cold
    assert 'from the scan-time model' in fit.message and node._scan_fem is None
    assert node._fem is not None and node._fem.poisson == pytest.approx(fit.poisson)
    # measured (0.006 m, 4 layers): E 55.9 kPa, nu 0.217 (truth 50 kPa, 0.30; nu is weakly
    # observable from one top view, see test/deformation/test_estimation.py)
    assert fit.young == pytest.approx(50e3, rel=0.15)
    assert fit.poisson == pytest.approx(0.30, abs=0.12)
    assert 0 < fit.residual_rms < 5e-4
    assert fit.model_version == 1 and model_versions(str(tmp_path / 'models')) == [1]
    # held-out push (8 mm, 2.6 N), cloud in the camera's frame with its published pose
    held = pushes[3]
    cam = held['camera_pose']
    pose = PoseStamped()
    pose.header.frame_id = 'base'
    pose.pose.position = to_point(cam[:3, 3])
    o = pose.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in matrix_to_quaternion(cam[:3, :3]))
    cell.camera_pub.publish(pose)
    cell.graph.wait_for(lambda: node._camera_pose is not None, 10.0, 'camera pose')
    cell.send_cloud((_cloud(held, 2) - cam[:3, 3]) @ cam[:3, :3], frame='camera_optical')
    est = cell.estimate_at(held['contact_point'])
    assert est.success, est.message
    force = np.array([est.wrench.wrench.force.x, est.wrench.wrench.force.y,
                      est.wrench.wrench.force.z])
    truth = held['force'][2]
    # measured: 9.3 % (the wing's foam block figure: median 6.5 %, worst 11.7 % at 4 mm)
    assert np.linalg.norm(force - truth) < 0.15 * np.linalg.norm(truth), (force, truth)
    assert est.wrench.header.frame_id == 'base' and est.points > 100
    cov = np.array(est.covariance).reshape(3, 3)
    assert np.all(np.diag(cov) > 0) and 0 < est.magnitude_std < 0.3
    assert 0 < est.residual_rms < 5e-4
    # a second node on the same model_dir starts with the saved model
    again = cell.graph.add(DeformationForceNode(
        context=cell.graph.context,
        parameter_overrides=[Parameter('model_dir', value=str(tmp_path / 'models'))]))
    assert again._model.version == 1
    assert again._model.young == pytest.approx(fit.young)


def test_bad_requests_are_refused_and_a_saturated_ft_is_flagged(cell, monkeypatch):
    node = cell.node
    pushes = [_fixture(f'push_foam_block_{k}') for k in range(6)]
    for push in pushes[:3]:
        cell.poke(push, 0)
    fit = cell.call(cell.identify, IdentifyDeformation.Request(), 'identify')
    assert fit.success, fit.message
    held = pushes[3]
    point = held['contact_point']
    cell.send_cloud(np.zeros((0, 3)))
    refused = cell.estimate_at(point)
    assert not refused.success and 'empty point cloud' in refused.message
    cell.send_cloud(np.full((50, 3), np.nan))
    refused = cell.estimate_at(point)
    assert not refused.success and 'NaN' in refused.message
    # a cloud with some invalid pixels (as realsense-ros marks them) is used without them
    cloud = _cloud(held, 2)
    cell.send_cloud(np.vstack([cloud, np.full((20, 3), np.nan)]))
    off = cell.estimate_at(point + [0.0, 0.0, 0.03])
    assert not off.success and 'not on it' in off.message
    good = cell.estimate_at(point)
    assert good.success and good.method == 'fem', good.message
    refused = cell.estimate_at(point, tip=held['probe_position'][2])
    assert not refused.success and 'no point model' in refused.message, refused.message
    assert cell.estimate_at(point).success

    def exhausted(*args, **kwargs):
        raise MemoryError()

    with monkeypatch.context() as patch:
        patch.setattr(deformation_force, 'estimate_force', exhausted)
        refused = cell.estimate_at(point)
    assert not refused.success and 'out of memory' in refused.message
    # camera estimates while a poke runs: the truth agrees, an F/T stuck at 1 N does not
    # the clouds above were sent while no poke ran, as rest frames would be: a real camera
    # streams its rest frames between pokes, and those become the next poke's reference
    for frame in _rest_views()[2]:
        cell.send_cloud(frame)
    cell.poke(held, 2, end=False)
    cell.graph.wait_for(lambda: cell.reports, 20.0, 'consistency report')
    assert cell.forces and cell.forces[-1].header.frame_id == 'base'
    assert cell.reports[-1].level == DiagnosticStatus.OK, cell.reports[-1].message
    values = dict((v.key, v.value) for v in cell.reports[-1].values)
    assert values['reference'] == '4 rest frame(s) of this camera', values
    truth = held['force'][2]
    snap = cell.call(cell.observe, Trigger.Request(), 'observe')  # by hand, probe held still
    assert snap.success and snap.message.startswith('observe-'), snap.message
    np.testing.assert_allclose(node._observations[snap.message].force, truth)
    np.testing.assert_allclose(node._observations[snap.message].contact_point,
                               held['contact_point'])
    cell.wrench(np.zeros(3))
    cell.reports.clear()
    cell.poke(held, 2, ft_force=truth / np.linalg.norm(truth), end=False)
    cell.graph.wait_for(lambda: cell.reports, 20.0, 'consistency report')
    report = cell.reports[-1]
    assert report.level == DiagnosticStatus.ERROR and 'saturated' in report.message, \
        report.message
    distance = float(dict((v.key, v.value) for v in report.values)['distance_sigma'])
    assert distance > 3.0
    # the node still answers
    assert cell.estimate_at(point).success
    assert node.estimates_published == 2


def test_an_ft_hovering_at_the_threshold_is_no_observation(cell):
    """A demo run held 27 observations of 0.2 N at one spot: the F/T crossing contact_force."""
    push = _fixture('push_foam_block_0')
    for _ in range(3):
        cell.poke(push, 0, ft_force=[0.0, 0.0, -0.3])
    assert cell.node._observations == {}
    cell.poke(push, 0)          # a real push: its force is newtons
    assert list(cell.node._observations) == ['contact-1']


def test_identify_counts_each_observation_once_and_bounds_how_many(cell):
    """Audit 39: one id named 40 times ran 40 identical pokes (0.12 s each, so a request of
    1000 ran for minutes) and reported "from 40 observation(s)"."""
    node = cell.node
    for k in range(2):
        cell.poke(_fixture(f'push_foam_block_{k}'), 0)
    names = list(node._observations)
    refused = cell.call(cell.identify, IdentifyDeformation.Request(
        poke_ids=[names[0]] * 40 + [names[1]]), 'identify')
    assert not refused.success and 'more than once' in refused.message, refused.message
    assert names[0] in refused.message and node._model is None
    many = [f'poke-{k}' for k in range(deformation_force.MAX_IDENTIFY_POKES + 1)]
    refused = cell.call(cell.identify, IdentifyDeformation.Request(poke_ids=many), 'identify')
    assert not refused.success and f'at most {len(many) - 1}' in refused.message
    fit = cell.call(cell.identify, IdentifyDeformation.Request(poke_ids=names), 'identify')
    assert fit.success and 'from 2 observation(s),' in fit.message, fit.message


def test_poses_in_an_unknown_frame_or_with_nan_are_ignored(cell):
    """Audit 39: a camera pose stamped 'map' was taken as base (every cloud moved by it) and
    a NaN TCP became the next poke's contact point."""
    node = cell.node
    cell.tcp([0.5, 0.0, 0.04])
    held = node._tcp

    def pose(frame, position):
        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.pose.position = to_point(position)
        msg.pose.orientation.w = 1.0
        return msg

    node._on_tcp(pose('base', [np.nan, 0.0, 0.0]))
    node._on_tcp(pose('map', [3.0, 2.0, 1.0]))
    assert node._tcp is held
    node._on_camera(pose('map', [3.0, 2.0, 1.0]))
    assert node._camera_pose is None
    node._on_camera(pose('', [0.4, 0.0, 0.5]))     # no frame: base, as for clouds
    np.testing.assert_allclose(node._camera_pose.position, [0.4, 0.0, 0.5])
    node._on_tcp(pose('base', [0.5, 0.01, 0.04]))
    np.testing.assert_allclose(node._tcp[0], [0.5, 0.01, 0.04])
    # session 41: a frame the tf tree places is moved through it (base <- map: 0.1 m along x,
    # a quarter turn about z)
    node.tf.set_transform('base', 'map', 0.0, [0.1, 0.0, 0.0],
                          [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], static=True)
    node._on_tcp(pose('map', [0.01, -0.4, 0.04]))
    np.testing.assert_allclose(node._tcp[0], [0.5, 0.01, 0.04], atol=1e-12)
    np.testing.assert_allclose(node._tcp[1], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    node._on_camera(pose('map', [0.0, -0.3, 0.5]))
    np.testing.assert_allclose(node._camera_pose.position, [0.4, 0.0, 0.5], atol=1e-12)
    assert node._camera_pose.frame == 'base'


def test_a_cloud_in_a_frame_that_is_neither_base_nor_the_cameras_is_refused(cell):
    """Session 40: a cloud in any frame but base was taken as the camera's and moved by its
    pose (a second camera's cloud, or one that needs tf, landed wrong by that frame's offset)."""
    node = cell.node
    points = np.random.default_rng(6).uniform(-0.05, 0.05, (200, 3)) + [0.5, 0.0, 0.3]
    m = pose_to_matrix(node.default_pose)
    for frame in ('base', ''):                         # base, and unstamped, as they are
        np.testing.assert_allclose(node._cloud_in_base(msg_from_cloud(points, frame_id=frame)),
                                   points, atol=1e-6)
    moved = node._cloud_in_base(msg_from_cloud(points, frame_id='camera_depth_optical_frame'))
    np.testing.assert_allclose(moved, points @ m[:3, :3].T + m[:3, 3], atol=1e-6)
    assert node.camera_frame.camera == 'camera_depth_optical_frame'
    with pytest.raises(InvalidInput, match="'map'.*'camera_depth_optical_frame'"):
        node._cloud_in_base(msg_from_cloud(points, frame_id='map'))
    # /diagnostics before: a rest mesh, no model yet
    level, message, values = node.health()
    assert level == DiagnosticStatus.WARN and 'no deformation model yet' in message
    assert int(values['rest_mesh_nodes']) > 0
    # over the topic: refused with the reason kept for the next answer and the health report;
    # the node goes on
    cell.send_cloud(points, frame='camera_color_optical_frame')
    assert 'camera_color_optical_frame' in node._cloud and 'refused' in node._cloud
    level, message, values = node.health()
    assert level == DiagnosticStatus.WARN and "'camera_color_optical_frame'" in message
    assert int(values['clouds_since_last']) >= 1
    cell.send_cloud(points, frame='camera_depth_optical_frame')
    assert isinstance(node._cloud, tuple) and len(node._cloud[0]) == len(points)
    assert 'no deformation model yet' in node.health()[1]


def test_a_cloud_is_moved_by_the_tf_tree_and_a_camera_moved_on_it_forgets_its_rest_frames(
        cell):
    """Session 41: with no tf, a camera placed on /tf_static (a real cell's hand-eye mount) was
    refused or placed by the camera pose parameter; a re-mounted camera kept rest frames
    taken from its old viewpoint."""
    node = cell.node
    mounts = cell.graph.add(Node('camera_mount', context=cell.graph.context))
    static_pub = mounts.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS)
    first = pose_to_matrix(node.default_pose)
    first[:3, 3] += [0.05, -0.02, 0.01]     # not the camera pose parameter's
    second = first.copy()
    second[:3, 3] += [0.0, 0.03, 0.0]
    points = np.random.default_rng(9).uniform(-0.05, 0.05, (200, 3)) + [0.0, 0.0, 0.3]

    def mount(m):
        static_pub.publish(TFMessage(transforms=[transform_to_msg(m, 'base', 'wrist_optical')]))
        cell.graph.wait_for(lambda: node.tf.knows('wrist_optical') and np.allclose(
            node.tf.lookup('base', 'wrist_optical'), m, atol=1e-9), 10.0, 'camera mount')

    mount(first)
    for k in range(2):                      # two rest frames from the first mount
        cell.send_cloud(points + 1e-4 * k, frame='wrist_optical')
        np.testing.assert_allclose(node._cloud[0], (points + 1e-4 * k) @ first[:3, :3].T
                                   + first[:3, 3], atol=1e-6)
    assert node._rest_frames.pending == 2
    assert node.camera_frame.camera is None     # the tree placed it: nothing adopted
    mount(second)                               # re-mounted: those frames are of another view
    cell.send_cloud(points, frame='wrist_optical')
    np.testing.assert_allclose(node._cloud[0], points @ second[:3, :3].T + second[:3, 3],
                               atol=1e-6)
    assert node._rest_frames.pending == 1


def test_a_tcp_stream_ahead_of_a_slower_tf_waits_for_it(cell):
    """Session 42: a TCP pose stamped in a frame /tf places (``world``, the arm's driver
    publishing at 500 Hz while /tf comes at 10) was refused as extrapolation into the future
    whenever it was newer than /tf's newest sample; now it waits for that sample."""
    node = cell.node
    arm = cell.graph.add(Node('world_publisher', context=cell.graph.context))
    tf_pub = arm.create_publisher(TFMessage, '/tf', TF_QOS)
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.pose.orientation.w = 1.0

    def world_at(stamp, x):
        m = np.eye(4)
        m[:3, 3] = [x, 0.0, 0.0]
        tf_pub.publish(TFMessage(transforms=[transform_to_msg(m, 'base', 'world', stamp)]))
        cell.graph.wait_for(lambda: node.tf.knows('world') and np.isclose(
            node.tf.lookup('base', 'world')[0, 3], x), 10.0, '/tf sample')

    def tcp_at(stamp, y):
        sec_to_stamp(stamp, msg.header.stamp)
        msg.pose.position = to_point([0.0, y, 0.04])

        def state():
            return node._tcp_waiting.held_back, len(node._tcp_waiting), id(node._tcp)

        before = state()
        cell.tcp_pub.publish(msg)
        cell.graph.wait_for(lambda: state() != before, 10.0, 'TCP pose taken')

    world_at(100.0, 0.5)
    tcp_at(100.0, 0.01)
    np.testing.assert_allclose(node._tcp[0], [0.5, 0.01, 0.04], atol=1e-12)
    tcp_at(100.05, 0.02)                    # newer than /tf: waits (it was refused)
    tcp_at(100.08, 0.03)
    np.testing.assert_allclose(node._tcp[0], [0.5, 0.01, 0.04], atol=1e-12)
    assert len(node._tcp_waiting) == 2
    world_at(100.1, 0.6)                    # /tf catches up: the next TCP sample places them
    tcp_at(100.12, 0.04)
    np.testing.assert_allclose(node._tcp[0], [0.58, 0.03, 0.04], atol=1e-9)  # at its stamp
    assert len(node._tcp_waiting) == 1      # 100.12 waits for /tf in its turn


def test_held_observations_are_bounded_by_the_bytes_of_their_clouds(cell, monkeypatch):
    """Audit 39: observations kept their whole clouds up to ``max_observations`` (100 by
    default, bound 10 000): about 1 GB at the default for a depth camera's 10 MB clouds."""
    node = cell.node
    cloud = np.random.default_rng(0).uniform(-0.05, 0.05, (20_000, 3))   # 480 kB
    monkeypatch.setattr(deformation_force, 'OBSERVATION_BYTES', 3 * cloud.nbytes)
    with node._lock:
        for k in range(6):
            node._add_observation(f'big-{k}', Poke([0.5, 0.0, 0.04], [0.0, 0.0, -1.0],
                                                   cloud + k))
    assert list(node._observations) == ['big-3', 'big-4', 'big-5']
    monkeypatch.setattr(deformation_force, 'OBSERVATION_BYTES', cloud.nbytes // 2)
    with node._lock:   # one cloud over the budget on its own: the newest is still held
        node._add_observation('big-6', Poke([0.5, 0.0, 0.04], [0.0, 0.0, -1.0], cloud))
    assert list(node._observations) == ['big-6']


@pytest.mark.parametrize('rest_frames', [4, 0])
def test_a_biased_camera_is_measured_from_its_own_rest_frames(ros_graph, tmp_path, rest_frames):
    """A 2 mm depth bias: within the 10 % goal from the pushing camera's rest frames only.

    The bias moves each view's points along that view's rays, so the merged two-view surface
    does not cancel the bias of the camera that films the pushes. Node defaults (mesh 4 mm,
    6 layers); identification on the three identification pokes at 3 mm, then each held-out
    push at 3, 5 and 8 mm from its cloud alone. Measured: mean magnitude error 4.6 % (worst
    10.0 %) from 4 rest frames; 16.0 % (worst 34.2 %) from the merged surface
    (``rest_frames`` 0, as the node measured before; with the frames ignored, the first case
    fails).
    """
    bias = 0.002
    node = ros_graph.add(DeformationForceNode(
        context=ros_graph.context,
        parameter_overrides=[Parameter('model_dir', value=''),
                             Parameter('point_model_dir', value=''),
                             Parameter('cloud_topic', value=TOPIC),
                             Parameter('rest_frames', value=rest_frames)]))
    cell = Cell(ros_graph, node)
    merged, normals, frames = _rest_views(bias)
    cell.surface_pub.publish(msg_from_cloud(merged, normals=normals, frame_id='base'))
    ros_graph.wait_for(lambda: node._rest is not None, 30.0, 'rest mesh')
    for frame in frames:   # the camera streams while the arm approaches: rest frames
        cell.send_cloud(frame)
    pushes = [_fixture(f'push_foam_block_{k}') for k in range(6)]
    for push in pushes[:3]:
        cell.poke(push, 0, bias=bias)
    fit = cell.call(cell.identify, IdentifyDeformation.Request(), 'identify')
    assert fit.success, fit.message
    used = '4 rest frame(s) of this camera' if rest_frames else 'merged rest surface'
    assert f'reference: {used}' in fit.message, fit.message
    errors = []
    for push in pushes[3:]:
        for k in range(3):
            cell.poke(push, k, bias=bias)
            est = cell.estimate_at(push['contact_point'])
            stored = used if rest_frames else "the model's stored reference"
            assert est.success and stored in est.message, est.message
            force = est.wrench.wrench.force
            errors.append(abs(np.linalg.norm([force.x, force.y, force.z])
                              / np.linalg.norm(push['force'][k]) - 1.0))
    if rest_frames:
        assert np.mean(errors) < 0.10 and max(errors) < 0.2, errors
    else:
        assert np.mean(errors) > 0.10, errors


def _lamb_point_model(lamb, version=1, gain=1.0):
    """The learner's point model of the lamb (cropped to the sites), as the learner saves it."""
    response = BakedResponse(depths=lamb['model_depths'],
                             forces=gain * lamb['model_forces'].astype(float),
                             slopes=lamb['model_slopes'], std=lamb['model_std'].astype(float))
    return ContactModel(Surface(lamb['model_points'], lamb['model_normals']), response,
                        float(lamb['model_shape_constant']), version=version)


class Lamb:
    """The lamb's states (``fused_lamb.npz``) on a node holding the learner's point model."""

    def __init__(self, graph, tmp_path):
        self.data = data = _fixture('fused_lamb')
        self.learner = tmp_path / 'learner'
        save_model(_lamb_point_model(data), self.learner)
        node = graph.add(DeformationForceNode(
            context=graph.context,
            parameter_overrides=[Parameter('model_dir', value=str(tmp_path / 'models')),
                                 Parameter('point_model_dir', value=str(self.learner)),
                                 Parameter('point_model_poll', value=0.2),
                                 Parameter('cloud_topic', value=TOPIC),
                                 Parameter('element_size', value=0.006),
                                 Parameter('layers', value=4)]))
        self.cell = cell = Cell(graph, node)
        cell.surface_pub.publish(msg_from_cloud(data['rest_points'],
                                                normals=data['rest_normals'], frame_id='base'))
        graph.wait_for(lambda: node._rest is not None, 30.0, 'rest mesh')
        cell.send_cloud(data['rest_frame'])       # the pushing camera at rest
        assert node._point is not None and node._point.version == 1

    def state(self, i):
        """``(contact point, tip, F/T force, cloud)`` of state ``i``."""
        d, s = self.data, self.data['cloud_start']
        return d['q'][i], d['tip'][i], d['force'][i], d['cloud'][s[i]:s[i + 1]].astype(float)

    def identify(self):
        """Identification pokes at the two sites over the bone, 3 and 5 mm."""
        for i in np.flatnonzero(self.data['site'] != 2):
            self.cell.press(*self.state(i))
        fit = self.cell.call(self.cell.identify, IdentifyDeformation.Request(), 'identify')
        assert fit.success, fit.message
        return fit


def test_the_fused_force_on_a_buried_bone_is_near_the_ft_where_the_fem_is_not(
        ros_graph, tmp_path):
    """The lamb's off-bone push, identified on the two sites over the bone.

    The bone shields the far field under the identification sites, so the FEM reads a stiff
    object and overestimates the off-bone push's force (measured, mesh 6 mm: +76 to +257 %).
    The point model read at the probe tip's depth (calibrated at the identification pushes)
    is near the F/T (+11 to +19 %), and the FEM's cross-validated spread (each site left out)
    gives it the weight. Before issue 18's wiring the node published and served the FEM's.
    """
    lamb = Lamb(ros_graph, tmp_path)
    cell = lamb.cell
    fit = lamb.identify()
    assert 'cross-validated over 2 sites' in fit.message, fit.message
    # what the fusion needs is stored with the model, from the identification pushes only
    stored = load_latest(str(tmp_path / 'models')).fusion
    assert stored.spread_source == 'cross-site' and stored.fem_spread > 0.3
    np.testing.assert_allclose(stored.tips, lamb.data['tip'][:4])
    # ~/force while the held-out push runs (5 mm): the fused force, the F/T check on it
    q, tip, truth, cloud = lamb.state(5)
    cell.press(q, tip, truth, cloud, end=False)
    cell.graph.wait_for(lambda: cell.reports, 20.0, 'consistency report')
    values = dict((v.key, v.value) for v in cell.reports[-1].values)
    assert values['method'] == 'fused', values
    published = cell.forces[-1].wrench.force
    published = np.linalg.norm([published.x, published.y, published.z])
    assert float(values['fused_magnitude_n']) == pytest.approx(published, rel=1e-3)
    fem = float(values['fem_magnitude_n'])
    size = np.linalg.norm(truth)
    assert abs(published / size - 1) < 0.3 and abs(fem / size - 1) > 0.5, (published, fem, size)
    assert 'depth offset' in values['fusion'], values['fusion']
    cell.wrench(np.zeros(3))
    # ~/estimate_force at the 8 mm state's tip: the fused force, and the FEM's beside it
    q, tip, truth, cloud = lamb.state(6)
    cell.press(q, tip, truth, cloud)
    fused = cell.estimate_at(q, tip=tip)
    assert fused.success and fused.method == 'fused', fused.message
    f = fused.wrench.wrench.force
    size = np.linalg.norm(truth)
    magnitude = np.linalg.norm([f.x, f.y, f.z])
    assert abs(magnitude / size - 1) < 0.3, (magnitude, size)
    assert abs(fused.fem_magnitude / size - 1) > 0.5 and fused.point_weight > 0.5
    assert abs(fused.point_magnitude / size - 1) < 0.3 and fused.point_magnitude_std > 0
    assert np.dot([f.x, f.y, f.z], truth) > 0.9 * magnitude * size   # the FEM's direction
    plain = cell.estimate_at(q)
    assert plain.success and plain.method == 'fem' and np.isnan(plain.point_magnitude)
    assert plain.fem_magnitude == pytest.approx(fused.fem_magnitude, rel=1e-6)


def test_bad_tips_and_a_corrupt_point_model_are_refused_and_the_node_keeps_serving(ros_graph,
                                                                                   tmp_path):
    lamb = Lamb(ros_graph, tmp_path)
    cell, node = lamb.cell, lamb.cell.node
    lamb.identify()
    q, tip, truth, cloud = lamb.state(5)
    cell.press(q, tip, truth, cloud)
    for bad, reason in (([np.nan, 0.0, 0.04], 'finite'),
                        (tip + [0.0, 0.0, 0.02], 'above the scanned surface'),
                        (tip + [0.3, 0.0, 0.0], 'scan points within')):
        refused = cell.estimate_at(q, tip=bad)
        assert not refused.success and reason in refused.message, refused.message
    assert cell.estimate_at(q, tip=tip).method == 'fused'
    # the learner's newest file is truncated: quarantined and logged, the last good one kept
    good = (lamb.learner / 'model-v000001.npz').read_bytes()
    (lamb.learner / 'model-v000002.npz').write_bytes(good[:len(good) // 2])
    cell.graph.wait_for(lambda: (lamb.learner / QUARANTINE / 'model-v000002.npz').exists(),
                        10.0, 'the corrupt file quarantined')
    assert node._point.version == 1
    after = cell.estimate_at(q, tip=tip)
    assert after.success and after.method == 'fused', after.message
    # a newer good one (a refit) is picked up
    save_model(_lamb_point_model(lamb.data, version=3, gain=1.02), lamb.learner)
    cell.graph.wait_for(lambda: node._point.version == 3, 10.0, 'point model v3')
    assert cell.estimate_at(q, tip=tip).success
