"""The ``'layer'`` decay law of the contact simulator (issue 17, session 30).

A thin soft layer on a stiff substrate stiffens more under a point poke, and spreads a dent
less far, than a thick one. :func:`layer_proxy` reads that off the point response
(``F(d0 + 8 mm) / F(d0 + 3 mm)`` against its median); the law multiplies every decay length of
a query by the median proxy under its candidate contacts.

* the proxy of a response stiffening by a known amount is the closed form, ones where nothing
  stiffens differently or nothing pushes back;
* two contacts over the stiffening region share their dent over ``L t e / E``, over the rest
  over the penetration law's ``L e / E``, by the closed form;
* batch, single query and displacement field agree under the law.
"""

import numpy as np
import pytest

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.contact.simulator import DECAY_FLOOR, DECAY_REFERENCE, layer_proxy
from pointforce_ros.lab.synthetic_contact import grid_surface
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.shapes import box
from pointforce_ros.types import Pose

K = 1000.0  # N/m, the first 3 mm everywhere
C = 0.003  # m
L = 0.008  # m
DOWN = np.array([0.0, 0.0, -1.0])
EDGE = 0.01  # m: points past x = EDGE stiffen four times faster after 3 mm
T_LAYER = (1.0 + 5.0 / 3.0) / (1.0 + 4.0 * 5.0 / 3.0)   # s_ref / s there: 8 / 23


def bilinear(surface, knee=0.003, depths=np.linspace(-0.002, 0.03, 321)):
    """``K d`` up to ``knee``, then slope ``K`` (x <= EDGE) or ``4 K`` (x > EDGE)."""
    after = np.where(surface.points[:, 0] > EDGE, 4.0 * K, K)
    d = np.clip(depths, 0.0, None)
    forces = K * np.minimum(d, knee)[None] + after[:, None] * np.clip(d - knee, 0.0, None)[None]
    return BakedResponse(depths=depths, forces=forces, slopes=after)


@pytest.fixture(scope='module')
def layered():
    surface = grid_surface(half=0.03, step=0.001)
    return ContactSimulator(surface, bilinear(surface), c=C, decay=L, decay_law='layer')


def test_the_proxy_is_the_ratio_of_stiffenings_and_ones_without_a_difference(layered):
    surface = layered.surface
    t = layer_proxy(layered.response, np.zeros(len(surface)))
    stiff = surface.points[:, 0] > EDGE
    assert 0.2 < stiff.mean() < 0.5           # the median is the rest's
    np.testing.assert_allclose(t[~stiff], 1.0, rtol=1e-9)
    np.testing.assert_allclose(t[stiff], T_LAYER, rtol=1e-9)
    np.testing.assert_array_equal(layered.layer_thickness(), t)    # the simulator's
    same = BakedResponse(depths=np.array([0.0, 0.01]),
                         forces=np.outer(np.full(len(surface), K), [0.0, 0.01]),
                         slopes=np.full(len(surface), K))
    np.testing.assert_allclose(layer_proxy(same, np.zeros(len(surface))), 1.0, rtol=1e-12)
    nothing = BakedResponse(depths=np.array([0.0, 0.01]), forces=np.zeros((len(surface), 2)),
                            slopes=np.zeros(len(surface)))
    np.testing.assert_array_equal(layer_proxy(nothing, np.zeros(len(surface))), 1.0)


@pytest.mark.parametrize('centre, scale', [(0.02, T_LAYER), (-0.015, 1.0)])
def test_a_dent_over_the_stiffening_region_spreads_less_far(layered, centre, scale):
    """Two contacts 10 mm apart, both over one region: the closed form of each law."""
    gap = 0.01
    pair = np.array([[centre - gap / 2 + 0.00025, 0.00025, -DECAY_REFERENCE],
                     [centre + gap / 2 + 0.00025, 0.00025, -DECAY_REFERENCE]])
    penetration = layered.with_shape_constant(C, decay_law='penetration')
    for sim, factor in ((layered, scale), (penetration, 1.0)):
        res = sim.query_points(pair, DOWN, np.zeros(3))
        g = C / (C + gap) * np.exp(-gap / (L * factor))
        exact = np.linalg.solve([[1, g], [g, 1]], [DECAY_REFERENCE, DECAY_REFERENCE])
        np.testing.assert_allclose(res.actual_displacements, exact, rtol=1e-9)
    over = layered.query_points(pair, DOWN, np.zeros(3)).wrench.force[2]
    plain = penetration.query_points(pair, DOWN, np.zeros(3)).wrench.force[2]
    if scale < 1.0:       # shared less: each contact keeps more of its dent, more force
        assert over > 1.02 * plain
    else:
        assert over == pytest.approx(plain, rel=1e-12)


def test_batch_single_query_and_displacement_field_agree_under_the_layer_law(layered):
    mesh = box((0.024, 0.008, 0.004))        # across the region's edge
    poses = [Pose(position=[EDGE + 0.00023, 0.00041, -d], orientation=[0.0, 0.05, 0.0, np.sqrt(
        1 - 0.05 ** 2)]) for d in (0.001, 0.002, 0.004)]
    batch = layered.query_batch(mesh, poses + poses[::-1], DOWN, np.zeros(3)).wrenches
    plain = layered.with_shape_constant(C, decay_law='penetration')
    for i, pose in enumerate(poses):
        one = layered.query(mesh, pose, DOWN, np.zeros(3), return_displacements=True)
        np.testing.assert_allclose(batch[i], one.wrench.as_vector(), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(batch[-1 - i], batch[i], rtol=1e-12, atol=1e-14)
        assert abs(one.wrench.force[2]) > 0.0
        assert not np.allclose(one.wrench.as_vector(),
                               plain.query(mesh, pose, DOWN, np.zeros(3)).wrench.as_vector(),
                               rtol=1e-3)
        # the field at the contacts: each dent over its own length times the pose's factor,
        # the median over the candidates (the detailed run's) of their neighbours' weighted
        # mean proxy
        run = layered._run(layered._samples(mesh), pose.rotation()[None], pose.position[None],
                           DOWN, np.zeros((1, 3)), detail=True)
        factor = float(np.median(np.einsum('kj,kj->k', layered.layer_thickness()[run['nbr']],
                                           run['w'])))
        assert factor < 0.99                  # the deeper end presses the stiffening region
        e = np.maximum(one.nominal_displacements, DECAY_FLOOR * DECAY_REFERENCE)
        r = np.linalg.norm(layered.surface.points[:, None] - one.contact_points[None], axis=2)
        want = (C / (C + r) * np.exp(-r / (L * factor * e / DECAY_REFERENCE))
                ) @ one.actual_displacements
        np.testing.assert_allclose(one.displacements, want, rtol=1e-9, atol=1e-15)
