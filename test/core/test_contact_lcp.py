"""Displacement LCP (seed 000, eq. 2-3): closed forms, invariants, the paper's scheme."""

import numpy as np
import pytest
from scipy.optimize import nnls

from pointforce_ros.contact import (lcp_residual, shape_function, shape_matrix, solve_lcp,
                                    solve_lcp_batch, solve_lcp_paper)
from pointforce_ros.errors import InvalidInput, NotConverged

C = 0.004


def random_problem(rng, m, spread=0.02, c=C):
    """Random contact-like instance: points in a patch, mostly positive nominal displacements."""
    q = np.column_stack([rng.uniform(-spread, spread, (m, 2)), rng.normal(0, 1e-3, m)])
    d = rng.uniform(-0.5e-3, 3e-3, m)
    return shape_matrix(q, c), d


def check_complementary(G, d, x, tol=1e-12):
    w = G @ x - d
    scale = np.abs(d).max()
    assert np.all(x >= 0.0)
    assert np.all(w >= -tol * scale)
    assert np.max(np.abs(x * w)) <= tol * scale * scale + 1e-30
    pos = d > 0
    assert np.all(x[pos] <= d[pos] + tol * scale)  # d~ <= d
    assert np.all(x[~pos] == 0.0)


def test_shape_function_closed_form():
    r = np.array([0.0, C, 3 * C])
    np.testing.assert_allclose(shape_function(r, C), [1.0, 0.5, 0.25])
    G = shape_matrix(np.array([[0, 0, 0], [C, 0, 0.0]]), C)
    np.testing.assert_allclose(G, [[1.0, 0.5], [0.5, 1.0]])


def test_shape_function_tail_decay_closed_form_and_positive_definite():
    r = np.array([0.0, C, 3 * C])
    L = 2 * C
    np.testing.assert_allclose(shape_function(r, C, L), [1.0, 0.5 * np.exp(-0.5),
                                                         0.25 * np.exp(-1.5)])
    np.testing.assert_allclose(shape_function(r, C, np.inf), shape_function(r, C))
    # the cut-off keeps G positive definite (a positive mixture of exponential kernels)
    pts = np.random.default_rng(3).uniform(-0.02, 0.02, (60, 3))
    for decay in (0.5 * C, 4 * C, np.inf):
        assert np.linalg.eigvalsh(shape_matrix(pts, C, decay)).min() > 0


def test_single_point_actual_equals_nominal():
    sol = solve_lcp(np.ones((1, 1)), np.array([2.5e-3]))
    np.testing.assert_allclose(sol.x, [2.5e-3], rtol=1e-15)
    assert sol.residual == 0.0 and sol.converged


def test_two_points_closed_form_and_decoupling():
    d = np.array([2e-3, 1e-3])
    for r in (0.5 * C, 10 * C, 1e4 * C):
        g = C / (C + r)
        sol = solve_lcp(np.array([[1.0, g], [g, 1.0]]), d)
        both = np.array([d[0] - g * d[1], d[1] - g * d[0]]) / (1 - g * g)
        expected = both if both.min() > 0 else np.array([d[0], 0.0])
        np.testing.assert_allclose(sol.x, expected, rtol=1e-12, atol=1e-18)
    # Far apart the points decouple: d~ -> d (g = 1e-4 here).
    np.testing.assert_allclose(sol.x, d, rtol=3e-4)
    # Close together the shallow point is lifted off: d~_2 = 0, its gap w_2 = g d_1 - d_2 > 0.
    sol = solve_lcp(np.array([[1.0, 0.8], [0.8, 1.0]]), d)
    np.testing.assert_allclose(sol.x, [2e-3, 0.0], atol=1e-18)
    np.testing.assert_allclose(sol.w, [0.0, 0.8 * 2e-3 - 1e-3], atol=1e-18)


