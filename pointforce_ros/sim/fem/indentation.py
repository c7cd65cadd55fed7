"""Offline full nonlinear solves of an object (validation data, line and cylinder probes).

These run the complete FE model (seconds to minutes per solve); the 250 Hz path is
:class:`pointforce_ros.sim.fem.live.LiveContact`.
"""

from typing import Optional, Tuple

import numpy as np

from pointforce_ros.sim.fem.solver import FemModel, IndentationResult
from pointforce_ros.sim.objects import ObjectSpec
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array, Mesh, Pose


def object_model(spec: ObjectSpec, refine_at, h: Optional[float] = None,
                 fine_radius=0.008, nonlinear: bool = True, growth: float = 1.4) -> FemModel:
    """FE model of ``spec`` refined around ``refine_at`` (x, y) with element size ``h`` (m).

    ``h`` defaults to the object's validation mesh size.
    """
    h = h or spec.mesh_validation
    mesh = spec.build_mesh(h, refine_at=refine_at, fine_radius=fine_radius, growth=growth)
    return FemModel(mesh, spec.gauss_young(mesh), spec.poisson, support=spec.support,
                    nonlinear=nonlinear)


def _contact_zone(probe_mesh: Mesh, pose: Pose, direction: np.ndarray, reach: float):
    """Centre (x, y) and half-widths of the probe part within ``reach`` of its leading point."""
    v = pose.apply(probe_mesh.vertices)
    lead = v @ direction
    near = v[lead >= lead.max() - reach]
    lo, hi = near[:, :2].min(axis=0), near[:, :2].max(axis=0)
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def solve_indentation(spec: ObjectSpec, probe_mesh: Mesh, start_pose: Pose, direction,
                      depths, torque_centre=None, nonlinear: bool = True,
                      h: Optional[float] = None, stop_force: Optional[float] = None,
                      keep_solved: bool = False) -> IndentationResult:
    """Quasi-static indentation of object ``spec`` by a rigid probe (full FE solve).

    Args:
        spec: the object (ground-truth field, geometry, support).
        probe_mesh: probe (``types.Mesh``) in its own frame, metres.
        start_pose: probe pose at depth 0 (``base``); usually just touching the surface.
        direction: (3,) push direction, ``base``.
        depths: (K,) increasing probe travel, metres.
        torque_centre: (3,) torque reference point, metres (default: start position).
        nonlinear: neo-Hookean (True) or small-strain linear (False).
        h: element size near the probe (default ``spec.mesh_validation``).
        stop_force: end the push after the first depth whose force along ``-direction``
            exceeds this (N); the result holds the depths solved so far.
        keep_solved: when a step after the first fails, return the depths solved so far
            (fewer than ``depths``) instead of raising.

    Returns:
        :class:`IndentationResult` (depths (K,), force (K, 3), torque (K, 3), surface (K, P, 3)).

    Raises:
        InvalidInput: bad shapes or a probe that does not face the object.
        NotConverged: the Newton solve failed (the message names the step and residual).

    """
    direction = as_array(direction, 'direction', (3,))
    direction = direction / max(np.linalg.norm(direction), 1e-300)
    depths = as_array(depths, 'depths', (None,))
    if not len(depths):
        raise InvalidInput('depths: empty')
    centre, half = _contact_zone(probe_mesh, start_pose, direction, float(depths[-1]) + 0.003)
    fine = tuple(np.maximum(half + 0.004 + float(depths[-1]), 0.006))
    model = object_model(spec, centre, h=h, fine_radius=fine, nonlinear=nonlinear)
    return model.indent(probe_mesh, start_pose, direction, depths, torque_centre,
                        stop_force=stop_force, keep_solved=keep_solved)


def probe_wrench_full(spec: ObjectSpec, probe_mesh: Mesh, pose: Pose, torque_centre=None,
                      steps: int = 4, h: Optional[float] = None
                      ) -> Tuple[np.ndarray, np.ndarray]:
    """Wrench on a probe at ``pose`` reached by pushing along its +z axis (full solve).

    The loading path starts where the probe just clears the undeformed surface along its
    axis, so the result is the quasi-static wrench of an approach along the probe's z axis.

    Returns:
        ``(force (3,), torque (3,))`` on the probe, N and N m, ``base``.

    Raises:
        InvalidInput: the probe axis does not point down into the object.

    """
    axis = pose.rotation()[:, 2]
    if axis[2] > -0.2:
        raise InvalidInput('probe_wrench: the probe +z axis must point down into the object '
                           '(z component < -0.2)')
    v = pose.apply(probe_mesh.vertices)
    over = spec.footprint_mask(v[:, 0], v[:, 1])
    if not np.any(over):
        return np.zeros(3), np.zeros(3)
    # depth of each vertex below the top surface, measured along the axis (vertical approx.)
    pen = (spec.top_height(v[over, 0], v[over, 1]) - v[over, 2]) / max(-axis[2], 1e-9)
    travel = float(pen.max())
    if travel <= 0:
        return np.zeros(3), np.zeros(3)
    back = travel + 0.0005
    start = Pose(pose.position - back * axis, pose.orientation)
    depths = np.linspace(back / steps, back, steps)
    res = solve_indentation(spec, probe_mesh, start, axis, depths,
                            pose.position if torque_centre is None else torque_centre, h=h)
    return res.force[-1], res.torque[-1]
