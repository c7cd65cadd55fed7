"""visualization_msgs/MarkerArray of a learned model, for RViz and Foxglove.

Namespaces (each array starts with a DELETEALL, so a latched array replaces the previous one):

* ``stiffness``: one SPHERE_LIST marker, a sphere per surface point coloured by the predicted
  normal force at the reference depth (blue: softest, red: stiffest of this model);
* ``suggested_pokes``: one ARROW per suggested next poke, pointing along ``-normal`` onto the
  surface, green;
* ``legend``: a TEXT_VIEW_FACING marker with the colour scale's range in newtons.
"""

from typing import Optional

import numpy as np
from builtin_interfaces.msg import Duration
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.geometry import sec_to_stamp, to_point

ARROW_LENGTH = 0.03
"""Length of a suggestion arrow, m (its tip on the surface)."""


def colormap(values: np.ndarray) -> np.ndarray:
    """(N, 3) RGB in [0, 1] for ``values``: blue (lowest) through green to red (highest)."""
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    lo = float(values[finite].min()) if finite.any() else 0.0
    hi = float(values[finite].max()) if finite.any() else 1.0
    t = np.clip((np.where(finite, values, lo) - lo) / max(hi - lo, 1e-12), 0.0, 1.0)
    return np.column_stack([np.clip(2.0 * t - 1.0, 0.0, 1.0),
                            1.0 - np.abs(2.0 * t - 1.0),
                            np.clip(1.0 - 2.0 * t, 0.0, 1.0)])


def _marker(ns: str, marker_id: int, kind: int, frame: str, stamp: float) -> Marker:
    marker = Marker(ns=ns, id=marker_id, type=kind, action=Marker.ADD,
                    lifetime=Duration(sec=0, nanosec=0), frame_locked=False)
    marker.header.frame_id = frame
    sec_to_stamp(stamp, marker.header.stamp)
    marker.pose.orientation.w = 1.0
    return marker


def model_markers(points: np.ndarray, forces: np.ndarray, depth: float, *,
                  suggestions: Optional[np.ndarray] = None,
                  suggestion_normals: Optional[np.ndarray] = None,
                  frame: str = 'base', stamp: float = 0.0,
                  point_size: float = 0.003) -> MarkerArray:
    """Build the MarkerArray of the stiffness ``forces`` (N,) at ``points`` and the suggestions.

    Args:
        points: surface points, m, ``frame``.
        forces: predicted normal force at each point at the reference ``depth``, N.
        depth: the reference depth, m (stated in the legend).
        suggestions: (K, 3) suggested poke points, or None.
        suggestion_normals: (K, 3) their outward normals.
        frame: frame of every marker.
        stamp: header stamp, s.
        point_size: sphere diameter, m.

    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    forces = np.asarray(forces, dtype=np.float64).reshape(-1)
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id = frame
    out = MarkerArray(markers=[clear])
    cloud = _marker('stiffness', 0, Marker.SPHERE_LIST, frame, stamp)
    cloud.scale.x = cloud.scale.y = cloud.scale.z = float(point_size)
    cloud.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    cloud.points = [to_point(p) for p in points]
    cloud.colors = [ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0)
                    for r, g, b in colormap(forces)]
    out.markers.append(cloud)
    if len(forces):
        legend = _marker('legend', 0, Marker.TEXT_VIEW_FACING, frame, stamp)
        legend.pose.position = to_point(points.mean(axis=0) + [0.0, 0.0, 0.05])
        legend.scale.z = 0.01
        legend.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
        legend.text = (f'force at {1e3 * depth:.1f} mm: {np.nanmin(forces):.2f} N (blue) .. '
                       f'{np.nanmax(forces):.2f} N (red)')
        out.markers.append(legend)
    if suggestions is not None:
        normals = np.asarray(suggestion_normals, dtype=np.float64).reshape(-1, 3)
        for i, (p, n) in enumerate(zip(np.asarray(suggestions).reshape(-1, 3), normals)):
            arrow = _marker('suggested_pokes', i, Marker.ARROW, frame, stamp)
            arrow.points = [to_point(p + ARROW_LENGTH * n), to_point(p)]
            arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.002, 0.005, 0.006
            arrow.color = ColorRGBA(r=0.1, g=0.9, b=0.2, a=1.0)
            out.markers.append(arrow)
    return out
