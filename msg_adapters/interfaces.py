"""pointforce_interfaces (Poke, ContactWrench, ContactWrenchBatch, SuggestPoke) <-> core types.

Request readers raise :class:`~pointforce_ros.errors.InvalidInput` with a message that names the
offending field; the nodes turn that into ``success=False`` (services) or a rejected goal (action).
Response writers take core results duck-typed: a single result has ``wrench``,
``contact_count``, ``max_displacement`` and, when displacements were asked for,
``displaced_indices`` and ``displacements``; a batch result has the arrays ``wrenches`` (B, 6),
``contact_count`` (B,) and ``max_displacement`` (B,).
"""

from typing import NamedTuple, Optional

import numpy as np
from geometry_msgs.msg import Vector3, Wrench as WrenchMsg
from pointforce_interfaces.action import Poke
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch, SuggestPoke
from std_msgs.msg import Header

from msg_adapters.geometry import (mesh_from_flat, mesh_from_msg, pose_from_msg, to_point,
                                   to_vector3, unit_vector, vec)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.rotations import pose_to_matrix, quaternion_product
from pointforce_ros.types import ContactQuery, Mesh, Pose, PokeGoal


MODEL_FRAME = 'base'
"""The frame the contact model, and so every contact query, is in."""


def check_frame(header, frame: str = MODEL_FRAME) -> None:
    """Refuse a request stamped in another frame than ``frame`` (an empty frame_id means it).

    Raises:
        InvalidInput: naming the frame given and the one the service answers in.

    """
    if header.frame_id not in ('', frame):
        raise InvalidInput(f'header.frame_id: {header.frame_id!r} is not the model frame '
                           f'{frame!r}; transform the query into {frame!r} (or leave the '
                           f'frame_id empty for {frame!r})')


def request_mesh(req):
    """Return the request's mesh: ``mesh`` or the flat ``mesh_vertices`` / ``mesh_triangles``.

    Raises:
        InvalidInput: both forms given, or a bad mesh in the one given.

    """
    if len(req.mesh_vertices) or len(req.mesh_triangles):
        if len(req.mesh.vertices) or len(req.mesh.triangles):
            raise InvalidInput('mesh: given twice (mesh and mesh_vertices / mesh_triangles); '
                               'fill one form')
        return mesh_from_flat(req.mesh_vertices, req.mesh_triangles)
    return mesh_from_msg(req.mesh)


def contact_query_from_request(req: ContactWrench.Request,
                               base_from_frame: Optional[np.ndarray] = None) -> ContactQuery:
    """Convert a ContactWrench request to a :class:`ContactQuery` with one pose, in ``base``.

    ``base_from_frame``: the (4, 4) transform ``base <- header.frame_id`` (the node looks it
    up in the tf tree); ``None`` accepts only ``base`` (or an empty frame_id).

    Raises:
        InvalidInput: a frame other than ``base`` without its transform, empty/NaN/degenerate
            mesh, bad pose, approach not unit, NaN centre.

    """
    pose, approach = pose_from_msg(req.pose), unit_vector(req.approach, 'approach')
    centre = vec(req.torque_centre)
    if base_from_frame is None:
        check_frame(req.header)
    else:
        m = np.asarray(base_from_frame, dtype=np.float64)
        pose = Pose.from_matrix(m @ pose_to_matrix(pose))
        approach, centre = m[:3, :3] @ approach, m[:3, :3] @ centre + m[:3, 3]
    return ContactQuery(mesh=request_mesh(req), poses=(pose,), approach=approach,
                        torque_centre=centre,
                        return_displacements=bool(req.return_displacements))


def contact_query_from_batch_request(req: ContactWrenchBatch.Request) -> ContactQuery:
    """Convert a ContactWrenchBatch request to a :class:`ContactQuery` with every pose.

    Raises:
        InvalidInput: as :func:`contact_query_from_request`, or no poses (the message names the
            index of a bad pose).

    """
    check_frame(req.header)
    if len(req.poses) == 0:
        raise InvalidInput('poses: the batch is empty')
    poses = []
    for i, p in enumerate(req.poses):
        try:
            poses.append(pose_from_msg(p))
        except InvalidInput as exc:
            raise InvalidInput(f'poses[{i}]: {exc}') from None
    return ContactQuery(mesh=request_mesh(req), poses=tuple(poses),
                        approach=unit_vector(req.approach, 'approach'),
                        torque_centre=vec(req.torque_centre))


def pose_rows_from_msgs(poses) -> np.ndarray:
    """(B, 7) ``[x, y, z, qx, qy, qz, qw]`` of geometry_msgs/Pose messages, in one pass.

    A zero quaternion (an unfilled message) is read as the identity, as :func:`pose_from_msg`
    does; the rows are not validated here (:meth:`WrenchServer.answer_rows` refuses non-finite
    values and non-unit quaternions, naming the row).
    """
    rows = np.array([(p.position.x, p.position.y, p.position.z, p.orientation.x,
                      p.orientation.y, p.orientation.z, p.orientation.w) for p in poses],
                    dtype=np.float64).reshape(-1, 7)
    unfilled = ~np.any(rows[:, 3:], axis=1)
    rows[unfilled, 6] = 1.0
    return rows


