"""Simulated depth camera of the cell: renders a triangle mesh as a RealSense-like point cloud.

The camera casts one ray per pixel through the optical centre (pinhole model, no distortion) with
Open3D's ``RaycastingScene``, so nearer triangles hide farther ones. The depth ``z`` of each hit
(metres, along the optical axis) then gets the sensor model of a stereo depth camera

    ``z_measured = z + depth_bias + N(0, sigma(z))``,  ``sigma(z) = noise_a + noise_b * z**2``

and optionally quantisation to ``depth_unit`` (the RealSense default unit is 1 mm). A measured
point stays on its pixel's ray (``p = ray * z_measured`` with ``ray = ((u - cx) / fx,
(v - cy) / fy, 1)``), as a deprojected depth image does. Pixels with no hit or a true depth outside
``[min_range, max_range]`` are NaN (organised output) or dropped (unorganised output).

Frames: the camera pose is the pose of ``camera_depth_optical_frame`` in ``base`` (z forward,
x right, y down), as a (4, 4) homogeneous matrix ``base <- optical``.
"""

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import open3d as o3d

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array, Mesh

OPTICAL_FRAME = 'camera_depth_optical_frame'


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of the depth stream (defaults: a D435 depth stream at 424 x 240).

    Attributes:
        width, height: image size, pixels.
        fx, fy: focal lengths, pixels.
        cx, cy: principal point, pixels (pixel centres are at integer coordinates).
        min_range, max_range: valid true depth interval, metres (D435 at 424 x 240 sees from
            about 0.1 m).

    Raises:
        InvalidInput: non-positive size or focal length, or an empty range interval.

    """

    width: int = 424
    height: int = 240
    fx: float = 213.0
    fy: float = 213.0
    cx: float = 211.5
    cy: float = 119.5
    min_range: float = 0.105
    max_range: float = 10.0

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise InvalidInput(f'CameraIntrinsics: image size must be positive, got '
                               f'{self.width} x {self.height}')
        for name in ('fx', 'fy', 'cx', 'cy', 'min_range', 'max_range'):
            if not np.isfinite(float(getattr(self, name))):
                raise InvalidInput(f'CameraIntrinsics.{name}: must be finite')
        if self.fx <= 0 or self.fy <= 0:
            raise InvalidInput(f'CameraIntrinsics: focal lengths must be positive, got '
                               f'fx={self.fx}, fy={self.fy}')
        if not 0 <= self.min_range < self.max_range:
            raise InvalidInput(f'CameraIntrinsics: need 0 <= min_range < max_range, got '
                               f'{self.min_range}, {self.max_range}')
        object.__setattr__(self, 'width', int(self.width))
        object.__setattr__(self, 'height', int(self.height))

    def pixel_rays(self) -> np.ndarray:
        """(H, W, 3) ray of each pixel in the optical frame, scaled so that its z is 1."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64),
                           np.arange(self.height, dtype=np.float64))
        return np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy,
                         np.ones_like(u)], axis=-1)


