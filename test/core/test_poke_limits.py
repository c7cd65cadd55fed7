"""Poke goal checks that keep the arm out of the object (issue 16, item 4).

An inverted normal put the stand-off 6 mm inside the object (the arm tared while pressed in
and "retracted" there), a horizontal normal was accepted, and ``surface_index=-2`` was
treated as -1.
"""

import numpy as np
import pytest

from msg_adapters.interfaces import poke_goal_from_msg, poke_goal_to_msg
from pointforce_ros.errors import InvalidInput, UnsafeCommand
from pointforce_ros.pokes.limits import check_goal, PokeLimits
from pointforce_ros.types import PokeGoal, Surface

LIMITS = PokeLimits()


def _dome():
    """A spherical cap of radius 0.1 m centred at (0.5, 0, -0.05): top at z = 0.05 m."""
    rng = np.random.default_rng(4)
    direction = rng.normal(size=(4000, 3))
    direction[:, 2] = np.abs(direction[:, 2])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    direction = direction[direction[:, 2] > 0.8]
    return Surface(points=np.array([0.5, 0.0, -0.05]) + 0.1 * direction, normals=direction)


DOME = _dome()


def _goal(**overrides):
    values = dict(point=[0.5, 0.0, 0.05], normal=[0.0, 0.0, 1.0], force_limit=3.0,
                  depth_limit=0.008, speed=0.005, standoff=0.008)
    values.update(overrides)
    return PokeGoal(**values)


def test_a_good_goal_passes_with_and_without_the_surface():
    for surface in (None, DOME):
        point, normal = check_goal(_goal(), LIMITS, surface)
        np.testing.assert_allclose(normal, [0, 0, 1])
    # on the dome's flank, along its own normal (25 deg from up): accepted
    n = np.array([np.sin(np.radians(25)), 0.0, np.cos(np.radians(25))])
    check_goal(_goal(point=[0.5, 0.0, -0.05] + 0.1 * n, normal=n), LIMITS, DOME)


@pytest.mark.parametrize('normal, surface, match', [
    ([0.0, 0.0, -1.0], DOME, 'deg from up'),               # inverted: into the object
    ([1.0, 0.0, 0.0], DOME, 'deg from up'),                # horizontal
    ([1.0, 0.0, 0.0], None, 'deg from up'),                # horizontal, no surface known
    ([0.0, 0.0, -1.0], None, 'deg from up'),
    ([np.sin(0.7), 0.0, np.cos(0.7)], DOME, 'from the surface normal'),   # 40 deg off
])
def test_normals_that_do_not_point_out_of_the_surface_are_refused(normal, surface, match):
    with pytest.raises(UnsafeCommand, match=match):
        check_goal(_goal(normal=normal), LIMITS, surface)


def test_a_stand_off_inside_the_object_is_refused():
    # 2.5 mm below the top (inside the 3 mm tolerance), stand-off 4 mm: 1.5 mm out < 2 mm
    with pytest.raises(UnsafeCommand, match='inside the object'):
        check_goal(_goal(point=[0.5, 0.0, 0.0475], standoff=0.004), LIMITS, DOME)
    check_goal(_goal(point=[0.5, 0.0, 0.0475], standoff=0.01), LIMITS, DOME)


@pytest.mark.parametrize('index, match', [(-2, 'must be -1'), (-100, 'must be -1'),
                                          (len(DOME), 'out of range'), (10 ** 9, 'out of range')])
def test_surface_indices_are_validated_exactly(index, match):
    with pytest.raises(InvalidInput, match=match):
        check_goal(_goal(surface_index=index), LIMITS, DOME)
    message = poke_goal_to_msg(_goal())
    message.surface_index = index
    if index < -1:
        with pytest.raises(InvalidInput, match='must be -1'):
            poke_goal_from_msg(message)


def test_every_surface_index_and_none_is_accepted():
    top = int(np.argmax(DOME.points[:, 2]))
    for index in (-1, 0, top, len(DOME) - 1):
        point, normal = check_goal(_goal(surface_index=index), LIMITS, DOME)
        if index >= 0:
            np.testing.assert_array_equal(point, DOME.points[index])
    with pytest.raises(InvalidInput, match='no equilibrium surface'):
        check_goal(_goal(surface_index=0), LIMITS, None)


@pytest.mark.parametrize('speed', [1e-300, 1e-5])
def test_a_push_slower_than_the_longest_push_time_is_refused(speed):
    """A speed of 1e-300 m/s passed the (0, max_speed] check and held the arm for good."""
    with pytest.raises(UnsafeCommand, match=r'longer than max_push_time 300 s'):
        check_goal(_goal(speed=speed), LIMITS)
    # 16 mm at 0.1 mm/s is 160 s: accepted, refused when the limit is 100 s
    check_goal(_goal(speed=1e-4), LIMITS)
    with pytest.raises(UnsafeCommand, match=r'would take 160 s'):
        check_goal(_goal(speed=1e-4), PokeLimits(max_push_time=100.0))