@pytest.mark.parametrize('seed', range(6))
def test_bpp_is_complementary_and_matches_the_qp(seed):
    rng = np.random.default_rng(seed)
    G, d = random_problem(rng, 60)
    sol = solve_lcp(G, d)
    assert sol.converged and sol.residual <= 1e-12 * np.abs(d).max()
    check_complementary(G, d, sol.x)
    # Same as the QP min 1/2 x'Gx - d'x, x >= 0, solved as NNLS on the Cholesky factor.
    L = np.linalg.cholesky(G)
    ref, _ = nnls(L.T, np.linalg.solve(L, d), maxiter=2000)
    np.testing.assert_allclose(sol.x, ref, atol=1e-9 * np.abs(d).max())
    assert 0 < np.count_nonzero(sol.x) < len(d)  # a genuinely mixed active set


def test_warm_start_gives_the_same_solution():
    rng = np.random.default_rng(10)
    G, d = random_problem(rng, 40)
    ref = solve_lcp(G, d).x
    for free in (np.zeros(40, bool), rng.random(40) < 0.5, ref > 0):
        np.testing.assert_allclose(solve_lcp(G, d, free=free).x, ref, atol=1e-15)
    assert solve_lcp(G, d, free=ref > 0).iterations == 1


def test_batch_with_padding_equals_single_solves():
    rng = np.random.default_rng(4)
    problems = [random_problem(rng, m) for m in (1, 7, 30, 18)]
    m = max(len(d) for _, d in problems)
    Gs = np.stack([np.pad(G, (0, m - len(d)), constant_values=7.0) for G, d in problems])
    ds = np.stack([np.pad(d, (0, m - len(d)), constant_values=1.0) for _, d in problems])
    valid = np.stack([np.arange(m) < len(d) for _, d in problems])
    x, res, it = solve_lcp_batch(Gs, ds, valid)
    for k, (G, d) in enumerate(problems):
        np.testing.assert_allclose(x[k, :len(d)], solve_lcp(G, d).x, atol=1e-18)
        assert np.all(x[k, len(d):] == 0.0)
    assert np.all(res <= 1e-12 * np.abs(ds).max())


def test_paper_scheme_agrees_where_it_converges_and_its_failures_are_penetrations():
    # Strong coupling (80 points within 2 mm, c = 4 mm) is where the scheme can fail: it drops
    # every negative point at once and never re-admits one (~3 % of such instances).
    rng = np.random.default_rng(1)
    agree = fail = 0
    for _ in range(200):
        G, d = random_problem(rng, 80, spread=0.002)
        ours = solve_lcp(G, d)
        paper = solve_lcp_paper(G, d)
        if paper.converged:
            agree += 1
            np.testing.assert_allclose(paper.x, ours.x, atol=1e-12)
        else:
            fail += 1
            # Never a negative d~ (it drops those), always a dropped point left penetrated.
            assert np.all(paper.x >= 0)
            dropped = paper.x == 0
            assert np.min(paper.w[dropped]) < 0
            assert paper.residual == pytest.approx(-np.min(paper.w[dropped]), rel=1e-9)
            assert paper.iterations <= 80
            assert solve_lcp(G, d).converged
    assert agree > 150 and fail >= 2  # both regimes are exercised by this seed


def test_duplicate_points_do_not_crash_the_solver():
    q = np.array([[0.0, 0, 0], [0.0, 0, 0], [0.01, 0, 0]])
    G = shape_matrix(q, C)  # rows 0 and 1 identical: singular
    d = np.array([2e-3, 2e-3, 1e-3])
    sol = solve_lcp(G, d)
    assert np.all(np.isfinite(sol.x)) and np.all(sol.x >= 0)
    assert lcp_residual(G, d, sol.x) < 1e-9
    with pytest.raises(NotConverged, match='singular'):
        solve_lcp_paper(G, d)


def test_bad_shapes_raise_invalid_input():
    with pytest.raises(InvalidInput, match='G must be'):
        solve_lcp(np.eye(3), np.ones(2))
    with pytest.raises(InvalidInput, match='finite'):
        solve_lcp(np.eye(2), np.array([1.0, np.nan]))
