"""Safety limits of a poke and the check every goal passes before the arm moves.

Beyond the force, depth, speed and workspace limits, the geometry must keep the arm out of the
object: the normal must point up out of the table (``max_tilt``) and, when the equilibrium
surface is known, agree with the surface normal at the point (``max_normal_angle``), and the
stand-off pose (where the arm tares the F/T sensor and retracts to) must lie outside the
surface by at least half the stand-off.
"""

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput, UnsafeCommand
from pointforce_ros.types import PokeGoal, Surface


@dataclass(frozen=True)
class PokeLimits:
    """What the poke server accepts (SI units, ``base``).

    Attributes:
        max_force: largest force limit, N.
        max_depth: largest depth limit past the surface point, m.
        max_speed: largest push speed, m/s.
        max_push_time: longest push, s: the stand-off plus the depth limit at the goal's
            speed (a speed of 1e-300 m/s passed every other check and held the server busy
            until cancelled, session 38).
        standoff_range: (min, max) stand-off, m.
        surface_tolerance: largest distance of a goal point from the equilibrium surface, m
            (checked when a surface is known).
        workspace_min, workspace_max: (3,) box the whole motion must stay in, m.
        max_normal_angle: largest angle between the goal normal and the surface normal at the
            goal point (mean of its ``normal_neighbours`` nearest surface points), degrees.
        max_tilt: largest angle between the goal normal and ``up`` (base +z), degrees; a
            horizontal or downward normal is refused even with no surface known.
        normal_neighbours: surface points whose normals are averaged at the goal point.

    """

    max_force: float = 15.0
    max_depth: float = 0.03
    max_speed: float = 0.01
    max_push_time: float = 300.0
    standoff_range: Tuple[float, float] = (0.002, 0.05)
    surface_tolerance: float = 0.003
    workspace_min: Tuple[float, float, float] = (0.2, -0.4, 0.0)
    workspace_max: Tuple[float, float, float] = (0.8, 0.4, 0.5)
    max_normal_angle: float = 30.0
    max_tilt: float = 80.0
    normal_neighbours: int = 5


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between unit vectors ``a`` and ``b``, degrees."""
    return float(np.degrees(np.arccos(np.clip(float(a @ b), -1.0, 1.0))))


def _surface_side(surface: Surface, p: np.ndarray, k: int) -> Tuple[float, np.ndarray, float]:
    """(distance to the nearest point, mean unit normal of the k nearest, signed height).

    The signed height is ``p``'s mean height over the k nearest points along their normals
    (m; > 0 outside the object).
    """
    distance = np.linalg.norm(surface.points - p, axis=1)
    k = min(k, len(distance))
    near = np.argpartition(distance, k - 1)[:k]
    normal = surface.normals[near].sum(axis=0)
    length = float(np.linalg.norm(normal))
    normal = normal / length if length > 0 else surface.normals[near[0]]
    height = float(np.mean(np.einsum('ij,ij->i', p - surface.points[near],
                                     surface.normals[near])))
    return float(distance.min()), normal, height


def check_goal(goal: PokeGoal, limits: PokeLimits,
               surface: Optional[Surface] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Validate ``goal``; return the (point, unit normal) to poke, ``base``.

    Raises:
        InvalidInput: a surface index other than -1 (none) or 0..N-1 of a known surface, a
            non-unit normal.
        UnsafeCommand: force, depth, speed or stand-off outside ``limits``; a push longer than
            ``max_push_time`` (stand-off plus depth limit over the speed); a normal tilted
            more than ``max_tilt`` from up; with a surface: a point farther than
            ``surface_tolerance`` from it, a normal more than ``max_normal_angle`` from its
            normal, a stand-off less than half the stand-off outside it; motion leaving the
            workspace box.

    """
    index = goal.surface_index
    if index != -1 and not (surface is not None and 0 <= index < len(surface)):
        if index < -1:
            raise InvalidInput(f'surface_index {index}: must be -1 (use point and normal) or '
                               'a surface point index >= 0')
        if surface is None:
            raise InvalidInput('surface_index given but no equilibrium surface is known yet')
        raise InvalidInput(f'surface_index {index} out of range: the surface has '
                           f'{len(surface)} points (0..{len(surface) - 1})')
    if goal.surface_index >= 0:
        point = surface.points[goal.surface_index].copy()
        normal = surface.normals[goal.surface_index].copy()
    else:
        point, normal = np.array(goal.point), np.array(goal.normal)
        length = float(np.linalg.norm(normal))
        if abs(length - 1.0) > 1e-3:
            raise InvalidInput(f'normal must be a unit vector (|n| = {length:.4g})')
        normal = normal / length
    checks = (
        ('force_limit', goal.force_limit, 0.0, limits.max_force, 'N'),
        ('depth_limit', goal.depth_limit, 0.0, limits.max_depth, 'm'),
        ('speed', goal.speed, 0.0, limits.max_speed, 'm/s'),
    )
    for name, value, lo, hi, unit in checks:
        if not lo < value <= hi:
            raise UnsafeCommand(f'{name} {value:g} {unit} outside ({lo:g}, {hi:g}] {unit}')
    s_lo, s_hi = limits.standoff_range
    if not s_lo <= goal.standoff <= s_hi:
        raise UnsafeCommand(f'standoff {goal.standoff:g} m outside [{s_lo:g}, {s_hi:g}] m')
    travel = goal.standoff + goal.depth_limit
    if not travel <= goal.speed * limits.max_push_time:
        raise UnsafeCommand(f'speed {goal.speed:g} m/s: the push of {1e3 * travel:.1f} mm '
                            f'(stand-off plus depth limit) would take {travel / goal.speed:.3g} '
                            f's, longer than max_push_time {limits.max_push_time:g} s; at '
                            f'least {travel / limits.max_push_time:.2g} m/s')
    tilt = _angle(normal, np.array([0.0, 0.0, 1.0]))
    if tilt > limits.max_tilt:
        raise UnsafeCommand(f'normal {np.round(normal, 3).tolist()} is {tilt:.0f} deg from up '
                            f'(limit {limits.max_tilt:g} deg): the probe would push sideways '
                            'or upwards')
    if surface is not None:
        distance, surface_normal, _ = _surface_side(surface, point, limits.normal_neighbours)
        if goal.surface_index < 0 and distance > limits.surface_tolerance:
            raise UnsafeCommand(f'point is {1e3 * distance:.1f} mm from the equilibrium surface '
                                f'(tolerance {1e3 * limits.surface_tolerance:.1f} mm): not on '
                                'the object')
        angle = _angle(normal, surface_normal)
        if angle > limits.max_normal_angle:
            raise UnsafeCommand(f'normal is {angle:.0f} deg from the surface normal '
                                f'{np.round(surface_normal, 3).tolist()} at the point (limit '
                                f'{limits.max_normal_angle:g} deg): it must point out of the '
                                'surface')
        standoff = point + goal.standoff * normal
        _, _, height = _surface_side(surface, standoff, limits.normal_neighbours)
        if height < 0.5 * goal.standoff:
            raise UnsafeCommand(f'the stand-off {np.round(standoff, 4).tolist()} m is '
                                f'{1e3 * height:.1f} mm outside the surface (needs at least '
                                f'{0.5e3 * goal.standoff:.1f} mm): the arm would tare and '
                                'retract inside the object')
    lo, hi = np.array(limits.workspace_min), np.array(limits.workspace_max)
    for label, p in (('stand-off', point + goal.standoff * normal),
                     ('deepest', point - goal.depth_limit * normal)):
        if np.any(p < lo) or np.any(p > hi):
            raise UnsafeCommand(f'{label} position {np.round(p, 4).tolist()} m leaves the '
                                f'workspace box {lo.tolist()}..{hi.tolist()} m')
    return point, normal
