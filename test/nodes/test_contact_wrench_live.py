"""contact_wrench's run-time parameters take effect (or are refused) and ~/last_query (issue 21).

Each set is checked by what the service then does with a request, not by the stored value.
"""

import time

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import Vector3
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.geometry import mesh_to_flat, mesh_to_msg, pose_to_msg, to_point
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import ContactModel, save_model
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode, LATCHED, TIMING_PERIOD
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import ContactQuery, Pose

from test_contact_wrench_node import _request, SPHERE  # noqa: I100 - the same fixtures
from test_contact_wrench_node import served  # noqa: F401,F811 - the fixture

pytestmark = pytest.mark.ros


def _set(graph, client_node, name, value):
    client = client_node.create_client(SetParameters, '/contact_wrench/set_parameters')
    assert client.wait_for_service(timeout_sec=30.0)
    request = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
    return graph.wait_future(client.call_async(request), 20, name).results[0]


def _batch(n, depth=0.003):
    vertices, triangles = mesh_to_flat(SPHERE)
    xs = np.linspace(0.49, 0.51, n)
    return ContactWrenchBatch.Request(
        poses=[pose_to_msg(Pose(position=[x, 0.0, 0.06 - depth])) for x in xs],
        approach=Vector3(x=0.0, y=0.0, z=-1.0), torque_centre=to_point([0.5, 0.0, 0.06]),
        mesh_vertices=vertices, mesh_triangles=triangles)


def _call(graph, client, request):
    return graph.wait_future(client.call_async(request), 30, 'contact request')


def test_request_limits_apply_to_the_next_request(served):  # noqa: F811
    graph, node, client_node, single, batch, model, _ = served
    assert _call(graph, batch, _batch(5)).success
    assert _set(graph, client_node, 'max_batch', 3).successful
    refused = _call(graph, batch, _batch(5))
    assert not refused.success and 'max_batch 3' in refused.message
    assert _call(graph, batch, _batch(3)).success
    # work: 5 poses x ~1200 samples passed; at most 1000 sample-poses refuses even one pose
    assert _set(graph, client_node, 'max_sample_poses', 1000).successful
    refused = _call(graph, single, _request(0.003)[0])
    assert not refused.success and 'request too large' in refused.message
    assert _set(graph, client_node, 'max_sample_poses', 100_000_000).successful
    # depth: 3 mm passed; a 1 mm limit refuses it
    assert _call(graph, single, _request(0.003)[0]).success
    assert _set(graph, client_node, 'max_depth', 0.001).successful
    refused = _call(graph, single, _request(0.003)[0])
    assert not refused.success and 'limit 0.001 m' in refused.message
    assert _set(graph, client_node, 'max_depth', 0.1).successful
    # torque arm and distance: a centre 0.3 m above the pose passed; limits below refuse it
    far, _ = _request(0.003)
    far.torque_centre.z = 0.36
    assert _call(graph, single, far).success
    assert _set(graph, client_node, 'max_torque_arm', 0.2).successful
    refused = _call(graph, single, far)
    assert not refused.success and 'limit 0.2 m' in refused.message
    assert _set(graph, client_node, 'max_torque_arm', 5.0).successful
    assert _set(graph, client_node, 'max_distance', 0.2).successful
    refused = _call(graph, single, far)
    assert not refused.success and 'torque_centre' in refused.message
    assert _set(graph, client_node, 'max_distance', 10.0).successful
    # memory: at 16 MiB a pose of a 40 mm sphere sampled at 0.5 mm (~90 000 samples, ~22 MiB)
    # no longer fits
    big, _ = _request(0.003)
    big.mesh = mesh_to_msg(icosphere(0.04, 2))
    big.pose.position.z = 0.08 - 0.003
    assert _set(graph, client_node, 'sample_spacing', 0.0005).successful
    assert _call(graph, single, big).success
    assert _set(graph, client_node, 'max_request_memory', 16.0).successful
    refused = _call(graph, single, big)
    assert not refused.success and 'limit of 16 MiB' in refused.message
    # time budget: a batch that needs more than 10 ms is refused between its chunks
    assert _set(graph, client_node, 'max_request_memory', 256.0).successful
    assert _set(graph, client_node, 'sample_spacing', 0.003).successful
    assert _set(graph, client_node, 'max_batch', 20000).successful
    assert _call(graph, batch, _batch(3000)).success
    assert _set(graph, client_node, 'max_request_seconds', 0.01).successful
    refused = _call(graph, batch, _batch(3000))
    assert not refused.success and 'budget' in refused.message
    # out of bounds and read-only sets are refused; the node keeps its values
    assert not _set(graph, client_node, 'max_batch', 0).successful
    assert not _set(graph, client_node, 'model_dir', '/tmp').successful
    assert node.model_dir != '/tmp'


