"""Round trips for geometry, mesh and interface adapters; bad requests give InvalidInput."""

import array
import gc
import tracemalloc

import numpy as np
import pytest
from geometry_msgs.msg import Vector3
from pointforce_interfaces.action import Poke
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch

from msg_adapters import geometry as g
from msg_adapters import interfaces as itf
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Mesh, Pose, PokeGoal, Wrench


def _box_mesh(size=0.02):
    v = np.array([[x, y, z] for x in (0, size) for y in (0, size) for z in (0, size)], float)
    t = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return Mesh(vertices=v, triangles=t)


def _random_pose(rng):
    q = rng.normal(size=4)
    return Pose(position=rng.uniform(-1, 1, 3), orientation=q / np.linalg.norm(q))


def test_pose_wrench_mesh_round_trip():
    rng = np.random.default_rng(3)
    pose = _random_pose(rng)
    back = g.pose_stamped_from_msg(g.pose_stamped_to_msg(pose, stamp=3.5))
    np.testing.assert_allclose(back.position, pose.position)
    np.testing.assert_allclose(back.orientation, pose.orientation)
    w = Wrench(force=rng.normal(size=3), torque=rng.normal(size=3), frame='tool0_controller')
    wb = g.wrench_stamped_from_msg(g.wrench_stamped_to_msg(w, stamp=1.0))
    np.testing.assert_allclose(wb.as_vector(), w.as_vector())
    assert wb.frame == 'tool0_controller'
    mesh = _box_mesh()
    mb = g.mesh_from_msg(g.mesh_to_msg(mesh))
    np.testing.assert_allclose(mb.vertices, mesh.vertices)
    np.testing.assert_array_equal(mb.triangles, mesh.triangles)


def test_pose_rotation_matches_quaternion_convention():
    # 90 degrees about z: x axis maps to y
    s = np.sqrt(0.5)
    pose = Pose(position=[1.0, 0, 0], orientation=[0, 0, s, s])
    np.testing.assert_allclose(pose.apply(np.array([[1.0, 0, 0]])), [[1.0, 1.0, 0]], atol=1e-12)


def test_contact_request_round_trip_and_batch():
    rng = np.random.default_rng(5)
    req = ContactWrench.Request()
    req.mesh = g.mesh_to_msg(_box_mesh())
    pose = _random_pose(rng)
    req.pose = g.pose_to_msg(pose)
    req.approach = Vector3(x=0.0, y=0.0, z=-1.0)
    req.torque_centre = g.to_point([0.1, 0.2, 0.3])
    req.return_displacements = True
    q = itf.contact_query_from_request(req)
    np.testing.assert_allclose(q.poses[0].position, pose.position)
    np.testing.assert_allclose(q.approach, [0, 0, -1])
    np.testing.assert_allclose(q.torque_centre, [0.1, 0.2, 0.3])
    assert q.return_displacements
    breq = ContactWrenchBatch.Request(mesh=req.mesh, approach=req.approach,
                                      poses=[g.pose_to_msg(_random_pose(rng)) for _ in range(4)])
    assert len(itf.contact_query_from_batch_request(breq).poses) == 4


@pytest.mark.parametrize('breakage, match', [
    (lambda r: setattr(r.approach, 'z', 0.5), 'approach'),
    (lambda r: setattr(r.approach, 'x', float('nan')), 'approach'),
    (lambda r: setattr(r.pose.position, 'x', float('nan')), 'non-finite'),
    (lambda r: setattr(r.mesh, 'triangles', []), 'empty'),
    (lambda r: setattr(r.mesh.vertices[0], 'x', float('inf')), 'non-finite'),
    (lambda r: setattr(r.pose.orientation, 'w', 3.0), 'quaternion'),
])
def test_bad_contact_requests_are_invalid_input(breakage, match):
    req = ContactWrench.Request()
    req.mesh = g.mesh_to_msg(_box_mesh())
    req.approach = Vector3(x=0.0, y=0.0, z=-1.0)
    breakage(req)
    with pytest.raises(InvalidInput, match=match):
        itf.contact_query_from_request(req)


def test_degenerate_mesh_is_invalid_input():
    m = g.mesh_to_msg(_box_mesh())
    for v in m.vertices:
        v.x = v.y = v.z = 0.0
    with pytest.raises(InvalidInput, match='degenerate'):
        g.mesh_from_msg(m)


def test_empty_batch_is_invalid_input():
    with pytest.raises(InvalidInput, match='empty'):
        itf.contact_query_from_batch_request(ContactWrenchBatch.Request(
            mesh=g.mesh_to_msg(_box_mesh()), approach=Vector3(x=0.0, y=0.0, z=-1.0)))


def test_poke_goal_round_trip_and_non_unit_normal():
    goal = PokeGoal(point=[0.5, 0.0, 0.04], normal=[0, 0, 1], force_limit=4.0,
                    depth_limit=0.012, speed=0.002, standoff=0.01)
    back = itf.poke_goal_from_msg(itf.poke_goal_to_msg(goal))
    np.testing.assert_allclose(back.point, goal.point)
    assert back.force_limit == 4.0 and back.depth_limit == 0.012
    bad = itf.poke_goal_to_msg(goal)
    bad.normal.z = 2.0
    with pytest.raises(InvalidInput, match='normal'):
        itf.poke_goal_from_msg(bad)
    bad.surface_index = 3  # normal is ignored when a surface index is given
    assert itf.poke_goal_from_msg(bad).surface_index == 3


def test_contact_response_fields():
    class Result:
        wrench = Wrench(force=[0, 0, 2.5], torque=[0.01, 0, 0])
        contact_count = 7
        max_displacement = 0.004
        displaced_indices = np.array([1, 5, 9])
        displacements = np.array([0.001, 0.004, 0.002])
    resp = itf.fill_contact_response(ContactWrench.Response(), Result(), 3, True)
    assert resp.success and resp.wrench.force.z == 2.5 and resp.contact_count == 7
    assert list(resp.displaced_indices) == [1, 5, 9] and resp.model_version == 3
    failed = itf.fail(ContactWrench.Response(), 'mesh: empty')
    assert not failed.success and failed.message == 'mesh: empty'
    assert Poke.Result().outcome == ''


def test_the_flat_mesh_cache_keeps_no_mesh_with_a_huge_triangle_list():
    """Four distinct flat meshes of 600 000 triangles leave less than 16 MiB held (session 38).

    The cache bounded the vertices alone: one triangle listed 1e6 times (9 vertex values)
    was kept whole, key bytes and all, 16 times over; a resent small mesh is still one object.
    """
    triangles = array.array('I', np.tile([0, 2, 1], 600_000).astype(np.uint32).tobytes())
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(4):
            vertices = array.array('d', [0, 0, 0, 0.002, 0, 0, 0, 0.002, 1e-7 * k])
            assert len(g.mesh_from_flat(vertices, triangles).triangles) == 600_000
        gc.collect()
        held = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert held < 16 * 2 ** 20, f'{held / 2 ** 20:.0f} MiB held by the cache'
    small = g.mesh_to_flat(Mesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0]], triangles=[[0, 1, 2]]))
    assert g.mesh_from_flat(*small) is g.mesh_from_flat(*small)