@dataclass(frozen=True)
class CameraFrame:
    """One depth frame as a point cloud with colour.

    Attributes:
        points: (H, W, 3) when ``organised`` (NaN where nothing valid was hit), else (N, 3)
            with only valid points; metres, in ``frame``.
        rgb: colours with the leading shape of ``points``, float in [0, 1]; zeros where nothing
            was hit.
        camera_pose: (4, 4) homogeneous transform ``base <- frame``.
        organised: whether ``points`` keeps the image layout.
        stamp: acquisition time, seconds.
        frame: frame id of ``points`` (``camera_depth_optical_frame``, or ``base`` for a
            merged cloud).

    Raises:
        InvalidInput: mismatched shapes, a camera pose that is not a rigid transform, colours
            outside [0, 1].

    """

    points: np.ndarray
    rgb: np.ndarray
    camera_pose: np.ndarray
    organised: bool
    stamp: float = 0.0
    frame: str = OPTICAL_FRAME

    def __post_init__(self):
        shape = (None, None, 3) if self.organised else (None, 3)
        points = as_array(self.points, 'CameraFrame.points', shape, finite=False)
        rgb = as_array(self.rgb, 'CameraFrame.rgb', points.shape)
        if rgb.size and (rgb.min() < 0.0 or rgb.max() > 1.0):
            raise InvalidInput('CameraFrame.rgb: values must lie in [0, 1]')
        if not self.organised and not np.all(np.isfinite(points)):
            raise InvalidInput('CameraFrame.points: an unorganised cloud may not hold NaN')
        object.__setattr__(self, 'points', points)
        object.__setattr__(self, 'rgb', rgb)
        object.__setattr__(self, 'camera_pose',
                           _rigid(self.camera_pose, 'CameraFrame.camera_pose'))
        object.__setattr__(self, 'organised', bool(self.organised))
        object.__setattr__(self, 'stamp', float(self.stamp))

    def valid(self) -> np.ndarray:
        """Boolean mask (leading shape of ``points``) of points with finite coordinates."""
        return np.all(np.isfinite(self.points), axis=-1)

    def in_base(self):
        """Return ``(points (N, 3), rgb (N, 3))`` of the valid points, in ``base``, metres."""
        mask = self.valid()
        pts = self.points[mask]
        rot, trans = self.camera_pose[:3, :3], self.camera_pose[:3, 3]
        return np.einsum('ij,kj->ik', pts, rot) + trans, np.array(self.rgb[mask])


