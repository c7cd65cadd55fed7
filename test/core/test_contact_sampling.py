"""Rigid mesh sampling (seed 000, IV.A.1): counts, coverage, no repeats, outward normals."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pointforce_ros.contact import sample_mesh_surface
from pointforce_ros.contact.sampling import MAX_SAMPLES, mesh_sample_count
from pointforce_ros.lab.synthetic_contact import fibonacci_sphere_mesh
from pointforce_ros.errors import InvalidInput
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Mesh


def random_surface_points(mesh, n, rng):
    """Uniform random points on the mesh surface (area-weighted)."""
    tri = mesh.vertices[mesh.triangles]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(tri), n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])


def test_box_count_matches_the_closed_form():
    # 20 mm cube at 3 mm: 8 vertices; 12 edges of 20 mm -> ceil(20/3) - 1 = 6 points each;
    # 6 face diagonals of 28.3 mm -> 9 each; 12 triangles with n = 10 -> (9 * 8) / 2 = 36 each.
    pts, normals = sample_mesh_surface(box((0.02, 0.02, 0.02)), 0.003)
    assert len(pts) == 8 + 12 * 6 + 6 * 9 + 12 * 36
    # Edge points equally spaced: the 6 interior points of the bottom x-edge at 20/7 mm.
    edge = pts[(np.abs(pts[:, 1] + 0.01) < 1e-12) & (np.abs(pts[:, 2]) < 1e-12)]
    np.testing.assert_allclose(np.diff(np.sort(edge[:, 0])), 0.02 / 7, rtol=1e-9)


@pytest.mark.parametrize('mesh', [box((0.03, 0.02, 0.01)), icosphere(0.02, 2)])
def test_coverage_no_repeats_and_outward_normals(mesh):
    spacing = 0.003
    pts, normals = sample_mesh_surface(mesh, spacing)
    tree = cKDTree(pts)
    # No point repeated (shared edges and vertices sampled once).
    assert tree.query(pts, k=2)[0][:, 1].min() > 1e-6
    # Every surface location lies within one spacing of a sample.
    probe = random_surface_points(mesh, 5000, np.random.default_rng(0))
    assert tree.query(probe)[0].max() <= spacing
    # Unit normals pointing away from the centroid of these convex solids.
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-12)
    centre = mesh.vertices.mean(axis=0)
    assert np.all(np.einsum('ij,ij->i', normals, pts - centre) > 0)


def test_coarse_spacing_gives_exactly_the_vertices():
    mesh = fibonacci_sphere_mesh(150, 0.02)
    pts, normals = sample_mesh_surface(mesh, 0.01)
    assert len(pts) == 150
    np.testing.assert_allclose(pts, mesh.vertices)
    # Vertex normals of a sphere are close to radial.
    radial = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    assert np.min(np.einsum('ij,ij->i', normals, radial)) > 0.98


def test_bad_spacing_and_meshes():
    with pytest.raises(InvalidInput, match='spacing'):
        sample_mesh_surface(box(), 0.0)
    with pytest.raises(InvalidInput, match='million'):
        sample_mesh_surface(box((1.0, 1.0, 1.0)), 1e-4)
    with pytest.raises(InvalidInput, match='non-finite'):
        Mesh(vertices=[[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], triangles=[[0, 1, 2]])
    with pytest.raises(InvalidInput, match='empty'):
        Mesh(vertices=np.zeros((3, 3)), triangles=np.zeros((0, 3)))


@pytest.mark.parametrize('mesh, spacing', [(box((0.03, 0.02, 0.01)), 0.003),
                                           (icosphere(0.02, 2), 0.003),
                                           (box((0.5, 0.5, 0.5)), 0.01)])
def test_sample_count_without_sampling_equals_the_samples(mesh, spacing):
    assert mesh_sample_count(mesh, spacing) == len(sample_mesh_surface(mesh, spacing)[0])


@pytest.mark.parametrize('size', [1e20, 1e300])
def test_huge_coordinates_cannot_wrap_the_count_past_the_cap(size):
    """A float-to-int cast of 3e22 steps wrapped to a negative count: only 3 points placed."""
    mesh = Mesh(vertices=[[0, 0, 0], [size, 0, 0], [0, size, 0]], triangles=[[0, 1, 2]])
    with pytest.raises(InvalidInput, match='units'):
        sample_mesh_surface(mesh, 0.003)
    with pytest.raises(InvalidInput, match='units'):
        mesh_sample_count(mesh, 0.003)


def test_the_count_reports_an_oversized_mesh_the_sampler_refuses():
    """A 2.9 m plate (two triangles) at 1 mm: counted in microseconds, refused by the sampler."""
    plate = Mesh(vertices=[[0, 0, 0], [2.9, 0, 0], [2.9, 2.9, 0], [0, 2.9, 0]],
                 triangles=[[0, 1, 2], [0, 2, 3]])
    assert mesh_sample_count(plate, 0.001) > MAX_SAMPLES
    with pytest.raises(InvalidInput, match='million'):
        sample_mesh_surface(plate, 0.001)
