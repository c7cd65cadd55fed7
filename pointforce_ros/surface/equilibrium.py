"""Equilibrium surface from depth-camera clouds (seed 000, section III).

Pipeline, one call for one or more scans given as arrays (a ROS adapter turns
``sensor_msgs/PointCloud2`` into :class:`Scan` elsewhere):

1. drop rows with a NaN/inf coordinate (realsense emits NaN where depth is invalid);
2. map every scan into ``base`` with its 4x4 transform and merge;
3. crop to the region of interest (an axis-aligned box in ``base``);
4. voxel-downsample (Open3D; points and colours are averaged per voxel);
5. remove statistical outliers (Open3D: mean distance to ``k`` neighbours beyond
   ``std_ratio`` standard deviations of the cloud-wide mean);
6. estimate normals by local PCA (Open3D, hybrid radius / max-neighbour search);
7. orient the normals outward. Rule ``'camera'`` (default): a point's normal must point to the
   side of the surface that the sensors which saw the point were on, i.e. ``n . v > 0`` with
   ``v`` the sum of unit vectors from the point to the viewpoint of every scan, each weighted by
   the number of that scan's raw points around it (in the 8 nearest occupied voxel cells within
   1.5 voxel diagonals; a camera only sees the outside of an object, and the weighting
   outvotes stray flying pixels). Rule
   ``'centroid'``: ``n . (p - centroid) > 0`` (for a closed, roughly convex object). Rule
   ``'up'``: ``n . up > 0`` with ``up`` a direction in ``base`` (an object lying on a table);
8. smooth the positions (:func:`smooth_surface`): move each point along its normal onto a
   quadric fitted to its neighbours within ``smooth_voxels`` voxel edges that face the same
   way. A voxel centroid keeps the depth camera's range noise (0.4-0.9 mm per 2 mm voxel on
   the cell's realistic scenario); a poke measures its displacement ``d`` from that point, so
   that noise became a per-poke offset of the force curve that no model can predict at a new
   location. The fit cut the spread of the learned onsets from 0.35 to 0.13 mm (plush) and
   0.33 to 0.11 mm (vest) on the cell's poke fixtures; a quadric keeps curved surfaces
   unbiased (a plane would flatten a dome).

The result is a :class:`pointforce_ros.types.Surface` in ``base``.
"""

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple, Union

import numpy as np
from scipy.spatial import cKDTree

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array, Surface

ORIENTATIONS = ('camera', 'centroid', 'up')
MAX_VOXELS_PER_AXIS = 2_000_000
"""Most voxel edges the cropped points may span on one axis: Open3D's voxel grid counts cells
in a C ``int`` (it raises past 2^31) and the camera rule's cell keys multiply three axes' spans
in int64 (2e6 cubed fits). 2e6 edges of the default 2 mm voxel are 4 km."""


