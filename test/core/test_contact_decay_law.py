"""The ``'penetration'`` decay law of the contact simulator (issue 17).

* :func:`varying_shape_function` is the fixed shape function when the lengths are equal, and
  positive definite with diagonal one for any lengths;
* :class:`PointShapeStack` with per-point lengths is that matrix, and the LCP solved from the
  points equals the dense stack's;
* a dent pressed twice as deep spreads twice as far: on a linear surface two contacts carry a
  force no longer proportional to the depth (the fixed law's is), by the closed form;
* batch, single query and displacement field agree under the law;
* :func:`calibrate_shape` asked for the law identifies ``(c, L)`` of pushes made with it, and
  the fixed law cannot fit them as well.
"""

import numpy as np
import pytest

from pointforce_ros.contact import ContactSimulator, shape_function, solve_lcp_batch
from pointforce_ros.contact.identify import calibrate_shape, DECAY_GRID
from pointforce_ros.contact.lcp import PointShapeStack, varying_shape_function
from pointforce_ros.contact.simulator import (check_decay_law, DECAY_FLOOR, DECAY_LAW, DECAY_LAWS,
                                              DECAY_REFERENCE)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.lab.synthetic_contact import grid_surface, linear_response, power_response
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Pose

K = 1000.0  # N/m
C = 0.003  # m
L = 0.008  # m
DOWN = np.array([0.0, 0.0, -1.0])


@pytest.fixture(scope='module')
def flat():
    surface = grid_surface(half=0.03, step=0.001)
    return ContactSimulator(surface, linear_response(K, len(surface)), c=C, decay=L,
                            decay_law='penetration')


def test_varying_shape_function_is_the_fixed_one_at_equal_lengths_and_positive_definite():
    rng = np.random.default_rng(41)
    q = np.column_stack([rng.uniform(-0.02, 0.02, (80, 2)), rng.normal(0, 1e-3, 80)])
    r = np.linalg.norm(q[:, None] - q[None], axis=2)
    same = np.full(80, L)
    np.testing.assert_allclose(varying_shape_function(r, C, same[:, None], same[None]),
                               shape_function(r, C, L), rtol=1e-13, atol=0.0)
    lengths = rng.uniform(0.0005, 0.03, 80)
    G = varying_shape_function(r, C, lengths[:, None], lengths[None])
    np.testing.assert_allclose(G, G.T, rtol=1e-13, atol=0.0)
    np.testing.assert_allclose(np.diagonal(G), 1.0, rtol=1e-13)
    assert np.linalg.eigvalsh(G).min() > 1e-6


def test_point_stack_with_lengths_is_the_varying_matrix_and_solves_alike():
    rng = np.random.default_rng(42)
    sizes = (40, 23, 40, 6)
    m = max(sizes)
    points = np.zeros((len(sizes), m, 3))
    d = np.zeros((len(sizes), m))
    lengths = np.full((len(sizes), m), L)
    valid = np.zeros((len(sizes), m), dtype=bool)
    for b, n in enumerate(sizes):
        q = np.column_stack([rng.uniform(-0.015, 0.015, (n, 2)), np.zeros(n)])
        points[b, :n] = q - q.mean(axis=0)
        d[b, :n] = 3e-3 - 0.5 * np.sum(q[:, :2] ** 2, axis=1) / 0.02 + rng.normal(0, 2e-4, n)
        lengths[b, :n] = rng.uniform(0.002, 0.02, n)
        valid[b, :n] = True
    stack = PointShapeStack(points, C, L, lengths)
    dense = stack.dense()
    for b, n in enumerate(sizes):
        r = np.linalg.norm(points[b, :n, None] - points[b, None, :n], axis=2)
        want = varying_shape_function(r, C, lengths[b, :n, None], lengths[b, None, :n])
        np.testing.assert_allclose(dense[b, :n, :n], want, rtol=1e-9, atol=1e-12)
    x0, r0, _ = solve_lcp_batch(dense, d, valid)
    x1, r1, _ = solve_lcp_batch(stack, d, valid)
    np.testing.assert_allclose(x1, x0, rtol=1e-10, atol=1e-16)
    assert r1.max() < 1e-12


