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

from pointforce_ros.errors import InvalidInput
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


def ball_section_error(mesh: TetMesh, material: Material, config: SceneConfig,
                       compression: float, truth: np.ndarray, hold: float = 0.3) -> Dict:
    """Hold the plate-on-ball replica at ``compression`` and compare its section with ``truth``.

    The plate pushes at the static speed to ``compression`` past the ball's undeformed top
    (less the collision margin when the replica counts depth from the geometry, as the force
    is read), holds ``hold`` seconds, and the replica's outline in ``y = 0``
    (:func:`section_outline`) is compared with ``truth`` (S, 2), ``(x, z)`` metres, table
    frame, about the deformed centre (the ball's axis, ``(top - compression) / 2`` high)
    (:func:`section_error`). Also returns the plate's actual compression, metres.

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
    out = section_error(truth, section_outline(mesh, nodes),
                        (float(xy[0]), 0.5 * (top - compression)))
    out['compression_m'] = float(trace.depth[-1] + margin)
    return out