@dataclass(frozen=True)
class Scan:
    """One depth-camera cloud as arrays.

    Attributes:
        points: (N, 3) positions in the scan's own frame (e.g. ``camera_depth_optical_frame``),
            metres. Rows with a NaN or inf coordinate are allowed and dropped.
        colors: (N, 3) RGB in [0, 1], or ``None`` when the cloud has no colour.
        transform: (4, 4) homogeneous rigid transform from the scan frame to ``base``.
        viewpoint: (3,) sensor origin in the scan frame, metres (the optical centre: zeros for
            an optical frame).

    Raises:
        InvalidInput: wrong shapes, no points, every point non-finite, colours outside [0, 1],
            or a transform that is not a proper rigid transform.

    """

    points: np.ndarray
    colors: Optional[np.ndarray] = None
    transform: np.ndarray = None
    viewpoint: np.ndarray = None

    def __post_init__(self):
        points = as_array(self.points, 'Scan.points', (None, 3), finite=False)
        if len(points) == 0:
            raise InvalidInput('Scan.points: empty cloud (0 points); nothing to build a surface '
                               'from')
        finite = np.all(np.isfinite(points), axis=1)
        if not np.any(finite):
            raise InvalidInput(f'Scan.points: all {len(points)} points are NaN/inf (no valid '
                               'depth in this scan; check the camera exposure and range)')
        colors = None
        if self.colors is not None:
            colors = as_array(self.colors, 'Scan.colors', (len(points), 3), finite=False)
            good = colors[finite]
            if not np.all(np.isfinite(good)) or good.min() < 0.0 or good.max() > 1.0:
                raise InvalidInput('Scan.colors: values must be finite and lie in [0, 1] '
                                   '(divide 8-bit colours by 255)')
        transform = np.eye(4) if self.transform is None else self.transform
        transform = as_array(transform, 'Scan.transform', (4, 4))
        rot = transform[:3, :3]
        if (np.abs(rot.T @ rot - np.eye(3)).max() > 1e-6 or np.linalg.det(rot) < 0.0
                or np.abs(transform[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-12):
            raise InvalidInput('Scan.transform: not a rigid transform (rotation block must be '
                               'orthonormal with det +1 and the last row [0, 0, 0, 1])')
        viewpoint = np.zeros(3) if self.viewpoint is None else self.viewpoint
        viewpoint = as_array(viewpoint, 'Scan.viewpoint', (3,))
        object.__setattr__(self, 'points', points)
        object.__setattr__(self, 'colors', colors)
        object.__setattr__(self, 'transform', transform)
        object.__setattr__(self, 'viewpoint', viewpoint)

    def in_base(self) -> Tuple[np.ndarray, Optional[np.ndarray], np.ndarray]:
        """Return finite points (M, 3) and colours (M, 3) or None in ``base``, and the viewpoint.

        The viewpoint (3,) is the sensor origin in ``base``, metres.
        """
        finite = np.all(np.isfinite(self.points), axis=1)
        rot, trans = self.transform[:3, :3], self.transform[:3, 3]
        points = self.points[finite] @ rot.T + trans
        colors = None if self.colors is None else self.colors[finite]
        return points, colors, rot @ self.viewpoint + trans


@dataclass(frozen=True)
class SurfaceConfig:
    """Parameters of :func:`equilibrium_surface` (lengths in metres, ``base`` frame).

    Attributes:
        roi_min, roi_max: (3,) corners of the region-of-interest box in ``base``, or ``None``
            for no crop.
        voxel_size: voxel edge of the downsampling grid (> 0).
        outlier_neighbours: ``k`` of the statistical outlier filter (0 disables it).
        outlier_std_ratio: points whose mean ``k``-neighbour distance exceeds the cloud mean by
            this many standard deviations are removed.
        radius_min_neighbours: after the statistical filter, points with fewer neighbours than
            this within ``radius_voxels`` voxel edges are removed (isolated flying pixels a few
            millimetres off the surface, which the statistical filter keeps; 0 disables).
        radius_voxels: radius of that neighbour count, in voxel edges.
        normal_radius: search radius of the normal estimation; ``None`` = 4 voxels.
        normal_max_nn: most neighbours used for one normal.
        smooth_voxels: radius of the position smoothing (step 8), in voxel edges; 0 disables.
        smooth_max_angle_deg: neighbours whose normal differs from the point's by more than
            this are left out of its fit (edges and the far side of thin parts).
        orientation: ``'camera'``, ``'centroid'`` or ``'up'`` (see the module docstring).
        up: (3,) direction in ``base`` used by ``orientation='up'``.
        min_points: fewest points the finished surface may have.

    Raises:
        InvalidInput: non-positive sizes, an empty box, or an unknown orientation rule.

    """

    roi_min: Optional[np.ndarray] = None
    roi_max: Optional[np.ndarray] = None
    voxel_size: float = 0.002
    outlier_neighbours: int = 20
    outlier_std_ratio: float = 2.0
    radius_min_neighbours: int = 5
    radius_voxels: float = 2.5
    normal_radius: Optional[float] = None
    normal_max_nn: int = 30
    smooth_voxels: float = 4.0
    smooth_max_angle_deg: float = 35.0
    orientation: str = 'camera'
    up: Tuple[float, float, float] = (0.0, 0.0, 1.0)
    min_points: int = 10

    def __post_init__(self):
        if (self.roi_min is None) != (self.roi_max is None):
            raise InvalidInput('SurfaceConfig: give both roi_min and roi_max, or neither')
        if self.roi_min is not None:
            lo = as_array(self.roi_min, 'SurfaceConfig.roi_min', (3,))
            hi = as_array(self.roi_max, 'SurfaceConfig.roi_max', (3,))
            if np.any(hi <= lo):
                raise InvalidInput(f'SurfaceConfig: empty region of interest, roi_max {hi} '
                                   f'must exceed roi_min {lo} on every axis')
            object.__setattr__(self, 'roi_min', lo)
            object.__setattr__(self, 'roi_max', hi)
        if not (np.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise InvalidInput(f'SurfaceConfig.voxel_size: must be > 0 m, got {self.voxel_size}')
        if self.normal_radius is not None and not (self.normal_radius > 0):
            raise InvalidInput('SurfaceConfig.normal_radius: must be > 0 m or None')
        if self.outlier_neighbours < 0 or not (self.outlier_std_ratio > 0):
            raise InvalidInput('SurfaceConfig: outlier_neighbours must be >= 0 and '
                               'outlier_std_ratio > 0')
        if self.radius_min_neighbours < 0 or not (self.radius_voxels > 0):
            raise InvalidInput('SurfaceConfig: radius_min_neighbours must be >= 0 and '
                               'radius_voxels > 0')
        if not (self.smooth_voxels >= 0 and 0 < self.smooth_max_angle_deg <= 90):
            raise InvalidInput('SurfaceConfig: smooth_voxels must be >= 0 and '
                               'smooth_max_angle_deg in (0, 90]')
        if self.normal_max_nn < 3 or self.min_points < 3:
            raise InvalidInput('SurfaceConfig: normal_max_nn and min_points must be >= 3')
        if self.orientation not in ORIENTATIONS:
            raise InvalidInput(f'SurfaceConfig.orientation: {self.orientation!r} is not one of '
                               f'{ORIENTATIONS}')
        up = as_array(self.up, 'SurfaceConfig.up', (3,))
        if np.linalg.norm(up) < 1e-9:
            raise InvalidInput('SurfaceConfig.up: must be a non-zero direction')
        object.__setattr__(self, 'up', up / np.linalg.norm(up))


@dataclass(frozen=True)
class SurfaceReport:
    """Point counts through the pipeline of one :func:`build_equilibrium_surface` call."""

    n_input: int
    n_non_finite: int
    n_outside_roi: int
    n_after_voxel: int
    n_outliers: int
    n_surface: int
    n_flipped: int


def build_equilibrium_surface(scans: Union[Scan, Sequence[Scan]],
                              config: SurfaceConfig = SurfaceConfig()
                              ) -> Tuple[Surface, SurfaceReport]:
    """Merge, crop, clean and orient ``scans`` into an equilibrium surface in ``base``.

    Args:
        scans: one :class:`Scan` or a sequence of them (all non-empty).
        config: pipeline parameters.

    Returns:
        ``(surface, report)``: the :class:`Surface` (points, outward normals, colours, frame
        ``base``) and the point counts of each stage.

    Raises:
        InvalidInput: no scans, a scan that is empty or all-NaN, fewer than
            ``config.min_points`` points left after cropping or filtering (the message names
            the stage), or cropped points spanning more than ``MAX_VOXELS_PER_AXIS`` voxels.

    """
    import open3d as o3d

    if isinstance(scans, Scan):
        scans = [scans]
    scans = list(scans)
    if not scans:
        raise InvalidInput('build_equilibrium_surface: no scans given')
    for i, scan in enumerate(scans):
        if not isinstance(scan, Scan):
            raise InvalidInput(f'build_equilibrium_surface: scans[{i}] is a '
                               f'{type(scan).__name__}, expected pointforce_ros.surface.Scan')
    n_input = sum(len(s.points) for s in scans)
    have_colour = any(s.colors is not None for s in scans)
    parts, colours, owners, views = [], [], [], []
    for i, scan in enumerate(scans):
        pts, col, view = scan.in_base()
        if col is None:
            col = np.zeros_like(pts)
        keep = _inside(pts, config)
        parts.append(pts[keep])
        colours.append(col[keep])
        owners.append(np.full(int(keep.sum()), i))
        views.append(view)
    points = np.concatenate(parts)
    n_finite = sum(int(np.all(np.isfinite(s.points), axis=1).sum()) for s in scans)
    if len(points) < config.min_points:
        raise InvalidInput(f'equilibrium surface: only {len(points)} of {n_finite} valid points '
                           'lie inside the region of interest; check roi_min/roi_max and the '
                           'scan transforms')
    span = float(np.max(points.max(axis=0) - points.min(axis=0)))
    if span / config.voxel_size > MAX_VOXELS_PER_AXIS:
        raise InvalidInput(f'equilibrium surface: the points inside the region of interest '
                           f'span {span:.4g} m, over {MAX_VOXELS_PER_AXIS} voxel edges of '
                           f'{config.voxel_size:g} m (far stray points); narrow '
                           'roi_min/roi_max or raise voxel_size')
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    if have_colour:
        cloud.colors = o3d.utility.Vector3dVector(np.concatenate(colours))
    cloud = cloud.voxel_down_sample(config.voxel_size)
    n_voxel = len(cloud.points)
    if config.outlier_neighbours > 0 and n_voxel > config.outlier_neighbours:
        cloud, _ = cloud.remove_statistical_outlier(nb_neighbors=config.outlier_neighbours,
                                                    std_ratio=config.outlier_std_ratio)
    if config.radius_min_neighbours > 0:
        cloud, _ = cloud.remove_radius_outlier(nb_points=config.radius_min_neighbours,
                                               radius=config.radius_voxels * config.voxel_size)
    n_clean = len(cloud.points)
    if n_clean < config.min_points:
        raise InvalidInput(f'equilibrium surface: {n_clean} points left after downsampling and '
                           f'outlier removal (< min_points {config.min_points}); lower '
                           'voxel_size or relax the outlier filter')
    radius = config.normal_radius or 4.0 * config.voxel_size
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius,
                                                                max_nn=config.normal_max_nn))
    out_points = np.asarray(cloud.points).copy()
    normals = np.asarray(cloud.normals).copy()
    lengths = np.linalg.norm(normals, axis=1)
    good = lengths > 0.5
    out_points, normals = out_points[good], normals[good] / lengths[good, None]
    out_colours = np.asarray(cloud.colors)[good].clip(0.0, 1.0) if have_colour else None
    outward = _outward_directions(out_points, np.concatenate(parts), np.concatenate(owners),
                                  np.array(views), config)
    flip = np.einsum('ij,ij->i', normals, outward) < 0.0
    normals[flip] *= -1.0
    if config.smooth_voxels > 0:
        out_points = smooth_surface(out_points, normals, config.smooth_voxels * config.voxel_size,
                                    config.smooth_max_angle_deg)
    surface = Surface(points=out_points, normals=normals, colors=out_colours, frame='base')
    report = SurfaceReport(n_input=n_input, n_non_finite=n_input - n_finite,
                           n_outside_roi=n_finite - len(points), n_after_voxel=n_voxel,
                           n_outliers=n_voxel - n_clean, n_surface=len(surface),
                           n_flipped=int(flip.sum()))
    return surface, report


def equilibrium_surface(scans: Union[Scan, Sequence[Scan]],
                        config: SurfaceConfig = SurfaceConfig()) -> Surface:
    """Return the equilibrium :class:`Surface` of ``scans`` (see ``build_equilibrium_surface``).

    Raises:
        InvalidInput: as :func:`build_equilibrium_surface`.

    """
    return build_equilibrium_surface(scans, config)[0]


def surface_from_cloud(points: np.ndarray, colors: Optional[np.ndarray] = None,
                       transform: Optional[np.ndarray] = None,
                       config: SurfaceConfig = SurfaceConfig()) -> Surface:
    """Build a surface from one cloud: ``points`` (N, 3) metres in the camera frame.

    ``transform`` (4, 4) maps the camera frame to ``base`` (identity when ``None``); the
    camera sits at the frame origin.

    Raises:
        InvalidInput: as :class:`Scan` and :func:`build_equilibrium_surface`.

    """
    return equilibrium_surface(Scan(points=points, colors=colors, transform=transform), config)


def smooth_surface(points: np.ndarray, normals: np.ndarray, radius: float,
                   max_angle_deg: float = 35.0, max_neighbours: int = 64) -> np.ndarray:
    """Return ``points`` moved along ``normals`` onto locally fitted quadrics (denoising).

    For each point ``p`` with unit normal ``n``, the neighbours within ``radius`` whose
    normals lie within ``max_angle_deg`` of ``n`` give heights ``h = (q - p) . n`` over
    in-plane coordinates ``(u, v)``; a weighted least-squares fit of ``h = a0 + a1 u + a2 v +
    a3 u^2 + a4 u v + a5 v^2`` (weights ``(1 - r^2 / radius^2)^2``) moves ``p`` to ``p + a0
    n``. A point with fewer than 10 such neighbours gets a plane (3 terms) when it has 4, and
    stays where it is otherwise. Vectorised over points (batched 6 x 6 solves).

    Args:
        points: (N, 3) metres. normals: (N, 3) unit. radius: metres (> 0).

    Returns:
        (N, 3) smoothed positions; the normals are not changed.

    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    n_pts = len(points)
    k = int(min(max_neighbours, n_pts))
    if n_pts < 4 or not radius > 0:
        return points.copy()
    dist, nbr = cKDTree(points).query(points, k=k, distance_upper_bound=radius)
    valid = np.isfinite(dist)
    nbr = np.where(valid, nbr, 0)
    cos_max = np.cos(np.radians(max_angle_deg))
    valid &= np.einsum('ikj,ij->ik', normals[nbr], normals) >= cos_max
    helper = np.eye(3)[np.argmin(np.abs(normals), axis=1)]
    e1 = np.cross(normals, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(normals, e1)
    rel = points[nbr] - points[:, None, :]
    u = np.einsum('ikj,ij->ik', rel, e1) / radius        # scaled: well-conditioned solves
    v = np.einsum('ikj,ij->ik', rel, e2) / radius
    h = np.einsum('ikj,ij->ik', rel, normals)
    w = np.where(valid, (1.0 - np.minimum(u * u + v * v, 1.0)) ** 2, 0.0)
    count = valid.sum(axis=1)
    out = points.copy()
    for terms, least in ((6, 10), (3, 4)):
        rows = count >= least if terms == 6 else (count >= least) & (count < 10)
        if not np.any(rows):
            continue
        cols = [np.ones_like(u[rows]), u[rows], v[rows], u[rows] ** 2, u[rows] * v[rows],
                v[rows] ** 2][:terms]
        a = np.stack(cols, axis=-1)                                   # (M, k, terms)
        aw = a * w[rows][..., None]
        m = np.einsum('mki,mkj->mij', aw, a) + 1e-9 * np.eye(terms)
        rhs = np.einsum('mki,mk->mi', aw, h[rows])
        a0 = np.linalg.solve(m, rhs[..., None])[:, 0, 0]
        out[rows] += a0[:, None] * normals[rows]
    return out


def _inside(points: np.ndarray, config: SurfaceConfig) -> np.ndarray:
    if config.roi_min is None:
        return np.ones(len(points), dtype=bool)
    return np.all((points >= config.roi_min) & (points <= config.roi_max), axis=1)


def _outward_directions(points: np.ndarray, raw: np.ndarray, owner: np.ndarray,
                        views: np.ndarray, config: SurfaceConfig) -> np.ndarray:
    """(M, 3) direction each normal must agree with (not normalised), by the orientation rule."""
    if config.orientation == 'up':
        return np.broadcast_to(config.up, points.shape)
    centroid_rule = points - points.mean(axis=0)
    if config.orientation == 'centroid':
        return centroid_rule
    voxel = config.voxel_size
    reach = 1.5 * np.sqrt(3.0) * voxel * 1.01
    towards = np.zeros_like(points)
    seen = np.zeros(len(points), dtype=bool)
    for i, view in enumerate(views):
        mine = raw[owner == i]
        if len(mine) == 0:
            continue
        # Vote by how many raw points of this scan lie near the point (counted per voxel cell,
        # the 8 nearest occupied cells within reach): a stray flying pixel of a scan that
        # cannot see this face carries one vote against dozens.
        cells = np.floor(mine / voxel).astype(np.int64)
        cells -= cells.min(axis=0)
        span = cells.max(axis=0) + 1
        key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
        key, first, count = np.unique(key, return_index=True, return_counts=True)
        centres = (np.floor(mine[first] / voxel) + 0.5) * voxel
        k = min(8, len(centres))
        dist, idx = cKDTree(centres).query(points, k=k, distance_upper_bound=reach)
        dist, idx = dist.reshape(len(points), k), idx.reshape(len(points), k)
        found = np.isfinite(dist)
        votes = np.where(found, count[np.minimum(idx, len(count) - 1)], 0).sum(axis=1)
        hit = votes > 0
        ray = view - points[hit]
        towards[hit] += votes[hit, None] * ray / np.maximum(
            np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
        seen |= hit
    towards[~seen] = centroid_rule[~seen]
    return towards
