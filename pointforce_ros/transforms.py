"""Rotation and pose conversions shared by the core (UR rotation vectors, quaternions, 4x4).

Quaternions are ``(x, y, z, w)`` as in ROS; rotation vectors ``axis * angle`` as UR reports them.
All functions are vectorised over leading axes.
"""

import numpy as np

from pointforce_ros.types import Pose


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) UR rotation vectors -> (..., 3, 3) rotation matrices (Rodrigues)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    angle = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    safe = np.where(angle > 1e-12, angle, 1.0)
    k = rotvec / safe
    kx, ky, kz = k[..., 0], k[..., 1], k[..., 2]
    zero = np.zeros_like(kx)
    kmat = np.stack([np.stack([zero, -kz, ky], -1), np.stack([kz, zero, -kx], -1),
                     np.stack([-ky, kx, zero], -1)], -2)
    a = angle[..., None]
    eye = np.broadcast_to(np.eye(3), kmat.shape)
    return eye + np.sin(a) * kmat + (1 - np.cos(a)) * (kmat @ kmat)


def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (x, y, z, w), w >= 0."""
    rot = np.asarray(rot, dtype=np.float64)
    w = np.sqrt(np.clip(1.0 + rot[..., 0, 0] + rot[..., 1, 1] + rot[..., 2, 2], 0, None)) / 2
    x = np.sqrt(np.clip(1.0 + rot[..., 0, 0] - rot[..., 1, 1] - rot[..., 2, 2], 0, None)) / 2
    y = np.sqrt(np.clip(1.0 - rot[..., 0, 0] + rot[..., 1, 1] - rot[..., 2, 2], 0, None)) / 2
    z = np.sqrt(np.clip(1.0 - rot[..., 0, 0] - rot[..., 1, 1] + rot[..., 2, 2], 0, None)) / 2
    x = np.copysign(x, rot[..., 2, 1] - rot[..., 1, 2])
    y = np.copysign(y, rot[..., 0, 2] - rot[..., 2, 0])
    z = np.copysign(z, rot[..., 1, 0] - rot[..., 0, 1])
    q = np.stack([x, y, z, w], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def quaternion_to_rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) -> (..., 3) rotation vectors."""
    q = np.asarray(q, dtype=np.float64)
    q = q * np.where(q[..., 3:4] < 0, -1.0, 1.0)
    s = np.linalg.norm(q[..., :3], axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s, q[..., 3:4])
    return np.where(s > 1e-12, q[..., :3] / np.where(s > 1e-12, s, 1.0) * angle, 2 * q[..., :3])


def pose_to_matrix(pose: Pose) -> np.ndarray:
    """Return the (4, 4) homogeneous transform of ``pose``."""
    m = np.eye(4)
    m[:3, :3] = pose.rotation()
    m[:3, 3] = pose.position
    return m


def matrix_to_pose(matrix: np.ndarray, frame: str = 'base') -> Pose:
    """Return the :class:`Pose` of a (4, 4) rigid transform."""
    matrix = np.asarray(matrix, dtype=np.float64)
    return Pose(position=matrix[:3, 3], orientation=matrix_to_quaternion(matrix[:3, :3]),
                frame=frame)


def pose6_to_matrix(pose6: np.ndarray) -> np.ndarray:
    """Return (..., 4, 4) transforms of UR poses ``[x, y, z, rx, ry, rz]`` (..., 6)."""
    pose6 = np.asarray(pose6, dtype=np.float64)
    out = np.zeros(pose6.shape[:-1] + (4, 4))
    out[..., :3, :3] = rotvec_to_matrix(pose6[..., 3:])
    out[..., :3, 3] = pose6[..., :3]
    out[..., 3, 3] = 1.0
    return out


def rotvec_aligning_z(axis: np.ndarray) -> np.ndarray:
    """UR rotation vector (3,) of a tool whose z axis points along ``axis`` (3,).

    The rotation is the shortest one from base z to ``axis``; for ``axis = -z`` it is a half
    turn about x (tool pointing straight down, as a poke of a level surface).
    """
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    z = np.array([0.0, 0.0, 1.0])
    cross = np.cross(z, a)
    s = float(np.linalg.norm(cross))
    c = float(np.dot(z, a))
    if s < 1e-12:
        return np.zeros(3) if c > 0 else np.array([np.pi, 0.0, 0.0])
    return cross / s * np.arctan2(s, c)
