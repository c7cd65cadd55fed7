"""Shape-constant identification on synthetic dents and second-probe pokes with known c."""

import numpy as np
import pytest

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.contact.identify import (DECAY_GRID, decay_grid, dent_profile,
                                             identify_shape_constant,
                                             identify_shape_constant_from_probe,
                                             identify_shape_constant_from_probes,
                                             object_thickness)
from pointforce_ros.lab.synthetic_contact import grid_surface, linear_response
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.shapes import box, cylinder
from pointforce_ros.types import Pose, Surface

DOWN = np.array([0.0, 0.0, -1.0])


@pytest.mark.parametrize('c_true', [0.001, 0.004, 0.02])
def test_noisy_dent_profile_recovers_c(c_true):
    rng = np.random.default_rng(int(c_true * 1e4))
    r = rng.uniform(0.0, 0.05, 800)
    u0 = 0.004
    u = u0 * c_true / (c_true + r) + rng.normal(0.0, 2e-5, len(r))  # 20 um camera noise
    fit = identify_shape_constant(r, u)
    assert fit.c == pytest.approx(c_true, rel=0.05)
    assert fit.u0 == pytest.approx(u0, rel=0.02)
    assert fit.rmse == pytest.approx(2e-5, rel=0.15)
    known = identify_shape_constant(r, u, u0=u0)
    assert known.c == pytest.approx(c_true, rel=0.03)


def test_dent_from_the_simulated_poke_field_and_from_an_observed_cloud():
    c_true = 0.006
    surface = grid_surface(half=0.04, step=0.001)
    sim = ContactSimulator(surface, linear_response(800.0, len(surface)), c=c_true)
    depth = 0.003
    tip = np.array([0.00025, 0.00025, -depth])
    res = sim.query_points(tip[None], DOWN, np.zeros(3), return_displacements=True)
    displaced = surface.points - res.displacements[:, None] * surface.normals
    r, u = dent_profile(surface, displaced, res.contact_points[0])
    fit = identify_shape_constant(r, u, u0=depth)
    assert fit.c == pytest.approx(c_true, rel=1e-6)
    # The same dent seen by a camera: a different, noisy point set (no correspondence).
    rng = np.random.default_rng(2)
    seen = rng.uniform(-0.035, 0.035, (20000, 2))
    r_seen = np.linalg.norm(seen - res.contact_points[0, :2], axis=1)
    z = -depth * c_true / (c_true + r_seen) + rng.normal(0, 1e-5, len(seen))
    r, u = dent_profile(surface, np.column_stack([seen, z]), res.contact_points[0])
    assert len(r) > 0.5 * len(surface.points)
    fit = identify_shape_constant(r, u)
    assert fit.c == pytest.approx(c_true, rel=0.05)


@pytest.mark.parametrize('mesh', [box((0.012, 0.012, 0.004)), cylinder(0.005, 0.02, 16)])
def test_second_probe_pokes_recover_c(mesh):
    c_true = 0.004
    surface = grid_surface(half=0.025, step=0.001)
    sim = ContactSimulator(surface, linear_response(800.0, len(surface)), c=c_true)
    depths = np.linspace(0.0005, 0.004, 8)
    poses = [Pose(position=[0.00023, 0.00041, -d]) for d in depths]
    measured = -sim.query_batch(mesh, poses, DOWN, np.zeros(3)).wrenches[:, :3] @ DOWN
    noisy = measured * (1 + np.random.default_rng(0).normal(0, 0.01, len(measured)))
    fit = identify_shape_constant_from_probe(sim.with_shape_constant(0.05), mesh, poses, DOWN,
                                             noisy)
    assert fit.method == 'probe'
    assert fit.c == pytest.approx(c_true, rel=0.1)
    exact = identify_shape_constant_from_probe(sim, mesh, poses, DOWN, measured)
    assert exact.c == pytest.approx(c_true, rel=1e-3)


def test_a_joint_fit_over_several_probe_pokes_resists_a_local_model_error():
    c_true = 0.004
    surface = grid_surface(half=0.03, step=0.001)
    sim = ContactSimulator(surface, linear_response(800.0, len(surface)), c=c_true)
    stiffer = ContactSimulator(surface, linear_response(1200.0, len(surface)), c=c_true)
    depths = np.linspace(0.0005, 0.004, 6)
    pokes = []
    for k, (mesh, truth) in enumerate([(box((0.012, 0.012, 0.004)), stiffer),
                                       (cylinder(0.005, 0.02, 16), sim),
                                       (box((0.02, 0.006, 0.004)), sim)]):
        poses = [Pose(position=[0.008 * (k - 1), 0.0003, -d]) for d in depths]
        measured = -truth.query_batch(mesh, poses, DOWN, np.zeros(3)).wrenches[:, :3] @ DOWN
        pokes.append((mesh, poses, DOWN, measured))
    # the first poke alone: the model is 1.5x too soft there, so c shrinks to add force
    alone = identify_shape_constant_from_probe(sim, *pokes[0])
    joint = identify_shape_constant_from_probes(sim, pokes)
    assert abs(np.log(joint.c / c_true)) < 0.5 * abs(np.log(alone.c / c_true)), (alone.c,
                                                                                 joint.c)
    assert joint.n_points == 3 * len(depths)
    with pytest.raises(InvalidInput, match='no pokes'):
        identify_shape_constant_from_probes(sim, [])


