"""Co-rotational tet FEM: closed-form linear cases, co-rotation invariants, polar decomposition."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointforce_ros.deformation.fem import (CorotationalFem, lame, polar_rotation,
                                            surface_point_load)
from pointforce_ros.deformation.mesh import block_mesh
from pointforce_ros.errors import InvalidInput, NotConverged

SIZE = (0.02, 0.016, 0.012)


def _block():
    return block_mesh(SIZE, 0.004, 3, grading=1.3)


def _top_pressure(mesh, p):
    """Consistent nodal loads (area / 3 per node) of a uniform pressure p (Pa) on the top."""
    load = np.zeros((mesh.n_nodes, 3))
    tri = mesh.surface_triangles
    c = mesh.nodes[tri]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    top = n[:, 2] > 0.99 * np.linalg.norm(n, axis=1)
    area = 0.5 * np.linalg.norm(n[top], axis=1)
    for k in range(3):
        np.add.at(load[:, 2], tri[top, k], -p * area / 3)
    return load.ravel()


def test_confined_compression_is_exact():
    # sides fixed in their normal direction, bottom in z: u_z = -p z / (lambda + 2 mu)
    mesh = _block()
    x = mesh.nodes
    fixed = np.zeros((mesh.n_nodes, 3), dtype=bool)
    fixed[:, 0] = np.isclose(x[:, 0], 0) | np.isclose(x[:, 0], SIZE[0])
    fixed[:, 1] = np.isclose(x[:, 1], 0) | np.isclose(x[:, 1], SIZE[1])
    fixed[:, 2] = np.isclose(x[:, 2], 0)
    young, nu, p = 3e4, 0.4, 500.0
    fem = CorotationalFem(mesh, young, nu, fixed_dofs=fixed)
    u = fem.solve_linear(_top_pressure(mesh, p)).reshape(-1, 3)
    lam, mu = lame(young, nu)
    np.testing.assert_allclose(u[:, 2], -p * x[:, 2] / (lam + 2 * mu), rtol=0, atol=1e-12)
    np.testing.assert_allclose(u[:, :2], 0.0, atol=1e-12)


def test_uniaxial_stress_gives_young_and_poisson():
    # sliding bottom, free sides: u_z = -p z / E, lateral u = nu p (x - x0) / E
    mesh = _block()
    x = mesh.nodes
    fixed = np.zeros((mesh.n_nodes, 3), dtype=bool)
    bottom = np.isclose(x[:, 2], 0)
    fixed[bottom, 2] = True
    origin = np.flatnonzero(bottom & np.isclose(x[:, 0], 0) & np.isclose(x[:, 1], 0))[0]
    other = np.flatnonzero(bottom & np.isclose(x[:, 0], SIZE[0]) & np.isclose(x[:, 1], 0))[0]
    fixed[origin, :2] = True
    fixed[other, 1] = True
    young, nu, p = 5e4, 0.3, 800.0
    fem = CorotationalFem(mesh, young, nu, fixed_dofs=fixed)
    u = fem.solve_linear(_top_pressure(mesh, p)).reshape(-1, 3)
    want = np.column_stack([nu * p * x[:, 0] / young, nu * p * x[:, 1] / young,
                            -p * x[:, 2] / young])
    np.testing.assert_allclose(u, want, rtol=0, atol=1e-10)


def test_corotation_ignores_rigid_rotation_and_rotates_with_the_body():
    mesh = _block()
    fem = CorotationalFem(mesh, 4e4, 0.35)
    rot = Rotation.from_rotvec([0.3, -0.5, 0.8]).as_matrix()
    centre = mesh.nodes.mean(axis=0)
    rigid = (mesh.nodes - centre) @ rot.T + centre - mesh.nodes
    np.testing.assert_allclose(fem.internal_force(rigid.ravel()), 0.0, atol=1e-9)
    # the linear model would see large strain in the rigid rotation
    assert np.abs(fem.k @ rigid.ravel()).max() > 1e-2
    rng = np.random.default_rng(3)
    strain = 1e-3 * rng.normal(size=mesh.nodes.shape)
    f0 = fem.internal_force(strain.ravel()).reshape(-1, 3)
    moved = (mesh.nodes + strain - centre) @ rot.T + centre - mesh.nodes
    f1 = fem.internal_force(moved.ravel()).reshape(-1, 3)
    np.testing.assert_allclose(f1, f0 @ rot.T, atol=1e-9 * np.abs(f0).max() + 1e-12)


def test_corotational_solve_tends_to_linear_at_small_load_and_balances_large_ones():
    mesh = _block()
    fem = CorotationalFem(mesh, 2e4, 0.3)
    nodes, w = surface_point_load(mesh, [0.01, 0.008, SIZE[2]], 0.003)
    load = np.zeros((mesh.n_nodes, 3))
    load[nodes] = np.outer(w, [0.3, 0.0, -1.0])

    def deviation(scale):
        lin = fem.solve_linear(scale * load.ravel())
        return np.abs(fem.solve(scale * load.ravel(), tol=1e-10) - lin).max() / np.abs(lin).max()

    # geometric nonlinearity: the relative deviation from linear grows with the load
    assert deviation(1e-3) < 1e-3
    assert deviation(0.3) > 30 * deviation(1e-3)
    # 3.3 mm under the patch of a 12 mm block (the rest stiffness alone diverges at 2x this)
    big = fem.solve(0.5 * load.ravel(), tol=1e-9, max_iter=60)
    r = 0.5 * load.ravel() - fem.internal_force(big)
    assert np.linalg.norm(r[fem.free]) <= 1e-9 * np.linalg.norm(0.5 * load)
    assert np.abs(big).max() > 3e-3
    assert np.all(mesh.volumes(mesh.nodes + big.reshape(-1, 3)) > 0)
    with pytest.raises(NotConverged):
        fem.solve(load.ravel(), tol=1e-14, max_iter=2)


def test_polar_rotation_matches_the_svd():
    rng = np.random.default_rng(5)
    rot = Rotation.random(200, random_state=2).as_matrix()
    s = np.eye(3) + 0.3 * rng.normal(size=(200, 3, 3))
    s = s @ s.transpose(0, 2, 1) + 0.1 * np.eye(3)  # symmetric positive definite stretch
    r = polar_rotation(rot @ s)
    np.testing.assert_allclose(r, rot, atol=1e-10)


def test_material_and_load_errors():
    mesh = _block()
    with pytest.raises(InvalidInput):
        CorotationalFem(mesh, -1.0, 0.3)
    with pytest.raises(InvalidInput):
        CorotationalFem(mesh, 1e4, 0.5)
    with pytest.raises(InvalidInput):
        CorotationalFem(mesh, np.ones(3), 0.3)
    with pytest.raises(InvalidInput, match='not on it'):
        surface_point_load(mesh, [0.01, 0.008, SIZE[2] + 0.05], 0.003)
    with pytest.raises(InvalidInput):
        surface_point_load(mesh, [np.nan, 0.0, 0.0], 0.003)


def test_per_element_modulus_scales_the_response():
    mesh = _block()
    fem = CorotationalFem(mesh, 3e4, 0.3)
    load = _top_pressure(mesh, 100.0)
    u1 = fem.solve_linear(load)
    fem.set_material(np.full(len(mesh.tets), 6e4), 0.3)
    np.testing.assert_allclose(fem.solve_linear(load), 0.5 * u1, atol=1e-14)
    np.testing.assert_allclose(fem.element_young, 6e4)


def test_a_load_radius_far_below_the_node_spacing_still_gives_finite_weights():
    """Audit 39: every exp(-(d/r)^2) underflowed to 0, the weights were 0/0 = NaN and the
    estimate failed in the SVD (a model file with load_radius 1e-300)."""
    mesh = block_mesh((0.04, 0.04, 0.02), 0.005, 3)
    point = np.array([0.0213, 0.0187, 0.02])   # on the top, not at a node
    nodes, w = surface_point_load(mesh, point, 0.004)
    surf = mesh.surface_nodes
    d = np.linalg.norm(mesh.nodes[surf] - point, axis=1)
    tri = mesh.surface_triangles
    c = mesh.nodes[tri]
    area = np.bincount(tri.ravel(), np.repeat(0.5 * np.linalg.norm(
        np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1) / 3.0, 3),
        minlength=mesh.n_nodes)
    expected = area[surf[d <= 0.012]] * np.exp(-(d[d <= 0.012] / 0.004) ** 2)
    np.testing.assert_allclose(w, expected / expected.sum(), rtol=1e-12)   # unchanged
    for radius in (1e-6, 1e-300, 5e-324):
        nodes, w = surface_point_load(mesh, point, radius)
        assert np.all(np.isfinite(w)) and w.sum() == pytest.approx(1.0)
        assert nodes.tolist() == [surf[np.argmin(d)]]
