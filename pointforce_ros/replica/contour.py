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
