"""Frozen record types shared by the core, the adapters and the nodes.

Conventions (all records): SI units (metres, newtons, newton-metres, seconds), float64 arrays,
positions and normals in the robot ``base`` frame unless a ``frame`` field says otherwise.
Arrays are validated and made read-only on construction, so a record can be shared between
threads (the learner and the contact service) without copies.
"""

import math
import numbers
import re
from dataclasses import dataclass, field
from typing import Mapping, Optional, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.rotations import matrix_to_quaternion, quaternion_to_matrix

ORIENTED_TOLERANCE = 1e-3
"""Largest accepted deviation of a normal's length from one."""

POKE_ID_MAX_LENGTH = 128
"""Longest accepted poke id, in characters: a poke id names files (a bag folder, a recovery
file), whose names the file system bounds at 255 bytes."""

_POKE_ID = re.compile(r'[A-Za-z0-9_-]([A-Za-z0-9._ +=@-]*[A-Za-z0-9._+=@-])?')


def as_array(value, name: str, shape: Tuple[Optional[int], ...], *, finite: bool = True,
             dtype=np.float64) -> np.ndarray:
    """Return ``value`` as a read-only array of ``shape`` (``None`` = any size) or raise.

    Raises:
        InvalidInput: wrong number of dimensions, wrong size, or non-finite entries when
            ``finite`` is set.

    """
    try:
        arr = np.array(value, dtype=dtype, copy=True)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f'{name}: cannot be read as {np.dtype(dtype).name} array: {exc}')
    if arr.ndim != len(shape):
        raise InvalidInput(f'{name}: expected {len(shape)}-D array of shape '
                           f'{_shape_text(shape)}, got shape {arr.shape}')
    for axis, (want, got) in enumerate(zip(shape, arr.shape)):
        if want is not None and want != got:
            raise InvalidInput(f'{name}: expected shape {_shape_text(shape)}, '
                               f'got {arr.shape} (axis {axis})')
    # a finite sum means every entry is finite (inf or NaN would carry through); only a sum
    # that is not (a non-finite entry, or finite ones overflowing) pays for the full check
    if (finite and arr.dtype.kind == 'f' and arr.size and not math.isfinite(arr.sum())
            and not np.isfinite(arr).all()):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise InvalidInput(f'{name}: {bad} non-finite value(s) (NaN or inf)')
    arr.setflags(write=False)
    return arr


def check_poke_id(poke_id, name: str = 'poke_id') -> str:
    """Return ``poke_id`` if it is a plain file name, else raise.

    A poke id names the poke's bag folder in a store and its recovery file, so it must not
    reach outside them: 1 to :data:`POKE_ID_MAX_LENGTH` ASCII letters, digits, ``.``, ``_``,
    ``-``, ``+``, ``=``, ``@`` or inner spaces (a table's ``site A 2``), not starting with
    ``.`` (no ``.``, ``..``, hidden or ``.tmp-*`` names, no path separator, no absolute
    path).

    Raises:
        InvalidInput: ``'<name>: <id>: ...'`` naming the refused id.

    """
    if not isinstance(poke_id, str) or not poke_id:
        raise InvalidInput(f'{name}: must be a non-empty string, got {poke_id!r}')
    if len(poke_id) > POKE_ID_MAX_LENGTH or not _POKE_ID.fullmatch(poke_id):
        shown = poke_id if len(poke_id) <= 80 else poke_id[:77] + '...'
        raise InvalidInput(f'{name}: {shown!r} ({len(poke_id)} characters) is not a plain '
                           f'name: a poke id is 1 to {POKE_ID_MAX_LENGTH} letters, digits, '
                           "'.', '_', '-', '+', '=', '@' or inner spaces, not starting with "
                           "'.' (it names a file)")
    return poke_id


def _shape_text(shape) -> str:
    return '(' + ', '.join('N' if s is None else str(s) for s in shape) + ')'


def unit_rows(vectors: np.ndarray, name: str) -> np.ndarray:
    """Check that every row of ``vectors`` (N, 3) has unit length within tolerance.

    Raises:
        InvalidInput: a row whose length differs from one by more than ``ORIENTED_TOLERANCE``.

    """
    norms = np.linalg.norm(vectors, axis=-1)
    bad = np.abs(norms - 1.0) > ORIENTED_TOLERANCE
    if np.any(bad):
        first = int(np.flatnonzero(np.atleast_1d(bad))[0])
        raise InvalidInput(f'{name}: {int(np.count_nonzero(bad))} vector(s) are not unit length '
                           f'(first at index {first}: |n| = {np.atleast_1d(norms)[first]:.4g})')
    return vectors


