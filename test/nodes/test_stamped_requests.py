"""Stamped contact requests, the flat mesh form and the Poke constants (issue 21).

A planner's frame mistake used to be silent: the request carried a bare Pose with ``base``
implied. Now the request carries a header; a frame the model is not in is refused with a reason.
"""

import array

import numpy as np
import pytest
from geometry_msgs.msg import Vector3
from pointforce_interfaces.action import Poke
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from msg_adapters.geometry import mesh_to_flat, mesh_to_msg, pose_to_msg, to_point
from pointforce_ros.bringup.bench_ros import round_trip
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import Pose

pytestmark = pytest.mark.ros


def test_a_request_in_another_frame_is_refused_with_the_reason(ros_graph, tmp_path):
    save_model(patch_contact_model(spacing=0.003), tmp_path / 'models')
    ros_graph.add(ContactWrenchNode(context=ros_graph.context, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'models'))]))
    probe = ros_graph.add(Node('frame_probe', context=ros_graph.context))
    single = probe.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    batch = probe.create_client(ContactWrenchBatch, '/contact_wrench/contact_wrench_batch')
    assert single.wait_for_service(timeout_sec=30.0) and batch.wait_for_service(timeout_sec=30.0)
    common = dict(mesh=mesh_to_msg(icosphere(0.02, 1)), approach=Vector3(x=0.0, y=0.0, z=-1.0),
                  torque_centre=to_point([0.5, 0.0, 0.06]))
    pose = pose_to_msg(Pose(position=[0.5, 0.0, 0.058]))
    answers = {}
    for frame in ('', 'base', 'world', 'tool0'):
        _, resp = round_trip(single, ContactWrench.Request(
            header=Header(frame_id=frame), pose=pose, **common), 20, frame)
        _, resp_batch = round_trip(batch, ContactWrenchBatch.Request(
            header=Header(frame_id=frame), poses=[pose, pose], **common), 20, frame)
        answers[frame] = (resp, resp_batch)
    for frame in ('', 'base'):
        resp, resp_batch = answers[frame]
        assert resp.success and resp_batch.success, (resp.message, resp_batch.message)
        assert resp.wrench.force.z > 0
        assert np.isclose(resp_batch.wrenches[0].force.z, resp.wrench.force.z)
    for frame in ('world', 'tool0'):
        for resp in answers[frame]:
            assert not resp.success
            assert 'header.frame_id' in resp.message and repr(frame) in resp.message
            assert "'base'" in resp.message


def test_poke_outcomes_and_phases_are_interface_constants():
    outcomes = {Poke.Result.OUTCOME_FORCE_LIMIT, Poke.Result.OUTCOME_DEPTH_LIMIT,
                Poke.Result.OUTCOME_CANCELED, Poke.Result.OUTCOME_ABORTED}
    assert outcomes == {'force_limit', 'depth_limit', 'canceled', 'aborted'}
    phases = [Poke.Feedback.PHASE_APPROACH, Poke.Feedback.PHASE_TARE, Poke.Feedback.PHASE_PUSH,
              Poke.Feedback.PHASE_HOLD, Poke.Feedback.PHASE_RETRACT]
    assert phases == ['approach', 'tare', 'push', 'hold', 'retract']


def test_the_flat_mesh_form_answers_as_the_mesh_message(ros_graph, tmp_path):
    save_model(patch_contact_model(spacing=0.003), tmp_path / 'models')
    ros_graph.add(ContactWrenchNode(context=ros_graph.context, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'models'))]))
    probe = ros_graph.add(Node('flat_probe', context=ros_graph.context))
    single = probe.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    batch = probe.create_client(ContactWrenchBatch, '/contact_wrench/contact_wrench_batch')
    assert single.wait_for_service(timeout_sec=30.0) and batch.wait_for_service(timeout_sec=30.0)
    sphere = icosphere(0.02, 2)
    vertices, triangles = mesh_to_flat(sphere)
    common = dict(approach=Vector3(x=0.0, y=0.0, z=-1.0),
                  torque_centre=to_point([0.5, 0.0, 0.06]))
    poses = [pose_to_msg(Pose(position=[0.5 + dx, 0.0, 0.058])) for dx in (0.0, 0.004)]

    def call(**fields):
        return round_trip(single, ContactWrench.Request(pose=poses[0], **common, **fields),
                          20, 'contact_wrench')[1]

    def call_batch(**fields):
        return round_trip(batch, ContactWrenchBatch.Request(poses=poses, **common, **fields),
                          20, 'contact_wrench_batch')[1]
    as_msg = call(mesh=mesh_to_msg(sphere))
    flat = call(mesh_vertices=vertices, mesh_triangles=triangles)
    assert as_msg.success and flat.success, (as_msg.message, flat.message)
    assert as_msg.wrench.force.z > 0 and flat.wrench == as_msg.wrench
    assert flat.contact_count == as_msg.contact_count
    batch_msg = call_batch(mesh=mesh_to_msg(sphere))
    batch_flat = call_batch(mesh_vertices=vertices, mesh_triangles=triangles)
    assert batch_flat.success and batch_flat.wrenches == batch_msg.wrenches
    both = call(mesh=mesh_to_msg(sphere), mesh_vertices=vertices, mesh_triangles=triangles)
    assert not both.success and 'given twice' in both.message
    ragged = call(mesh_vertices=vertices[:-1], mesh_triangles=triangles)
    assert not ragged.success and 'multiples of 3' in ragged.message
    bad_index = array.array('I', triangles)
    bad_index[0] = 10_000
    outside = call_batch(mesh_vertices=vertices, mesh_triangles=bad_index)
    assert not outside.success and outside.message
