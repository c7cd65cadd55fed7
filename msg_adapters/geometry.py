"""geometry_msgs / shape_msgs <-> core types (Pose, Wrench, Mesh, vectors).

Message fields are copied once into numpy; validation is done by the core types, so a NaN or a
degenerate mesh in a request becomes :class:`~pointforce_ros.errors.InvalidInput`.
"""

import array
import math

import numpy as np
from geometry_msgs.msg import (Point, Pose as PoseMsg, PoseStamped, Quaternion, Transform,
                               TransformStamped, Vector3, Wrench as WrenchMsg, WrenchStamped)
from shape_msgs.msg import Mesh as MeshMsg, MeshTriangle

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Mesh, Pose, Wrench


def vec(msg) -> np.ndarray:
    """(3,) array from a Point or Vector3."""
    return np.array([msg.x, msg.y, msg.z], dtype=np.float64)


def to_point(v) -> Point:
    """Point message from a (3,) array."""
    x, y, z = (float(c) for c in v)
    return Point(x=x, y=y, z=z)


def to_vector3(v) -> Vector3:
    """Vector3 message from a (3,) array."""
    x, y, z = (float(c) for c in v)
    return Vector3(x=x, y=y, z=z)


def stamp_to_sec(stamp) -> float:
    """builtin_interfaces/Time -> seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


def sec_to_stamp(t: float, stamp) -> None:
    """Write seconds ``t`` into a builtin_interfaces/Time in place."""
    sec = int(np.floor(t))
    stamp.sec = sec
    stamp.nanosec = min(int(round((t - sec) * 1e9)), 999_999_999)


def pose_from_msg(msg: PoseMsg, frame: str = 'base') -> Pose:
    """geometry_msgs/Pose -> :class:`Pose`.

    A zero quaternion (an unfilled message) is read as the identity rotation, as rviz does.

    Raises:
        InvalidInput: NaN, or a non-zero quaternion that is not unit length.

    """
    q = np.array([msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w])
    if not q.any():
        q = np.array([0.0, 0.0, 0.0, 1.0])
    return Pose(position=vec(msg.position), orientation=q, frame=frame)


def pose_to_msg(pose: Pose) -> PoseMsg:
    """:class:`Pose` -> geometry_msgs/Pose."""
    x, y, z, w = (float(c) for c in pose.orientation)
    return PoseMsg(position=to_point(pose.position), orientation=Quaternion(x=x, y=y, z=z, w=w))


def pose_stamped_from_msg(msg: PoseStamped) -> Pose:
    """geometry_msgs/PoseStamped -> :class:`Pose` in the header's frame."""
    return pose_from_msg(msg.pose, frame=msg.header.frame_id or 'base')


def pose_stamped_to_msg(pose: Pose, stamp: float = 0.0) -> PoseStamped:
    """:class:`Pose` -> geometry_msgs/PoseStamped."""
    out = PoseStamped(pose=pose_to_msg(pose))
    out.header.frame_id = pose.frame
    sec_to_stamp(stamp, out.header.stamp)
    return out


def transform_to_msg(matrix, parent: str, child: str, stamp: float = 0.0) -> TransformStamped:
    """(4, 4) rigid transform ``parent <- child`` -> geometry_msgs/TransformStamped (for /tf)."""
    pose = Pose.from_matrix(matrix)
    x, y, z, w = (float(c) for c in pose.orientation)
    out = TransformStamped(child_frame_id=child, transform=Transform(
        translation=to_vector3(pose.position), rotation=Quaternion(x=x, y=y, z=z, w=w)))
    out.header.frame_id = parent
    sec_to_stamp(stamp, out.header.stamp)
    return out


def wrench_from_msg(msg: WrenchMsg, frame: str = 'base') -> Wrench:
    """geometry_msgs/Wrench -> :class:`Wrench`."""
    return Wrench(force=vec(msg.force), torque=vec(msg.torque), frame=frame)


def wrench_to_msg(wrench: Wrench) -> WrenchMsg:
    """:class:`Wrench` -> geometry_msgs/Wrench."""
    return WrenchMsg(force=to_vector3(wrench.force), torque=to_vector3(wrench.torque))


def wrench_stamped_from_msg(msg: WrenchStamped) -> Wrench:
    """geometry_msgs/WrenchStamped -> :class:`Wrench` in the header's frame."""
    return wrench_from_msg(msg.wrench, frame=msg.header.frame_id or 'base')


def wrench_stamped_to_msg(wrench: Wrench, stamp: float = 0.0) -> WrenchStamped:
    """:class:`Wrench` -> geometry_msgs/WrenchStamped."""
    out = WrenchStamped(wrench=wrench_to_msg(wrench))
    out.header.frame_id = wrench.frame
    sec_to_stamp(stamp, out.header.stamp)
    return out


