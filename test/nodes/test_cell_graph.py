"""The product nodes as one graph (issue 21): namespaced cells, matching QoS, RViz markers.

* Two cells under ``/cell1`` and ``/cell2`` on one domain: each learner gets its own capture
  node's surface and each capture node its own camera's clouds, never the other cell's.
* The five nodes together: every publisher/subscriber pair they form has compatible QoS (no
  incompatible-QoS event), and the learner's record-from-topics mode rebuilds a poke that a live
  poke server streams.
* The learner's latched ``~/markers``: the surface coloured by the learned force, and arrows at
  its suggested next pokes.
"""

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pointforce_interfaces.action import Poke
from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import SuggestPoke
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_check_compatible, QoSCompatibility, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.interfaces import poke_goal_to_msg
from msg_adapters.pointcloud2 import msg_from_cloud
from pointforce_ros.drivers.ur_arm import ArmSample, PushResult
from pointforce_ros.model.files import load_model, save_surface
from pointforce_ros.nodes.cloud_capture import CloudCaptureNode
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.nodes.deformation_force import DeformationForceNode
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.nodes.stiffness_learner import LATCHED, StiffnessLearnerNode
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.types import PokeGoal, Surface

from idle_arm import IdleArm  # noqa: I100 - the test helper beside this file

pytestmark = pytest.mark.ros
PRODUCT = {'cloud_capture', 'poke_server', 'stiffness_learner', 'contact_wrench',
           'deformation_force'}


def _plane_cloud(half: float) -> PointCloud2:
    """A flat square of side ``2 half`` m, 2 mm grid, 0.46 m in front of the camera.

    Under cloud_capture's default ``camera_pose`` (0.5 m above (0.5, 0), looking down) it lies
    at z = 0.04 m in ``base``, inside the default ROI.
    """
    g = np.arange(-half, half + 1e-9, 0.002)
    xs, ys = np.meshgrid(g, g)
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.46)])
    return msg_from_cloud(points, frame_id='camera_depth_optical_frame')


def _call(graph, client, what):
    assert client.wait_for_service(timeout_sec=30.0), f'{what} service missing'
    return graph.wait_future(client.call_async(Trigger.Request()), 30, what)


def test_two_namespaced_cells_on_one_domain_keep_their_own_data(ros_graph, tmp_path):
    cells, pokers = {}, {}
    for ns, half in (('/cell1', 0.02), ('/cell2', 0.012)):
        work = tmp_path / ns.strip('/')
        capture = ros_graph.add(CloudCaptureNode(
            context=ros_graph.context, namespace=ns, parameter_overrides=[
                Parameter('surface_file', value=str(work / 'surface.npz'))]))
        learner = ros_graph.add(StiffnessLearnerNode(
            context=ros_graph.context, namespace=ns, parameter_overrides=[
                Parameter('store_dir', value=str(work / 'pokes')),
                Parameter('model_dir', value=str(work / 'models')),
                Parameter('poll_period', value=600.0)]))
        pokers[ns] = ros_graph.add(PokeServerNode(
            arm_factory=StreamingArm, context=ros_graph.context, namespace=ns,
            parameter_overrides=[Parameter('store_dir', value=str(work / 'poke_store'))]))
        cells[ns] = (capture, learner, half)
    probe = ros_graph.add(Node('cells_probe', context=ros_graph.context))
    for ns, (capture, learner, half) in cells.items():
        camera = probe.create_publisher(PointCloud2, f'{ns}/camera/camera/depth/color/points',
                                        10)
        ros_graph.wait_for(lambda: camera.get_subscription_count() == 1, 10,
                           f'{ns} capture node on its camera topic')
        deadline = time.monotonic() + 10.0
        while capture._latest is None and time.monotonic() < deadline:
            camera.publish(_plane_cloud(half))
            time.sleep(0.1)
        result = _call(ros_graph, probe.create_client(Trigger, f'{ns}/cloud_capture/capture'),
                       f'{ns} capture')
        assert result.success, result.message
    for ns, (capture, learner, half) in cells.items():
        ros_graph.wait_for(lambda: learner.learner is not None, 15, f'{ns} learner surface')
    size = {ns: len(capture.surface) for ns, (capture, _, _) in cells.items()}
    assert size['/cell1'] > 1.5 * size['/cell2']          # two distinguishable surfaces
    for ns, (capture, learner, half) in cells.items():
        ros_graph.wait_for(lambda: pokers[ns].surface is not None, 10, f'{ns} poke server surface')
    time.sleep(1.0)   # a cross-talking surface would have arrived by now
    for ns, (capture, learner, half) in cells.items():
        assert len(pokers[ns].surface) == size[ns], ns
        assert len(learner.learner.surface) == size[ns], ns
        np.testing.assert_allclose(learner.learner.surface.points, capture.surface.points,
                                   atol=1e-6)
    # the cells' topics really are apart: nothing on the absolute (root) names
    names = {name for name, _ in probe.get_topic_names_and_types()}
    assert '/cell1/cloud_capture/surface' in names and '/cell2/cloud_capture/surface' in names
    assert '/cloud_capture/surface' not in names