def test_a_deeper_dent_spreads_farther(flat):
    """Two contacts 10 mm apart on a linear surface: the closed form of each law.

    Under the fixed law the force is proportional to the depth; under the penetration law the
    decay length grows with it, the contacts share more, and twice the depth carries less than
    twice the force.
    """
    gap = 0.01

    def pair(depth):
        return np.array([[-gap / 2 + 0.00025, 0.00025, -depth],
                         [gap / 2 + 0.00025, 0.00025, -depth]])

    fixed = flat.__class__(flat.surface, flat.response, c=C, decay=L, decay_law='fixed')
    forces = {}
    for law, sim in (('fixed', fixed), ('penetration', flat)):
        for depth in (DECAY_REFERENCE, 2 * DECAY_REFERENCE):
            res = sim.query_points(pair(depth), DOWN, np.zeros(3))
            length = L * depth / DECAY_REFERENCE if law == 'penetration' else L
            g = C / (C + gap) * np.exp(-gap / length)
            exact = np.linalg.solve([[1, g], [g, 1]], [depth, depth])
            np.testing.assert_allclose(res.actual_displacements, exact, rtol=1e-9)
            forces[law, depth] = res.wrench.force[2]
    ref, deep = DECAY_REFERENCE, 2 * DECAY_REFERENCE
    assert forces['fixed', deep] == pytest.approx(2 * forces['fixed', ref], rel=1e-9)
    assert forces['penetration', ref] == pytest.approx(forces['fixed', ref], rel=1e-9)
    assert forces['penetration', deep] < 0.97 * 2 * forces['penetration', ref]


def test_batch_single_query_and_displacement_field_agree_under_the_law(flat):
    mesh = box((0.012, 0.008, 0.004))
    poses = [Pose(position=[0.00023, 0.00041, -d], orientation=[0.0, 0.05, 0.0, np.sqrt(
        1 - 0.05 ** 2)]) for d in (0.001, 0.002, 0.004)]
    batch = flat.query_batch(mesh, poses, DOWN, np.zeros(3)).wrenches
    for i, pose in enumerate(poses):
        one = flat.query(mesh, pose, DOWN, np.zeros(3), return_displacements=True)
        np.testing.assert_allclose(batch[i], one.wrench.as_vector(), rtol=1e-9, atol=1e-12)
        # the field at the contacts: each contact's dent over its own length
        e = np.maximum(one.nominal_displacements, DECAY_FLOOR * DECAY_REFERENCE)
        lengths = L * e / DECAY_REFERENCE
        r = np.linalg.norm(flat.surface.points[:, None] - one.contact_points[None], axis=2)
        want = (C / (C + r) * np.exp(-r / lengths)) @ one.actual_displacements
        np.testing.assert_allclose(one.displacements, want, rtol=1e-9, atol=1e-15)
    assert flat.with_shape_constant(2 * C).decay_law == 'penetration'
    paper = flat.with_shape_constant(C, np.inf)      # no tail: the law has nothing to scale
    assert paper.decay_lengths(np.array([0.001, 0.004])) is None


def test_calibrate_shape_identifies_the_law_it_is_given():
    surface = grid_surface(half=0.04, step=0.0015)
    response = power_response(3e4, 1.5, len(surface))
    truth = ContactSimulator(surface, response, c=0.004, decay=0.016, decay_law='penetration')
    sphere, rod = icosphere(0.02, 3), box((0.05, 0.012, 0.01))
    pokes = []
    for mesh, lift, depths in ((sphere, 0.02, (0.002, 0.005)), (rod, 0.0, (0.0015, 0.004))):
        poses = [Pose(position=[0.0003, 0.0002, lift - d]) for d in depths]
        force = [truth.query(mesh, p, DOWN, p.position).wrench.force[2] for p in poses]
        pokes.append((mesh, poses, DOWN, np.array(force)))
    fixed = ContactSimulator(surface, response, c=0.002, decay=0.008, decay_law='fixed')
    law = calibrate_shape(fixed, pokes, decays=DECAY_GRID, decay_law='penetration')
    assert law.fit.c == pytest.approx(0.004, rel=0.02)
    assert law.fit.decay == 0.016
    assert law.in_sample_std < 0.005
    assert calibrate_shape(fixed, pokes, decays=DECAY_GRID).in_sample_std > 3 * max(
        law.in_sample_std, 1e-3)
    assert fixed.decay_law == 'fixed'             # the caller's simulator is left alone


def test_an_unknown_law_is_refused_and_the_default_is_the_penetration_law():
    surface = grid_surface(half=0.01, step=0.001)
    response = linear_response(K, len(surface))
    with pytest.raises(InvalidInput, match='decay_law'):
        ContactSimulator(surface, response, c=C, decay_law='depth')
    sim = ContactSimulator(surface, response, c=C, decay=L)
    assert sim.decay_law == DECAY_LAW == 'penetration'
    with pytest.raises(InvalidInput, match='decay_law'):
        sim.with_shape_constant(C, decay_law='depth')


def test_check_decay_law_returns_each_law_and_refuses_others_by_name():
    for law in DECAY_LAWS:
        assert check_decay_law(law) == law
    with pytest.raises(InvalidInput, match=r"^ContactModel\.shape_decay_law: .*'fixed'.*'depth'"):
        check_decay_law('depth', 'ContactModel.shape_decay_law')
    for bad in (None, 'Fixed', 3):
        with pytest.raises(InvalidInput, match='^decay_law: must be one of'):
            check_decay_law(bad)