@pytest.mark.parametrize('name, value, setting, bad, reason', [
    ('sample_spacing', 0.0015, 'spacing', 1.0, None),       # out of bounds
    ('neighbour_weights', 'smooth', 'neighbours', 'cubic',
     "neighbour_weights: must be one of ('equal', 'smooth')")])
def test_a_simulator_setting_rebuilds_the_simulator_for_the_next_request(
        served, name, value, setting, bad, reason):  # noqa: F811
    graph, node, client_node, single, _, model, _ = served
    request, pose = _request(0.003, x=0.5007, y=0.0011)   # off the patch's grid
    before = _call(graph, single, request)
    assert _set(graph, client_node, name, value).successful
    after = _call(graph, single, request)
    assert before.success and after.success
    for settings, response in (({}, before), ({setting: value}, after)):
        core = WrenchServer(**settings)
        core.swap(model)
        direct, _ = core.answer(ContactQuery(mesh=SPHERE, poses=(pose,), approach=[0, 0, -1],
                                             torque_centre=pose.position))
        assert response.wrench.force.z == pytest.approx(direct.wrench.force[2], rel=1e-12)
    assert abs(after.wrench.force.z - before.wrench.force.z) > 1e-4 * before.wrench.force.z
    refused = _set(graph, client_node, name, bad)
    assert not refused.successful and (reason is None or reason in refused.reason)
    assert _call(graph, single, request).wrench.force.z == after.wrench.force.z


def test_series_compliance_and_hold_time_apply_to_the_next_request(ros_graph, tmp_path):
    clean = patch_contact_model(spacing=0.003)
    effects = {'series_compliance': {'compliance': 2e-4}, 'viscoelastic': {'g': 0.25, 'tau': 2.0}}
    save_model(ContactModel(surface=clean.surface, response=clean.response, version=3,
                            shape_constant=clean.shape_constant, effects=effects),
               tmp_path / 'models')
    ros_graph.add(ContactWrenchNode(context=ros_graph.context, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'models'))]))
    client_node = ros_graph.add(Node('live_effects', context=ros_graph.context))
    single = client_node.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    assert single.wait_for_service(timeout_sec=30.0)
    request, pose = _request(0.003)
    compliant = _call(ros_graph, single, request).wrench.force.z
    assert _set(ros_graph, client_node, 'series_compliance', False).successful
    plain = _call(ros_graph, single, request).wrench.force.z
    reference = WrenchServer()
    reference.swap(clean)
    direct, _ = reference.answer(ContactQuery(mesh=SPHERE, poses=(pose,), approach=[0, 0, -1],
                                              torque_centre=pose.position))
    assert plain == pytest.approx(direct.wrench.force[2], rel=1e-12)
    assert compliant < 0.95 * plain
    assert _set(ros_graph, client_node, 'hold_time', 1.0).successful
    relaxed = _call(ros_graph, single, request).wrench.force.z
    assert relaxed == pytest.approx(plain * (1 - 0.25 * (1 - np.exp(-0.5))), rel=1e-9)


def test_poll_period_applies_to_the_next_poll(served):  # noqa: F811
    graph, node, client_node, single, _, model, tmp_path = served
    assert _set(graph, client_node, 'poll_period', 60.0).successful
    newer = ContactModel(surface=model.surface, response=model.response,
                         version=model.version + 1, shape_constant=model.shape_constant)
    save_model(newer, tmp_path / 'models')
    time.sleep(1.0)
    assert node.server.version == model.version      # not polled for a minute
    assert _set(graph, client_node, 'poll_period', 0.1).successful
    graph.wait_for(lambda: node.server.version == newer.version, 5, 'the newer model')


