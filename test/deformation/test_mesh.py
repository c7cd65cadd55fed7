"""Volume mesh by extrusion: volumes, orientation, closure, fixed bottom, mesh from a cloud."""

import numpy as np
import pytest

from pointforce_ros.deformation.mesh import (block_mesh, crease_nodes, extrude_height_field,
                                             graded_layers, MAX_MESH_NODES,
                                             volume_mesh_from_surface)
from pointforce_ros.errors import InvalidInput


def _closed_volume(mesh):
    """Signed volume enclosed by the surface triangles and the table (z = 0) below them."""
    c = mesh.nodes[mesh.surface_triangles]
    n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    # divergence theorem with the field (0, 0, z): the table face contributes nothing
    return float(np.sum(n[:, 2] * c[:, :, 2].mean(axis=1)) / 2.0)


def test_block_volume_orientation_and_fixed_bottom():
    mesh = block_mesh((0.03, 0.02, 0.01), 0.005, 4, grading=1.5)
    vol = mesh.volumes()
    assert np.all(vol > 0)
    assert vol.sum() == pytest.approx(0.03 * 0.02 * 0.01, rel=1e-12)
    assert _closed_volume(mesh) == pytest.approx(vol.sum(), rel=1e-12)
    np.testing.assert_allclose(mesh.nodes[mesh.fixed_nodes, 2], 0.0)
    assert len(mesh.fixed_nodes) == 7 * 5
    assert not np.any(np.all(mesh.nodes[mesh.surface_triangles][:, :, 2] == 0, axis=1))
    # the box's 12 edges are creases, face interiors are not
    crease = crease_nodes(mesh.nodes, mesh.surface_triangles)
    top_centre = np.argmin(np.linalg.norm(mesh.nodes - [0.015, 0.01, 0.01], axis=1))
    corner = np.argmin(np.linalg.norm(mesh.nodes - [0.03, 0.02, 0.01], axis=1))
    assert crease[corner] and not crease[top_centre]


def test_graded_layers_and_sloped_height_field():
    z = graded_layers(5, 2.0)
    assert z[0] == 0 and z[-1] == 1 and np.all(np.diff(np.diff(z)) < 0)  # finer at the top
    x = np.linspace(0, 0.04, 9)
    y = np.linspace(0, 0.02, 5)
    h = 0.01 + 0.25 * x[:, None] + 0 * y[None, :]
    cells = np.ones((8, 4), dtype=bool)
    cells[0, 0] = False  # a notch in the footprint
    mesh = extrude_height_field(x, y, h, cells, layers=3)
    cell_area = 0.005 * 0.005
    want = 0.02 * (0.01 * 0.04 + 0.125 * 0.04 ** 2) - cell_area * (0.01 + 0.25 * 0.0025)
    assert mesh.volumes().sum() == pytest.approx(want, rel=1e-12)
    assert np.all(mesh.volumes() > 0)
    with pytest.raises(InvalidInput):
        extrude_height_field(x, y, -h, cells)
    with pytest.raises(InvalidInput):
        extrude_height_field(x, y, h, np.zeros((8, 4), dtype=bool))


def test_mesh_from_a_noisy_dome_cloud():
    rng = np.random.default_rng(4)
    xy = rng.uniform(-0.04, 0.04, size=(20000, 2))
    r2 = (xy ** 2).sum(axis=1) / 0.04 ** 2
    xy = xy[r2 <= 1]
    r2 = r2[r2 <= 1]
    z = 0.01 + 0.02 * (1 - r2)
    pts = np.column_stack([xy, z + rng.normal(0, 2e-4, len(z))])
    normals = np.column_stack([0.02 * 2 * xy / 0.04 ** 2, np.ones(len(z))])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    mesh = volume_mesh_from_surface(pts, normals, element_size=0.004, layers=5)
    exact = np.pi * 0.04 ** 2 * (0.01 + 0.02 / 2)
    # the footprint is staircased at the element size: a few percent
    assert mesh.volumes().sum() == pytest.approx(exact, rel=0.06)
    assert np.all(mesh.volumes() > 0)
    assert mesh.nodes[:, 2].max() == pytest.approx(0.03, abs=5e-4)
    with pytest.raises(InvalidInput):
        volume_mesh_from_surface(pts[:5])
    with pytest.raises(InvalidInput):
        volume_mesh_from_surface(np.full((100, 3), np.nan))


def test_a_stray_far_point_is_refused_before_the_mesh_is_built():
    """Audit 39: one stray point 20 m off made the node allocate 3.9 GB for 58 s; at 1 m it
    silently meshed an isolated column there (the bounding box sets the grid)."""
    rng = np.random.default_rng(39)
    points = np.column_stack([rng.uniform(0.0, 0.05, 400), rng.uniform(0.0, 0.05, 400),
                              np.full(400, 0.03)])
    normals = np.tile([0.0, 0.0, 1.0], (400, 1))
    assert volume_mesh_from_surface(points, normals).n_nodes < MAX_MESH_NODES
    for far in (1.0, 20.0, 1e300):
        stray = points.copy()
        stray[0, :2] = far
        with pytest.raises(InvalidInput, match='stray point'):
            volume_mesh_from_surface(stray, normals)