@dataclass(frozen=True)
class Surface:
    """Equilibrium surface ``S = {x = [p, rgb, n]}`` (seed paper section III).

    Attributes:
        points: (N, 3) positions, metres, in ``frame``.
        normals: (N, 3) outward unit normals in ``frame``.
        colors: (N, 3) RGB in [0, 1]; zeros when the source had no colour.
        frame: frame id of points and normals (``base`` for a surface the learner uses).

    Raises:
        InvalidInput: mismatched lengths, NaN, non-unit normals, colours outside [0, 1].

    """

    points: np.ndarray
    normals: np.ndarray
    colors: Optional[np.ndarray] = None
    frame: str = 'base'

    def __post_init__(self):
        points = as_array(self.points, 'Surface.points', (None, 3))
        normals = unit_rows(as_array(self.normals, 'Surface.normals', (len(points), 3)),
                            'Surface.normals')
        if self.colors is None:
            colors = as_array(np.zeros((len(points), 3)), 'Surface.colors', (len(points), 3))
        else:
            colors = as_array(self.colors, 'Surface.colors', (len(points), 3))
            if colors.size and (colors.min() < 0.0 or colors.max() > 1.0):
                raise InvalidInput('Surface.colors: values must lie in [0, 1]')
        object.__setattr__(self, 'points', points)
        object.__setattr__(self, 'normals', normals)
        object.__setattr__(self, 'colors', colors)

    def __len__(self) -> int:
        """Return the number of surface points."""
        return len(self.points)

    @property
    def features(self) -> np.ndarray:
        """(N, 9) feature rows ``[p, rgb, n]`` as the seed paper's ``x``."""
        return np.hstack([self.points, self.colors, self.normals])


@dataclass(frozen=True)
class Mesh:
    """Rigid triangle mesh (a probe or a planner's object) in its own frame.

    Attributes:
        vertices: (V, 3) metres.
        triangles: (M, 3) int64 vertex indices, counter-clockwise seen from outside.

    Raises:
        InvalidInput: no triangles, NaN vertices, out-of-range indices, or only zero-area
            triangles.

    """

    vertices: np.ndarray
    triangles: np.ndarray

    def __post_init__(self):
        vertices = as_array(self.vertices, 'Mesh.vertices', (None, 3))
        triangles = as_array(self.triangles, 'Mesh.triangles', (None, 3), dtype=np.int64)
        if len(triangles) == 0:
            raise InvalidInput('Mesh: no triangles (empty mesh)')
        if triangles.min() < 0 or triangles.max() >= len(vertices):
            raise InvalidInput(f'Mesh.triangles: vertex index out of range 0..{len(vertices) - 1}')
        tri = vertices[triangles]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        if not np.any(area > 1e-14):
            raise InvalidInput('Mesh: degenerate, every triangle has zero area')
        object.__setattr__(self, 'vertices', vertices)
        object.__setattr__(self, 'triangles', triangles)


@dataclass(frozen=True)
class Pose:
    """Rigid transform: ``position`` (3,) metres and unit quaternion ``orientation`` (x, y, z, w).

    Raises:
        InvalidInput: NaN or a quaternion far from unit length.

    """

    position: np.ndarray
    orientation: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))
    frame: str = 'base'

    def __post_init__(self):
        position = as_array(self.position, 'Pose.position', (3,))
        quat = as_array(self.orientation, 'Pose.orientation', (4,))
        norm = math.sqrt(float(quat @ quat))    # as np.linalg.norm computes it, less its overhead
        if abs(norm - 1.0) > 1e-3:
            raise InvalidInput(f'Pose.orientation: quaternion must be unit length, '
                               f'|q| = {norm:.4g}')
        quat = quat / norm
        quat.setflags(write=False)
        object.__setattr__(self, 'position', position)
        object.__setattr__(self, 'orientation', quat)

    def rotation(self) -> np.ndarray:
        """Return the (3, 3) rotation matrix of ``orientation``."""
        return quaternion_to_matrix(self.orientation)

    @classmethod
    def from_matrix(cls, matrix: np.ndarray, frame: str = 'base') -> 'Pose':
        """Return the pose of a (4, 4) rigid transform (child frame in ``frame``)."""
        matrix = np.asarray(matrix, dtype=np.float64)
        return cls(position=matrix[:3, 3], orientation=matrix_to_quaternion(matrix[:3, :3]),
                   frame=frame)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map (N, 3) points from the pose's child frame into ``frame``."""
        return np.asarray(points) @ self.rotation().T + self.position