def test_last_query_markers_show_the_answer_and_are_drawn_off_the_hot_path(
        served):  # noqa: F811
    graph, node, client_node, single, _, _, _ = served
    received = []
    client_node.create_subscription(MarkerArray, '/contact_wrench/last_query', received.append,
                                    LATCHED)
    request, pose = _request(0.004)
    response = _call(graph, single, request)
    assert response.success and response.contact_count > 3
    graph.wait_for(lambda: received, 5, 'markers')
    markers = {m.ns: m for m in received[-1].markers if m.action == Marker.ADD}
    assert received[-1].markers[0].action == Marker.DELETEALL
    assert len(markers['contact_points'].points) == response.contact_count
    arrow = markers['wrench'].points
    force = np.array([response.wrench.force.x, response.wrench.force.y,
                      response.wrench.force.z])
    np.testing.assert_allclose([arrow[0].x, arrow[0].y, arrow[0].z], pose.position, atol=1e-12)
    np.testing.assert_allclose([arrow[1].x - arrow[0].x, arrow[1].y - arrow[0].y,
                                arrow[1].z - arrow[0].z], 0.01 * force, atol=1e-12)
    # nothing new answered: nothing republished at 20 Hz
    assert _set(graph, client_node, 'marker_rate', 20.0).successful
    count = node.markers_published
    time.sleep(0.5)
    assert node.markers_published == count
    # the arrow scale applies to the next drawing
    assert _set(graph, client_node, 'marker_force_scale', 0.05).successful
    received.clear()
    assert _call(graph, single, request).success
    graph.wait_for(lambda: received, 5, 'new markers')
    arrow = {m.ns: m for m in received[-1].markers}['wrench'].points
    assert arrow[1].z - arrow[0].z == pytest.approx(0.05 * force[2], rel=1e-9)
    # a slow rate: an answer is drawn only at the next tick
    assert _set(graph, client_node, 'marker_rate', 0.2).successful
    count = node.markers_published
    assert _call(graph, single, _request(0.002)[0]).success
    time.sleep(1.0)
    assert node.markers_published == count


def test_service_timing_reports_where_the_answers_spent_their_time(served):  # noqa: F811
    graph, node, client_node, single, batch, _, _ = served
    received = []
    client_node.create_subscription(DiagnosticStatus, '/contact_wrench/service_timing',
                                    received.append, 10)
    for depth in (0.002, 0.003, 0.004):
        assert _call(graph, single, _request(depth)[0]).success
    assert _call(graph, batch, _batch(40)).success
    graph.wait_for(lambda: received, 2 * TIMING_PERIOD + 5, 'a service timing report')
    values = {kv.key: float(kv.value) for kv in received[-1].values}
    single_name = '/contact_wrench/contact_wrench'
    batch_name = f'{single_name}_batch'
    assert values[f'{single_name} answers'] >= 3 and values[f'{batch_name} answers'] >= 1
    assert values['requests_taken'] == node._service_loop.requests_taken
    # a 40-pose batch's callback outlasts a single query's; each stage is timed
    assert values[f'{batch_name} callback_p50_ms'] > values[f'{single_name} callback_p50_ms']
    for name in (single_name, batch_name):
        for stage in ('take', 'callback', 'send'):
            assert 0.0 < values[f'{name} {stage}_p50_ms'] <= values[f'{name} {stage}_p99_ms']
    # nothing answered since: no new report
    count = len(received)
    time.sleep(TIMING_PERIOD + 1.0)
    assert len(received) == count


def test_hot_wait_keeps_the_service_thread_polling_after_an_answer_then_not(served):  # noqa: F811
    """Issue 21: ``hot_wait`` ms of polling after each answer (an idle vCPU answers its next
    request up to 2x slower); set at run time, it applies from the next answer."""
    graph, node, client_node, single, _, _, _ = served
    loop = node._service_loop
    request = _request(0.003)[0]
    polls = {}
    for hot in (100.0, 0.0):
        assert _set(graph, client_node, 'hot_wait', hot).successful
        before = loop.polls
        assert _call(graph, single, request).success   # the window opens after this answer
        time.sleep(0.3)
        polls[hot] = loop.polls - before
    # 100 ms of zero-timeout waits of ~60 us each: about 1600 (a loaded machine, fewer)
    assert polls[100.0] > 50 and polls[0.0] == 0, polls