class BatchArrays(NamedTuple):
    """A ContactWrenchBatch request as arrays (``base``, metres)."""

    mesh: Mesh
    poses: np.ndarray          # (B, 7) x y z qx qy qz qw
    approach: np.ndarray       # (3,) unit
    torque_centre: np.ndarray  # (3,)


def batch_arrays_from_request(req: ContactWrenchBatch.Request,
                              base_from_frame: Optional[np.ndarray] = None) -> BatchArrays:
    """Convert a ContactWrenchBatch request to arrays without a :class:`Pose` per pose.

    The batch service's form (10 000 poses convert in about 20 ms, a tenth of the Pose path).
    ``base_from_frame`` as in :func:`contact_query_from_request`: every pose, the approach and
    the torque centre are moved into ``base`` (a quaternion keeps its norm, so one that is not
    unit is still refused, naming its row).

    Raises:
        InvalidInput: a frame other than ``base`` without its transform, no poses, a bad mesh,
            approach not unit, NaN centre.

    """
    if base_from_frame is None:
        check_frame(req.header)
    if len(req.poses) == 0:
        raise InvalidInput('poses: the batch is empty')
    centre = vec(req.torque_centre)
    if not np.all(np.isfinite(centre)):
        raise InvalidInput('torque_centre: non-finite value(s) (NaN or inf)')
    rows, approach = pose_rows_from_msgs(req.poses), unit_vector(req.approach, 'approach')
    if base_from_frame is not None:
        m = np.asarray(base_from_frame, dtype=np.float64)
        rows = np.column_stack([rows[:, :3] @ m[:3, :3].T + m[:3, 3],
                                quaternion_product(Pose.from_matrix(m).orientation,
                                                   rows[:, 3:])])
        approach, centre = m[:3, :3] @ approach, m[:3, :3] @ centre + m[:3, 3]
    return BatchArrays(mesh=request_mesh(req), poses=rows, approach=approach,
                       torque_centre=centre)


