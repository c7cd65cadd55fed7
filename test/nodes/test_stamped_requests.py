"""Stamped contact requests, the flat mesh form and the Poke constants (issue 21).

A planner's frame mistake used to be silent: the request carried a bare Pose with ``base``
implied. Now the request carries a header; a frame the tf tree cannot place in the model's
frame is refused with a reason, and one it can (session 41) is answered in that frame.
"""

import array
import dataclasses
import threading
import time

import numpy as np
import pytest
from geometry_msgs.msg import Vector3
from pointforce_interfaces.action import Poke
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rclpy.node import Node
from rclpy.parameter import Parameter
from scipy.spatial.transform import Rotation
from std_msgs.msg import Header
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import (mesh_to_flat, mesh_to_msg, pose_to_msg, sec_to_stamp,
                                   to_point, transform_to_msg, vec)
from pointforce_ros.bringup.bench_ros import round_trip
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.nodes.common import TF_QOS, TF_STATIC_QOS
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


def _wrench_rows(wrenches):
    return np.array([np.concatenate([vec(w.force), vec(w.torque)]) for w in wrenches])


@pytest.mark.parametrize('turn', ['quarter', 'any'])
def test_a_request_in_a_frame_tf_places_is_answered_in_that_frame(ros_graph, tmp_path, turn):
    """Session 41: a planner's query in ``world`` (MoveIt's planning frame) was refused; with
    ``world <- base`` on /tf_static it is moved into ``base`` and answered in ``world``."""
    base = patch_contact_model(spacing=0.003)   # with a spread, so wrench_std is answered
    save_model(dataclasses.replace(base, meta={**base.meta, 'shape_cov': [[0.04, 0.5],
                                                                          [0.5, 400.0]],
                                               'relative_std': 0.05, 'lateral_std': 0.02}),
               tmp_path / 'models')
    node = ros_graph.add(ContactWrenchNode(context=ros_graph.context, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'models'))]))
    probe = ros_graph.add(Node('world_probe', context=ros_graph.context))
    world_from_base = np.eye(4)
    world_from_base[:3, :3] = (Rotation.from_euler('z', 90, degrees=True) if turn == 'quarter'
                               else Rotation.random(random_state=7)).as_matrix()
    world_from_base[:3, 3] = [1.2, -0.4, 0.75]
    probe.create_publisher(TFMessage, '/tf_static', TF_STATIC_QOS).publish(
        TFMessage(transforms=[transform_to_msg(world_from_base, 'world', 'base')]))
    ros_graph.wait_for(lambda: node.tf.knows('world'), 10, 'world <- base on /tf_static')
    single = probe.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    batch = probe.create_client(ContactWrenchBatch, '/contact_wrench/contact_wrench_batch')
    assert single.wait_for_service(timeout_sec=30.0) and batch.wait_for_service(timeout_sec=30.0)
    rot = world_from_base[:3, :3]
    poses = [np.eye(4), np.eye(4)]
    # off the surface grid's symmetries: there a sample point sits on a cell boundary, and the
    # 1e-16 round-off of a frame change moves the answer by up to 1 % (0.503, 0.002, 0.057
    # with a 10 degree tilt: 1.9273 N, 1.9116 N 1e-15 m away)
    poses[0][:3, 3], poses[1][:3, 3] = [0.5007, 0.0011, 0.0583], [0.5031, 0.0023, 0.0571]
    poses[1][:3, :3] = Rotation.from_euler('x', 10, degrees=True).as_matrix()
    approach, centre = np.array([0.0, 0.0, -1.0]), np.array([0.5, 0.0, 0.06])

    def ask(frame, m):
        common = dict(header=Header(frame_id=frame), mesh=mesh_to_msg(icosphere(0.02, 1)),
                      approach=Vector3(**dict(zip('xyz', (m[:3, :3] @ approach).tolist()))),
                      torque_centre=to_point(m[:3, :3] @ centre + m[:3, 3]))
        msgs = [pose_to_msg(Pose.from_matrix(m @ p)) for p in poses]
        _, one = round_trip(single, ContactWrench.Request(pose=msgs[1], **common), 20, frame)
        _, many = round_trip(batch, ContactWrenchBatch.Request(poses=msgs, **common), 20,
                             frame)
        assert one.success and many.success, (one.message, many.message)
        return one, many

    in_base, in_world = ask('base', np.eye(4)), ask('world', world_from_base)
    assert in_base[0].wrench.force.z > 0.1 and in_base[0].has_wrench_std
    for base_rows, world_rows in ((_wrench_rows([in_base[0].wrench]),
                                   _wrench_rows([in_world[0].wrench])),
                                  (_wrench_rows(in_base[1].wrenches),
                                   _wrench_rows(in_world[1].wrenches))):
        np.testing.assert_allclose(world_rows[:, :3], base_rows[:, :3] @ rot.T, atol=1e-6)
        np.testing.assert_allclose(world_rows[:, 3:], base_rows[:, 3:] @ rot.T, atol=1e-7)
    assert in_world[0].contact_count == in_base[0].contact_count
    if turn == 'quarter':       # the spread of x in base is the spread of y in world
        std_b = _wrench_rows([in_base[0].wrench_std])
        std_w = _wrench_rows([in_world[0].wrench_std])
        np.testing.assert_allclose(std_w[0, [1, 0, 2]], std_b[0, :3], rtol=1e-6, atol=1e-9)
    # a frame the tree does not hold is still refused, naming what to do
    _, refused = round_trip(single, ContactWrench.Request(
        header=Header(frame_id='tool0'), pose=pose_to_msg(Pose(position=[0.5, 0.0, 0.058])),
        mesh=mesh_to_msg(icosphere(0.02, 1)), approach=Vector3(x=0.0, y=0.0, z=-1.0)), 20, 't')
    assert not refused.success and "'tool0'" in refused.message
    assert 'tf_dynamic' in refused.message and 'world' in refused.message
    # the batch's second pose is the single query's
    np.testing.assert_allclose(_wrench_rows(in_world[1].wrenches)[1],
                               _wrench_rows([in_world[0].wrench])[0], atol=1e-6)


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