def mesh_from_msg(msg: MeshMsg) -> Mesh:
    """shape_msgs/Mesh -> :class:`Mesh`.

    Raises:
        InvalidInput: no vertices or triangles, NaN vertices, indices out of range, or every
            triangle of zero area.

    """
    if len(msg.vertices) == 0 or len(msg.triangles) == 0:
        raise InvalidInput(f'Mesh: empty ({len(msg.vertices)} vertices, '
                           f'{len(msg.triangles)} triangles)')
    # flat comprehension and one concatenate of rclpy's (3,) uint32 arrays: a quarter of the
    # time of a row per element (0.3 ms instead of 1.2 ms for a 162-vertex sphere; issue 21)
    vertices = np.array([c for v in msg.vertices for c in (v.x, v.y, v.z)],
                        dtype=np.float64).reshape(-1, 3)
    triangles = np.concatenate([t.vertex_indices for t in msg.triangles]).astype(
        np.int64).reshape(-1, 3)
    return Mesh(vertices=vertices, triangles=triangles)


def mesh_from_flat(vertices, triangles) -> Mesh:
    """Flat ``float64[]`` vertices (x y z each) and ``uint32[]`` triangles -> :class:`Mesh`.

    The flat form of the contact requests: rclpy hands both over as buffers, read here without a
    Python loop.

    Raises:
        InvalidInput: lengths that are not multiples of 3, an empty mesh, NaN vertices, indices
            out of range, or every triangle of zero area.

    """
    v = np.frombuffer(vertices, dtype=np.float64) if isinstance(vertices, array.array) else \
        np.asarray(vertices, dtype=np.float64)
    t = np.frombuffer(triangles, dtype=np.uint32) if isinstance(triangles, array.array) else \
        np.asarray(triangles, dtype=np.int64)
    # planners resend one mesh with every query: a mesh seen before (same bytes) is the same
    # read-only Mesh object, already validated, so the service's caches hit by identity
    key = (v.tobytes(), t.dtype.str, t.tobytes())
    hit = _FLAT_MESHES.get(key)
    if hit is not None:
        return hit
    mesh = _mesh_from_arrays(v, t)
    if len(v) <= _CACHED_FLAT_VALUES and len(t) <= 2 * _CACHED_FLAT_VALUES:
        if len(_FLAT_MESHES) >= 16:
            _FLAT_MESHES.clear()
        _FLAT_MESHES[key] = mesh
    return mesh


_FLAT_MESHES: dict = {}
_CACHED_FLAT_VALUES = 30000
"""Largest flat mesh (values of ``mesh_vertices``; twice as many of ``mesh_triangles``, as a
closed mesh has) kept by :func:`mesh_from_flat`'s cache: 16 entries of at most 1.2 MB. The
triangles are bounded too: one triangle listed 1e6 times passed a vertex bound alone and 16
such requests held 600 MB (session 38)."""


def _mesh_from_arrays(v: np.ndarray, t: np.ndarray) -> Mesh:
    if len(v) % 3 or len(t) % 3:
        raise InvalidInput(f'mesh_vertices / mesh_triangles: {len(v)} and {len(t)} values, '
                           'both must be multiples of 3 (x y z; three indices)')
    if len(v) == 0 or len(t) == 0:
        raise InvalidInput(f'Mesh: empty ({len(v) // 3} vertices, {len(t) // 3} triangles)')
    return Mesh(vertices=v.reshape(-1, 3).copy(), triangles=t.astype(np.int64).reshape(-1, 3))


def mesh_to_flat(mesh: Mesh):
    """:class:`Mesh` -> (``float64[]``, ``uint32[]``) buffers for a request's flat mesh fields."""
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    triangles = np.ascontiguousarray(mesh.triangles, dtype=np.uint32)
    return array.array('d', vertices.tobytes()), array.array('I', triangles.tobytes())


def mesh_to_msg(mesh: Mesh) -> MeshMsg:
    """:class:`Mesh` -> shape_msgs/Mesh."""
    out = MeshMsg()
    out.vertices = [to_point(v) for v in mesh.vertices]
    tris = []
    for t in mesh.triangles:
        tri = MeshTriangle()
        tri.vertex_indices = [int(i) for i in t]
        tris.append(tri)
    out.triangles = tris
    return out


def unit_vector(msg: Vector3, name: str) -> np.ndarray:
    """(3,) unit vector from a Vector3, or :class:`InvalidInput` if NaN or not unit length."""
    v = vec(msg)
    norm = math.sqrt(float(v @ v))   # np.linalg.norm's sum; not finite if any entry is not
    if not math.isfinite(norm) or abs(norm - 1.0) > 1e-3:
        raise InvalidInput(f'{name}: must be a finite unit vector, got ({v[0]:.4g}, {v[1]:.4g}, '
                           f'{v[2]:.4g}) with length {norm:.4g}')
    return v / norm
