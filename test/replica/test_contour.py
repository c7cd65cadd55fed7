"""Contour of the replica under load: its own deformed top matches, the undeformed one does not.

And the plate-on-ball section (seed 002's cross-section check) against a known outline.
"""

import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator

from pointforce_ros.errors import InvalidInput
from pointforce_ros.replica.build import PLATE_CONFIG
from pointforce_ros.replica.contour import (ball_section_error, contour_error, section_error,
                                            section_outline, top_nodes)
from pointforce_ros.replica.mesh import ball_tet_mesh, box_tet_mesh
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


def _circle(radius, centre, n=72):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)])


def test_section_error_is_zero_on_itself_and_the_radial_gap_otherwise():
    centre = (0.0, 0.045)
    truth = _circle(0.045, centre)
    same = section_error(truth, truth[::-1], centre)
    assert same['rms_m'] < 1e-12 and same['width_error_pct'] == 0.0
    wider = section_error(truth, _circle(0.046, centre, n=50), centre)
    # a polygon's radius between its vertices dips by r (1 - cos(pi / n)): < 0.1 mm here
    np.testing.assert_allclose(wider['rms_m'], 0.001, atol=1e-4)
    np.testing.assert_allclose(wider['width_m'], 0.09, rtol=1e-3)
    np.testing.assert_allclose(wider['error_pct'], 100 * 0.001 / 0.09, rtol=0.1)


def test_ball_section_outline_lies_on_the_sphere_and_sees_the_plate():
    mesh = ball_tet_mesh(0.045, 0.015)
    outline = section_outline(mesh, mesh.nodes)
    np.testing.assert_allclose(np.linalg.norm(outline - [0.0, 0.045], axis=1), 0.045,
                               atol=1e-9)
    material = Material.from_young(5e4, 0.3, damping=0.003)
    squashed = ball_section_error(mesh, material, PLATE_CONFIG, 0.02, outline)
    assert squashed['compression_m'] == pytest.approx(0.02, abs=0.002)
    # the undeformed circle misses a ball squashed by 20 mm by far more than 1.5 %
    assert squashed['error_pct'] > 3.0 and squashed['max_pct'] > 10.0
    off_plane = box_tet_mesh([0.09, 0.07, 0.04], [0.0, 0.004], 0.015)  # no nodes at y = 0
    with pytest.raises(InvalidInput, match='y = 0'):
        section_outline(off_plane, off_plane.nodes)