class StreamingArm(IdleArm):
    """Stands in for UrArm and streams its samples through the driver's sample callback.

    Pushes ``samples`` samples into a 1000 N/m spring 8 mm below the stand-off, with wall-clock
    stamps, so the poke server publishes ``tcp_pose`` and ``wrench`` as with a real arm.
    """

    def __init__(self, host, samples=120):
        super().__init__(host)
        self.samples = samples
        self.callbacks = []

    def add_sample_callback(self, callback):
        self.callbacks.append(callback)

    def push_until(self, standoff, direction, *, force_limit, travel_limit, speed,
                   approach_speed, retract_speed, cancel, max_force, max_travel,
                   phase=None):
        n = self.samples
        travel = np.linspace(0.0, travel_limit, n)
        direction = np.asarray(direction, float)
        pose = np.tile(np.asarray(standoff, float), (n, 1))
        pose[:, :3] += travel[:, None] * direction
        force = 1000.0 * np.maximum(travel - 0.004, 0.0)
        wrench = np.zeros((n, 6))
        wrench[:, :3] = -force[:, None] * direction
        t = np.round((time.time() + np.arange(n) * 0.004) * 1e6) / 1e6
        for i in range(n):
            for callback in self.callbacks:
                callback(ArmSample(t_wall=float(t[i]), t_controller=float(t[i] - t[0]),
                                   pose=pose[i], wrench=wrench[i]))
            time.sleep(0.001)
        return PushResult(t_wall=t, t_controller=t - t[0], tcp_pose=pose, wrench=wrench,
                          outcome='depth_limit', peak_force=float(force.max()),
                          max_travel=float(travel.max()), standoff=np.asarray(standoff, float),
                          direction=direction)


def _incompatible_pairs(probe):
    """(topic, publisher node, subscriber node, reason) of every product pair that cannot match."""
    bad = []
    for topic, _ in probe.get_topic_names_and_types():
        pubs = [p for p in probe.get_publishers_info_by_topic(topic) if p.node_name in PRODUCT]
        subs = [s for s in probe.get_subscriptions_info_by_topic(topic)
                if s.node_name in PRODUCT]
        for pub in pubs:
            for sub in subs:
                compatible, reason = qos_check_compatible(pub.qos_profile, sub.qos_profile)
                if compatible == QoSCompatibility.ERROR:
                    bad.append((topic, pub.node_name, sub.node_name, reason))
    return bad


