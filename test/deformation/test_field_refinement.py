"""A seeded modulus field refined by the identification's own fit (issue 18, beyond the paper).

Closed loop: the estimator's own FEM with a known heterogeneous field renders the pokes, so
the refinement's answer is known: the field is ``seed ** a * exp(c * depth)``.
"""

import numpy as np
import pytest

from pointforce_ros.deformation.bench import surface_samples
from pointforce_ros.deformation.cell_check import depth_fraction, refine_field
from pointforce_ros.deformation.fem import CorotationalFem, load_columns, surface_point_load
from pointforce_ros.deformation.force import estimate_force
from pointforce_ros.deformation.identify import identify_elasticity, IdentifyConfig, Poke
from pointforce_ros.deformation.mesh import block_mesh
from pointforce_ros.errors import InvalidInput

SIZE = (0.06, 0.05, 0.03)
CORNER = (0.47, -0.025)


@pytest.fixture(scope='module')
def mesh():
    return block_mesh(SIZE, 0.006, 5, grading=1.5, corner=CORNER)


def _push(fem, point, force, radius=0.004):
    nodes, w = surface_point_load(fem.mesh, point, radius)
    return fem.solve(load_columns(fem.mesh, nodes, w) @ np.asarray(force))


def _pokes(truth, points, forces, seed):
    rng = np.random.default_rng(seed)
    return [Poke(p, f, surface_samples(truth.mesh, _push(truth, p, f), 3000, 1e-5, rng))
            for p, f in zip(points, forces)]


def test_depth_fraction_is_zero_at_the_top_and_one_on_the_table(mesh):
    depth = depth_fraction(mesh)
    z = mesh.nodes[mesh.tets][:, :, 2].mean(axis=1)
    assert depth.shape == (len(mesh.tets),)
    np.testing.assert_allclose(depth, 1.0 - z / SIZE[2], atol=1e-9)
    assert depth.min() < 0.1 and depth.max() > 0.9


def test_refinement_recovers_the_seed_exponent_and_the_depth_layer(mesh):
    depth = depth_fraction(mesh)
    x = mesh.nodes[mesh.tets][:, :, 0].mean(axis=1)
    seed = np.exp(40.0 * (x - x.mean()))          # a point model's map: x-gradient, e^2.4
    a_true, c_true = 0.5, 1.5                     # half its contrast; stiffer at depth
    field = seed ** a_true * np.exp(c_true * (depth - depth.mean()))
    truth = CorotationalFem(mesh, 1e5 * field / field.mean(), 0.35)
    top = SIZE[2]
    points = [[0.485, -0.010, top], [0.515, 0.008, top], [0.50, 0.0, top]]
    forces = [[0.0, 0.0, -0.6], [0.05, 0.0, -0.8], [0.0, -0.05, -0.7]]
    pokes = _pokes(truth, points, forces, 1)
    config = IdentifyConfig()
    homogeneous, fem_h = identify_elasticity(mesh, pokes, config)
    refined, fit, fem, info = refine_field(mesh, pokes, config, seed=seed, max_evaluations=20)
    # measured: exponent 0.50, layer 1.57; residual 18.2 (one E) and 16.3 (the seed as given)
    # -> 13.6 um, over a camera noise of 10 um
    assert info.accepted
    assert info.exponent == pytest.approx(a_true, abs=0.15)
    assert info.layer == pytest.approx(c_true, abs=0.4)
    assert fit.residual_rms == pytest.approx(info.residual_rms)
    assert info.residual_rms < 0.9 * info.start_rms
    assert fit.residual_rms < 0.8 * homogeneous.residual_rms
    # a held-out push near the soft side: the refined field's force is the better one
    p, f = [0.48, 0.012, top], np.array([0.05, 0.0, -0.7])
    cloud = surface_samples(mesh, _push(truth, p, f), 3000, 1e-5, np.random.default_rng(9))
    err_h = np.linalg.norm(estimate_force(fem_h, p, cloud).force - f) / np.linalg.norm(f)
    err_r = np.linalg.norm(estimate_force(fem, p, cloud).force - f) / np.linalg.norm(f)
    assert err_r < 0.05 and err_r < err_h, (err_r, err_h)


def test_a_depth_layer_alone_and_a_bad_seed(mesh):
    depth = depth_fraction(mesh)
    truth = CorotationalFem(mesh, 1e5 * np.exp(-1.0 * (depth - depth.mean())), 0.35)
    top = SIZE[2]
    pokes = _pokes(truth, [[0.49, -0.008, top], [0.51, 0.01, top]],
                   [[0.0, 0.0, -0.6], [0.0, 0.0, -0.8]], 2)
    _, _, _, info = refine_field(mesh, pokes, IdentifyConfig(), max_evaluations=12)
    # measured: layer -1.06 (a soft core under a stiffer top)
    assert info.layer == pytest.approx(-1.0, abs=0.4) and info.exponent == 1.0
    assert info.accepted and info.best == (1.0, info.layer)
    with pytest.raises(InvalidInput, match='seed'):
        refine_field(mesh, pokes, IdentifyConfig(), seed=-np.ones(len(mesh.tets)))


def test_a_gain_within_the_noise_is_not_taken(mesh):
    """A homogeneous object: whatever depth layer the noise prefers, the field stays as seeded."""
    truth = CorotationalFem(mesh, 1e5, 0.35)
    top = SIZE[2]
    pokes = _pokes(truth, [[0.49, -0.008, top], [0.51, 0.01, top]],
                   [[0.0, 0.0, -0.6], [0.0, 0.0, -0.8]], 3)
    field, fit, _, info = refine_field(mesh, pokes, IdentifyConfig(), max_evaluations=8)
    assert not info.accepted and info.layer == 0.0 and info.exponent == 1.0
    assert info.best_rms <= info.start_rms and fit.residual_rms == pytest.approx(info.start_rms)
    np.testing.assert_allclose(field, 1.0)
