"""The compiled single-pose path (contact/single_pose.py) against the stacked numpy path.

The two share no code between the KD-tree query and the wrench: the numpy path stacks poses
and solves with ``solve_lcp_batch``, the compiled one loops. Every check compares them on
seeded random poses that exercise both de-duplications, both decay laws, response onsets
off the observed surface and a baked response that is not linear.
"""

import copy

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.contact import simulator as simulator_module
from pointforce_ros.contact import single_pose
from pointforce_ros.contact.lcp import bpp_dense, shape_matrix
from pointforce_ros.contact.simulator import _deepest_per_key, _deepest_per_triple, \
    _sorted_triples
from pointforce_ros.errors import NotConverged
from pointforce_ros.lab.synthetic_contact import grid_surface, linear_response, power_response
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Pose, Surface

DOWN = np.array([0.0, 0.0, -1.0])


def _bumpy_surface(rng, n=61, half=0.03):
    """A wavy, jittered sheet (no distance ties) with tilted normals."""
    x, y = np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n))
    xy = np.column_stack([x.ravel(), y.ravel()]) + rng.uniform(-2e-4, 2e-4, (n * n, 2))
    z = 0.002 * np.sin(xy[:, 0] / 0.007) * np.cos(xy[:, 1] / 0.011)
    gx = 0.002 / 0.007 * np.cos(xy[:, 0] / 0.007) * np.cos(xy[:, 1] / 0.011)
    gy = -0.002 / 0.011 * np.sin(xy[:, 0] / 0.007) * np.sin(xy[:, 1] / 0.011)
    normals = np.column_stack([-gx, -gy, np.ones(len(z))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Surface(points=np.column_stack([xy, z]), normals=normals)


def _heterogeneous_response(rng, count, stiffening=False):
    """A baked power law, stiffness varying by 3x and onsets from -1.5 to +1 mm.

    ``stiffening``: exponents from 1.2 to 2.2 (the ``'layer'`` law's proxy varies), else 1.6.
    """
    k = rng.uniform(2e3, 6e3, count)
    p = rng.uniform(1.2, 2.2, count) if stiffening else np.full(count, 1.6)
    base = power_response(k, 1.6, depths=np.linspace(-0.004, 0.02, 121))
    shift = rng.uniform(-0.0015, 0.001, count)
    d = base.depths
    forces = k[:, None] * np.clip(d[None] - shift[:, None], 0.0, None) ** p[:, None]
    slopes = k * p * (d[-1] - shift) ** (p - 1.0)
    return BakedResponse(depths=d, forces=forces, slopes=slopes)


def _numpy_twin(sim):
    """The same simulator answering single poses on the stacked numpy path."""
    twin = copy.copy(sim)
    twin._compiled = False
    return twin


def _random_poses(rng, n, depth=(0.001, 0.007)):
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    return [Pose(position=[*rng.uniform(-0.012, 0.012, 2), 0.004 - rng.uniform(*depth)],
                 orientation=q) for q in quat]


@pytest.mark.parametrize('decay_law, decay, near, neighbours', [
    ('penetration', 0.008, 'paper', 'equal'), ('fixed', 0.006, 'paper', 'equal'),
    ('fixed', np.inf, 'paper', 'equal'), ('penetration', 0.008, 'flat', 'equal'),
    ('fixed', np.inf, 'flat', 'equal'), ('layer', 0.008, 'paper', 'equal'),
    ('penetration', 0.008, 'paper', 'smooth'), ('layer', 0.008, 'paper', 'smooth')])
def test_single_poses_equal_the_stacked_numpy_path(decay_law, decay, near, neighbours):
    rng = np.random.default_rng(21)
    surface = _bumpy_surface(rng)
    sim = ContactSimulator(surface, _heterogeneous_response(rng, len(surface),
                                                            decay_law == 'layer'),
                           c=0.004, spacing=0.002, decay=decay, decay_law=decay_law, near=near,
                           neighbours=neighbours)
    assert sim._baked is not None
    if decay_law == 'layer':
        assert np.ptp(sim.layer_thickness()) > 0.5
    twin = _numpy_twin(sim)
    compared = 0
    for mesh in (box((0.014, 0.01, 0.008)), icosphere(0.008, 2)):
        for pose in _random_poses(rng, 12):
            centre = pose.position + rng.uniform(-0.02, 0.02, 3)
            fast = sim.query(mesh, pose, DOWN, centre)
            slow = twin.query(mesh, pose, DOWN, centre)
            assert fast.contact_count == slow.contact_count
            assert fast.candidate_count == slow.candidate_count
            np.testing.assert_allclose(fast.wrench.as_vector(), slow.wrench.as_vector(),
                                       rtol=1e-9, atol=1e-12)
            assert fast.max_displacement == pytest.approx(slow.max_displacement, rel=1e-9,
                                                          abs=1e-15)
            # the same contacts in the same order
            np.testing.assert_allclose(fast.contact_points, slow.contact_points, atol=1e-15)
            np.testing.assert_allclose(fast.actual_displacements, slow.actual_displacements,
                                       rtol=1e-9, atol=1e-15)
            np.testing.assert_allclose(fast.contact_forces, slow.contact_forces, rtol=1e-9,
                                       atol=1e-12)
            assert fast.lcp_residual < 1e-12
            compared += fast.contact_count > 3
    assert compared >= 12


def test_a_response_that_is_not_a_plain_table_is_called_not_interpolated():
    rng = np.random.default_rng(22)
    surface = _bumpy_surface(rng, n=41)
    table = _heterogeneous_response(rng, len(surface))

    class Doubled(BakedResponse):
        def force(self, indices, d):
            return 2.0 * BakedResponse.force(self, indices, d)

    doubled = Doubled(depths=table.depths, forces=table.forces, slopes=table.slopes)
    plain = ContactSimulator(surface, table, c=0.004, spacing=0.002)
    twice = ContactSimulator(surface, doubled, c=0.004, spacing=0.002)
    assert twice._baked is None
    sphere = icosphere(0.008, 2)
    for pose in _random_poses(rng, 5):
        a = plain.query(sphere, pose, DOWN, pose.position)
        b = twice.query(sphere, pose, DOWN, pose.position)
        np.testing.assert_allclose(b.wrench.as_vector(), 2.0 * a.wrench.as_vector(),
                                   rtol=1e-12, atol=1e-14)


def test_the_kernels_deduplication_keeps_the_numpy_paths_candidates_in_its_order():
    rng = np.random.default_rng(23)
    n_points = 30
    table = np.zeros((n_points, 8))
    table[:, 2] = 1.0                                    # normals +z
    table[:, 5:] = rng.uniform(-0.01, 0.01, (n_points, 3))
    table[:, 3] = table[:, 7]                             # n . x = z
    for trial in range(20):
        k = 40
        nbr = rng.integers(0, n_points, (k, 3))
        nbr[: k // 2, 0] = rng.integers(0, 6, k // 2)     # repeated first neighbours
        nbr[k - 5:] = nbr[k - 10:k - 5][:, ::-1]         # repeated triples, permuted
        posed = rng.uniform(-0.01, 0.01, (k, 3))
        pos = np.zeros(3)
        w = rng.uniform(0.0, 1.0, (k, 3))
        w /= w.sum(axis=1, keepdims=True)
        out = single_pose.solve_single(nbr, w, posed, pos, table, 0.004, np.inf, False,
                                       np.zeros(0), False, 0.004, 0.1, 0.65, 200, 1e-12)
        keep = out[0]
        # the numpy path's selection, step by step
        sums = np.einsum('kj,kjc->kc', w, table[nbr])
        d = sums[:, 3] - np.einsum('ki,ki->k', posed, sums[:, :3])
        e = d - sums[:, 4]
        idx = np.flatnonzero(e > 0.0)
        sel = _deepest_per_key(nbr[idx, 0], e[idx])
        idx = idx if sel is None else idx[sel]
        sel = _deepest_per_triple(np.zeros(len(idx), dtype=np.int64), _sorted_triples(nbr[idx]),
                                  e[idx])
        idx = idx if sel is None else idx[sel]
        np.testing.assert_array_equal(keep, idx)
        np.testing.assert_allclose(out[5], e[idx], rtol=1e-12)


def test_the_compiled_pivoting_equals_the_dense_solver_and_survives_duplicates():
    rng = np.random.default_rng(24)
    for m in (1, 5, 30, 90):
        q = rng.uniform(-0.01, 0.01, (m, 3))
        G = shape_matrix(q, 0.004, 0.01)
        d = rng.uniform(-0.001, 0.003, m)
        free = np.ones(m, dtype=bool)
        x, rounds, status = single_pose.bpp(G, d, free, 200, 1e-12)
        ref, ref_rounds = bpp_dense(G, d, free=free)
        assert status == single_pose.OK and rounds == ref_rounds
        np.testing.assert_allclose(x, ref, rtol=1e-9, atol=1e-15)
    # two coincident points: G singular, the ridge answers; their sum is what is determined
    q = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.005, 0.0, 0.0]])
    G = shape_matrix(q, 0.004)
    d = np.array([0.002, 0.002, 0.001])
    x, _, status = single_pose.bpp(G, d, np.ones(3, dtype=bool), 200, 1e-12)
    assert status == single_pose.OK
    np.testing.assert_allclose(G @ x, d, atol=1e-9)