def test_five_nodes_match_qos_and_the_learner_records_a_live_poke(ros_graph, tmp_path):
    ctx = ros_graph.context
    ros_graph.add(CloudCaptureNode(context=ctx, parameter_overrides=[
        Parameter('surface_file', value=str(tmp_path / 'surface.npz'))]))
    ros_graph.add(PokeServerNode(arm_factory=StreamingArm, context=ctx, parameter_overrides=[
        Parameter('store_dir', value=str(tmp_path / 'pokes'))]))
    learner = ros_graph.add(StiffnessLearnerNode(context=ctx, parameter_overrides=[
        Parameter('store_dir', value=str(tmp_path / 'recorded')),
        Parameter('model_dir', value=str(tmp_path / 'models')),
        Parameter('record_topics', value=True),
        Parameter('poll_period', value=600.0)]))
    ros_graph.add(ContactWrenchNode(context=ctx))
    ros_graph.add(DeformationForceNode(context=ctx, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'deformation')),
        Parameter('point_model_dir', value='')]))
    probe = ros_graph.add(Node('qos_probe', context=ctx))
    health = {}
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda m: health.update(
        (s.name, s) for s in m.status), 50)

    def matched():
        subs = {(s.node_name, t) for t in ('/poke_server/tcp_pose', '/poke_server/wrench',
                                           '/poke_server/poke_record', '/cloud_capture/surface',
                                           '/stiffness_learner/model',
                                           '/poke_server/poke_landed',
                                           '/cloud_capture/camera_pose', '/tf', '/tf_static')
                for s in probe.get_subscriptions_info_by_topic(t)}
        return {('stiffness_learner', '/poke_server/tcp_pose'),
                ('stiffness_learner', '/poke_server/wrench'),
                ('stiffness_learner', '/poke_server/poke_record'),
                ('stiffness_learner', '/cloud_capture/surface'),
                ('poke_server', '/cloud_capture/surface'),
                ('contact_wrench', '/stiffness_learner/model'),
                ('deformation_force', '/poke_server/tcp_pose'),
                ('deformation_force', '/poke_server/wrench'),
                ('deformation_force', '/poke_server/poke_landed'),
                ('deformation_force', '/cloud_capture/surface'),
                ('deformation_force', '/cloud_capture/camera_pose'),
                ('deformation_force', '/stiffness_learner/model'),
                ('cloud_capture', '/tf'), ('cloud_capture', '/tf_static'),
                ('deformation_force', '/tf'), ('deformation_force', '/tf_static')} <= subs
    ros_graph.wait_for(matched, 15, 'the five nodes discovered')
    assert _incompatible_pairs(probe) == []
    # each node reports its health on /diagnostics under a name of its own (1 Hz)
    names = {'cloud_capture: surface capture', 'poke_server: arm and F/T stream',
             'stiffness_learner: stiffness learner', 'contact_wrench: contact service',
             'deformation_force: deformation model'}
    ros_graph.wait_for(lambda: names <= set(health), 10, 'five health reports')
    assert all(health[name].message for name in names)
    assert health['contact_wrench: contact service'].level == DiagnosticStatus.ERROR  # no model
    # a stand-in driver without the fault and loss records (arm_factory) is no error itself
    assert 'health unknown' not in health['poke_server: arm and F/T stream'].message
    client = ActionClient(probe, Poke, '/poke_server/poke')
    assert client.wait_for_server(timeout_sec=30.0)
    goal = poke_goal_to_msg(PokeGoal(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0],
                                     force_limit=3.0, depth_limit=0.008, speed=0.005,
                                     standoff=0.008))
    handle = ros_graph.wait_future(client.send_goal_async(goal), 15, 'goal response')
    assert handle.accepted
    result = ros_graph.wait_future(handle.get_result_async(), 30, 'poke result').result
    assert result.poke_id
    ros_graph.wait_for(lambda: result.poke_id in PokeStore(tmp_path / 'recorded').ids(), 30,
                       'the poke rebuilt from the topics')
    original = PokeStore(tmp_path / 'pokes').get(result.poke_id)
    rebuilt = PokeStore(tmp_path / 'recorded').get(result.poke_id)
    assert len(rebuilt) == len(original) == result.samples
    np.testing.assert_allclose(rebuilt.wrench, original.wrench, atol=1e-6)
    assert learner.incompatible_qos == []
    # the watch is live: a best-effort writer on a reliable input is reported, not silent
    probe.create_publisher(String, '/poke_server/poke_landed',
                           QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
    ros_graph.wait_for(lambda: learner.incompatible_qos, 10, 'incompatible-QoS event')
    assert learner.incompatible_qos[0][0] == 'poke_server/poke_landed'


def _learner_with_model(graph, tmp_path, **params):
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 15), np.linspace(-0.035, 0.035, 15))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    save_surface(Surface(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1))),
                 tmp_path / 'surface.npz')
    obj = halfspace_object(HalfSpaceContact(z0=0.04, ripple=0.3),
                           region=((0.47, 0.53), (-0.03, 0.03)))
    store = PokeStore(tmp_path / 'pokes')
    for record in simulate_campaign(obj, load_scenario('clean'), count=4, seed=3,
                                    force_limit=3.0, depth_limit=0.01, speed=0.004, gap=0.5):
        store.add(record)
    overrides = [Parameter('store_dir', value=str(tmp_path / 'pokes')),
                 Parameter('model_dir', value=str(tmp_path / 'models')),
                 Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
                 Parameter('poll_period', value=600.0)]
    overrides += [Parameter(k, value=v) for k, v in params.items()]
    return graph.add(StiffnessLearnerNode(context=graph.context, parameter_overrides=overrides))


