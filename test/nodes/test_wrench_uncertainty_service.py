"""contact_wrench answers each wrench with its standard deviation (issue 17), over real DDS."""

import dataclasses

import numpy as np
import pytest
from geometry_msgs.msg import Vector3
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rclpy.node import Node
from rclpy.parameter import Parameter

from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
from pointforce_ros.contact.uncertainty import wrench_uncertainty
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import Pose

pytestmark = pytest.mark.ros
SPHERE = icosphere(0.02, 2)
DOWN = [0.0, 0.0, -1.0]
COV = [[0.04, 0.5], [0.5, 400.0]]   # (log c, 1/L [1/m])


def _pose(depth, x=0.5):
    return Pose(position=[x, 0.0, 0.06 - depth])


def _single(pose, skip=False):
    return ContactWrench.Request(mesh=mesh_to_msg(SPHERE), pose=pose_to_msg(pose),
                                 approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                 torque_centre=to_point(pose.position), skip_uncertainty=skip)


def _std(msg):
    return np.array([msg.force.x, msg.force.y, msg.force.z,
                     msg.torque.x, msg.torque.y, msg.torque.z])


def _serve(ros_graph, model_dir):
    node = ros_graph.add(ContactWrenchNode(
        context=ros_graph.context,
        parameter_overrides=[Parameter('model_dir', value=str(model_dir)),
                             Parameter('poll_period', value=0.1)]))
    client_node = ros_graph.add(Node('test_uncertainty_client', context=ros_graph.context))
    single = client_node.create_client(ContactWrench, '/contact_wrench/contact_wrench')
    batch = client_node.create_client(ContactWrenchBatch, '/contact_wrench/contact_wrench_batch')
    assert single.wait_for_service(timeout_sec=30.0) and batch.wait_for_service(timeout_sec=30.0)
    return node, single, batch


def test_service_std_equals_the_core_propagation_and_can_be_skipped(ros_graph, tmp_path):
    base = patch_contact_model(spacing=0.003)
    model = dataclasses.replace(base, meta={**base.meta, 'shape_cov': COV,
                                            'relative_std': 0.05, 'lateral_std': 0.02})
    save_model(model, tmp_path / 'models')
    node, single, batch = _serve(ros_graph, tmp_path / 'models')
    poses = [_pose(0.002), _pose(0.004, x=0.51), _pose(0.006, x=0.49)]
    expected = wrench_uncertainty(model, SPHERE, poses, DOWN, poses[0].position).std
    answer = ros_graph.wait_future(single.call_async(_single(poses[0])), 20, 'single')
    assert answer.success and answer.has_wrench_std, answer.message
    np.testing.assert_allclose(_std(answer.wrench_std), expected[0], rtol=1e-9, atol=1e-12)
    # the spread grows with the force: a relative share of 5 % at least, less than the force
    assert 0.05 * answer.wrench.force.z <= answer.wrench_std.force.z < answer.wrench.force.z
    skipped = ros_graph.wait_future(single.call_async(_single(poses[0], skip=True)), 20, 'skip')
    assert skipped.success and not skipped.has_wrench_std
    assert skipped.wrench.force.z == answer.wrench.force.z
    request = ContactWrenchBatch.Request(mesh=mesh_to_msg(SPHERE), poses=[pose_to_msg(p)
                                                                          for p in poses],
                                         approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                         torque_centre=to_point(poses[0].position))
    rows = ros_graph.wait_future(batch.call_async(request), 20, 'batch')
    assert rows.success and len(rows.wrench_stds) == 3, rows.message
    np.testing.assert_allclose([_std(w) for w in rows.wrench_stds], expected, rtol=1e-9,
                               atol=1e-12)
    request.skip_uncertainty = True
    bare = ros_graph.wait_future(batch.call_async(request), 20, 'batch, skipped')
    assert bare.success and len(bare.wrench_stds) == 0
    node.set_parameters([Parameter('uncertainty', value=False)])
    off = ros_graph.wait_future(single.call_async(_single(poses[0])), 20, 'turned off')
    assert off.success and not off.has_wrench_std


def test_a_model_without_uncertainty_answers_the_wrench_and_says_why(ros_graph, tmp_path):
    save_model(patch_contact_model(spacing=0.003), tmp_path / 'models')
    _, single, _ = _serve(ros_graph, tmp_path / 'models')
    answer = ros_graph.wait_future(single.call_async(_single(_pose(0.003))), 20, 'single')
    assert answer.success and answer.wrench.force.z > 0.5
    assert not answer.has_wrench_std and 'carries no uncertainty' in answer.message
