"""Contour of the replica under load against the camera's view of the measured object.

The camera sees the top surface of the object while the probe holds it at a depth (the
deformation fixtures store that cloud). The replica is held at the same depth and its deformed
top is compared along the section through the probe: the camera's points within
``band`` of the probe's y, against the replica's deformed top interpolated at their x-y. The
error is the RMS vertical deviation as a percentage of the section's width (the body's extent
in x), the measure closest to seed 002's cross-section diameter deviation that a top-down
camera gives.
"""

from typing import Dict

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from pointforce_ros.errors import InvalidInput, reading
from pointforce_ros.replica.mesh import TetMesh
from pointforce_ros.replica.scene import deformed_nodes, Material, ReplicaScene, SceneConfig


def top_nodes(mesh: TetMesh, tol: float = 1e-6) -> np.ndarray:
    """Return the indices of the highest node of every x-y column of ``mesh``."""
    key = np.round(mesh.nodes[:, :2] / max(tol, 1e-9)).astype(np.int64)
    _, column = np.unique(key, axis=0, return_inverse=True)
    column = column.ravel()
    order = np.lexsort((mesh.nodes[:, 2], column))
    last = np.r_[column[order][1:] != column[order][:-1], True]
    return order[last]


def contour_error(mesh: TetMesh, material: Material, config: SceneConfig, xy, depth: float,
                  cloud: np.ndarray, band: float = 0.0025, reach: float = 0.02,
                  hold: float = 0.2) -> Dict:
    """Hold the replica at ``depth`` under ``xy`` and compare its top with ``cloud``.

    Args:
        mesh, material, config: the replica.
        xy: (2,) probe x-y, metres.
        depth: metres past the undeformed top.
        cloud: (P, 3) camera points of the measured object at that depth, metres, ``base``.
        band: half-width of the section, metres.
        reach: the section is compared within this x-distance of the probe, metres (the
            loaded region; the scan's side points make the mesh's outer edge low).
        hold: seconds held before the comparison.

    Returns:
        ``{'rms_m', 'width_m', 'error_pct', 'points'}``.

    Raises:
        InvalidInput: fewer than 10 camera points in the section over the replica's top.

    """
    with ReplicaScene(mesh, material, config) as scene:
        scene.poke(xy, depth, 0.008, hold=hold, retract=False)
        nodes = deformed_nodes(scene)
    top = nodes[top_nodes(mesh)]
    section = (np.abs(cloud[:, 1] - xy[1]) < band) & (np.abs(cloud[:, 0] - xy[0]) < reach)
    pts = cloud[section]
    z_rep = LinearNDInterpolator(top[:, :2], top[:, 2])(pts[:, :2])
    keep = np.isfinite(z_rep) & (pts[:, 2] > 0.5 * mesh.nodes[:, 2].max())
    if keep.sum() < 10:
        raise InvalidInput(f'contour_error: {int(keep.sum())} camera points in the section '
                           'over the replica (need 10)')
    rms = float(np.sqrt(np.mean((pts[keep, 2] - z_rep[keep]) ** 2)))
    width = float(np.ptp(mesh.nodes[:, 0]))  # the section's width: the body's x extent
    return {'rms_m': rms, 'width_m': width, 'error_pct': 100 * rms / width,
            'points': int(keep.sum())}


