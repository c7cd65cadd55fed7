"""visualization_msgs/MarkerArray of the last answered contact query, for RViz and Foxglove.

Namespaces (the array starts with a DELETEALL, so a latched array replaces the previous one):

* ``contact_points``: one SPHERE_LIST marker, a sphere per contact at its estimated
  equilibrium point ``q_i`` (base, metres), coloured by its share of the normal force (blue:
  least, red: most);
* ``wrench``: one ARROW from the torque centre along the contact force, ``force_scale`` metres
  per newton long (a force of 0 N gives no arrow);
* ``label``: a TEXT_VIEW_FACING marker above the torque centre with the force (N), torque
  (N m), contact count and model version.
"""

import numpy as np
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from msg_adapters.geometry import to_point
from msg_adapters.markers import _marker, colormap

POINT_DIAMETER = 0.003
"""Diameter of a contact point's sphere, m."""


def contact_markers(result, model_version: int, stamp: float, frame: str = 'base',
                    force_scale: float = 0.01) -> MarkerArray:
    """Build the MarkerArray of one contact answer.

    Args:
        result: a core contact result (``wrench`` with ``force``, ``torque`` and
            ``torque_centre``; ``contact_points`` (K, 3) m; ``contact_forces`` (K,) N;
            ``contact_count``), frame ``frame``.
        model_version: the model that answered (shown in the label).
        stamp: header time, s.
        frame: frame of the result (``base``).
        force_scale: arrow length per newton of contact force, m/N (> 0).

    """
    out = MarkerArray()
    out.markers.append(Marker(action=Marker.DELETEALL))
    points = np.asarray(result.contact_points, dtype=np.float64).reshape(-1, 3)
    spheres = _marker('contact_points', 0, Marker.SPHERE_LIST, frame, stamp)
    spheres.scale.x = spheres.scale.y = spheres.scale.z = POINT_DIAMETER
    spheres.points = [to_point(p) for p in points]
    forces = np.asarray(result.contact_forces, dtype=np.float64).reshape(-1)
    spheres.colors = [ColorRGBA(r=float(r), g=float(g), b=float(b), a=1.0)
                      for r, g, b in (colormap(forces) if len(forces) else [])]
    spheres.color = ColorRGBA(r=0.2, g=0.6, b=1.0, a=1.0)
    out.markers.append(spheres)
    wrench = result.wrench
    centre = np.asarray(wrench.torque_centre, dtype=np.float64)
    force = np.asarray(wrench.force, dtype=np.float64)
    arrow = _marker('wrench', 0, Marker.ARROW, frame, stamp)
    arrow.points = [to_point(centre), to_point(centre + force_scale * force)]
    arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.004, 0.008, 0.01   # shaft, head, head
    arrow.color = ColorRGBA(r=1.0, g=0.5, b=0.0, a=1.0)
    if float(np.linalg.norm(force)) > 0.0:
        out.markers.append(arrow)
    label = _marker('label', 0, Marker.TEXT_VIEW_FACING, frame, stamp)
    label.pose.position = to_point(centre + [0.0, 0.0, 0.02])
    label.scale.z = 0.01
    label.color = ColorRGBA(r=1.0, g=1.0, b=1.0, a=1.0)
    torque = np.asarray(wrench.torque, dtype=np.float64)
    label.text = (f'F = {np.array2string(force, precision=3)} N, '
                  f'tau = {np.array2string(torque, precision=4)} N m, '
                  f'{int(result.contact_count)} contacts, model v{int(model_version)}')
    out.markers.append(label)
    return out