@dataclass(frozen=True)
class Wrench:
    """Force (3,) in newtons and torque (3,) in newton-metres, in ``frame``.

    ``torque_centre`` (3,) metres is the point the torque is taken about, in ``frame``.
    """

    force: np.ndarray
    torque: np.ndarray
    frame: str = 'base'
    torque_centre: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        object.__setattr__(self, 'force', as_array(self.force, 'Wrench.force', (3,)))
        object.__setattr__(self, 'torque', as_array(self.torque, 'Wrench.torque', (3,)))
        object.__setattr__(self, 'torque_centre',
                           as_array(self.torque_centre, 'Wrench.torque_centre', (3,)))

    def as_vector(self) -> np.ndarray:
        """Return ``[fx, fy, fz, tx, ty, tz]``."""
        return np.concatenate([self.force, self.torque])


@dataclass(frozen=True)
class PokeRecord:
    """One point-probe poke: the request and the raw time series as the arm streamed it.

    Attributes:
        poke_id: unique id (``poke-000017`` style), also the stem of its file in the store,
            so a plain file name (:func:`check_poke_id`).
        point: (3,) commanded surface point, metres, ``base``.
        normal: (3,) unit outward surface normal at ``point``; the probe pushes along ``-normal``.
        t: (T,) ROS (wall) time of each sample, seconds.
        t_controller: (T,) controller timestamp of each sample, seconds, strictly increasing.
        tcp_pose: (T, 6) UR TCP pose ``[x, y, z, rx, ry, rz]`` (position, rotation vector),
            ``base``.
        wrench: (T, 6) ``[fx, fy, fz, tx, ty, tz]`` as ``getActualTCPForce``: base-oriented,
            tared right before the push, payload-compensated.
        speed: commanded push speed, m/s.
        probe: probe name (``point`` for the tapered point probe).
        outcome: ``completed``, ``force_limit``, ``depth_limit``, ``canceled``, ``aborted: ...``.
        meta: free-form extra fields (scenario, object, surface index, ...), JSON-serialisable.

    Raises:
        InvalidInput: a poke id that is no plain file name (see :func:`check_poke_id`),
            mismatched lengths, NaN, non-unit normal, non-increasing controller time, or a
            field of the wrong type (``speed`` not a number; ``probe``, ``outcome`` not
            strings; ``meta`` not a mapping).

    """

    poke_id: str
    point: np.ndarray
    normal: np.ndarray
    t: np.ndarray
    t_controller: np.ndarray
    tcp_pose: np.ndarray
    wrench: np.ndarray
    speed: float = 0.002
    probe: str = 'point'
    outcome: str = 'completed'
    meta: Mapping = field(default_factory=dict)

    def __post_init__(self):
        check_poke_id(self.poke_id, 'PokeRecord.poke_id')
        if isinstance(self.speed, bool) or not isinstance(self.speed, numbers.Real):
            raise InvalidInput(f'PokeRecord.speed: must be a number (m/s), got '
                               f'{type(self.speed).__name__} {self.speed!r:.80}')
        for name in ('probe', 'outcome'):
            value = getattr(self, name)
            if not isinstance(value, str):
                raise InvalidInput(f'PokeRecord.{name}: must be a string, got '
                                   f'{type(value).__name__} {value!r:.80}')
        if not isinstance(self.meta, Mapping):
            raise InvalidInput(f'PokeRecord.meta: must be a mapping of fields, got '
                               f'{type(self.meta).__name__} {self.meta!r:.80}')
        point = as_array(self.point, 'PokeRecord.point', (3,))
        normal = unit_rows(as_array(self.normal, 'PokeRecord.normal', (3,)), 'PokeRecord.normal')
        t = as_array(self.t, 'PokeRecord.t', (None,))
        n = len(t)
        t_ctrl = as_array(self.t_controller, 'PokeRecord.t_controller', (n,))
        if n > 1 and np.any(np.diff(t_ctrl) <= 0):
            raise InvalidInput('PokeRecord.t_controller: must be strictly increasing '
                               '(de-duplicate samples on controller time)')
        pose = as_array(self.tcp_pose, 'PokeRecord.tcp_pose', (n, 6))
        wrench = as_array(self.wrench, 'PokeRecord.wrench', (n, 6))
        if not np.isfinite(self.speed) or self.speed <= 0:
            raise InvalidInput(f'PokeRecord.speed: must be positive, got {self.speed}')
        for name, value in (('point', point), ('normal', normal), ('t', t),
                            ('t_controller', t_ctrl), ('tcp_pose', pose), ('wrench', wrench)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, 'speed', float(self.speed))
        object.__setattr__(self, 'meta', dict(self.meta))

    def __len__(self) -> int:
        """Return the number of samples."""
        return len(self.t)

    def displacement(self) -> np.ndarray:
        """(T,) probe-tip displacement ``d`` along ``-normal`` from ``point``, metres.

        Positive when the tip is below the equilibrium surface point (pushing in).
        """
        return -(self.tcp_pose[:, :3] - self.point) @ self.normal

    def normal_force(self) -> np.ndarray:
        """(T,) force the object exerts on the probe along ``normal``, newtons (push-back > 0).

        The F/T reading is the force the environment applies to the tool, base-oriented.
        """
        return self.wrench[:, :3] @ self.normal