def test_learner_publishes_latched_stiffness_and_suggestion_markers(ros_graph, tmp_path):
    _learner_with_model(ros_graph, tmp_path, marker_depth=0.004, marker_suggestions=3)
    probe = ros_graph.add(Node('marker_probe', context=ros_graph.context))
    statuses, arrays = [], []
    probe.create_subscription(ModelStatus, '/stiffness_learner/model', statuses.append, LATCHED)
    ros_graph.wait_for(lambda: statuses and statuses[-1].version == 4, 30, 'model v4')
    # a late joiner (RViz opened after the fit) still gets the array: latched
    probe.create_subscription(MarkerArray, '/stiffness_learner/markers', arrays.append, LATCHED)
    ros_graph.wait_for(lambda: arrays, 10, 'latched markers')
    markers = arrays[-1].markers
    assert markers[0].action == Marker.DELETEALL
    by_ns = {}
    for m in markers[1:]:
        by_ns.setdefault(m.ns, []).append(m)
        assert m.header.frame_id == 'base'
    model = load_model(statuses[-1].model_path)
    n = len(model.surface)
    (cloud,) = by_ns['stiffness']
    assert cloud.type == Marker.SPHERE_LIST and len(cloud.points) == len(cloud.colors) == n
    forces = model.response.force(np.arange(n), np.full(n, 0.004))
    red = np.array([c.r for c in cloud.colors])
    blue = np.array([c.b for c in cloud.colors])
    assert np.ptp(forces) > 0
    # colour follows the learned force: red for the stiffest, blue for the softest points
    assert red[np.argmax(forces)] > 0.9 and blue[np.argmin(forces)] > 0.9
    assert np.corrcoef(red - blue, forces)[0, 1] > 0.95
    arrows = by_ns['suggested_pokes']
    assert len(arrows) == 3 and all(a.type == Marker.ARROW for a in arrows)
    tips = np.array([[a.points[1].x, a.points[1].y, a.points[1].z] for a in arrows])
    gaps = np.linalg.norm(tips[:, None] - model.surface.points[None], axis=2).min(axis=1)
    assert gaps.max() < 1e-6              # each arrow ends on a surface point
    # the arrows are the pokes ~/suggest_poke suggests next, in its frame
    client = probe.create_client(SuggestPoke, '/stiffness_learner/suggest_poke')
    assert client.wait_for_service(timeout_sec=30.0)
    answer = ros_graph.wait_future(client.call_async(SuggestPoke.Request(count=3)), 20,
                                   'suggest_poke')
    assert answer.success and answer.header.frame_id == arrows[0].header.frame_id
    np.testing.assert_allclose(tips, [[p.x, p.y, p.z] for p in answer.points], atol=1e-9)
    assert '4.0 mm' in by_ns['legend'][0].text