def test_probes_on_a_layer_with_a_short_dent_recover_c_and_the_tail_decay():
    """A line and a cylinder on a response whose dent dies out (decay 6 mm, as a thin layer's):
    the paper's ``g`` fits no single ``c`` to both, the joint fit finds the pair."""
    c_true, decay_true = 0.004, 0.006
    surface = grid_surface(half=0.03, step=0.001)
    truth = ContactSimulator(surface, linear_response(800.0, len(surface)), c=c_true,
                             decay=decay_true)
    depths = np.linspace(0.0005, 0.004, 6)
    pokes = []
    for k, mesh in enumerate([box((0.03, 0.004, 0.004)), cylinder(0.008, 0.03, 24)]):
        poses = [Pose(position=[0.006 * (2 * k - 1), 0.0003, -d]) for d in depths]
        measured = -truth.query_batch(mesh, poses, DOWN, np.zeros(3)).wrenches[:, :3] @ DOWN
        pokes.append((mesh, poses, DOWN, measured))
    start = truth.with_shape_constant(0.05, np.inf)
    paper = identify_shape_constant_from_probes(start, pokes)
    joint = identify_shape_constant_from_probes(start, pokes, decays=DECAY_GRID + (0.006,))
    assert np.isinf(paper.decay)
    assert joint.decay == pytest.approx(decay_true)
    assert joint.c == pytest.approx(c_true, rel=1e-3)
    assert joint.rmse < 1e-3 * paper.rmse, (paper.rmse, joint.rmse)
    # without decays, c is fitted at the simulator's own decay length (a served model's)
    own = identify_shape_constant_from_probes(truth.with_shape_constant(0.05), pokes)
    assert own.decay == decay_true and own.c == pytest.approx(c_true, rel=1e-3)
    with pytest.raises(InvalidInput, match='decays'):
        identify_shape_constant_from_probes(start, pokes, decays=(0.0,))
    with pytest.raises(InvalidInput, match='decay'):
        ContactSimulator(surface, linear_response(800.0, len(surface)), c=c_true, decay=-1.0)


def test_undetermined_and_bad_input():
    r = np.linspace(0, 0.02, 50)
    with pytest.raises(NotConverged, match='bound'):
        identify_shape_constant(r, np.full(50, 0.002))  # flat: c -> infinity
    with pytest.raises(InvalidInput, match='>= 3'):
        identify_shape_constant(r[:2], r[:2])
    with pytest.raises(InvalidInput, match='no positive'):
        identify_shape_constant(r, -r)
    with pytest.raises(InvalidInput, match='c_bounds'):
        identify_shape_constant(r, r + 1e-3, c_bounds=(0.1, 0.01))
    with pytest.raises(InvalidInput, match='non-finite'):
        identify_shape_constant(r, np.full(50, np.nan))


def _block_with_walls(top, support=0.0):
    """A flat top at height ``top`` and two side walls down to ``support`` (normals +-x)."""
    flat = grid_surface(half=0.03, step=0.002, z=top)
    zs = np.arange(support + 0.001, top, 0.002)
    wall = np.array([(x, y, z) for x in (-0.031, 0.031) for y in np.arange(-0.03, 0.031, 0.002)
                     for z in zs])
    normals = np.where(wall[:, :1] > 0, [[1.0, 0.0, 0.0]], [[-1.0, 0.0, 0.0]])
    return Surface(points=np.vstack([flat.points, wall]),
                   normals=np.vstack([flat.normals, normals]))


def test_the_decay_grid_stops_at_one_and_a_half_thicknesses_of_the_object():
    surface = _block_with_walls(0.030)       # side walls outnumber the top's points below it
    assert object_thickness(surface) == pytest.approx(0.030)
    grid = decay_grid(surface)
    assert grid == tuple(v for v in DECAY_GRID if v <= 0.045)       # 1.5 thicknesses
    assert np.inf not in grid and 0.064 not in grid and 0.032 in grid
    # a table that is not at z = 0: the thickness is measured from it
    raised = _block_with_walls(0.050, support=0.020)
    assert object_thickness(raised, support_z=0.020) == pytest.approx(0.030)
    assert decay_grid(raised, support_z=0.020) == grid
    assert 0.064 in decay_grid(raised)                   # 50 mm above z = 0: 75 mm cap
    # a thin layer keeps the shortest lengths; a cap below all of them keeps the shortest one
    assert decay_grid(_block_with_walls(0.004)) == (0.004, 0.002)
    assert decay_grid(_block_with_walls(0.002), decays=(0.008, 0.004)) == (0.004,)


def test_the_decay_grid_is_whole_where_the_thickness_is_unknown():
    down = Surface(points=np.array([[0.0, 0.0, 0.03], [0.01, 0.0, 0.03]]),
                   normals=np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]))
    assert np.isnan(object_thickness(down))
    assert decay_grid(down) == tuple(DECAY_GRID)
    below = grid_surface(half=0.01, step=0.002, z=-0.01)    # under the support plane
    assert np.isnan(object_thickness(below))
    assert decay_grid(below) == tuple(DECAY_GRID)
    assert decay_grid(_block_with_walls(0.030), cap=None) == tuple(DECAY_GRID)
