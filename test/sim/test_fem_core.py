"""FEM core: material law, assembly, probes, contact geometry, objects (fast, closed-form)."""

import numpy as np
import pytest

from pointforce_ros.sim.fem.contact import closest_point_on_triangles, RigidProbe
from pointforce_ros.sim.fem.hyperelastic import Assembler, isochoric, volumetric
from pointforce_ros.sim.fem.mesh import graded_axis, structured_hex
from pointforce_ros.sim.fem.probes import (box_probe, cylinder_probe, paddle_probe,
                                           point_probe, pose_for_push, sphere_probe)
from pointforce_ros.sim.objects import list_objects, load_object
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.types import Mesh


def _random_f(rng, scale=0.3):
    f = np.eye(3) + scale * rng.standard_normal((3, 3))
    if np.linalg.det(f) < 0:
        f[0] *= -1
    return f


@pytest.mark.parametrize('law', [isochoric, volumetric])
def test_stress_and_tangent_match_finite_differences(law):
    rng = np.random.default_rng(3)
    f = _random_f(rng)
    w, p, a = law(f, 1.7)
    eps = 1e-6
    p_fd = np.zeros((3, 3))
    a_fd = np.zeros((3, 3, 3, 3))
    for k in range(3):
        for m in range(3):
            d = np.zeros((3, 3))
            d[k, m] = eps
            p_fd[k, m] = (law(f + d, 1.7)[0] - law(f - d, 1.7)[0]) / (2 * eps)
            a_fd[:, :, k, m] = (law(f + d, 1.7)[1] - law(f - d, 1.7)[1]) / (2 * eps)
    np.testing.assert_allclose(p, p_fd, atol=1e-7 * np.abs(p).max())
    np.testing.assert_allclose(a, a_fd, atol=1e-7 * np.abs(a).max())


def test_energy_and_stress_vanish_at_rest_and_are_frame_indifferent():
    rng = np.random.default_rng(4)
    w_iso, p_iso, _ = isochoric(np.eye(3), 2.0)
    w_vol, p_vol, _ = volumetric(np.eye(3), 5.0)
    assert abs(w_iso) < 1e-14 and abs(w_vol) < 1e-14
    assert np.abs(p_iso).max() < 1e-14 and np.abs(p_vol).max() < 1e-14
    f = _random_f(rng)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    q *= np.sign(np.linalg.det(q))
    assert isochoric(q @ f, 2.0)[0] == pytest.approx(isochoric(f, 2.0)[0], rel=1e-12)
    assert volumetric(q @ f, 5.0)[0] == pytest.approx(volumetric(f, 5.0)[0], rel=1e-12)


def test_small_strain_limit_is_linear_elasticity():
    """Uniaxial stress of one element: K0 reproduces E and nu (selective-reduced hex)."""
    e, nu = 2.0e5, 0.3
    mesh = structured_hex([0, 1e-2], [0, 1e-2], [0, 1e-2])
    asm = Assembler(mesh, e, nu)
    k0 = asm.linear_stiffness().toarray()
    eps = 1e-4
    x = mesh.nodes
    u = np.stack([-nu * eps * x[:, 0], -nu * eps * x[:, 1], eps * x[:, 2]], -1)
    f = (k0 @ u.ravel()).reshape(-1, 3)
    top = x[:, 2] > 5e-3
    sigma_zz = f[top, 2].sum() / 1e-4
    assert sigma_zz == pytest.approx(e * eps, rel=1e-10)
    np.testing.assert_allclose(f[:, :2], 0.0, atol=1e-9 * abs(f).max())


