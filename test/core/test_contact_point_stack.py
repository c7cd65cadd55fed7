"""The batch contact path's column-wise LCP and run reductions (issue 16) keep the answers.

* :class:`PointShapeStack` is the shape matrix of its points (diagonal exactly one), also with
  a finite decay;
* the LCP stack solved from the points (only the free sets' columns built) gives the solutions,
  pivoting rounds, residuals and ``G x`` of the dense stack;
* the deepest entry per key, found per run of a stable sort, is the one a lexicographic sort
  (key, then depth descending) picks, ties included;
* a batch whose poses share one rotation (heights from one product for all of them) answers
  as the single queries do, tilted or not.
"""

import numpy as np
import pytest

from pointforce_ros.contact import ContactSimulator, shape_matrix, solve_lcp_batch
from pointforce_ros.contact.lcp import PointShapeStack
from pointforce_ros.contact.simulator import _deepest_per_key
from pointforce_ros.lab.synthetic_contact import dome_surface, linear_response
from pointforce_ros.shapes import box
from pointforce_ros.types import Pose

C = 0.004


def _problems(rng, sizes):
    m = max(sizes)
    points = np.zeros((len(sizes), m, 3))
    d = np.ones((len(sizes), m))
    valid = np.zeros((len(sizes), m), dtype=bool)
    for b, n in enumerate(sizes):
        q = np.column_stack([rng.uniform(-0.02, 0.02, (n, 2)), rng.normal(0, 1e-3, n)])
        points[b, :n] = q - q.mean(axis=0)
        d[b, :n] = 3e-3 - 0.5 * np.sum(q[:, :2] ** 2, axis=1) / 0.02 + rng.normal(0, 2e-4, n)
        valid[b, :n] = True
    return points, d, valid


@pytest.mark.parametrize('decay', [np.inf, 0.01])
def test_point_stack_is_the_shape_matrix_of_its_points(decay):
    rng = np.random.default_rng(31)
    points, _, valid = _problems(rng, (30, 17, 30, 5))
    dense = PointShapeStack(points, C, decay).dense()
    for b in range(len(points)):
        n = int(valid[b].sum())
        np.testing.assert_allclose(dense[b, :n, :n], shape_matrix(points[b, :n], C, decay),
                                   rtol=1e-12, atol=0.0)
        assert np.all(np.diagonal(dense[b]) == 1.0)


def test_point_stack_columns_follow_the_row_order():
    rng = np.random.default_rng(32)
    points, _, _ = _problems(rng, (12, 12, 12))
    stack = PointShapeStack(points, C)
    full = stack.dense()
    order = np.stack([rng.permutation(12) for _ in range(2)])
    problems = np.array([2, 0])
    cols = stack.columns(problems, order, 5)
    for i, p in enumerate(problems):
        np.testing.assert_allclose(cols[i], full[p][np.ix_(order[i], order[i, :5])],
                                   rtol=1e-12, atol=0.0)


@pytest.mark.parametrize('warm', [None, 0.65])
def test_lcp_from_points_equals_the_dense_stack(warm):
    rng = np.random.default_rng(33)
    points, d, valid = _problems(rng, (60, 45, 52, 9, 60, 1))
    G = PointShapeStack(points, C).dense()
    top = np.where(valid, d, -np.inf).max(axis=1, keepdims=True)
    free = None if warm is None else valid & (d >= warm * top)
    u_dense, u_points = np.empty_like(d), np.empty_like(d)
    x0, r0, it0 = solve_lcp_batch(G, d, valid, free=free, product=u_dense)
    x1, r1, it1 = solve_lcp_batch(PointShapeStack(points, C), d, valid, free=free,
                                  product=u_points)
    assert it0.max() >= 3                        # several pivoting rounds ran
    np.testing.assert_array_equal(it1, it0)
    np.testing.assert_array_equal(x1 > 0, x0 > 0)
    np.testing.assert_allclose(x1, x0, rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(np.where(valid, u_points, 0), np.where(valid, u_dense, 0),
                               rtol=1e-12, atol=1e-18)
    assert np.all(r1 <= 1e-12 * np.abs(d).max())
    assert np.all(x1[~valid] == 0.0)
    # complementarity on every problem: G x - d >= 0, x >= 0, (G x - d) x = 0
    w = np.where(valid, u_points - d, 0.0)
    assert np.all(w >= -1e-15) and np.all(np.abs(w * x1) <= 1e-18)


def test_deepest_per_key_picks_as_the_lexicographic_sort():
    rng = np.random.default_rng(34)
    for trial in range(20):
        n = int(rng.integers(2, 400))
        key = np.sort(rng.integers(0, n // 2 + 1, n)) + rng.integers(0, 2, n)  # nearly sorted
        depth = rng.choice([0.1, 0.2, 0.3], n) if trial % 2 else rng.uniform(0, 1, n)
        sel = _deepest_per_key(key, depth)
        order = np.lexsort((-depth, key))
        first = np.ones(n, dtype=bool)
        first[1:] = key[order][1:] != key[order][:-1]
        if np.all(first):
            assert sel is None
        else:
            np.testing.assert_array_equal(sel, order[first])
    assert _deepest_per_key(np.array([3, 1, 2]), np.ones(3)) is None


@pytest.mark.parametrize('orientation', [[0.0, 0.0, 0.0, 1.0], [0.1, -0.2, 0.3, 0.9]])
def test_batch_of_one_shared_rotation_equals_single_queries(orientation):
    surface = dome_surface(n=81, half=0.03, radius=0.1)
    sim = ContactSimulator(surface, linear_response(np.full(len(surface), 500.0)), c=C)
    q = np.asarray(orientation) / np.linalg.norm(orientation)
    rng = np.random.default_rng(35)
    rows = np.column_stack([rng.uniform(-0.01, 0.01, (30, 2)), rng.uniform(-0.003, 0.006, 30),
                            np.tile(q, (30, 1))])
    mesh = box((0.015, 0.01, 0.006))
    down = np.array([0.0, 0.0, -1.0])
    batch = sim.query_batch(mesh, rows, down, np.zeros(3))
    assert 5 < np.count_nonzero(batch.contact_count) < 30
    for i, row in enumerate(rows):
        one = sim.query(mesh, Pose(position=row[:3], orientation=row[3:]), down, np.zeros(3))
        assert batch.contact_count[i] == one.contact_count
        np.testing.assert_allclose(batch.wrenches[i], one.wrench.as_vector(), rtol=1e-10,
                                   atol=1e-13)
