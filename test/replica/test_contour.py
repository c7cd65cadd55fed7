"""Contour of the replica under load: its own deformed top matches, the undeformed one does not."""

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from pointforce_ros.replica.contour import contour_error, top_nodes
from pointforce_ros.replica.mesh import box_tet_mesh
from pointforce_ros.replica.scene import deformed_nodes, Material, ReplicaScene, SceneConfig


def test_contour_error_sees_the_dent_and_not_its_own_deformed_top():
    mesh = box_tet_mesh([0.09, 0.07, 0.04], [0.5, 0.0], 0.015)
    material, config = Material.from_young(3e4, 0.3), SceneConfig()
    xy = np.array([0.5, 0.0])
    with ReplicaScene(mesh, material, config) as scene:
        scene.poke(xy, 0.006, 0.008, hold=0.2, retract=False)
        top = deformed_nodes(scene)[top_nodes(mesh)]
    assert top[:, 2].min() < 0.04 - 0.004  # the tip dented the top by most of 6 mm
    gx, gy = np.meshgrid(np.linspace(0.48, 0.52, 41), np.linspace(-0.002, 0.002, 5))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    own = np.column_stack([grid, LinearNDInterpolator(top[:, :2], top[:, 2])(grid)])
    flat = np.column_stack([grid, np.full(len(grid), 0.04)])
    same = contour_error(mesh, material, config, xy, 0.006, own)
    undeformed = contour_error(mesh, material, config, xy, 0.006, flat)
    assert same['error_pct'] < 0.05  # the engine is deterministic: the same dent again
    assert undeformed['error_pct'] > 1.0  # a flat top misses the dent by millimetres