def rows_in_frame(rows, rotation: Optional[np.ndarray]) -> np.ndarray:
    """(B, 6) wrench rows ``[f, tau]`` rotated by ``rotation`` (frame <- base); None: as is."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 6)
    if rotation is None:
        return rows
    r = np.asarray(rotation, dtype=np.float64)
    return np.hstack([rows[:, :3] @ r.T, rows[:, 3:] @ r.T])


def std_rows_in_frame(rows, rotation: Optional[np.ndarray]) -> np.ndarray:
    """(B, 6) standard deviations of ``[f, tau]`` in the rotated frame; None: as is.

    ``rotation``: frame <- base. The components are taken as independent (only their spreads
    are known).
    """
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, 6)
    if rotation is None:
        return rows
    r2 = np.asarray(rotation, dtype=np.float64) ** 2
    return np.sqrt(np.hstack([rows[:, :3] ** 2 @ r2.T, rows[:, 3:] ** 2 @ r2.T]))


def fill_contact_response(resp: ContactWrench.Response, result, model_version: int,
                          with_displacements: bool,
                          rotation: Optional[np.ndarray] = None) -> ContactWrench.Response:
    """Write a core contact result into a ContactWrench response (success=True).

    ``rotation`` (3, 3), frame <- base: the wrench is given in the request's frame.
    """
    resp.success = True
    resp.message = ''
    force, torque = resp.wrench.force, resp.wrench.torque   # in place: no message built
    f, tau = result.wrench.force, result.wrench.torque
    if rotation is not None:
        f, tau = rotation @ f, rotation @ tau
    force.x, force.y, force.z = (float(c) for c in f)
    torque.x, torque.y, torque.z = (float(c) for c in tau)
    resp.contact_count = int(result.contact_count)
    resp.max_displacement = float(result.max_displacement)
    resp.model_version = int(model_version)
    if with_displacements:
        resp.displaced_indices = np.asarray(result.displaced_indices, dtype=np.uint32).tolist()
        resp.displacements = np.asarray(result.displacements, dtype=np.float64).tolist()
    return resp


def fill_batch_response(resp: ContactWrenchBatch.Response, batch, model_version: int,
                        rotation: Optional[np.ndarray] = None) -> ContactWrenchBatch.Response:
    """Write a batch result into a ContactWrenchBatch response (success=True).

    ``batch`` has ``wrenches`` (B, 6), ``contact_count`` (B,) and ``max_displacement`` (B,);
    ``rotation`` as in :func:`fill_contact_response`.
    """
    wrenches = rows_in_frame(batch.wrenches, rotation).tolist()
    resp.success = True
    resp.message = ''
    resp.wrenches = [WrenchMsg(force=Vector3(x=fx, y=fy, z=fz), torque=Vector3(x=tx, y=ty, z=tz))
                     for fx, fy, fz, tx, ty, tz in wrenches]
    resp.contact_counts = np.asarray(batch.contact_count, dtype=np.uint32).tolist()
    resp.max_displacements = np.asarray(batch.max_displacement, dtype=np.float64).tolist()
    resp.model_version = int(model_version)
    return resp


def fill_wrench_std(resp, std, rotation: Optional[np.ndarray] = None) -> None:
    """Write standard deviations (6,) or (B, 6) into a ContactWrench / batch response.

    A single response gets ``wrench_std`` and ``has_wrench_std = True``; a batch response gets
    one ``wrench_stds`` entry per pose. ``rotation`` as in :func:`fill_contact_response`
    (:func:`std_rows_in_frame`).
    """
    rows = std_rows_in_frame(std, rotation).tolist()
    msgs = [WrenchMsg(force=Vector3(x=fx, y=fy, z=fz), torque=Vector3(x=tx, y=ty, z=tz))
            for fx, fy, fz, tx, ty, tz in rows]
    if hasattr(resp, 'wrench_stds'):
        resp.wrench_stds = msgs
    else:
        resp.wrench_std = msgs[0]
        resp.has_wrench_std = True


def fail(resp, message: str):
    """Mark any of our service responses as failed with ``message``; returns ``resp``."""
    resp.success = False
    resp.message = message
    return resp


def poke_goal_from_msg(goal: Poke.Goal,
                       base_from_frame: Optional[np.ndarray] = None) -> PokeGoal:
    """Convert a Poke goal message to a :class:`PokeGoal` in ``base``.

    The normal must be unit length unless ``surface_index`` selects a surface point;
    ``surface_index`` is -1 (none) or an index >= 0, nothing else. ``base_from_frame`` as in
    :func:`contact_query_from_request` (the point and normal are moved into ``base``).

    Raises:
        InvalidInput: a ``header.frame_id`` other than ``base`` (empty: ``base``) without its
            transform, NaN fields, a non-unit normal, or ``surface_index`` below -1.

    """
    if base_from_frame is None:
        check_frame(goal.header)
    if goal.surface_index < -1:
        raise InvalidInput(f'surface_index {goal.surface_index}: must be -1 (use point and '
                           'normal) or a surface point index >= 0')
    normal, point = vec(goal.normal), vec(goal.point)
    if goal.surface_index < 0:
        normal = unit_vector(goal.normal, 'normal')
    if base_from_frame is not None:
        m = np.asarray(base_from_frame, dtype=np.float64)
        point, normal = m[:3, :3] @ point + m[:3, 3], m[:3, :3] @ normal
    return PokeGoal(point=point, normal=normal, surface_index=goal.surface_index,
                    force_limit=goal.force_limit, depth_limit=goal.depth_limit,
                    speed=goal.speed, standoff=goal.standoff)


def poke_goal_to_msg(goal: PokeGoal) -> Poke.Goal:
    """Convert a :class:`PokeGoal` to a Poke goal message stamped in ``base``."""
    return Poke.Goal(header=Header(frame_id=MODEL_FRAME),
                     point=to_point(goal.point), normal=to_vector3(goal.normal),
                     surface_index=goal.surface_index, force_limit=goal.force_limit,
                     depth_limit=goal.depth_limit, speed=goal.speed, standoff=goal.standoff)


def poke_result_msg(poke_id: str, samples: int, peak_force: float, max_depth: float,
                    outcome: str, message: str = '') -> Poke.Result:
    """Build a Poke result message."""
    return Poke.Result(poke_id=poke_id, samples=int(samples), peak_force=float(peak_force),
                       max_depth=float(max_depth), outcome=outcome, message=message)


def poke_feedback_msg(depth: float, normal_force: float, samples: int,
                      phase: str) -> Poke.Feedback:
    """Build a Poke feedback message."""
    return Poke.Feedback(depth=float(depth), normal_force=float(normal_force),
                         samples=int(samples), phase=phase)


def fill_suggest_response(resp: SuggestPoke.Response, indices, points, normals,
                          uncertainty, frame: str = MODEL_FRAME) -> SuggestPoke.Response:
    """Write suggested poke locations into a SuggestPoke response (success=True).

    ``header.frame_id`` is ``frame``, the frame of ``points`` and ``normals``; the caller stamps
    the header.
    """
    resp.success = True
    resp.header.frame_id = frame
    resp.message = ''
    resp.surface_indices = [int(i) for i in indices]
    resp.points = [to_point(p) for p in np.asarray(points).reshape(-1, 3)]
    resp.normals = [to_vector3(n) for n in np.asarray(normals).reshape(-1, 3)]
    resp.uncertainty = [float(u) for u in uncertainty]
    return resp
