"""Probe and planner meshes are closed, outward-facing, of the right size and validated."""

import numpy as np
import pytest

from pointforce_ros import shapes
from pointforce_ros.errors import InvalidInput


def _volume_and_closed(mesh):
    tri = mesh.vertices[mesh.triangles]
    volume = np.einsum('ij,ij->i', tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    edges = np.sort(np.vstack([mesh.triangles[:, [0, 1]], mesh.triangles[:, [1, 2]],
                               mesh.triangles[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    return volume, bool(np.all(counts == 2))


@pytest.mark.parametrize('mesh, exact, rel', [
    (shapes.icosphere(0.02, 3), 4 / 3 * np.pi * 0.02 ** 3, 0.02),
    (shapes.box((0.02, 0.03, 0.04)), 0.02 * 0.03 * 0.04, 1e-12),
    (shapes.cylinder(0.01, 0.08, 48), np.pi * 0.01 ** 2 * 0.08, 0.01),
])
def test_meshes_are_closed_outward_and_of_the_right_volume(mesh, exact, rel):
    volume, closed = _volume_and_closed(mesh)
    assert closed
    assert volume == pytest.approx(exact, rel=rel)


def test_box_stands_on_the_plane_z0_and_sphere_is_centred():
    assert shapes.box().vertices[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(shapes.icosphere(0.02).vertices.mean(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(shapes.icosphere(0.02).vertices, axis=1), 0.02)


def test_bad_sizes_are_rejected():
    with pytest.raises(InvalidInput, match='radius'):
        shapes.icosphere(-1.0)
    with pytest.raises(InvalidInput, match='size'):
        shapes.box((0.01, float('nan'), 0.01))