def boundary_nodes(mesh: TetMesh) -> np.ndarray:
    """Return the sorted indices of the nodes on ``mesh``'s surface (faces of one tet only)."""
    faces = np.sort(mesh.tets[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3),
                    axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    return np.unique(uniq[count == 1])


def section_outline(mesh: TetMesh, nodes: np.ndarray, tol: float = 1e-7) -> np.ndarray:
    """Return the outline ``(x, z)`` (S, 2) of ``mesh`` in its plane ``y = 0``, metres.

    The surface nodes whose undeformed ``y`` is within ``tol`` of 0, at their positions in
    ``nodes`` (N, 3) (the deformed body, ``base``).

    Raises:
        InvalidInput: fewer than 8 surface nodes lie in that plane (the mesh has no node
            plane at ``y = 0``).

    """
    idx = boundary_nodes(mesh)
    idx = idx[np.abs(mesh.nodes[idx, 1]) <= tol]
    if len(idx) < 8:
        raise InvalidInput(f'section_outline: {len(idx)} surface nodes in the plane y = 0 '
                           '(need 8: the mesh must have a node plane there)')
    return np.asarray(nodes, float)[idx][:, [0, 2]]


def radius_by_angle(outline: np.ndarray, centre, angles: np.ndarray) -> np.ndarray:
    """Radius (A,) of a star-shaped outline (S, 2) about ``centre`` (2,) at ``angles`` (A,).

    The outline's points are ordered by angle about ``centre`` and their distance is
    interpolated linearly (periodically) in angle. Metres, radians.
    """
    rel = np.asarray(outline, float) - np.asarray(centre, float)
    theta = np.arctan2(rel[:, 1], rel[:, 0])
    order = np.argsort(theta)
    theta, r = theta[order], np.linalg.norm(rel, axis=1)[order]
    return np.interp(angles, theta, r, period=2 * np.pi)


def width_by_height(outline: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Width (L,) of a closed outline (S, 2) ``(x, z)`` at heights ``levels`` (L,), metres.

    The outline is closed in the order of its points' angles about their mean; the width at
    a level is the span of the x where its edges cross that level (NaN where none do). It
    does not move when the outline shifts sideways: the section's diameter at each height.
    """
    pts = np.asarray(outline, float)
    rel = pts - pts.mean(axis=0)
    pts = pts[np.argsort(np.arctan2(rel[:, 1], rel[:, 0]))]
    a, b = pts, np.roll(pts, -1, axis=0)
    out = np.full(len(levels), np.nan)
    for i, level in enumerate(np.asarray(levels, float)):
        cross = (a[:, 1] - level) * (b[:, 1] - level) <= 0
        cross &= a[:, 1] != b[:, 1]
        if np.any(cross):
            t = (level - a[cross, 1]) / (b[cross, 1] - a[cross, 1])
            x = a[cross, 0] + t * (b[cross, 0] - a[cross, 0])
            out[i] = float(np.ptp(x))
    return out


def section_error(truth: np.ndarray, replica: np.ndarray, centre, samples: int = 360,
                  levels: int = 17) -> Dict:
    """Compare two deformed sections (S, 2) ``(x, z)`` about ``centre`` (2,): seed 002's check.

    Returns ``{'rms_m', 'max_m', 'width_m', 'error_pct', 'max_pct', 'width_error_pct',
    'diameter_rms_pct', 'diameter_max_pct'}``: the RMS and largest radial gap between the
    outlines over ``samples`` angles about ``centre``, the truth's width (its x extent: the
    section's diameter under load), the RMS and largest gap as percentages of that width, the
    difference of the widths as a percentage of it, and the RMS and largest difference of the
    diameters (:func:`width_by_height`) at ``levels`` heights spread over the inner 90 % of
    the truth's height, as percentages of its width (seed 002's diameter deviation, blind to
    a sideways shift of the whole section).
    """
    truth, replica = np.asarray(truth, float), np.asarray(replica, float)
    angles = np.linspace(-np.pi, np.pi, samples, endpoint=False)
    gap = radius_by_angle(replica, centre, angles) - radius_by_angle(truth, centre, angles)
    width = float(np.ptp(truth[:, 0]))
    rms = float(np.sqrt(np.mean(gap ** 2)))
    lo, hi = truth[:, 1].min(), truth[:, 1].max()
    z = np.linspace(lo + 0.05 * (hi - lo), hi - 0.05 * (hi - lo), levels)
    diam = width_by_height(replica, z) - width_by_height(truth, z)
    diam = np.where(np.isfinite(diam), diam, width)  # a missing level counts as all missed
    return {'rms_m': rms, 'max_m': float(np.max(np.abs(gap))), 'width_m': width,
            'error_pct': 100 * rms / width, 'max_pct': 100 * float(np.max(np.abs(gap))) / width,
            'width_error_pct': 100 * (float(np.ptp(replica[:, 0])) - width) / width,
            'diameter_rms_pct': 100 * float(np.sqrt(np.mean(diam ** 2))) / width,
            'diameter_max_pct': 100 * float(np.max(np.abs(diam))) / width}


def ball_section(mesh: TetMesh, material: Material, config: SceneConfig, compression: float,
                 hold: float = 0.3):
    """Hold the plate-on-ball replica at ``compression``; return its loaded section.

    The plate pushes at the static speed to ``compression`` past the ball's undeformed top
    (less the collision margin when the replica counts depth from the geometry, as the force
    is read) and holds ``hold`` seconds.

    Returns:
        ``(outline (S, 2), centre (2,), compression_m)``: the replica's outline in ``y = 0``
        (:func:`section_outline`), ``(x, z)`` metres, table frame; the deformed centre (the
        ball's axis, ``(top - compression) / 2`` high); the plate's actual compression, m.

    Raises:
        InvalidInput: see :func:`section_outline`.
        NotConverged: the engine went unstable.

    """
    top = float(mesh.nodes[:, 2].max())
    xy = 0.5 * (mesh.nodes[:, :2].min(axis=0) + mesh.nodes[:, :2].max(axis=0))
    margin = config.collision_margin if config.onset == 'geometry' else 0.0
    with ReplicaScene(mesh, material, config) as scene:
        trace = scene.poke(xy, compression - margin, 0.008, hold=hold, retract=False)
        nodes = deformed_nodes(scene)
    centre = np.array([float(xy[0]), 0.5 * (top - compression)])
    return section_outline(mesh, nodes), centre, float(trace.depth[-1] + margin)


def ball_section_error(mesh: TetMesh, material: Material, config: SceneConfig,
                       compression: float, truth: np.ndarray, hold: float = 0.3) -> Dict:
    """Hold the plate-on-ball replica at ``compression`` and compare its section with ``truth``.

    :func:`ball_section`, compared with ``truth`` (S, 2), ``(x, z)`` metres, table frame,
    about the deformed centre (:func:`section_error`). Also returns the plate's actual
    compression, metres (``compression_m``).

    Raises:
        InvalidInput: see :func:`section_outline`.
        NotConverged: the engine went unstable.

    """
    outline, centre, actual = ball_section(mesh, material, config, compression, hold)
    out = section_error(truth, outline, centre)
    out['compression_m'] = actual
    return out


# -- the camera's section -----------------------------------------------------------------

def _rays(points: np.ndarray, pose: np.ndarray):
    """Return unit rays (P, 3), ranges (P,), optical-axis cosines (P,) of ``points``."""
    rel = np.asarray(points, float) - np.asarray(pose, float)[:3, 3]
    rng = np.linalg.norm(rel, axis=1)
    unit = rel / rng[:, None]
    return unit, rng, unit @ np.asarray(pose, float)[:3, 2]


def depth_bias_from_rest(points: np.ndarray, pose: np.ndarray, centre, radius: float) -> float:
    """Estimate a depth camera's constant depth bias from its view of the rest ball, metres.

    The rest shape is known (a ball of ``radius`` m about ``centre`` (3,), ``base``): along
    each point's ray from the camera (``pose`` (4, 4) ``base <- optical``) the measured range
    minus the range to the sphere, times the ray's cosine to the optical axis (the bias is
    on the optical-axis depth), median over the points that hit the sphere. Positive: the
    camera reads too far. As a cell's camera is checked on a known object before use.

    Raises:
        InvalidInput: fewer than 20 of ``points`` (P, 3) lie on rays that hit the sphere.

    """
    unit, rng, cos = _rays(points, pose)
    oc = np.asarray(pose, float)[:3, 3] - np.asarray(centre, float)
    b = unit @ oc
    disc = b ** 2 - (oc @ oc - radius ** 2)
    hit = disc > 0
    if np.count_nonzero(hit) < 20:
        raise InvalidInput(f'depth_bias_from_rest: {int(np.count_nonzero(hit))} camera points '
                           'on rays through the rest ball (need 20)')
    t_true = -b[hit] - np.sqrt(disc[hit])
    return float(np.median((rng[hit] - t_true) * cos[hit]))


def remove_depth_bias(points: np.ndarray, pose: np.ndarray, bias: float) -> np.ndarray:
    """Return ``points`` (P, 3) moved along their rays by the optical-axis depth ``-bias``, m."""
    unit, rng, cos = _rays(points, pose)
    return np.asarray(pose, float)[:3, 3] + unit * (rng - bias / cos)[:, None]


def camera_section(points: np.ndarray, centre_xy, band: float = 0.003) -> np.ndarray:
    """Return the section of an upright body of revolution in its plane through the axis.

    The points (P, 3) within ``band`` m of the plane, each at its horizontal distance from
    the vertical axis through ``centre_xy`` (2,) (the plane ``y = centre_y``), on its own side:
    ``(x, z)`` (S, 2), metres (a point
    ``y`` off the plane is ``y^2 / 2 r`` closer to the axis than its ``x`` says).
    """
    pts = np.asarray(points, float)
    rel = pts[:, :2] - np.asarray(centre_xy, float)
    keep = np.abs(rel[:, 1]) < band
    x = np.sign(rel[keep, 0]) * np.hypot(rel[keep, 0], rel[keep, 1]) + float(centre_xy[0])
    return np.column_stack([x, pts[keep, 2]])


def camera_section_error(camera_xz: np.ndarray, outline: np.ndarray, centre,
                         bin_deg: float = 3.0, level: float = 0.002) -> Dict:
    """Compare an outline (S, 2) ``(x, z)`` with the camera's section points (P, 2) ``(x, z)``.

    Only where the camera sees: the camera's points are binned by angle about ``centre``
    (2,) (``bin_deg`` wide bins with 3 or more points); per bin the median of the outline's
    radius minus the camera point's radius (:func:`radius_by_angle`) at each point's angle.
    The width is the camera's own: its diameter at the level of ``centre`` (median x of the
    points within ``level`` m of that height, right side minus left side). Diameters by
    height compare the median x of each side per ``2 level``-high band (both sides seen)
    with :func:`width_by_height` of the outline.

    Returns:
        ``{'rms_m', 'max_m', 'width_m', 'error_pct', 'max_pct', 'bias_m', 'diameter_rms_pct',
        'diameter_max_pct', 'bins', 'points', 'seen_deg'}``: the RMS and largest binned
        radial gap, the camera's width, both gaps as % of it, the median signed gap
        (outline minus camera, m), the diameters' RMS and largest difference as % of the
        width, the bins used, points used, and the angle the bins cover, degrees.

    Raises:
        InvalidInput: fewer than 3 bins, or the camera sees no side at the centre's height.

    """
    cam = np.asarray(camera_xz, float)
    centre = np.asarray(centre, float)
    rel = cam - centre
    theta = np.arctan2(rel[:, 1], rel[:, 0])
    gap = radius_by_angle(outline, centre, theta) - np.linalg.norm(rel, axis=1)
    edges = np.radians(np.arange(-180.0, 180.0 + bin_deg, bin_deg))
    which = np.digitize(theta, edges)
    per_bin = np.array([np.median(gap[which == k]) for k in np.unique(which)
                        if np.count_nonzero(which == k) >= 3])
    if len(per_bin) < 3:
        raise InvalidInput(f'camera_section_error: {len(per_bin)} angle bins with 3 camera '
                           'points (need 3)')
    mid = np.abs(rel[:, 1]) < level
    left, right = mid & (rel[:, 0] < 0), mid & (rel[:, 0] > 0)
    if not (left.any() and right.any()):
        raise InvalidInput('camera_section_error: the camera sees no side of the section at '
                           "its centre's height")
    width = float(np.median(cam[right, 0]) - np.median(cam[left, 0]))
    lo, hi = cam[:, 1].min() + level, cam[:, 1].max() - level
    levels = np.arange(lo, hi + 1e-12, 2 * level)
    diam = []
    for z in levels:
        band = np.abs(cam[:, 1] - z) < level
        lft, rgt = band & (rel[:, 0] < 0), band & (rel[:, 0] > 0)
        if np.count_nonzero(lft) >= 3 and np.count_nonzero(rgt) >= 3:
            seen = float(np.median(cam[rgt, 0]) - np.median(cam[lft, 0]))
            diam.append(width_by_height(outline, np.array([z]))[0] - seen)
    diam = np.array(diam)
    diam = np.where(np.isfinite(diam), diam, width)
    rms = float(np.sqrt(np.mean(per_bin ** 2)))
    return {'rms_m': rms, 'max_m': float(np.max(np.abs(per_bin))), 'width_m': width,
            'error_pct': 100 * rms / width,
            'max_pct': 100 * float(np.max(np.abs(per_bin))) / width,
            'bias_m': float(np.median(per_bin)),
            'diameter_rms_pct': (100 * float(np.sqrt(np.mean(diam ** 2))) / width
                                 if len(diam) else float('nan')),
            'diameter_max_pct': (100 * float(np.max(np.abs(diam))) / width
                                 if len(diam) else float('nan')),
            'bins': int(len(per_bin)), 'points': int(len(cam)),
            'seen_deg': float(bin_deg * len(per_bin))}


def read_camera_views(path) -> Dict:
    """Read a camera-views file of the plate-on-ball truth (``make_ball_camera.py``).

    Returns:
        ``{'pose': (C, 4, 4), 'rest': [(P, 3)] * C, 'loaded': [(Q, 3)] * C, 'compression',
        'radius', ...}`` (metres, ``base``).

    Raises:
        DataError: missing or unreadable.

    """
    with reading(path, 'camera views'):
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
        out = {k: (v.item() if v.ndim == 0 else v) for k, v in data.items()
               if not k.endswith(('_points', '_offsets'))}
        for state in ('rest', 'loaded'):
            off, pts = data[f'{state}_offsets'], np.asarray(data[f'{state}_points'], float)
            out[state] = [pts[off[i]:off[i + 1]] for i in range(len(off) - 1)]
    return out


def ball_camera_figures(views: Dict, outline: np.ndarray, truth: np.ndarray, centre,
                        band: float = 0.003) -> Dict:
    """Section of a loaded ball against the camera's: a replica's and the truth's (floor).

    ``views`` (:func:`read_camera_views`); ``outline`` (S, 2) the replica's loaded section,
    ``truth`` (T, 2) the truth's (``section_xz``), ``centre`` (2,) the deformed centre
    ``(x, z)``; the ball's axis is at ``y = 0``. Two readings of the camera: ``raw`` (its
    points as they come: the scenario's depth bias included) and ``rest_corrected`` (each
    camera's depth bias estimated on its rest frames of the known rest ball,
    :func:`depth_bias_from_rest`, and removed). Per reading: ``replica`` (the replica's
    section against the camera's, :func:`camera_section_error`), ``truth`` (the truth's
    against the camera's: the camera's own floor) and the bias estimates, metres.
    """
    centre = np.asarray(centre, float)
    radius = float(views['radius'])
    rest_centre = np.array([centre[0], 0.0, radius])
    raw = np.concatenate(views['loaded'])
    biases = [depth_bias_from_rest(r, p, rest_centre, radius)
              for r, p in zip(views['rest'], views['pose'])]
    corrected = np.concatenate([remove_depth_bias(pts, p, b) for pts, p, b in
                                zip(views['loaded'], views['pose'], biases)])
    out = {'band_m': band, 'compression_m': float(views['compression']),
           'nominal_bias_m': float(views.get('depth_bias', float('nan')))}
    for name, pts in (('raw', raw), ('rest_corrected', corrected)):
        cam = camera_section(pts, (centre[0], 0.0), band)
        out[name] = {'replica': camera_section_error(cam, outline, centre),
                     'truth': camera_section_error(cam, truth, centre)}
    out['rest_corrected']['bias_estimates_m'] = biases
    return out
