"""Contact simulator (seed 000, eq. 1-4): closed forms, invariants, batch, paper baseline."""

import numpy as np
import pytest

from pointforce_ros.contact import ContactSimulator, sample_mesh_surface, shape_matrix
from pointforce_ros.lab.paper_contact import PaperContactSimulator
from pointforce_ros.lab.synthetic_contact import (dome_surface, grid_surface, linear_response,
                                                  power_response)
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Pose, Surface

K = 1000.0  # N/m
C = 0.003  # m
DOWN = np.array([0.0, 0.0, -1.0])


@pytest.fixture(scope='module')
def flat():
    surface = grid_surface(half=0.03, step=0.001)
    return ContactSimulator(surface, linear_response(K, len(surface)), c=C)


@pytest.fixture(scope='module')
def dome():
    surface = dome_surface(n=121, half=0.03, radius=0.1)
    return ContactSimulator(surface, linear_response(K, len(surface)), c=C)


def jittered_dome(rng, n=81, half=0.025, radius=0.1):
    """Dome sampled at jittered xy (no distance ties), normals radial."""
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    xy = np.column_stack([x.ravel(), y.ravel()]) + rng.uniform(-2e-4, 2e-4, (n * n, 2))
    z = np.sqrt(radius ** 2 - (xy ** 2).sum(axis=1)) - radius
    p = np.column_stack([xy, z])
    normal = p - [0.0, 0.0, -radius]
    return p, normal / np.linalg.norm(normal, axis=1, keepdims=True)


def random_rotation(rng):
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def quat_matrix(q):
    return Pose(position=np.zeros(3), orientation=q).rotation()


