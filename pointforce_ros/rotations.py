"""Rotations and poses: the one home of rotation maths in the project, on scipy's ``Rotation``.

Quaternions are ``(x, y, z, w)`` as in ROS (and scipy); rotation vectors ``axis * angle`` (rad)
as UR reports them; UR poses ``[x, y, z, rx, ry, rz]`` (m, rad). Every function is vectorised
over leading axes and returns float64 arrays. Nothing here normalises silently beyond what
scipy does (a quaternion is normalised; a zero quaternion raises ``ValueError``).
"""

from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation


def _flat(a, tail: int):
    a = np.asarray(a, dtype=np.float64)
    flat = a.reshape((-1,) + a.shape[a.ndim - tail:])
    if not flat.flags.writeable:  # scipy's Cython views refuse read-only buffers
        flat = flat.copy()
    return flat, a.shape[:a.ndim - tail]


def rotvec_to_matrix(rotvec) -> np.ndarray:
    """(..., 3) rotation vectors (rad) -> (..., 3, 3) rotation matrices."""
    flat, lead = _flat(rotvec, 1)
    return Rotation.from_rotvec(flat).as_matrix().reshape(lead + (3, 3))


def matrix_to_rotvec(rot) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 3) rotation vectors, angle in [0, pi]."""
    flat, lead = _flat(rot, 2)
    return Rotation.from_matrix(flat).as_rotvec().reshape(lead + (3,))


def matrix_to_quaternion(rot) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (x, y, z, w), w >= 0."""
    flat, lead = _flat(rot, 2)
    return Rotation.from_matrix(flat).as_quat(canonical=True).reshape(lead + (4,))


def rotvec_matrix_and_quaternion(rotvec) -> tuple:
    """One rotation vector -> ``(3x3 matrix, (x, y, z, w) quaternion with w >= 0)``, closed form.

    The 250 Hz stream's path (one pose per sample): about 12 us against scipy's 90 us for the
    matrix and the quaternion from it (``pointforce bench streams``). Agrees with
    :func:`rotvec_to_matrix` and :func:`matrix_to_quaternion` to rounding, sign convention
    included (``test/core/test_rotations.py``); angles past pi are fine (the quaternion's sign
    is flipped to keep ``w >= 0``). A non-finite vector raises ``ValueError``.
    """
    x, y, z = (float(v) for v in np.asarray(rotvec, dtype=np.float64).reshape(3))
    t2 = x * x + y * y + z * z
    if not np.isfinite(t2):
        raise ValueError(f'rotvec_matrix_and_quaternion: non-finite rotation vector '
                         f'{[x, y, z]}')
    t = t2 ** 0.5
    if t < 1e-4:   # series: the closed form's 1 - cos loses digits near zero
        a, b, h = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 0.5 - t2 / 48.0
        w = 1.0 - t2 / 8.0
    else:
        s, c = np.sin(t), np.cos(t)
        a, b = s / t, (1.0 - c) / t2
        h, w = np.sin(0.5 * t) / t, np.cos(0.5 * t)
    matrix = np.array([[1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
                       [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
                       [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)]])
    q = [h * x, h * y, h * z, w]
    first = next((v for v in (q[3], q[0], q[1], q[2]) if v != 0.0), 1.0)
    if first < 0:   # scipy's canonical sign: w > 0, else the first non-zero of x, y, z
        q = [-v for v in q]
    return matrix, np.array(q)


def quaternion_to_matrix(q) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w; normalised here) -> (..., 3, 3) rotation matrices.

    One quaternion (the contact query's hot path) takes the closed form on floats, which
    costs 2 us against scipy's 20 us; arrays of them go through scipy. A zero quaternion
    raises ``ValueError`` either way.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (4,):
        flat, lead = _flat(q, 1)
        return Rotation.from_quat(flat).as_matrix().reshape(lead + (3, 3))
    x, y, z, w = (float(v) for v in q)
    n = x * x + y * y + z * z + w * w
    if not (n > 0 and np.isfinite(n)):
        raise ValueError(f'quaternion_to_matrix: zero or non-finite quaternion {q.tolist()}')
    s = 2.0 / n
    return np.array([[1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
                     [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
                     [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)]])


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton products ``a b`` of (4,) ``a`` and (B, 4) ``b``, x y z w, not normalised."""
    ax, ay, az, aw = (float(v) for v in a)
    bx, by, bz, bw = (np.asarray(b, dtype=np.float64)[:, k] for k in range(4))
    return np.column_stack([aw * bx + ax * bw + ay * bz - az * by,
                            aw * by - ax * bz + ay * bw + az * bx,
                            aw * bz + ax * by - ay * bx + az * bw,
                            aw * bw - ax * bx - ay * by - az * bz])


def quaternion_to_rotvec(q) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) -> (..., 3) rotation vectors, angle in [0, pi]."""
    flat, lead = _flat(q, 1)
    return Rotation.from_quat(flat).as_rotvec().reshape(lead + (3,))


def pose_to_matrix(pose) -> np.ndarray:
    """Return the (4, 4) homogeneous transform of a :class:`~pointforce_ros.types.Pose`."""
    m = np.eye(4)
    m[:3, :3] = quaternion_to_matrix(pose.orientation)
    m[:3, 3] = pose.position
    return m


def pose6_to_matrix(pose6) -> np.ndarray:
    """Return (..., 4, 4) transforms of UR poses ``[x, y, z, rx, ry, rz]`` (..., 6)."""
    pose6 = np.asarray(pose6, dtype=np.float64)
    out = np.zeros(pose6.shape[:-1] + (4, 4))
    out[..., :3, :3] = rotvec_to_matrix(pose6[..., 3:])
    out[..., :3, 3] = pose6[..., :3]
    out[..., 3, 3] = 1.0
    return out


def pose_trans(p_from: Sequence[float], p_from_to: Sequence[float]) -> np.ndarray:
    """Compose two UR poses (6,) as URScript ``pose_trans`` does; returns (6,)."""
    r1 = rotvec_to_matrix(np.asarray(p_from[3:6], dtype=np.float64))
    r2 = rotvec_to_matrix(np.asarray(p_from_to[3:6], dtype=np.float64))
    pos = np.asarray(p_from[:3], dtype=np.float64) + r1 @ np.asarray(p_from_to[:3],
                                                                     dtype=np.float64)
    return np.concatenate([pos, matrix_to_rotvec(r1 @ r2)])


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