def test_assembled_tangent_matches_finite_difference_of_forces():
    rng = np.random.default_rng(5)
    mesh = structured_hex(graded_axis(0, 0.01, 0.005), graded_axis(0, 0.01, 0.005),
                          graded_axis(0, 0.01, 0.005))
    young = rng.uniform(5e4, 2e5, (len(mesh.elements), 8))
    asm = Assembler(mesh, young, 0.49)
    u = 2e-4 * rng.standard_normal((mesh.n_nodes, 3))
    f0, k = asm.forces_tangent(u)
    du = 1e-9 * rng.standard_normal(u.shape)
    f1, _ = asm.forces_tangent(u + du, tangent=False)
    fm, _ = asm.forces_tangent(u - du, tangent=False)
    np.testing.assert_allclose((f1 - fm) / 2, k @ du.ravel(), rtol=0, atol=1e-6 * np.abs(
        k @ du.ravel()).max())
    # forces are the energy gradient
    e1, e0 = asm.energy(u + du), asm.energy(u - du)
    assert (e1 - e0) == pytest.approx(2 * f0 @ du.ravel(), rel=1e-5)
    assert abs((k - k.T).max()) < 1e-8 * abs(k).max()


def test_rigid_motion_is_stress_free():
    mesh = structured_hex(np.linspace(0, 0.02, 3), np.linspace(0, 0.02, 3),
                          np.linspace(0, 0.01, 2))
    asm = Assembler(mesh, 1e5, 0.45)
    c, s = np.cos(0.7), np.sin(0.7)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    u = mesh.nodes @ rot.T - mesh.nodes + [0.01, -0.02, 0.003]
    f, _ = asm.forces_tangent(u, tangent=False)
    assert np.abs(f).max() < 1e-9
    assert abs(asm.energy(u)) < 1e-12


def test_inverted_element_is_refused():
    mesh = structured_hex([0, 1e-2], [0, 1e-2], [0, 1e-2])
    asm = Assembler(mesh, 1e5, 0.3)
    u = np.zeros((8, 3))
    u[4:, 2] = -2e-2  # top pushed through the bottom
    assert asm.energy(u) == np.inf
    with pytest.raises(InvalidInput):
        asm.forces_tangent(u)


def test_boundary_faces_point_outward():
    mesh = structured_hex(np.linspace(0, 3, 4), np.linspace(0, 2, 3), np.linspace(0, 1, 3))
    x = mesh.nodes[mesh.boundary_faces]
    normal = np.cross(x[:, 1] - x[:, 0], x[:, 3] - x[:, 0])
    centre = mesh.nodes.mean(axis=0)
    assert np.all(np.einsum('ij,ij->i', normal, x.mean(axis=1) - centre) > 0)


@pytest.mark.parametrize('factory,volume', [
    (lambda: sphere_probe(0.01), 4 / 3 * np.pi * 1e-6),
    (lambda: cylinder_probe(0.01, 0.06, 0.002), None),
    (lambda: paddle_probe(), None),
    (lambda: box_probe(), None),
    (lambda: point_probe(), None),
])
def test_probes_are_closed_outward_and_lead_at_origin(factory, volume):
    mesh = factory()
    v = mesh.vertices[mesh.triangles]
    vol = np.einsum('ij,ij->i', v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6
    assert vol > 0
    if volume is not None:
        assert vol == pytest.approx(volume, rel=5e-3)
    assert mesh.vertices[:, 2].max() == pytest.approx(0.0, abs=1e-12)
    RigidProbe(mesh)  # raises unless watertight


def test_signed_distance_of_sphere_probe_is_exact():
    rng = np.random.default_rng(8)
    probe = RigidProbe(sphere_probe(0.01, rings=96, segments=128))
    pts = rng.uniform(-0.02, 0.01, (400, 3))
    phi, closest, normal = probe.query(pts)
    exact = np.linalg.norm(pts - [0, 0, -0.01], axis=1) - 0.01
    np.testing.assert_allclose(phi, exact, atol=1e-5)  # facet sag of the tessellation
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-9)
    # the normal points from the closest point towards outside points
    out = phi > 1e-4
    d = (pts[out] - closest[out]) / phi[out, None]
    np.testing.assert_allclose(d, normal[out], atol=1e-6)


