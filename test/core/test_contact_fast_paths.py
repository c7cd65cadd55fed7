"""The contact core's fast paths give the answers of the plain computation (issues 16, 21).

* the batched LCP solves only each problem's free set once pivoting has shrunk it (a stack
  compressed to the largest free count): the same solutions as the full masked systems;
* the simulator's first pass drops samples below the lowest height bound of the whole grid
  before computing their cells: the same candidates, so the same wrenches, as the per-cell
  bound alone.
"""

import numpy as np

import pointforce_ros.contact.simulator as simulator_module
from pointforce_ros.contact import ContactSimulator, shape_matrix, solve_lcp, solve_lcp_batch
from pointforce_ros.contact.lcp import _batched_solve, _solve_free
from pointforce_ros.lab.synthetic_contact import dome_surface, linear_response
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import Pose

C = 0.004


def _stack(rng, sizes):
    problems = []
    for m in sizes:
        q = np.column_stack([rng.uniform(-0.02, 0.02, (m, 2)), rng.normal(0, 1e-3, m)])
        problems.append((shape_matrix(q, C), rng.uniform(-0.5e-3, 3e-3, m)))
    m = max(sizes)
    G = np.stack([np.pad(g, (0, m - len(d)), constant_values=7.0) for g, d in problems])
    d = np.stack([np.pad(d, (0, m - len(d)), constant_values=1.0) for _, d in problems])
    valid = np.stack([np.arange(m) < len(dd) for _, dd in problems])
    return problems, G, d, valid


def test_compressed_free_set_solve_equals_the_full_masked_system():
    rng = np.random.default_rng(11)
    _, G, d, valid = _stack(rng, (40, 25, 33, 40, 12))
    m = G.shape[1]
    eye = np.eye(m, dtype=bool)
    for trial in range(5):
        free = valid & (rng.uniform(size=valid.shape) < 0.3)
        free[0, :] = False      # one problem with nothing free
        x = _solve_free(G, d, free, eye)
        full = np.where(free[:, :, None] & free[:, None, :], G, eye)
        expected = np.where(free, _batched_solve(full, np.where(free, d, 0.0))[0], 0.0)
        assert int(free.sum(axis=1).max()) < m          # the compressed branch ran
        np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-15)
        assert np.all(x[~free] == 0.0)


def test_batched_lcp_with_several_pivoting_rounds_equals_single_solves():
    rng = np.random.default_rng(12)
    problems, G, d, valid = _stack(rng, (60, 45, 52, 9, 60))
    x, res, it = solve_lcp_batch(G, d, valid)
    assert it.max() >= 3                                  # later rounds ran compressed
    for k, (g, dd) in enumerate(problems):
        np.testing.assert_allclose(x[k, :len(dd)], solve_lcp(g, dd).x, rtol=1e-9, atol=1e-15)
    assert np.all(res <= 1e-12 * np.abs(d).max())


def test_height_prefilter_keeps_the_answers_of_the_per_cell_bound():
    surface = dome_surface(n=61, half=0.05, radius=0.3)
    sim = ContactSimulator(surface, linear_response(np.full(len(surface), 800.0)), c=C,
                           spacing=0.003)
    sphere = icosphere(0.02, 2)
    rng = np.random.default_rng(13)
    n = 40
    quat = rng.normal(size=(n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    rows = np.column_stack([rng.uniform(-0.02, 0.02, (n, 2)),
                            0.02 - rng.uniform(-0.002, 0.006, n), quat])
    down = np.array([0.0, 0.0, -1.0])
    proj = sim.projection(down)
    assert np.isfinite(proj.floor) and proj.floor == np.min(proj.bound)
    fast = sim.query_batch(sphere, rows, down, np.zeros(3))
    assert np.count_nonzero(fast.contact_count) > n // 2
    # the same simulator with the prefilter made a no-op (a floor of -inf) answers the same
    proj.floor = -np.inf
    plain = sim.query_batch(sphere, rows, down, np.zeros(3))
    np.testing.assert_array_equal(fast.contact_count, plain.contact_count)
    np.testing.assert_allclose(fast.wrenches, plain.wrenches, rtol=1e-12, atol=1e-12)
    single = sim.query(sphere, Pose(position=rows[0, :3], orientation=rows[0, 3:]), down,
                       np.zeros(3))
    np.testing.assert_allclose(single.wrench.force, plain.wrenches[0, :3], rtol=1e-9,
                               atol=1e-12)


def test_warm_start_gives_the_papers_answers_in_fewer_pivoting_rounds(monkeypatch):
    surface = dome_surface(n=81, half=0.05, radius=0.3)
    sim = ContactSimulator(surface, linear_response(np.full(len(surface), 800.0)), c=C,
                           spacing=0.003)
    sphere = icosphere(0.02, 2)
    rng = np.random.default_rng(14)
    n = 60
    rows = np.column_stack([rng.uniform(-0.02, 0.02, (n, 2)), 0.02 - rng.uniform(0, 0.005, n),
                            np.zeros((n, 3)), np.ones(n)])
    down = np.array([0.0, 0.0, -1.0])
    rounds = []
    solve = simulator_module.solve_lcp_batch

    def counted(*args, **kwargs):
        out = solve(*args, **kwargs)
        rounds[-1] += int(out[2].sum())
        return out
    monkeypatch.setattr(simulator_module, 'solve_lcp_batch', counted)
    answers = []
    for warm in (0.0, simulator_module.WARM_START):   # 0: every candidate, the paper's guess
        monkeypatch.setattr(simulator_module, 'WARM_START', warm)
        rounds.append(0)
        answers.append(sim.query_batch(sphere, rows, down, np.zeros(3)))
    paper, warm = answers
    assert np.count_nonzero(paper.contact_count > 3) > n // 2
    np.testing.assert_array_equal(warm.contact_count, paper.contact_count)
    np.testing.assert_allclose(warm.wrenches, paper.wrenches, rtol=1e-12, atol=1e-12)
    assert rounds[1] < 0.85 * rounds[0]