@dataclass(frozen=True)
class PokeGoal:
    """A poke request: push the point probe into ``point`` along ``-normal``.

    Attributes:
        point: (3,) metres, ``base``; ignored when ``surface_index >= 0``.
        normal: (3,) unit outward normal, ``base``; ignored when ``surface_index >= 0``.
        surface_index: index into the current equilibrium surface, or -1.
        force_limit: N, stop pushing at this normal force.
        depth_limit: m, stop pushing at this depth past ``point``.
        speed: m/s, push speed.
        standoff: m, start this far out along ``normal``.

    Only shapes and finiteness are checked here; limits are checked against the server's
    configuration by :func:`pointforce_ros.pokes.limits.check_goal`.
    """

    point: np.ndarray
    normal: np.ndarray
    surface_index: int = -1
    force_limit: float = 5.0
    depth_limit: float = 0.015
    speed: float = 0.002
    standoff: float = 0.01

    def __post_init__(self):
        object.__setattr__(self, 'point', as_array(self.point, 'PokeGoal.point', (3,)))
        object.__setattr__(self, 'normal', as_array(self.normal, 'PokeGoal.normal', (3,)))
        for name in ('force_limit', 'depth_limit', 'speed', 'standoff'):
            value = float(getattr(self, name))
            if not np.isfinite(value):
                raise InvalidInput(f'PokeGoal.{name}: must be finite, got {value}')
            object.__setattr__(self, name, value)
        object.__setattr__(self, 'surface_index', int(self.surface_index))


@dataclass(frozen=True)
class ContactQuery:
    """A planner's contact-wrench question: a rigid mesh at some poses, pressed along ``approach``.

    Attributes:
        mesh: rigid mesh in its own frame.
        poses: mesh frame -> ``base``, one per query (a single query has one).
        approach: (3,) unit approach direction of the mesh, ``base``.
        torque_centre: (3,) metres, ``base``; torques are taken about this point.
        return_displacements: also return per-point surface displacements.

    Raises:
        InvalidInput: no poses, or an approach direction that is not unit length.

    """

    mesh: Mesh
    poses: Tuple[Pose, ...]
    approach: np.ndarray
    torque_centre: np.ndarray = field(default_factory=lambda: np.zeros(3))
    return_displacements: bool = False

    def __post_init__(self):
        poses = tuple(self.poses)
        if not poses:
            raise InvalidInput('ContactQuery.poses: at least one pose is needed')
        approach = as_array(self.approach, 'ContactQuery.approach', (3,))
        unit_rows(approach, 'ContactQuery.approach')
        object.__setattr__(self, 'poses', poses)
        object.__setattr__(self, 'approach', approach)
        object.__setattr__(self, 'torque_centre',
                           as_array(self.torque_centre, 'ContactQuery.torque_centre', (3,)))
