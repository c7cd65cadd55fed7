"""Hexahedral FEM ground truth for the simulated cell (pure core: no ROS imports).

Neo-Hookean (or linear) trilinear hexahedra with selective-reduced integration, unilateral
frictionless contact with rigid triangle-mesh probes, Newton with line search; see
:mod:`pointforce_ros.sim.fem.solver`. Public entry points are re-exported here.
"""

from pointforce_ros.sim.fem.probes import (box_probe, cylinder_probe, paddle_probe,
                                           point_probe, pose_for_push, sphere_probe)
from pointforce_ros.sim.fem.solver import FemModel, IndentationResult

__all__ = ['FemModel', 'IndentationResult', 'box_probe', 'cylinder_probe', 'paddle_probe',
           'point_probe', 'pose_for_push', 'sphere_probe']
