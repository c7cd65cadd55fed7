"""The batch contact request read as arrays (issue 16): the Pose path's values, no Pose per row."""

import numpy as np
import pytest
from geometry_msgs.msg import Vector3
from pointforce_interfaces.srv import ContactWrenchBatch

from msg_adapters import geometry as g
from msg_adapters import interfaces as itf
from pointforce_ros.errors import InvalidInput
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import Pose


def _request(rng, n):
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    poses = [Pose(position=rng.uniform(-1, 1, 3), orientation=q) for q in quat]
    vertices, triangles = g.mesh_to_flat(icosphere(0.02, 1))
    req = ContactWrenchBatch.Request(poses=[g.pose_to_msg(p) for p in poses],
                                     approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                     torque_centre=g.to_point([0.1, 0.2, 0.3]),
                                     mesh_vertices=vertices, mesh_triangles=triangles)
    return req


def test_batch_arrays_equal_the_pose_path_and_read_an_unfilled_quaternion_as_identity():
    req = _request(np.random.default_rng(3), 25)
    req.poses[7].orientation.w = 0.0   # an unfilled quaternion (all zero)
    req.poses[7].orientation.x = req.poses[7].orientation.y = req.poses[7].orientation.z = 0.0
    arrays = itf.batch_arrays_from_request(req)
    query = itf.contact_query_from_batch_request(req)
    assert arrays.poses.shape == (25, 7)
    np.testing.assert_array_equal(arrays.poses[:, :3], [p.position for p in query.poses])
    np.testing.assert_allclose(arrays.poses[:, 3:], [p.orientation for p in query.poses],
                               atol=1e-15)
    np.testing.assert_array_equal(arrays.poses[7, 3:], [0, 0, 0, 1])
    np.testing.assert_array_equal(arrays.mesh.vertices, query.mesh.vertices)
    np.testing.assert_array_equal(arrays.torque_centre, [0.1, 0.2, 0.3])


def test_batch_arrays_refuse_an_empty_batch_a_bad_frame_and_a_nan_centre():
    req = _request(np.random.default_rng(4), 3)
    req.torque_centre.x = float('nan')
    with pytest.raises(InvalidInput, match='torque_centre'):
        itf.batch_arrays_from_request(req)
    req = _request(np.random.default_rng(4), 3)
    req.header.frame_id = 'tool0'
    with pytest.raises(InvalidInput, match='frame_id'):
        itf.batch_arrays_from_request(req)
    req.header.frame_id = ''
    req.poses = []
    with pytest.raises(InvalidInput, match='empty'):
        itf.batch_arrays_from_request(req)


def test_fill_batch_response_writes_every_row():
    wrenches = np.arange(18, dtype=float).reshape(3, 6) - 4.5
    batch = type('B', (), dict(wrenches=wrenches, contact_count=np.array([0, 2, 5]),
                               max_displacement=np.array([0.0, 1e-3, 2e-3])))
    resp = itf.fill_batch_response(ContactWrenchBatch.Response(), batch, 7)
    back = np.array([[w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z]
                     for w in resp.wrenches])
    np.testing.assert_array_equal(back, wrenches)
    assert list(resp.contact_counts) == [0, 2, 5] and resp.model_version == 7 and resp.success


def test_a_resent_flat_mesh_is_the_same_validated_object_and_a_bad_one_is_refused_each_time():
    vertices, triangles = g.mesh_to_flat(icosphere(0.02, 1))
    first = g.mesh_from_flat(vertices, triangles)
    again = g.mesh_from_flat(type(vertices)('d', vertices.tobytes()),
                             type(triangles)('I', triangles.tobytes()))
    assert again is first and not first.vertices.flags.writeable
    moved = np.frombuffer(vertices, dtype=np.float64).copy()
    moved[0] += 1e-3
    other = g.mesh_from_flat(type(vertices)('d', moved.tobytes()), triangles)
    assert other is not first and other.vertices[0, 0] == pytest.approx(moved[0])
    moved[0] = float('nan')
    for _ in range(2):
        with pytest.raises(InvalidInput, match='non-finite'):
            g.mesh_from_flat(type(vertices)('d', moved.tobytes()), triangles)