def test_a_request_stamped_ahead_of_tf_waits_for_it(ros_graph, tmp_path):
    """Session 42: with ``tf_dynamic``, a planner's query stamped ``now`` in a frame /tf moves
    (``world`` <- ``base`` at 10 Hz) was refused as extrapolation into the future until /tf
    caught up; it now waits up to ``tf_wait`` for its transform, and past that is refused."""
    save_model(patch_contact_model(spacing=0.003), tmp_path / 'models')
    node = ros_graph.add(ContactWrenchNode(context=ros_graph.context, parameter_overrides=[
        Parameter('model_dir', value=str(tmp_path / 'models')),
        Parameter('tf_dynamic', value=True), Parameter('tf_wait', value=1.0)]))
    probe = ros_graph.add(Node('moving_world', context=ros_graph.context))
    tf_pub = probe.create_publisher(TFMessage, '/tf', TF_QOS)
    world_from_base = np.eye(4)

    def world_at(stamp, x):
        world_from_base[:3, 3] = [x, 0.0, 0.0]
        tf_pub.publish(TFMessage(transforms=[transform_to_msg(world_from_base, 'world', 'base',
                                                              stamp)]))

    world_at(50.0, 0.0)
    ros_graph.wait_for(lambda: node.tf.knows('world'), 10, 'world <- base on /tf')
    single = probe.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    assert single.wait_for_service(timeout_sec=30.0)

    def ask(stamp, x):
        header = Header(frame_id='world')
        sec_to_stamp(stamp, header.stamp)
        return ContactWrench.Request(
            header=header, pose=pose_to_msg(Pose(position=[0.5007 + x, 0.0011, 0.0583])),
            mesh=mesh_to_msg(icosphere(0.02, 1)), approach=Vector3(x=0.0, y=0.0, z=-1.0),
            torque_centre=to_point([0.5 + x, 0.0, 0.06]))

    _, now = round_trip(single, ask(50.0, 0.0), 20, 'at /tf')
    assert now.success, now.message
    done = threading.Event()
    future = single.call_async(ask(50.05, 0.1))     # /tf's newest is at 50.0: waits
    future.add_done_callback(lambda _f: done.set())
    assert not done.wait(0.3)
    world_at(50.1, 0.2)                             # at 50.05 world <- base is 0.1 m along x
    assert done.wait(20.0)
    ahead = future.result()
    assert ahead.success, ahead.message
    np.testing.assert_allclose(vec(ahead.wrench.force), vec(now.wrench.force), atol=1e-6)
    start = time.monotonic()                        # nothing comes: refused after tf_wait
    _, late = round_trip(single, ask(60.0, 0.0), 20, 'no /tf')
    assert not late.success and "'world'" in late.message
    assert 'not arrived yet (waited 1 s)' in late.message
    assert time.monotonic() - start >= 0.9
    # a frame nobody publishes: the first request waits tf_wait, the next ones are refused at
    # once (session 43: each held a service thread tf_wait), until /tf names the frame

    def ask_in(frame):
        request = ask(0.0, 0.0)
        request.header.frame_id = frame
        return request

    start = time.monotonic()
    _, ghost = round_trip(single, ask_in('ghost'), 20, 'ghost, first')
    assert not ghost.success and '(waited 1 s)' in ghost.message
    assert time.monotonic() - start >= 0.9
    start = time.monotonic()
    for _ in range(3):
        _, again = round_trip(single, ask_in('ghost'), 20, 'ghost, again')
        assert not again.success and "not waited for: no transform has named 'ghost'" in \
            again.message and 'waited 1 s' not in again.message
    assert time.monotonic() - start < 0.9
    assert node.health()[2]['refused_unwaited_frame'] == 3
    tf_pub.publish(TFMessage(transforms=[transform_to_msg(np.eye(4), 'world', 'ghost', 50.1)]))
    ros_graph.wait_for(lambda: node.tf.knows('ghost'), 10, 'world <- ghost on /tf')
    _, found = round_trip(single, ask_in('ghost'), 20, 'ghost, named')
    assert found.success, found.message
