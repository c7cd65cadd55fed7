"""The one rotation module (scipy Rotation): round trips and the cases hand-written code missed."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointforce_ros import rotations as rot
from pointforce_ros.types import Pose


def _random_rotvecs(n, seed):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return axes * rng.uniform(0.0, np.pi, size=(n, 1))


def test_half_turn_about_a_diagonal_axis_gives_the_right_quaternion():
    axis = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    matrix = Rotation.from_rotvec(np.pi * axis).as_matrix()
    q = rot.matrix_to_quaternion(matrix)
    np.testing.assert_allclose(rot.quaternion_to_matrix(q), matrix, atol=1e-12)
    np.testing.assert_allclose(np.abs(q), np.abs(np.r_[axis, 0.0]), atol=1e-12)
    # the pose built from it rotates points as the matrix does
    pose = Pose.from_matrix(np.block([[matrix, np.zeros((3, 1))], [np.zeros((1, 3)), 1.0]]))
    np.testing.assert_allclose(pose.rotation(), matrix, atol=1e-12)


@pytest.mark.parametrize('seed', [0, 1])
def test_round_trips_over_random_and_edge_rotations(seed):
    rotvecs = np.vstack([_random_rotvecs(200, seed), np.zeros((1, 3)),
                         [[np.pi, 0, 0], [0, np.pi, 0], [0, 0, np.pi]]])
    matrices = rot.rotvec_to_matrix(rotvecs)
    np.testing.assert_allclose(matrices @ np.swapaxes(matrices, 1, 2),
                               np.broadcast_to(np.eye(3), matrices.shape), atol=1e-12)
    q = rot.matrix_to_quaternion(matrices)
    assert np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(rot.quaternion_to_matrix(q), matrices, atol=1e-12)
    np.testing.assert_allclose(rot.rotvec_to_matrix(rot.matrix_to_rotvec(matrices)), matrices,
                               atol=1e-12)
    np.testing.assert_allclose(rot.rotvec_to_matrix(rot.quaternion_to_rotvec(q)), matrices,
                               atol=1e-12)
    # one quaternion (closed form) and many (scipy) agree, normalised or not
    for k in (0, 7, 203):
        np.testing.assert_allclose(rot.quaternion_to_matrix(3.0 * q[k]),
                                   rot.quaternion_to_matrix(q[k:k + 1])[0], atol=1e-12)
    with pytest.raises(ValueError):
        rot.quaternion_to_matrix(np.zeros(4))
    # read-only arrays (memory-mapped or from a bag reader) are accepted
    frozen = rotvecs.copy()
    frozen.flags.writeable = False
    np.testing.assert_allclose(rot.rotvec_to_matrix(frozen), matrices, atol=0)
    # leading axes are kept
    assert rot.rotvec_to_matrix(rotvecs.reshape(2, -1, 3)[:, :3]).shape == (2, 3, 3, 3)


@pytest.mark.parametrize('seed', [0, 1])
def test_closed_form_matrix_and_quaternion_match_scipy_at_every_angle(seed):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(60, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.r_[rng.uniform(0.0, 2.0 * np.pi, 40), 0.0, 1e-12, 1e-9, 3e-5, 9.9e-5, 1.01e-4,
                   1e-3, np.pi - 1e-9, np.pi, np.pi + 1e-9, 2.0 * np.pi - 1e-3,
                   rng.uniform(0.0, 1e-3, 9)]
    rotvecs = np.vstack([axes * angles[:, None], [[np.pi, 0, 0], [0, -np.pi, 0],
                                                  [0, 0, np.pi], [-2.0, 2.0, 0.0]]])
    for rotvec in rotvecs:
        matrix, q = rot.rotvec_matrix_and_quaternion(rotvec)
        expected = Rotation.from_rotvec(rotvec)
        np.testing.assert_allclose(matrix, expected.as_matrix(), atol=2e-15)
        # scipy's canonical sign: w >= 0, and the first non-zero component positive at w == 0
        np.testing.assert_allclose(q, expected.as_quat(canonical=True), atol=2e-15)
        np.testing.assert_allclose(q, rot.matrix_to_quaternion(expected.as_matrix()),
                                   atol=2e-15)
    for bad in ([np.nan, 0.0, 0.0], [0.0, np.inf, 1.0]):
        with pytest.raises(ValueError, match='non-finite'):
            rot.rotvec_matrix_and_quaternion(bad)


def test_tool_z_aligned_with_any_axis():
    for axis in ([0, 0, -1.0], [0, 0, 1.0], [1.0, 2.0, -0.5], [0.0, -1e-9, -1.0]):
        a = np.asarray(axis) / np.linalg.norm(axis)
        np.testing.assert_allclose(rot.rotvec_to_matrix(rot.rotvec_aligning_z(a))[:, 2], a,
                                   atol=1e-9)


def test_pose_trans_composes_like_homogeneous_matrices():
    rng = np.random.default_rng(3)
    a = np.r_[rng.normal(size=3), _random_rotvecs(1, 4)[0]]
    b = np.r_[rng.normal(size=3), _random_rotvecs(1, 5)[0]]
    np.testing.assert_allclose(rot.pose6_to_matrix(rot.pose_trans(a, b)),
                               rot.pose6_to_matrix(a) @ rot.pose6_to_matrix(b), atol=1e-12)
