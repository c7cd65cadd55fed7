"""Safety limits of a poke and the check every goal passes before the arm moves."""

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
        standoff_range: (min, max) stand-off, m.
        surface_tolerance: largest distance of a goal point from the equilibrium surface, m
            (checked when a surface is known).
        workspace_min, workspace_max: (3,) box the whole motion must stay in, m.

    """

    max_force: float = 15.0
    max_depth: float = 0.03
    max_speed: float = 0.01
    standoff_range: Tuple[float, float] = (0.002, 0.05)
    surface_tolerance: float = 0.003
    workspace_min: Tuple[float, float, float] = (0.2, -0.4, 0.0)
    workspace_max: Tuple[float, float, float] = (0.8, 0.4, 0.5)


def check_goal(goal: PokeGoal, limits: PokeLimits,
               surface: Optional[Surface] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Validate ``goal``; return the (point, unit normal) to poke, ``base``.

    Raises:
        InvalidInput: a surface index with no surface or out of range, a non-unit normal.
        UnsafeCommand: force, depth, speed or stand-off outside ``limits``; a point farther
            than ``surface_tolerance`` from the surface; motion leaving the workspace box.

    """
    if goal.surface_index >= 0:
        if surface is None:
            raise InvalidInput('surface_index given but no equilibrium surface is known yet')
        if goal.surface_index >= len(surface):
            raise InvalidInput(f'surface_index {goal.surface_index} out of range: the surface '
                               f'has {len(surface)} points')
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
    if surface is not None and goal.surface_index < 0:
        distance = float(np.min(np.linalg.norm(surface.points - point, axis=1)))
        if distance > limits.surface_tolerance:
            raise UnsafeCommand(f'point is {1e3 * distance:.1f} mm from the equilibrium surface '
                                f'(tolerance {1e3 * limits.surface_tolerance:.1f} mm): not on '
                                'the object')
    lo, hi = np.array(limits.workspace_min), np.array(limits.workspace_max)
    for label, p in (('stand-off', point + goal.standoff * normal),
                     ('deepest', point - goal.depth_limit * normal)):
        if np.any(p < lo) or np.any(p > hi):
            raise UnsafeCommand(f'{label} position {np.round(p, 4).tolist()} m leaves the '
                                f'workspace box {lo.tolist()}..{hi.tolist()} m')
    return point, normal