def test_pivoting_that_runs_out_of_rounds_raises_not_converged(monkeypatch):
    rng = np.random.default_rng(25)
    surface = _bumpy_surface(rng, n=41)
    sim = ContactSimulator(surface, linear_response(1e3, len(surface)), c=0.004,
                           spacing=0.002)
    pose = Pose(position=[0.0, 0.0, 0.004 - 0.006])
    mesh = box((0.02, 0.02, 0.006))
    assert sim.query(mesh, pose, DOWN, np.zeros(3)).contact_count > 5
    monkeypatch.setattr(simulator_module, 'MAX_PIVOTING', 1)
    monkeypatch.setattr(simulator_module, 'WARM_START', 0.0)   # every candidate free at first
    with pytest.raises(NotConverged, match='after 1 pivoting rounds'):
        sim.query(mesh, pose, DOWN, np.zeros(3))


def test_the_grid_neighbour_search_finds_the_kd_trees_three_nearest_within_max_gap():
    rng = np.random.default_rng(26)
    facing = rng.uniform(-0.03, 0.03, (2000, 2))
    max_gap = 0.002
    cell = 0.0025                                         # cells at least max_gap wide
    lo = facing.min(axis=0)
    origin = lo - 2 * cell
    last = (np.floor((facing.max(axis=0) - origin) / cell) + 2).astype(np.int64)
    starts, members = single_pose.cell_members(facing, origin, cell, last)
    assert starts[-1] == len(facing) and np.all(np.diff(starts) >= 0)
    # samples inside, at the rim and outside the cloud, plus a few exactly on facing points
    uv = np.vstack([rng.uniform(-0.04, 0.04, (3000, 2)), facing[:20]])
    dist, ref = cKDTree(facing).query(uv, k=4)
    within = np.flatnonzero(dist[:, 2] <= max_gap)
    assert 500 < len(within) < len(uv) - 500
    for smooth in (False, True):
        nn, w, rows = single_pose.three_nearest(uv, origin, cell, last, starts, members,
                                                facing, max_gap, smooth)
        np.testing.assert_array_equal(rows, within)
        np.testing.assert_array_equal(nn, ref[within, :3])
        np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=1e-14)
        if not smooth:
            np.testing.assert_array_equal(w, 1.0 / 3.0)
            continue
        # w_k = r4 - r_k over their sum, r4 the fourth-nearest (at most max_gap)
        r = dist[within]
        want = np.minimum(r[:, 3:], max_gap) - r[:, :3]
        np.testing.assert_allclose(w, want / want.sum(axis=1, keepdims=True), rtol=1e-9,
                                   atol=1e-12)
        assert np.all(np.diff(w, axis=1) <= 1e-15)        # nearer, heavier