def test_closest_point_on_triangles_is_no_farther_than_samples():
    rng = np.random.default_rng(9)
    tri = rng.standard_normal((300, 3, 3))
    p = 2 * rng.standard_normal((300, 3))
    c = closest_point_on_triangles(p, tri)
    g = np.linspace(0, 1, 41)
    uu, vv = np.meshgrid(g, g)
    keep = uu + vv <= 1
    uu, vv = uu[keep], vv[keep]
    samples = (tri[:, None, 0] + uu[None, :, None] * (tri[:, None, 1] - tri[:, None, 0])
               + vv[None, :, None] * (tri[:, None, 2] - tri[:, None, 0]))
    best = np.linalg.norm(samples - p[:, None], axis=2).min(axis=1)
    assert np.all(np.linalg.norm(c - p, axis=1) <= best + 1e-12)


def test_pose_for_push_points_z_along_direction():
    pose = pose_for_push([0.5, 0.0, 0.05], [0.0, 0.6, -0.8], roll=0.3)
    np.testing.assert_allclose(pose.rotation()[:, 2], [0.0, 0.6, -0.8], atol=1e-12)
    np.testing.assert_allclose(pose.rotation().T @ pose.rotation(), np.eye(3), atol=1e-12)


def test_open_mesh_probe_is_rejected():
    with pytest.raises(InvalidInput):
        RigidProbe(Mesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]]))


def test_shipped_objects_load_and_sit_on_the_table():
    names = list_objects()
    assert {'plush', 'vest', 'lamb', 'dome', 'thin_layer'} <= set(names)
    for name in names:
        spec = load_object(name)
        mesh, rgb = spec.surface_mesh(0.004)
        assert rgb.shape == (len(mesh.vertices), 3)
        assert rgb.min() >= 0 and rgb.max() <= 1
        assert mesh.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-9)
        assert 0.03 <= mesh.vertices[:, 2].max() <= 0.05
        centre = mesh.vertices[:, :2].mean(axis=0)
        np.testing.assert_allclose(centre, [0.5, 0.0], atol=0.01)
        assert 3.0 <= spec.force_cap <= 14.0
        # outward winding: signed volume of the open surface closed by the table is positive
        v = mesh.vertices[mesh.triangles]
        assert np.einsum('ij,ij->i', v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() > 0


def test_stiffness_field_and_colour_follow_the_yaml():
    lamb = load_object('lamb')
    bone = lamb.regions[-1].params['centre']
    fat = [0.5, 0.0, float(lamb.top_height(0.5, 0)) - 2.5e-3]
    e = lamb.stiffness_at([bone, [0.46, -0.02, 0.02], fat])
    assert e[0] == pytest.approx(3.0e6, rel=1e-3)
    assert e[1] == pytest.approx(9.0e4, rel=1e-3)
    assert e[2] == pytest.approx(4.0e4, rel=2e-2)  # inside the fat cap (2 mm blend)
    rgb = lamb.colour_at([[0.52, 0.009, 0.04], [0.46, 0.025, 0.04]])
    assert rgb[0].sum() > rgb[1].sum()  # paler over the bone than the muscle
    with pytest.raises(InvalidInput):
        lamb.stiffness_at([[0.5, 0.0]])


def test_load_object_errors_name_the_problem(tmp_path):
    with pytest.raises(DataError, match='known objects'):
        load_object('no_such_object')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('name: bad\ngeometry: {kind: box, size: [0.1, 0.1]}\nmaterial: {young: 1}\n')
    with pytest.raises(InvalidInput, match='size'):
        load_object(str(bad))
    bad.write_text('name: bad\ngeometry: {kind: box, size: [0.1, 0.1, 0.04]}\n'
                   'material: {young: 1.0e5, poisson: 0.5}\n')
    with pytest.raises(InvalidInput, match='poisson'):
        load_object(str(bad))
