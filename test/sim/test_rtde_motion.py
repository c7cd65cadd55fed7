"""The emulated TCP's kinematics: its pose follows every rotation (the rest pose is cached)."""

import numpy as np

from pointforce_ros.rotations import matrix_to_rotvec, rotvec_to_matrix
from pointforce_ros.sim.rtde.motion import Kinematics, LinearMove


def test_pose_follows_rotations_and_moves_after_a_rest():
    kin = Kinematics([0.3, 0.0, 0.3, np.pi, 0.0, 0.0])
    rest = kin.pose6()
    np.testing.assert_allclose(rotvec_to_matrix(rest[3:]), kin.r, atol=1e-12)
    np.testing.assert_array_equal(kin.pose6(), rest)             # at rest: the same pose
    kin.integrate(np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.2, 0.1]), 0.002)
    turned = kin.pose6()
    np.testing.assert_allclose(turned[3:], matrix_to_rotvec(kin.r), atol=1e-12)
    assert np.linalg.norm(turned[3:] - rest[3:]) > 1e-4 and turned[0] > rest[0]
    target = np.r_[kin.p + [0.0, 0.01, 0.0], matrix_to_rotvec(
        rotvec_to_matrix([0.0, 0.0, 0.3]) @ kin.r)]
    move = LinearMove(kin, target, 0.25, 1.2)
    while not move.step(kin, 0.002):
        np.testing.assert_allclose(kin.pose6()[3:], matrix_to_rotvec(kin.r), atol=1e-12)
    np.testing.assert_allclose(kin.pose6(), target, atol=1e-9)