def _rigid(matrix, name: str) -> np.ndarray:
    """Return ``matrix`` as a read-only (4, 4) rigid transform or raise InvalidInput."""
    mat = np.array(as_array(matrix, name, (4, 4)))
    rot = mat[:3, :3]
    if (not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0
            or not np.allclose(mat[3], [0.0, 0.0, 0.0, 1.0])):
        raise InvalidInput(f'{name}: not a rigid transform (rotation must be orthonormal with '
                           f'det +1 and the last row [0, 0, 0, 1])')
    mat.setflags(write=False)
    return mat


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Pose (4, 4) ``base <- camera_depth_optical_frame`` of a camera at ``eye`` facing ``target``.

    Args:
        eye: (3,) camera position, metres, ``base``.
        target: (3,) point the optical axis (z) passes through, metres, ``base``.
        up: (3,) direction that appears up in the image (image y points against it).

    Raises:
        InvalidInput: ``eye == target`` or a viewing direction parallel to ``up``.

    """
    eye = as_array(eye, 'look_at.eye', (3,))
    target = as_array(target, 'look_at.target', (3,))
    up = as_array(up, 'look_at.up', (3,))
    z_axis = target - eye
    dist = np.linalg.norm(z_axis)
    if dist < 1e-9:
        raise InvalidInput('look_at: eye and target coincide')
    z_axis = z_axis / dist
    x_axis = np.cross(z_axis, up)
    norm = np.linalg.norm(x_axis)
    if norm < 1e-6 * max(np.linalg.norm(up), 1e-12):
        raise InvalidInput('look_at: viewing direction is parallel to up; pick another up vector')
    x_axis /= norm
    pose = np.eye(4)
    pose[:3, 0] = x_axis
    pose[:3, 1] = np.cross(z_axis, x_axis)
    pose[:3, 2] = z_axis
    pose[:3, 3] = eye
    return pose


def ring_viewpoints(target, distance: float, *, count: int = 2, elevation_deg: float = 55.0,
                    azimuth0_deg: float = 180.0):
    """Camera poses evenly spaced on a ring around ``target``, all facing it.

    Args:
        target: (3,) point looked at, metres, ``base`` (e.g. the object centre).
        distance: camera-to-target distance, metres.
        count: number of viewpoints (>= 1).
        elevation_deg: angle of the line of sight above the table plane, degrees, in (0, 90).
        azimuth0_deg: azimuth of the first camera about +z, degrees (180 = on the -x side).

    Returns:
        list of (4, 4) poses ``base <- camera_depth_optical_frame``.

    Raises:
        InvalidInput: non-positive distance or count, elevation outside (0, 90).

    """
    target = as_array(target, 'ring_viewpoints.target', (3,))
    if not distance > 0 or int(count) < 1 or not 0 < elevation_deg < 90:
        raise InvalidInput(f'ring_viewpoints: need distance > 0, count >= 1 and elevation in '
                           f'(0, 90) degrees, got {distance}, {count}, {elevation_deg}')
    elev = np.radians(elevation_deg)
    poses = []
    for azim in np.radians(azimuth0_deg + 360.0 * np.arange(int(count)) / int(count)):
        offset = distance * np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim),
                                      np.sin(elev)])
        poses.append(look_at(target + offset, target))
    return poses


class DepthCamera:
    """Depth camera with range-dependent noise, a depth bias and occlusion.

    Args:
        intrinsics: pinhole model; defaults to a D435 depth stream at 424 x 240.
        depth_bias: constant offset added to every depth, metres (positive = reads too far).
        noise_a, noise_b: depth noise standard deviation ``noise_a + noise_b * z**2``, with
            ``noise_a`` in metres and ``noise_b`` in 1/m.
        depth_unit: quantisation step of the measured depth, metres (0 = none).
        seed: seed of the noise generator; frames from cameras with equal seeds and equal calls
            are identical. Each call draws fresh noise.

    Raises:
        InvalidInput: negative or non-finite noise parameters or depth unit, non-finite bias.

    """

    def __init__(self, intrinsics: Optional[CameraIntrinsics] = None, *, depth_bias: float = 0.0,
                 noise_a: float = 0.0, noise_b: float = 0.0, depth_unit: float = 0.0,
                 seed: Optional[int] = None):
        self.intrinsics = intrinsics if intrinsics is not None else CameraIntrinsics()
        for name, value in (('noise_a', noise_a), ('noise_b', noise_b),
                            ('depth_unit', depth_unit)):
            if not np.isfinite(value) or value < 0:
                raise InvalidInput(f'DepthCamera.{name}: must be finite and >= 0, got {value}')
        if not np.isfinite(depth_bias):
            raise InvalidInput(f'DepthCamera.depth_bias: must be finite, got {depth_bias}')
        self.depth_bias = float(depth_bias)
        self.noise_a = float(noise_a)
        self.noise_b = float(noise_b)
        self.depth_unit = float(depth_unit)
        self._rng = np.random.default_rng(seed)
        self._rays = self.intrinsics.pixel_rays()

    def noise_std(self, depth) -> np.ndarray:
        """Return the standard deviation of the depth noise at true depth ``depth`` (metres)."""
        depth = np.asarray(depth, dtype=np.float64)
        return self.noise_a + self.noise_b * depth ** 2

    def true_depth(self, mesh: Mesh, camera_pose, *, vertices=None):
        """Raycast ``mesh`` without the sensor model.

        Returns:
            ``(depth (H, W), triangle (H, W) int64, bary (H, W, 2))``: optical-axis depth in
            metres (``inf`` where nothing is hit), the index of the hit triangle (-1 for none)
            and the barycentric coordinates (u, v) of the hit on it.

        Raises:
            InvalidInput: bad pose, or ``vertices`` not of shape (V, 3) / not finite.

        """
        pose = _rigid(camera_pose, 'camera_pose')
        verts = mesh.vertices if vertices is None else as_array(
            vertices, 'vertices', mesh.vertices.shape)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(verts.astype(np.float32)),
                            o3d.core.Tensor(mesh.triangles.astype(np.uint32)))
        rot, origin = pose[:3, :3], pose[:3, 3]
        # einsum, not matmul: BLAS threads on a busy machine make a (N, 3) @ (3, 3) 30x slower
        dirs = np.einsum('ij,kj->ik', self._rays.reshape(-1, 3), rot)
        rays = np.empty((len(dirs), 6), dtype=np.float32)
        rays[:, :3] = origin
        rays[:, 3:] = dirs
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        prim = hit['primitive_ids'].numpy().astype(np.int64)
        missed = prim == int(o3d.t.geometry.RaycastingScene.INVALID_ID)
        prim[missed] = -1
        bary = hit['primitive_uvs'].numpy().astype(np.float64)
        # Re-intersect the hit triangle's plane in float64 (Open3D answers in float32).
        depth = np.full(len(prim), np.inf)
        ok = ~missed
        corner = verts[mesh.triangles]
        tri_normal = np.cross(corner[:, 1] - corner[:, 0], corner[:, 2] - corner[:, 0])
        tri_offset = np.einsum('ij,ij->i', tri_normal, corner[:, 0] - origin)
        hit_ids = prim[ok]
        denom = np.einsum('ij,ij->i', tri_normal[hit_ids], dirs[ok])
        with np.errstate(divide='ignore', invalid='ignore'):
            t_plane = tri_offset[hit_ids] / denom
        t_cast = hit['t_hit'].numpy()[ok].astype(np.float64)
        good = np.isfinite(t_plane) & (np.abs(t_plane - t_cast) < 1e-4 * (1.0 + t_cast))
        depth[ok] = np.where(good, t_plane, t_cast)
        shape = (self.intrinsics.height, self.intrinsics.width)
        return depth.reshape(shape), prim.reshape(shape), bary.reshape(shape + (2,))

    def render(self, mesh: Mesh, camera_pose, *, rgb=None, vertices=None,
               organised: bool = True, stamp: float = 0.0) -> CameraFrame:
        """Render one frame of ``mesh`` seen from ``camera_pose``.

        Args:
            mesh: visible surface, vertices in ``base``, metres.
            camera_pose: (4, 4) ``base <- camera_depth_optical_frame``.
            rgb: (V, 3) per-vertex colour in [0, 1], interpolated over triangles; grey if None.
            vertices: (V, 3) displaced vertices (same topology as ``mesh``) to render a deformed
                surface; ``mesh.vertices`` if None.
            organised: keep the (H, W) layout with NaN holes, or return only valid points.
            stamp: time stamp of the frame, seconds.

        Returns:
            CameraFrame in ``camera_depth_optical_frame``.

        Raises:
            InvalidInput: bad pose, colours of the wrong shape or outside [0, 1], bad vertices.

        """
        n_vert = len(mesh.vertices)
        if rgb is None:
            colours = np.full((n_vert, 3), 0.5)
        else:
            colours = as_array(rgb, 'rgb', (n_vert, 3))
            if colours.min() < 0.0 or colours.max() > 1.0:
                raise InvalidInput('rgb: per-vertex colours must lie in [0, 1]')
        depth, prim, bary = self.true_depth(mesh, camera_pose, vertices=vertices)
        intr = self.intrinsics
        valid = (prim >= 0) & (depth >= intr.min_range) & (depth <= intr.max_range)
        z_true = depth[valid]
        z_meas = z_true + self.depth_bias
        if self.noise_a > 0 or self.noise_b > 0:
            z_meas = z_meas + self._rng.standard_normal(z_true.shape) * self.noise_std(z_true)
        if self.depth_unit > 0:
            z_meas = np.round(z_meas / self.depth_unit) * self.depth_unit
        points = np.full(depth.shape + (3,), np.nan)
        points[valid] = self._rays[valid] * z_meas[:, None]
        colour_img = np.zeros(depth.shape + (3,))
        corners = colours[mesh.triangles[prim[valid]]]
        u, v = bary[valid][:, :1], bary[valid][:, 1:]
        colour_img[valid] = np.clip((1 - u - v) * corners[:, 0] + u * corners[:, 1]
                                    + v * corners[:, 2], 0.0, 1.0)
        if not organised:
            points, colour_img = points[valid], colour_img[valid]
        return CameraFrame(points=points, rgb=colour_img, camera_pose=camera_pose,
                           organised=organised, stamp=stamp)


def merge_frames(frames: Sequence[CameraFrame]) -> CameraFrame:
    """Transform the valid points of several frames into ``base`` and stack them.

    Returns:
        Unorganised CameraFrame in ``base`` (identity ``camera_pose``), stamped with the latest
        input stamp.

    Raises:
        InvalidInput: no frames given.

    """
    frames = list(frames)
    if not frames:
        raise InvalidInput('merge_frames: need at least one frame')
    parts = [frame.in_base() for frame in frames]
    return CameraFrame(points=np.vstack([p for p, _ in parts]),
                       rgb=np.vstack([c for _, c in parts]), camera_pose=np.eye(4),
                       organised=False, stamp=max(frame.stamp for frame in frames), frame='base')