def test_a_pose_over_a_regular_grid_gets_the_same_neighbours_single_and_batched():
    # samples equidistant from grid points: ties that a KD-tree breaks by its traversal
    surface = grid_surface(half=0.02, step=0.002)
    sim = ContactSimulator(surface, linear_response(2e3, len(surface)), c=0.004, spacing=0.002)
    sphere = icosphere(0.008, 2)
    poses = [Pose(position=[x, y, 0.008 - 0.003]) for x in (0.0, 0.001, 0.002)
             for y in (0.0, 0.001)]
    batch = sim.query_batch(sphere, poses, DOWN, np.zeros(3))
    for i, pose in enumerate(poses):
        one = sim.query(sphere, pose, DOWN, np.zeros(3))
        assert one.contact_count == batch.contact_count[i] > 0
        np.testing.assert_allclose(batch.wrenches[i], one.wrench.as_vector(), rtol=1e-9,
                                   atol=1e-12)


def test_smooth_neighbour_weights_take_the_steps_out_of_a_sideways_sweep():
    # One rigid point 1.5 mm into a jittered, heterogeneous surface, moved sideways over 3 mm
    # in 0.25 um steps. With equal weights its force jumps where its third and fourth nearest
    # surface points swap: the largest change does not shrink with the step. With smooth
    # weights the force is continuous: halve the step and the largest change halves.
    rng = np.random.default_rng(27)
    surface = _bumpy_surface(rng, n=41)
    table = _heterogeneous_response(rng, len(surface))
    xs = np.arange(0.0, 0.003, 2.5e-7) + 0.0013
    largest = {}
    for rule in ('equal', 'smooth'):
        sim = ContactSimulator(surface, table, c=0.004, spacing=0.002, neighbours=rule)
        fz = []
        for x in xs:
            z = 0.002 * np.sin(x / 0.007) * np.cos(0.0021 / 0.011)
            fz.append(sim.query_points(np.array([[x, 0.0021, z - 0.0015]]), DOWN,
                                       np.zeros(3)).wrench.force[2])
        fz = np.asarray(fz)
        assert np.all(fz > 0.0)
        # the largest change over a step of 0.5 um and of 0.25 um, as shares of the force
        largest[rule] = [np.max(np.abs(np.diff(fz[::k]))) / np.median(fz) for k in (2, 1)]
    coarse, fine = largest['equal']
    assert coarse > 0.1 and fine > 0.95 * coarse        # a jump of over 10 % of the force
    coarse, fine = largest['smooth']
    assert coarse < 0.02 and 1.7 * fine < coarse          # continuous