def quat_multiply(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


# ------------------------------------------------------------------------------ closed forms
def test_single_contact_point_actual_equals_nominal(flat):
    depth = 0.002
    point = np.array([[0.00025, 0.00025, -depth]])
    centre = np.array([0.01, -0.02, 0.03])
    res = flat.query_points(point, DOWN, centre)
    assert res.contact_count == 1
    np.testing.assert_allclose(res.actual_displacements, [depth], rtol=1e-12)
    np.testing.assert_allclose(res.wrench.force, [0, 0, K * depth], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(res.wrench.torque, np.cross(point[0] - centre, [0, 0, K * depth]),
                               rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize('bias', [0.002, -0.0015])
def test_contact_starts_at_the_responses_onset_not_at_the_observed_surface(bias):
    # A camera that sees the surface `bias` too deep learns y(d) = k (d + bias)^1.5: force
    # starts at d0 = -bias. The wrench of a body must then equal that of the true surface with
    # the unshifted law, for every pose: contacts between the two surfaces count too.
    rng = np.random.default_rng(3)
    depths = np.linspace(-0.004, 0.03, 681)
    true_surface = grid_surface(half=0.03, step=0.001)
    seen = Surface(points=true_surface.points - [0.0, 0.0, bias], normals=true_surface.normals)
    k = 2.0e4 * (1.0 + rng.uniform(0.0, 1.0, len(true_surface)))
    law = power_response(k, 1.5, depths=depths)
    shifted = power_response(k, 1.5, depths=depths + bias)
    shifted = type(law)(depths=depths, forces=shifted.forces, slopes=shifted.slopes)
    sim_true = ContactSimulator(true_surface, law, c=C)
    sim_seen = ContactSimulator(seen, shifted, c=C)
    np.testing.assert_allclose(shifted.onsets(), -bias, atol=1e-12)
    mesh = icosphere(0.012, 2)
    for depth in (0.0005, 0.002, 0.004):
        pose = Pose(position=np.array([0.002, -0.001, 0.012 - depth]),
                    orientation=np.array([0.0, 0.0, 0.0, 1.0]))
        a = sim_true.query(mesh, pose, DOWN, np.zeros(3))
        b = sim_seen.query(mesh, pose, DOWN, np.zeros(3))
        assert a.contact_count > 0 and b.contact_count == a.contact_count
        np.testing.assert_allclose(b.wrench.force, a.wrench.force, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(b.wrench.torque, a.wrench.torque, rtol=1e-6, atol=1e-11)


@pytest.mark.parametrize('neighbours', ['equal', 'smooth'])
def test_flat_punch_on_a_homogeneous_linear_surface(flat, neighbours):
    # 5 x 5 punch points 3 mm apart, each offset (0.25, 0.25) mm from a surface node: its 3
    # nearest nodes are (i, j), (i+1, j), (i, j+1), 0.354, 0.791 and 0.791 mm away, the fourth
    # (i+1, j+1) 1.061 mm. Equal weights put q at the punch point + (1/12, 1/12) mm; smooth
    # weights (r4 - r_k) at + (w1 - 0.25) mm each way, w1 = 0.27 / (0.707 + 2 x 0.27).
    # Every nominal displacement is the punch depth. Expected: F = k * depth * 1' G^-1 1.
    flat = ContactSimulator(flat.surface, flat.response, c=C, neighbours=neighbours)
    depth = 0.0015
    ticks = np.arange(-2, 3) * 0.003 + 0.00025
    x, y = np.meshgrid(ticks, ticks, indexing='ij')
    punch = np.column_stack([x.ravel(), y.ravel(), np.full(25, -depth)])
    q = punch.copy()
    r = np.hypot([0.25, 0.75], 0.25)
    w1 = (np.hypot(0.75, 0.75) - r[1]) / (3 * np.hypot(0.75, 0.75) - r[0] - 2 * r[1])
    q[:, :2] += (0.001 / 12.0 if neighbours == 'equal' else 0.001 * w1 - 0.00025)
    q[:, 2] = 0.0
    expected_x = np.linalg.solve(shape_matrix(q, C), np.full(25, depth))
    assert expected_x.min() > 0  # every point touches: the closed form applies
    centre = punch.mean(axis=0)
    res = flat.query_points(punch, DOWN, centre)
    assert res.contact_count == 25
    np.testing.assert_allclose(res.contact_points, q, atol=1e-12)
    np.testing.assert_allclose(res.wrench.force, [0, 0, K * expected_x.sum()], rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(res.wrench.torque, 0.0, atol=1e-12)  # symmetric about its centre
    # Coupling matters: the punch carries far less than 25 independent points would.
    assert res.wrench.force[2] < 0.5 * 25 * K * depth


def test_two_far_points_decouple(flat):
    d1, d2 = 0.002, 0.001
    pts = np.array([[-0.025 + 0.00025, 0.00025, -d1], [0.025 + 0.00025, 0.00025, -d2]])
    for c in (C, C / 10):
        res = flat.with_shape_constant(c).query_points(pts, DOWN, np.zeros(3))
        g = c / (c + 0.05)
        exact = np.linalg.solve([[1, g], [g, 1]], [d1, d2])
        np.testing.assert_allclose(res.actual_displacements, exact, rtol=1e-9)
    # 50 mm apart with c = 0.3 mm the points carry their nominal displacement to 1 %.
    np.testing.assert_allclose(res.wrench.force[2], K * (d1 + d2), rtol=0.01)


def test_a_tail_decay_cuts_the_coupling_in_every_path(flat):
    """``g(r) = c / (c + r) exp(-r / L)``: one pose, a batch and the displacement field."""
    d1, d2, L = 0.002, 0.001, 0.004
    pts = np.array([[-0.005 + 0.00025, 0.00025, -d1], [0.005 + 0.00025, 0.00025, -d2]])
    sim = flat.with_shape_constant(C, L, decay_law='fixed')   # one L (the default scales it)
    res = sim.query_points(pts, DOWN, np.zeros(3), return_displacements=True)
    g = C / (C + 0.01) * np.exp(-0.01 / L)
    exact = np.linalg.solve([[1, g], [g, 1]], [d1, d2])
    np.testing.assert_allclose(res.actual_displacements, exact, rtol=1e-9)
    r = np.linalg.norm(flat.surface.points[:, None] - res.contact_points[None], axis=2)
    np.testing.assert_allclose(res.displacements, (C / (C + r) * np.exp(-r / L)) @ exact,
                               rtol=1e-9, atol=1e-15)
    # the paper's g couples them more, so together they carry less
    paper = flat.query_points(pts, DOWN, np.zeros(3))
    assert paper.wrench.force[2] < res.wrench.force[2]
    mesh = box((0.012, 0.012, 0.004))
    poses = [Pose(position=[0.00023, 0.00041, -d]) for d in (0.001, 0.002, 0.003)]
    batch = sim.query_batch(mesh, poses, DOWN, np.zeros(3)).wrenches
    single = np.array([np.r_[w.force, w.torque] for w in
                       (sim.query(mesh, p, DOWN, np.zeros(3)).wrench for p in poses)])
    np.testing.assert_allclose(batch, single, rtol=1e-9, atol=1e-12)
    assert sim.with_shape_constant(C).decay == L  # the decay is kept unless given
    assert np.isinf(flat.decay)


def test_nonlinear_law_force_per_point_follows_eq_4():
    surface = grid_surface(half=0.02, step=0.001)
    sim = ContactSimulator(surface, power_response(2e4, 1.5, len(surface)), c=C)
    res = sim.query(icosphere(0.008, 2), Pose(position=[0.0002, 0.0001, 0.008 - 0.004]), DOWN,
                    np.zeros(3))
    d, x = res.nominal_displacements, res.actual_displacements
    assert res.contact_count > 5
    # Tolerance: linear interpolation of the 0.05 mm table of d^1.5 (error ~ k h^1.5 / 10).
    np.testing.assert_allclose(res.contact_forces, 2e4 * (d ** 1.5 - (d - x) ** 1.5),
                               rtol=1e-3, atol=2e-4)


# -------------------------------------------------------------------------------- invariants
@pytest.mark.parametrize('seed', range(3))
def test_invariants_on_random_poses(dome, seed):
    rng = np.random.default_rng(seed)
    for mesh in (icosphere(0.01, 2), box((0.02, 0.012, 0.008))):
        for _ in range(4):
            pose = Pose(position=np.append(rng.uniform(-0.01, 0.01, 2), rng.uniform(-0.006, 0)),
                        orientation=random_rotation(rng))
            res = dome.query(mesh, pose, DOWN, pose.position)
            d, x = res.nominal_displacements, res.actual_displacements
            assert res.lcp_residual <= 1e-12 * max(d.max(initial=0), 1e-3)
            assert np.all(x > 0) and np.all(x <= d * (1 + 1e-12))
            assert np.all(res.contact_forces >= 0)
            assert res.contact_count <= res.candidate_count
            assert res.max_displacement >= d.max(initial=0) * (1 - 1e-12)
            assert res.rigid_points_in_contact.shape == (res.contact_count, 3)


def test_symmetric_probe_on_symmetric_surface_has_no_torque_about_its_axis(dome):
    for depth in (0.001, 0.003, 0.006):
        centre = np.array([0.0, 0.0, 0.01 - depth])
        res = dome.query(icosphere(0.01, 2), Pose(position=centre), DOWN, centre)
        f = np.linalg.norm(res.wrench.force)
        assert f > 0.5
        assert abs(res.wrench.torque[2]) < 1e-4 * f * 0.01
        assert np.linalg.norm(res.wrench.torque) < 0.03 * f * 0.01
        assert abs(res.wrench.force[2]) > 0.999 * f


def test_force_is_monotone_in_depth(dome):
    forces = []
    for depth in np.linspace(0.0002, 0.008, 14):
        res = dome.query(icosphere(0.01, 2), Pose(position=[0.002, -0.001, 0.01 - depth]), DOWN,
                         np.zeros(3))
        forces.append(res.wrench.force[2])
    assert forces[0] > 0
    assert np.all(np.diff(forces) > 0)


def test_rotation_and_translation_equivariance():
    rng = np.random.default_rng(8)
    p, n = jittered_dome(rng)
    response = linear_response(K * (1 + rng.uniform(0, 1, len(p))))
    mesh = box((0.012, 0.008, 0.006))
    pose = Pose(position=[0.001, 0.002, -0.003], orientation=random_rotation(rng))
    centre = np.array([0.003, -0.004, 0.02])
    ref = ContactSimulator(Surface(p, n), response, c=C).query(mesh, pose, DOWN, centre)
    assert ref.contact_count > 5
    rot_q = random_rotation(rng)
    R = quat_matrix(rot_q)
    shift = np.array([0.3, -1.2, 0.7])
    sim = ContactSimulator(Surface(p @ R.T + shift, n @ R.T), response, c=C)
    moved = sim.query(mesh, Pose(position=R @ pose.position + shift,
                                 orientation=quat_multiply(rot_q, pose.orientation)),
                      R @ DOWN, R @ centre + shift)
    assert moved.contact_count == ref.contact_count
    np.testing.assert_allclose(moved.wrench.force, R @ ref.wrench.force, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(moved.wrench.torque, R @ ref.wrench.torque, rtol=1e-8,
                               atol=1e-12)


# ------------------------------------------------------------------------------------- batch
def test_batch_equals_per_pose_queries(dome):
    rng = np.random.default_rng(3)
    mesh = box((0.015, 0.01, 0.006))
    poses = [Pose(position=np.append(rng.uniform(-0.01, 0.01, 2), rng.uniform(-0.004, 0.02)),
                  orientation=random_rotation(rng)) for _ in range(40)]
    centres = rng.uniform(-0.01, 0.01, (40, 3))
    batch = dome.query_batch(mesh, poses, DOWN, centres, chunk=16)
    as_array = np.array([np.concatenate([p.position, p.orientation]) for p in poses])
    again = dome.query_batch(mesh, as_array, DOWN, centres)
    assert 5 < np.count_nonzero(batch.contact_count) < 40
    for i, pose in enumerate(poses):
        one = dome.query(mesh, pose, DOWN, centres[i])
        np.testing.assert_allclose(batch.wrenches[i], one.wrench.as_vector(), rtol=1e-10,
                                   atol=1e-13)
        assert batch.contact_count[i] == one.contact_count
        assert batch.max_displacement[i] == pytest.approx(one.max_displacement, rel=1e-10)
    np.testing.assert_allclose(again.wrenches, batch.wrenches, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(batch.wrench(3).as_vector(), batch.wrenches[3])


# ----------------------------------------------------------------------------- paper baseline
def test_paper_algorithm_agrees_where_it_converges():
    surface = dome_surface(n=121, half=0.03, radius=0.1)
    k = K * (1.0 + 20.0 * surface.points[:, 0])  # affine in x: averaging commutes with y
    ours = ContactSimulator(surface, linear_response(k), c=C, neighbours='equal')
    paper = PaperContactSimulator(
        surface, lambda feats, d: K * (1.0 + 20.0 * feats[:, 0]) * np.clip(d, 0, None), c=C)
    mesh = icosphere(0.01, 2)
    compared = 0
    # Positions off the surface grid: a rigid sample exactly over a node has tied neighbours,
    # which a KD-tree and a brute-force partition may break differently.
    for xy, depth in (((0.00013, 0.00007), 0.002), ((0.00613, -0.00393), 0.004),
                      ((-0.00987, 0.00507), 0.006)):
        pose = Pose(position=[*xy, 0.01 - depth])
        a = ours.query(mesh, pose, DOWN, pose.position)
        b = paper.query(mesh, pose, DOWN, pose.position)
        if b.lcp_residual < 1e-15 and a.candidate_count == b.candidate_count:
            compared += 1
            assert a.contact_count == b.contact_count
            np.testing.assert_allclose(a.wrench.as_vector(), b.wrench.as_vector(), rtol=1e-10,
                                       atol=1e-13)
    assert compared == 3
    assert set(paper.last_timing) == {'collision', 'lcp', 'model'}


def test_only_the_front_most_sample_counts(flat):
    # A 2 mm plate pushed 4 mm deep: its top face is also 2 mm "below" the surface. Only the
    # bottom face may push; the paper's projection pairs both faces with the same points.
    plate = box((0.012, 0.012, 0.002))
    pose = Pose(position=[0.0003, 0.0002, -0.004])
    res = flat.query(plate, pose, DOWN, np.zeros(3))
    local, _ = sample_mesh_surface(plate, flat.spacing)
    bottom = flat.query_points(pose.apply(local[np.abs(local[:, 2]) < 1e-12]), DOWN,
                               np.zeros(3))
    assert res.candidate_count > bottom.candidate_count  # inactive rim samples of the walls
    np.testing.assert_allclose(res.wrench.as_vector(), bottom.wrench.as_vector(), rtol=1e-10)
    paper = PaperContactSimulator(flat.surface, lambda f, d: K * np.clip(d, 0, None), c=C)
    with pytest.raises(NotConverged, match='singular'):
        paper.query(plate, pose, DOWN, np.zeros(3))


def test_occluded_samples_are_removed_and_the_deepest_kept():
    from pointforce_ros.contact.simulator import _deepest_per_key, _deepest_per_triple
    key = np.array([5, 3, 5, 7, 3])
    d = np.array([1.0, 4.0, 2.0, 0.5, 3.0])
    np.testing.assert_array_equal(np.sort(_deepest_per_key(key, d)), [1, 2, 3])
    assert _deepest_per_key(np.array([1, 9, 4]), d[:3]) is None
    b = np.array([0, 0, 0, 1])
    tri = np.array([[1, 2, 3], [1, 2, 3], [1, 2, 4], [1, 2, 3]])
    np.testing.assert_array_equal(_deepest_per_triple(b, tri, np.array([1.0, 2, 3, 4])),
                                  [1, 2, 3])
    assert _deepest_per_triple(b[:3], tri[[0, 2, 3]] + [[0, 0, 0], [0, 0, 0], [0, 0, 9]],
                               d[:3]) is None


def test_rigid_samples_farther_than_max_gap_from_the_surface_do_not_touch():
    patch = grid_surface(half=0.02, step=0.001)
    point = np.array([[0.023, 0.00013, -0.005]])  # 3 mm beyond the patch edge, below its top
    for gap, touches in ((0.005, True), (0.002, False)):
        sim = ContactSimulator(patch, linear_response(K, len(patch)), c=C, max_gap=gap)
        assert sim.query_points(point, DOWN, np.zeros(3)).contact_count == int(touches)


def test_a_body_beside_the_surface_does_not_touch_it():
    patch = grid_surface(half=0.02, step=0.001)
    sim = ContactSimulator(patch, linear_response(K, len(patch)), c=C)
    pose = Pose(position=[0.035, 0.0, -0.005])  # beside the patch, lower than its top
    res = sim.query(icosphere(0.01, 2), pose, DOWN, np.zeros(3))
    assert res.contact_count == 0
    np.testing.assert_array_equal(res.wrench.as_vector(), 0.0)


# ---------------------------------------------------------------------------- displacements
def test_displacement_field_of_a_single_poke(flat):
    depth = 0.002
    tip = np.array([0.00025, 0.00025, -depth])
    res = flat.query_points(tip[None], DOWN, np.zeros(3), return_displacements=True)
    pts = flat.surface.points
    assert res.displaced_indices.shape == (len(pts),)
    q = res.contact_points[0]
    np.testing.assert_allclose(res.displacements,
                               depth * C / (C + np.linalg.norm(pts - q, axis=1)), rtol=1e-12)
    assert res.max_displacement == pytest.approx(depth, rel=1e-12)


# -------------------------------------------------------------------------- degenerate input
def test_no_contact_gives_a_zero_wrench(dome):
    res = dome.query(icosphere(0.01, 2), Pose(position=[0, 0, 0.0105]), DOWN, np.zeros(3))
    assert res.contact_count == 0 and res.candidate_count == 0
    np.testing.assert_array_equal(res.wrench.as_vector(), 0.0)
    batch = dome.query_batch(icosphere(0.01, 2), [Pose(position=[0, 0, 0.05])] * 3, DOWN,
                             np.zeros(3))
    np.testing.assert_array_equal(batch.wrenches, 0.0)


def test_duplicate_surface_points_are_merged(flat):
    surface = flat.surface
    doubled = Surface(np.vstack([surface.points, surface.points]),
                      np.vstack([surface.normals, surface.normals]))
    sim = ContactSimulator(doubled, linear_response(K, len(doubled)), c=C)
    assert sim.duplicates_removed == len(surface)
    pose = Pose(position=[0.001, 0.0, 0.01 - 0.003])
    a = sim.query(icosphere(0.01, 2), pose, DOWN, np.zeros(3))
    b = flat.query(icosphere(0.01, 2), pose, DOWN, np.zeros(3))
    np.testing.assert_allclose(a.wrench.as_vector(), b.wrench.as_vector(), rtol=1e-12)


def test_bad_requests_raise_invalid_input(flat):
    mesh = icosphere(0.01, 1)
    pose = Pose(position=[0, 0, 0.01])
    with pytest.raises(InvalidInput, match='unit'):
        flat.query(mesh, pose, [0, 0, -2.0], np.zeros(3))
    with pytest.raises(InvalidInput, match='non-finite'):
        flat.query(mesh, pose, [0, np.nan, -1.0], np.zeros(3))
    with pytest.raises(InvalidInput, match='torque_centre'):
        flat.query(mesh, pose, DOWN, np.zeros(2))
    with pytest.raises(InvalidInput, match='frame'):
        flat.query(mesh, Pose(position=[0, 0, 0], frame='tool0'), DOWN, np.zeros(3))
    with pytest.raises(InvalidInput, match='bake'):
        ContactSimulator(flat.surface, linear_response(K, 10), c=C)
    with pytest.raises(InvalidInput, match='positive'):
        ContactSimulator(flat.surface, linear_response(K, len(flat.surface)), c=0.0)
    with pytest.raises(InvalidInput, match='quaternion'):
        flat.query_batch(mesh, np.zeros((2, 7)), DOWN, np.zeros(3))
