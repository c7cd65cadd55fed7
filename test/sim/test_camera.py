"""Tests of the simulated depth camera: geometry, sensor model, occlusion, merging."""

import numpy as np
import pytest

from pointforce_ros.sim.camera import (CameraFrame, CameraIntrinsics, DepthCamera, look_at,
                                       merge_frames, ring_viewpoints)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Mesh


def grid_plane(half=1.0, n=2, z=0.0):
    """Square plane at height ``z`` (base), ``n`` x ``n`` vertices, normal +z."""
    xs = np.linspace(-half, half, n)
    gx, gy = np.meshgrid(xs, xs, indexing='ij')
    verts = np.column_stack([gx.ravel(), gy.ravel(), np.full(n * n, z)])
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), \
        idx[:-1, 1:].ravel()
    tris = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return Mesh(verts, tris)


def box_on_plane(half_box=0.05, height=0.1, half_plane=1.0):
    """A plane at z = 0 plus a closed box standing on it, as one mesh."""
    plane = grid_plane(half_plane)
    h = half_box
    corners = np.array([[x, y, z] for z in (0.0, height) for y in (-h, h) for x in (-h, h)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = np.array([t for q in quads for t in ((q[0], q[1], q[2]), (q[0], q[2], q[3]))])
    off = len(plane.vertices)
    return Mesh(np.vstack([plane.vertices, corners]), np.vstack([plane.triangles, tris + off]))


DOWN = look_at([0.0, 0.0, 0.5], [0.0, 0.0, 0.0], up=[1.0, 0.0, 0.0])


def test_plane_depth_mean_and_noise_std_match_model():
    cam = DepthCamera(noise_a=0.0005, noise_b=0.004, seed=3)
    frame = cam.render(grid_plane(), DOWN)
    z = frame.points[..., 2]
    assert frame.points.shape == (240, 424, 3) and np.all(np.isfinite(z))
    sigma = 0.0005 + 0.004 * 0.5 ** 2
    assert abs(z.mean() - 0.5) < 5 * sigma / np.sqrt(z.size)
    assert z.std() == pytest.approx(sigma, rel=0.02)
    # every point stays on its pixel ray
    np.testing.assert_allclose(frame.points / z[..., None], cam.intrinsics.pixel_rays(),
                               atol=1e-12)


@pytest.mark.parametrize('distance', [0.4, 1.2])
def test_noise_grows_with_range_as_a_plus_b_z2(distance):
    cam = DepthCamera(noise_a=0.0002, noise_b=0.004, seed=11)
    pose = look_at([0.0, 0.0, distance], [0.0, 0.0, 0.0], up=[1.0, 0.0, 0.0])
    z = cam.render(grid_plane(half=2.0), pose).points[..., 2]
    assert z.std() == pytest.approx(0.0002 + 0.004 * distance ** 2, rel=0.02)


def test_bias_shifts_depth_exactly_along_the_ray():
    kwargs = dict(noise_a=0.001, noise_b=0.002, seed=5)
    plain = DepthCamera(**kwargs).render(grid_plane(), DOWN)
    biased = DepthCamera(depth_bias=0.002, **kwargs).render(grid_plane(), DOWN)
    shift = biased.points - plain.points
    np.testing.assert_allclose(shift[..., 2], 0.002, atol=1e-12)
    rays = DepthCamera().intrinsics.pixel_rays()
    np.testing.assert_allclose(shift, 0.002 * rays, atol=1e-12)


def test_box_occludes_the_plane_behind_it():
    cam = DepthCamera()
    frame = cam.render(box_on_plane(), DOWN)
    base, _ = frame.in_base()
    on_plane = np.abs(base[:, 2]) < 1e-9
    on_top = np.abs(base[:, 2] - 0.1) < 1e-9
    assert np.all(on_plane | on_top)
    # the box top hides the plane inside its shadow cone from the camera
    shadow = 0.05 * 0.5 / 0.4
    hidden = np.all(np.abs(base[on_plane, :2]) < shadow, axis=1)
    assert not np.any(hidden)
    # plane points just outside the shadow are visible
    assert np.any(np.all(np.abs(base[on_plane, :2]) < shadow + 0.01, axis=1))
    # the top face covers 0.1 m at 0.4 m: fx * 0.1 / 0.4 = 53.25 pixels a side
    side = cam.intrinsics.fx * 0.1 / 0.4
    assert (side - 1.5) ** 2 < np.count_nonzero(on_top) < (side + 1.5) ** 2
    assert frame.points[120, 212, 2] == pytest.approx(0.4, abs=1e-12)


def test_seeded_frames_repeat_and_different_seeds_differ():
    kwargs = dict(noise_a=0.001, noise_b=0.0, depth_bias=0.001)
    a = DepthCamera(seed=8, **kwargs).render(grid_plane(), DOWN)
    b = DepthCamera(seed=8, **kwargs).render(grid_plane(), DOWN)
    c = DepthCamera(seed=9, **kwargs).render(grid_plane(), DOWN)
    np.testing.assert_array_equal(a.points, b.points)
    assert np.max(np.abs(a.points - c.points)) > 1e-4
    # successive frames of one camera draw fresh noise
    cam = DepthCamera(seed=8, **kwargs)
    first, second = cam.render(grid_plane(), DOWN), cam.render(grid_plane(), DOWN)
    assert np.max(np.abs(first.points - second.points)) > 1e-4


def test_deformed_surface_shows_the_indent():
    mesh = grid_plane(half=0.2, n=41)
    centre = int(np.argmin(np.linalg.norm(mesh.vertices, axis=1)))
    displaced = np.array(mesh.vertices)
    displaced[centre, 2] -= 0.005
    cam = DepthCamera()
    flat = cam.render(mesh, DOWN)
    dented = cam.render(mesh, DOWN, vertices=displaced)
    dent = dented.points[120, 212, 2] - flat.points[120, 212, 2]
    assert dent == pytest.approx(0.005, abs=1e-3)
    # far from the dent nothing moves
    np.testing.assert_allclose(dented.points[:40], flat.points[:40], atol=1e-12)
    with pytest.raises(InvalidInput):
        cam.render(mesh, DOWN, vertices=displaced[:-1])


def test_unorganised_drops_what_organised_marks_nan_and_range_limits():
    cam = DepthCamera()
    small = grid_plane(half=0.1)
    org = cam.render(small, DOWN)
    flat = cam.render(small, DOWN, organised=False)
    valid = org.valid()
    assert 0 < np.count_nonzero(valid) < valid.size
    assert flat.points.shape == (np.count_nonzero(valid), 3)
    np.testing.assert_array_equal(flat.points, org.points[valid])
    assert np.all(org.rgb[~valid] == 0.0)
    too_close = look_at([0.0, 0.0, 0.08], [0.0, 0.0, 0.0], up=[1.0, 0.0, 0.0])
    assert not np.any(cam.render(small, too_close).valid())


def test_rgb_is_interpolated_linearly_over_triangles():
    mesh = grid_plane(half=0.3, n=7)
    x = mesh.vertices[:, 0]
    rgb = np.column_stack([(x + 0.3) / 0.6, np.full(len(x), 0.25), 1.0 - (x + 0.3) / 0.6])
    frame = DepthCamera().render(mesh, DOWN, rgb=rgb, organised=False)
    base, colour = frame.in_base()
    np.testing.assert_allclose(colour[:, 0], (base[:, 0] + 0.3) / 0.6, atol=1e-5)
    np.testing.assert_allclose(colour[:, 0] + colour[:, 2], 1.0, atol=1e-6)
    with pytest.raises(InvalidInput):
        DepthCamera().render(mesh, DOWN, rgb=rgb * 2.0)


def test_merge_two_views_into_base():
    mesh = box_on_plane(half_plane=0.3)
    cam = DepthCamera(intrinsics=CameraIntrinsics(width=160, height=120, fx=100.0, fy=100.0,
                                                  cx=79.5, cy=59.5))
    side = look_at([0.5, 0.0, 0.4], [0.0, 0.0, 0.05])
    frames = [cam.render(mesh, DOWN, stamp=1.0), cam.render(mesh, side, stamp=2.0)]
    merged = merge_frames(frames)
    assert merged.frame == 'base' and merged.stamp == 2.0 and not merged.organised
    assert len(merged.points) == sum(int(np.count_nonzero(f.valid())) for f in frames)
    # noise-free points lie on the object's faces: plane z=0, top z=0.1 or the box sides
    p = merged.points
    on_face = ((np.abs(p[:, 2]) < 1e-9) | (np.abs(p[:, 2] - 0.1) < 1e-9)
               | (np.abs(np.abs(p[:, 0]) - 0.05) < 1e-9) | (np.abs(np.abs(p[:, 1]) - 0.05) < 1e-9))
    assert np.all(on_face)
    # only the side camera sees the +x face of the box
    assert np.count_nonzero(np.abs(p[:, 0] - 0.05) < 1e-9) > 50


def test_ring_viewpoints_face_the_target_and_see_it_centred():
    target = np.array([0.5, 0.0, 0.04])
    poses = ring_viewpoints(target, 0.45, count=3, elevation_deg=50.0)
    cam = DepthCamera()
    plane = grid_plane(half=1.0)
    for pose in poses:
        to_target = target - pose[:3, 3]
        assert np.linalg.norm(to_target) == pytest.approx(0.45)
        np.testing.assert_allclose(pose[:3, 2], to_target / 0.45, atol=1e-12)
        assert pose[2, 1] < 0.0  # image y points down in the world
        # the centre pixel ray hits the target's height plane at the target
        centre = cam.render(Mesh(plane.vertices + [0.0, 0.0, 0.04], plane.triangles), pose)
        hit = pose[:3, :3] @ centre.points[120, 212] + pose[:3, 3]
        # pixel (212, 120) is half a pixel off the principal point: < 0.45 m * 0.71 / 213 / sin
        assert np.linalg.norm(hit - target) < 0.003
    azimuths = [np.arctan2(p[1, 3], p[0, 3] - 0.5) for p in poses]
    np.testing.assert_allclose(np.diff(np.sort(azimuths)), 2 * np.pi / 3, atol=1e-9)
    with pytest.raises(InvalidInput):
        ring_viewpoints(target, 0.45, elevation_deg=90.0)


def test_quantised_depth_lands_on_the_unit():
    cam = DepthCamera(noise_a=0.002, depth_unit=0.001, seed=1)
    z = cam.render(grid_plane(), DOWN).points[..., 2]
    np.testing.assert_allclose(z / 0.001, np.round(z / 0.001), atol=1e-9)
    assert len(np.unique(np.round(z, 6))) > 5


def test_invalid_inputs_raise():
    with pytest.raises(InvalidInput):
        look_at([0, 0, 1], [0, 0, 0])  # looking along up
    with pytest.raises(InvalidInput):
        look_at([0, 0, 1], [0, 0, 1])
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(InvalidInput):
        DepthCamera().render(grid_plane(), bad)
    with pytest.raises(InvalidInput):
        DepthCamera(noise_a=-1.0)
    with pytest.raises(InvalidInput):
        CameraIntrinsics(fx=0.0)
    with pytest.raises(InvalidInput):
        merge_frames([])
    with pytest.raises(InvalidInput):
        CameraFrame(points=np.full((3, 3), np.nan), rgb=np.zeros((3, 3)), camera_pose=np.eye(4),
                    organised=False)
