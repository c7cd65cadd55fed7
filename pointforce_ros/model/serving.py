"""Contact-wrench serving core: the current model, hot-swapped without dropping requests.

The contact service node wraps one :class:`WrenchServer`. Swapping builds the new simulator
outside any lock and then replaces one reference, so a request in flight finishes on the model it
started with and the next request sees the new one (read-copy-update). Pure Python, no ROS.

Accepted effects stored in the model (``ContactModel.effects``) are applied as their forward
terms (:mod:`pointforce_ros.effects.forward`): a surface offset the file has not applied yet, a
series compliance (the answer is the one at the pose moved back along the approach by
``compliance * F_n``, solved for the total normal force), and a viscoelastic hold fraction.

Every request passes :class:`RequestLimits` before any work (rigid samples x poses, a memory
estimate from the mesh's sample count, coordinates, depth past the surface, torque-centre
distance), and every answer is checked before it is returned: a non-finite wrench or one beyond
what the model's baked force table can give for the contacts found is refused with a message
about the request.
"""

import dataclasses
import hashlib
import os
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, NamedTuple, Optional, Tuple

import numpy as np

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.contact.sampling import MAX_SAMPLES, mesh_bytes, mesh_sample_count
from pointforce_ros.contact.simulator import (BatchContactResult, check_neighbours, NEIGHBOURS,
                                              normalise_approach, poses_as_arrays)
from pointforce_ros.contact.uncertainty import SOURCE_KEYS, wrench_uncertainty
from pointforce_ros.effects.forward import ForwardTerms, model_surface, solve_retreat
from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.model.files import ContactModel, load_latest_model, load_model
from pointforce_ros.response.blas import single_threaded_blas
from pointforce_ros.rotations import quaternion_to_matrix
from pointforce_ros.types import as_array, ContactQuery, Mesh, Pose

BYTES_PER_SAMPLE_POSE = 256
"""Working memory of one rigid sample at one pose in the simulator's first pass, bytes.

The posed coordinates (24), their in-plane cell indices and temporaries (~70), masks and, for a
sample that passes the height bound, its neighbour query and candidate arrays (~150).
"""

BYTES_PER_CONTACT_PAIR = 64
"""Working memory of one entry of a pose's contact problem (pairwise distances, ``G``,
products), bytes; a pose with ``K`` candidates needs about ``64 K^2``."""

UNCERTAINTY_CHUNK = 256
"""Poses per call of the uncertainty's four solves (bounds their working memory)."""

_MIB = float(2 ** 20)
_CACHED_SAMPLES = 200_000
_CACHE_BYTES = 64 * 2 ** 20
"""Most bytes of mesh arrays the request checks' cache keeps, one mesh at most an eighth of it
(a request's mesh may hold 1e6 triangles of a few samples: caches bounded by their entries
alone grew the service to 2 GB, session 38)."""
DEPTH_MARGIN = 0.001
"""How far past the deepest poke a contact may press before :meth:`WrenchServer.depth_note`
says the answer is extrapolated, metres."""

_NO_ANSWER = ('{where}: the model has no finite answer for this pose ({bad} of {count} poses); '
              'the mesh is outside what the model covers; check the pose and the mesh')


@dataclass(frozen=True)
class RequestLimits:
    """What one contact request may ask of the service; checked before any work.

    Attributes:
        max_sample_poses: largest rigid samples x poses of one request (the simulator's work;
            1e8 is a few seconds of one core).
        max_memory: largest working-memory estimate of one request, bytes. Batches are cut
            into chunks of poses that fit; a request whose single pose does not fit is refused.
            256 MiB keeps the service within its 600 MB RSS goal.
        max_distance: largest distance of a pose position or the torque centre from the
            surface's bounding box, and of a mesh vertex from the mesh origin, metres.
        max_depth: largest depth of a mesh vertex (over the surface, in the projection along
            the approach) past the deepest surface point, metres.
        max_torque_arm: largest distance from the torque centre to a pose position, metres.
        chunk: most poses solved together (memory permitting).
        max_seconds: time budget of one batch, s; checked between chunks of poses.

    Raises:
        InvalidInput: a limit that is not a positive finite number.

    """

    max_sample_poses: int = 100_000_000
    max_memory: int = 2 ** 28
    max_distance: float = 10.0
    max_depth: float = 0.1
    max_torque_arm: float = 5.0
    chunk: int = 1024
    max_seconds: float = 30.0

    def __post_init__(self):
        for name in ('max_sample_poses', 'max_memory', 'max_distance', 'max_depth',
                     'max_torque_arm', 'chunk', 'max_seconds'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise InvalidInput(f'RequestLimits.{name}: must be a positive number, got '
                                   f'{value!r}')


class _Bounds(NamedTuple):
    """Per-model constants of the request and answer checks."""

    lo: np.ndarray          # (3,) surface bounding box, m, base
    hi: np.ndarray          # (3,)
    contact_force: float    # largest force one contact can give within max_depth, N


def _model_bounds(model: ContactModel, limits: RequestLimits) -> _Bounds:
    """Bounding box of the surface and the per-contact force ceiling of the baked table.

    The ceiling is the table's largest force plus its steepest extrapolation slope over
    ``max_depth`` (or the table's depth span, if longer): no contact of an admitted request can
    give more, so a larger answer is an artefact, not a force.
    """
    response = model.response
    depths = np.asarray(response.depths, dtype=np.float64)
    span = max(limits.max_depth, float(depths[-1] - depths[0]))
    top = float(np.max(np.abs(response.forces))) if response.forces.size else 0.0
    slope = float(np.max(response.slopes)) if len(response.slopes) else 0.0
    ceiling = top + max(slope, 0.0) * span
    points = model.surface.points
    return _Bounds(points.min(axis=0), points.max(axis=0), ceiling)


def _box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(B,) distance of ``points`` (B, 3) from the box ``lo..hi`` (0 inside), metres."""
    gap = np.maximum(np.maximum(lo - points, points - hi), 0.0)
    with np.errstate(over='ignore'):
        return np.linalg.norm(gap, axis=1)


def _under_footprint(proj, footprint: np.ndarray) -> int:
    """Facing surface points under the oriented bounding box of ``footprint`` (V, 2), m.

    The box has the principal axes of the projected vertices and is widened by the
    projection's ``max_gap``; the surface points come from its KD-tree (projection plane).
    """
    centre = footprint.mean(axis=0)
    local = footprint - centre
    _, axes = np.linalg.eigh(local.T @ local)
    local = local @ axes
    lo, hi = local.min(axis=0) - proj.max_gap, local.max(axis=0) + proj.max_gap
    reach = float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))
    near = proj.tree.query_ball_point(centre, r=reach)
    if not near:
        return 0
    points = (proj.tree.data[near] - centre) @ axes
    return int(np.count_nonzero(np.all((points >= lo) & (points <= hi), axis=1)))


def _where(count: int, i: int) -> str:
    """Name pose ``i`` of a request the way the request does (``pose`` or ``poses[i]``)."""
    return 'pose' if count == 1 else f'poses[{i}]'


class WrenchServer:
    """Answers :class:`ContactQuery` objects from the latest loaded :class:`ContactModel`."""

    def __init__(self, spacing: float = 0.003, *, series_compliance: bool = True,
                 hold_time: float = 0.0, limits: Optional[RequestLimits] = None,
                 workers: Optional[int] = None, neighbours: Optional[str] = None):
        """Create an empty server.

        Args:
            spacing: rigid-mesh sampling distance, metres.
            series_compliance: apply a series compliance the model's effects hold.
            hold_time: seconds a pose is held after a fast approach, for a viscoelastic
                effect (0: the instantaneous force).
            limits: what one request may ask (default :class:`RequestLimits`).
            workers: threads a batch's chunks are solved on (default: the cores, at most 4).
            neighbours: the contact simulator's neighbour rule
                (:data:`~pointforce_ros.contact.simulator.NEIGHBOUR_RULES`; ``None``: its
                default): ``'smooth'`` for a planner that takes finite differences sideways.

        """
        self.limits = RequestLimits() if limits is None else limits
        if not isinstance(self.limits, RequestLimits):
            raise InvalidInput(f'WrenchServer: limits must be a RequestLimits, got '
                               f'{type(self.limits).__name__}')
        self._spacing = float(spacing)
        self._neighbours = check_neighbours(NEIGHBOURS if neighbours is None else neighbours)
        self._series = bool(series_compliance)
        self._hold_time = float(hold_time)
        ForwardTerms.of({}, hold_time=self._hold_time)  # validates hold_time
        self._current: Optional[Tuple[ContactModel, ContactSimulator, ForwardTerms,
                                      _Bounds]] = None
        self._swap_lock = threading.Lock()
        self._sizes = {}    # mesh content -> (radius, sample count, first mesh object)
        self._facing = {}   # projection -> (it, deepest facing height, in-plane box lo, hi)
        self.loaded_path: Optional[Path] = None
        self._workers = max(1, int(workers if workers is not None else
                                   min(4, os.cpu_count() or 1)))
        self._executor: Optional[ThreadPoolExecutor] = None
        self._last_mesh = None    # (mesh object, spacing, cache key, cache entry)

    @property
    def version(self) -> int:
        """Version of the model answering now, or -1 when none is loaded."""
        current = self._current
        return -1 if current is None else int(current[0].version)

    def swap(self, model: ContactModel) -> None:
        """Make ``model`` the one that answers (older versions are ignored).

        Raises:
            InvalidInput: the model's effects are malformed.

        """
        terms = ForwardTerms.of(model.effects, series_compliance=self._series,
                                hold_time=self._hold_time)
        simulator = self._simulator(model, self._spacing, self._neighbours)
        bounds = _model_bounds(model, self.limits)
        with self._swap_lock:
            if self._current is None or model.version >= self._current[0].version:
                self._current = (model, simulator, terms, bounds)

    @staticmethod
    def _simulator(model: ContactModel, spacing: float, neighbours: str) -> ContactSimulator:
        """Return the simulator that answers from ``model`` under these settings."""
        return ContactSimulator(model_surface(model), model.response, model.shape_constant,
                                spacing=spacing, decay=model.shape_decay,
                                decay_law=model.shape_decay_law, near=model.shape_near,
                                neighbours=neighbours)

    def configure(self, *, spacing: Optional[float] = None,
                  neighbours: Optional[str] = None,
                  series_compliance: Optional[bool] = None, hold_time: Optional[float] = None,
                  limits: Optional[RequestLimits] = None) -> None:
        """Change settings at run time; the next request uses them (``None``: unchanged).

        The model answering now is rebuilt with the new settings before they are made
        current (a request in flight finishes on what it started with). Everything is
        checked first, so a refused change leaves the server as it was.

        Raises:
            InvalidInput: a spacing that is not a positive length, an unknown neighbour
                rule, a negative hold time, limits that are not a :class:`RequestLimits`.

        """
        spacing = self._spacing if spacing is None else float(spacing)
        neighbours = self._neighbours if neighbours is None else check_neighbours(neighbours)
        if not (np.isfinite(spacing) and spacing > 0):
            raise InvalidInput(f'sample_spacing: must be a positive length in metres, got '
                               f'{spacing!r}')
        series = self._series if series_compliance is None else bool(series_compliance)
        hold_time = self._hold_time if hold_time is None else float(hold_time)
        ForwardTerms.of({}, hold_time=hold_time)  # validates hold_time
        limits = self.limits if limits is None else limits
        if not isinstance(limits, RequestLimits):
            raise InvalidInput(f'WrenchServer: limits must be a RequestLimits, got '
                               f'{type(limits).__name__}')
        current = self._current
        rebuilt = None
        if current is not None:
            model, simulator = current[0], current[1]
            if spacing != self._spacing:
                simulator = self._simulator(model, spacing, neighbours)
            elif neighbours != self._neighbours:   # shares the sampled meshes
                simulator = simulator.with_shape_constant(simulator.c, neighbours=neighbours)
            rebuilt = (model, simulator, ForwardTerms.of(model.effects,
                                                         series_compliance=series,
                                                         hold_time=hold_time),
                       _model_bounds(model, limits))
        with self._swap_lock:
            self._spacing, self._series, self._hold_time, self.limits = (
                spacing, series, hold_time, limits)
            self._neighbours = neighbours
            if rebuilt is not None and self._current is current:
                self._current = rebuilt
            elif self._current is not None and self._current is not current:
                model = self._current[0]   # swapped meanwhile: its bounds from the new limits
                self._current = self._current[:3] + (_model_bounds(model, limits),)

    @property
    def forward_terms(self) -> Optional[ForwardTerms]:
        """Forward terms of the model answering now (None when none is loaded)."""
        current = self._current
        return None if current is None else current[2]

    def load(self, path) -> ContactModel:
        """Load a model file and swap it in; raises DataError for a bad file."""
        model = load_model(path)
        self.swap(model)
        self.loaded_path = Path(path)
        return model

    def load_latest(self, directory, log: Optional[Callable[[str], None]] = None) -> bool:
        """Load the newest valid model in ``directory`` if it is newer than the current one.

        Unreadable files are quarantined beside the models (``log`` gets one line each) and
        the next older version is tried, so a restarted server serves the last good model.
        Returns whether a model was swapped in.

        Raises:
            InvalidInput: the model's effects are malformed.

        """
        found = load_latest_model(directory, newer_than=self.version, log=log)
        if found is None:
            return False
        model, path = found
        self.swap(model)
        self.loaded_path = Path(path)
        return True

    def _snapshot(self) -> Tuple[ContactModel, ContactSimulator, ForwardTerms, _Bounds]:
        current = self._current
        if current is None:
            raise ModelNotReady('no contact model loaded yet: run the learner or give model_dir')
        return current

    def simulator(self) -> ContactSimulator:
        """Return the contact simulator of the current model (identification, tools).

        Raises:
            ModelNotReady: no model loaded.

        """
        return self._snapshot()[1]

    def answer(self, query: ContactQuery):
        """Answer the first pose of ``query``: returns (ContactResult, model version).

        Raises:
            ModelNotReady: no model loaded.
            InvalidInput: a query the simulator cannot use, one beyond :attr:`limits` (checked
                before any work), or one whose answer is not finite or beyond what the model
                can give (a message about the request).

        """
        model, simulator, terms, bounds = self._snapshot()
        pose = query.poses[0]
        if pose.frame != simulator.surface.frame:
            poses_as_arrays([pose], simulator.surface.frame)    # raises, naming the frames
        known = self._known_mesh(query.mesh)
        chunk = self._admit(query.mesh, query.approach, query.torque_centre, simulator, bounds,
                            pose.position[None], pose.rotation()[None], known)
        mesh = query.mesh if known[2] is None else known[2]   # its samples are cached
        if terms.compliance > 0:
            shift = self._retreat(simulator, terms,
                                  _Batch(mesh, query.approach, query.torque_centre),
                                  query.poses[:1], chunk,
                                  time.monotonic() + self.limits.max_seconds)[0]
            pose = Pose(position=pose.position - shift * normalise_approach(query.approach),
                        orientation=pose.orientation, frame=pose.frame)
        try:
            result = simulator.query(mesh, pose, query.approach, query.torque_centre,
                                     return_displacements=query.return_displacements)
        except InvalidInput as exc:
            if not str(exc).startswith('Wrench'):
                raise
            # the request was checked already: a wrench the simulator cannot build is the
            # answer's fault, told about the request
            raise InvalidInput(_NO_ANSWER.format(where='pose', bad=1, count=1)) from exc
        if terms.force_scale != 1.0:
            k = terms.force_scale
            wrench = dataclasses.replace(result.wrench, force=result.wrench.force * k,
                                         torque=result.wrench.torque * k)
            result = dataclasses.replace(result, wrench=wrench,
                                         contact_forces=result.contact_forces * k)
        row = np.concatenate([result.wrench.force, result.wrench.torque])[None]
        self._check_answer(query.torque_centre, known[0], bounds, row,
                           np.array([result.contact_count]),
                           np.array([result.max_displacement]), pose.position[None])
        return result, int(model.version)

    def depth_note(self, result) -> str:
        """Return ``''``, or a note that ``result`` presses deeper than any poke reached.

        ``result``: a :class:`~pointforce_ros.contact.simulator.ContactResult` or
        :class:`~pointforce_ros.contact.simulator.BatchContactResult` of the current model.
        The point response past its pokes' deepest nominal displacement (the model's
        ``meta['learned_depth']``, written by the learner) is the model's law continued past its
        data (and a straight line past the baked table): the table's ``std`` grows there
        (:meth:`~pointforce_ros.response.baked.BakedResponse.with_extrapolation`), but how far
        the law holds is not measured on this object. A contact more than
        :data:`DEPTH_MARGIN` deeper than that gets the note, naming the first such poses
        of a batch (a model without the entry, from before it, gets none).
        """
        learned = self._snapshot()[0].meta.get('learned_depth')
        batch = isinstance(result, BatchContactResult)
        pressed = np.asarray(result.deepest_contacts if batch else
                             result.nominal_displacements, dtype=float).reshape(-1)
        if not isinstance(learned, (int, float)) or not len(pressed):
            return ''
        past = np.flatnonzero(pressed > float(learned) + DEPTH_MARGIN)
        if not len(past):
            return ''
        where = ''
        if batch:
            named = ', '.join(str(int(i)) for i in past[:5]) + (', ...' if len(past) > 5 else '')
            where = f' in {len(past)} of {len(pressed)} poses ({named})'
        return (f'extrapolated{where}: a contact {1e3 * float(pressed.max()):.1f} mm past the '
                f'scanned surface, the pokes reached {1e3 * float(learned):.1f} mm; the force '
                'beyond is the point model continued past its data: wrench_std widens with the '
                'distance, poke deeper to measure it')

    def answer_batch(self, query: ContactQuery):
        """Answer every pose of ``query``: returns (BatchContactResult, model version).

        Poses are solved in chunks; a batch still unfinished after ``max_seconds`` is refused
        at the next chunk boundary (the answer would come too late to plan with).

        Raises:
            ModelNotReady: no model loaded.
            InvalidInput: as :meth:`answer`; the message names the first offending pose; or
                the batch ran out of its time budget.

        """
        rows = _as_rows(query.poses, self._snapshot()[1].surface.frame)
        return self.answer_rows(query.mesh, rows, query.approach, query.torque_centre)

    def answer_rows(self, mesh: Mesh, rows, approach, torque_centre):
        """Answer a batch given as a (B, 7) array ``[x, y, z, qx, qy, qz, qw]`` (``base``).

        The form a batch request arrives in: no :class:`Pose` per row. Quaternions are
        normalised as :class:`Pose` does. Returns (BatchContactResult, model version); row
        ``i`` equals :meth:`answer_batch` of the same poses.

        Raises:
            ModelNotReady: no model loaded.
            InvalidInput: a malformed array (naming the row), or as :meth:`answer_batch`.

        """
        model, simulator, terms, bounds = self._snapshot()
        deadline = time.monotonic() + self.limits.max_seconds
        rows = _checked_rows(rows)
        approach = normalise_approach(approach)
        centre = as_array(torque_centre, 'torque_centre', (3,))
        known = self._known_mesh(mesh)
        positions, rotations = rows[:, :3], quaternion_to_matrix(rows[:, 3:])
        chunk = self._admit(mesh, approach, centre, simulator, bounds, positions, rotations,
                            known)
        mesh = mesh if known[2] is None else known[2]
        query = _Batch(mesh, approach, centre)
        poses = rows
        if terms.compliance > 0:
            shift = self._retreat(simulator, terms, query, rows, chunk, deadline)
            poses = _shifted(rows, simulator.surface.frame, shift, approach)
        batch = self._solve_in_time(simulator, query, poses, chunk, deadline)
        if terms.force_scale != 1.0:
            batch = dataclasses.replace(batch, wrenches=batch.wrenches * terms.force_scale)
        self._check_answer(centre, known[0], bounds, batch.wrenches, batch.contact_count,
                           batch.max_displacement, positions)
        return batch, int(model.version)

    def uncertainty(self, mesh: Mesh, rows, approach, torque_centre,
                    version: Optional[int] = None,
                    deadline: Optional[float] = None) -> np.ndarray:
        """Return the standard deviation (B, 6) of the wrench at each row of an answered request.

        From the answering model's sources (:func:`~pointforce_ros.contact.uncertainty.
        wrench_uncertainty`: the baked response's spread, ``meta`` ``shape_cov`` of ``(log c,
        1/L)``, ``relative_std``, ``lateral_std``), times the forward terms' force scale. Four
        solves per pose, in chunks of at most :data:`UNCERTAINTY_CHUNK` poses within the
        request's time budget. Under a series compliance the spread is taken at the commanded
        pose (the retreat moves the answer by less than the spread of the force that sets it).

        Args:
            mesh, rows, approach, torque_centre: the request as :meth:`answer_rows` takes it
                (a request that passed :meth:`answer` or :meth:`answer_rows`).
            version: the model version the answer came from; a model swapped in meanwhile
                refuses (the spread would be another model's).
            deadline: ``time.monotonic()`` by which the whole request must be done (the
                answer's own budget: its start plus ``max_seconds``); default now plus
                ``max_seconds``.

        Raises:
            ModelNotReady: no model loaded.
            InvalidInput: the model carries no uncertainty, it changed since the answer, or
                the time budget ran out.

        """
        if deadline is None:
            deadline = time.monotonic() + self.limits.max_seconds
        model, _, terms, _ = self._snapshot()
        if version is not None and int(model.version) != int(version):
            raise InvalidInput(f'the model changed (v{version} -> v{model.version}) after the '
                               'answer; ask again for a wrench with its spread')
        if model.response.std is None and not any(k in model.meta for k in SOURCE_KEYS):
            raise InvalidInput(f'model v{model.version} carries no uncertainty (no response '
                               'spread, no calibration sources)')
        rows = _checked_rows(rows)
        known = self._known_mesh(mesh)
        mesh = mesh if known[2] is None else known[2]
        centre = as_array(torque_centre, 'torque_centre', (3,))
        parts = []
        for start in range(0, len(rows), UNCERTAINTY_CHUNK):
            self._in_time(deadline, start, len(rows), 'poses with a spread')
            parts.append(wrench_uncertainty(model, mesh, rows[start:start + UNCERTAINTY_CHUNK],
                                            approach, centre, spacing=self._spacing,
                                            neighbours=self._neighbours).std)
        std = np.concatenate(parts) * abs(terms.force_scale)
        if not np.all(np.isfinite(std)):
            raise InvalidInput('the spread of this answer is not finite')
        return std

    # ------------------------------------------------------------------ request checks
    def _admit(self, mesh: Mesh, approach, torque_centre, simulator: ContactSimulator,
               bounds: _Bounds, positions: np.ndarray, rotations: np.ndarray, known) -> int:
        """Refuse a request beyond :attr:`limits` before any work; return the pose chunk.

        Raises:
            InvalidInput: too many samples x poses, too much memory, a mesh, pose or torque
                centre too far away, or a mesh reaching deeper than ``max_depth`` past the
                surface.

        """
        limits = self.limits
        radius, samples = known[:2]
        if samples > MAX_SAMPLES:
            raise InvalidInput(f'mesh: {samples} samples at {1e3 * self._spacing:g} mm spacing '
                               f'(more than {MAX_SAMPLES}); send a smaller or coarser mesh')
        count = len(positions)
        work = float(samples) * count
        if work > limits.max_sample_poses:
            most = max(int(limits.max_sample_poses // samples), 0)
            raise InvalidInput(
                f'request too large: {count} poses x {samples} mesh samples (at '
                f'{1e3 * self._spacing:g} mm spacing) = {work:.3g}, above the service limit '
                f'of {limits.max_sample_poses:.3g}; send at most {most} poses of this mesh '
                'per request, or a smaller mesh')
        per_pose = samples * BYTES_PER_SAMPLE_POSE
        if per_pose > limits.max_memory:
            raise InvalidInput(f'mesh: one pose of its {samples} samples needs about '
                               f'{per_pose / _MIB:.0f} MiB, above the service limit of '
                               f'{limits.max_memory / _MIB:.0f} MiB; send a smaller mesh')
        chunk = int(max(1, min(limits.chunk, limits.max_memory // (per_pose * self._workers))))
        centre = np.asarray(torque_centre, dtype=np.float64)
        # the poses' and the torque centre's distances from the object, in one pass
        far = _box_distance(np.concatenate([positions, centre[None]]), bounds.lo, bounds.hi)
        off = float(far[-1])
        far = far[:-1]
        worst = int(far.argmax())
        if not far[worst] <= limits.max_distance:
            raise InvalidInput(f'{_where(count, worst)}: position '
                               f'{np.array2string(positions[worst], precision=4)} m is '
                               f'{far[worst]:.3g} m from the object (limit '
                               f'{limits.max_distance:g} m); check the frame and units')
        if not off <= limits.max_distance:
            raise InvalidInput(f'torque_centre: {off:.3g} m from the object (limit '
                               f'{limits.max_distance:g} m); check the frame and units')
        with np.errstate(over='ignore'):
            arm = np.linalg.norm(positions - centre, axis=1)
        worst = int(arm.argmax())
        if not arm[worst] <= limits.max_torque_arm:
            raise InvalidInput(f'torque_centre: {arm[worst]:.3g} m from '
                               f'{_where(count, worst)} (limit {limits.max_torque_arm:g} m); '
                               'take the torque about a point near the body')
        self._check_geometry(mesh, approach, simulator, rotations, positions, samples, radius)
        return chunk

    def _known_mesh(self, mesh) -> Tuple[float, int, object]:
        """(radius, sample count, the first mesh seen with this content), cached by content.

        Answering with the first mesh object of a content lets the simulator reuse its
        samples (its cache is by identity, and every request brings a new object): one
        sampling per mesh instead of one per request. Only meshes of at most
        ``_CACHED_SAMPLES`` samples are kept, and at most ``_CACHE_BYTES`` of their arrays
        in all, so the cache stays small.
        """
        last = self._last_mesh   # the adapters hand a resent mesh over as the same object
        if last is not None and last[0] is mesh and last[1] == self._spacing:
            key, hit = last[2], last[3]
        else:
            digest = hashlib.blake2b(mesh.vertices.tobytes(), digest_size=16)
            digest.update(mesh.triangles.tobytes())
            key = (digest.digest(), len(mesh.vertices), self._spacing)
            hit = self._sizes.get(key)
        if hit is None:
            with np.errstate(over='ignore'):
                radius = float(np.max(np.linalg.norm(mesh.vertices, axis=1)))
        else:
            radius = hit[0]
        # checked on every request: max_distance can change at run time
        if not radius <= self.limits.max_distance:
            raise InvalidInput(f'mesh: a vertex lies {radius:.3g} m from the mesh origin '
                               f'(limit {self.limits.max_distance:g} m); check the mesh units')
        if hit is not None:
            self._last_mesh = (mesh, key[2], key, hit)
            return hit
        samples = mesh_sample_count(mesh, self._spacing)
        size = mesh_bytes(mesh)
        keep = samples <= _CACHED_SAMPLES and size <= _CACHE_BYTES // 8
        known = (radius, samples, mesh if keep else None)
        held = sum(mesh_bytes(k[2]) for k in self._sizes.values() if k[2] is not None)
        if len(self._sizes) >= 64 or held + (size if keep else 0) > _CACHE_BYTES:
            self._sizes.clear()
        self._sizes[key] = known
        return known

    def _check_geometry(self, mesh: Mesh, approach, simulator: ContactSimulator,
                        rotations: np.ndarray, positions: np.ndarray, samples: int,
                        radius: float) -> None:
        """Refuse a mesh too deep in the object, with too many possible contacts, or no facing.

        Facing: fewer than three surface points whose normal points against the approach
        (none the mesh could touch: the answer would be zero whatever the pose).

        Depth: a mesh vertex over the surface deeper than ``max_depth`` past all of it, along
        the approach, past the deepest surface point that faces the approach; "over the
        surface" is inside the facing points' bounding box in the projection plane (widened by
        the simulator's ``max_gap``). Vectorised in chunks of 1e6 vertex-poses.

        Contacts: a pose has at most as many contacts as facing surface points lie under its
        footprint (widened by ``max_gap`` in the projection plane) and as it has samples;
        ``BYTES_PER_CONTACT_PAIR`` times its square must fit ``max_memory``. Counted only
        when the whole surface could exceed it, first within the mesh radius of the pose, and
        for a pose over the limit then under the oriented bounding box of its projected
        vertices (a 60 mm paddle covers a tenth of its circle).
        """
        a = normalise_approach(approach)
        proj = simulator.projection(a)
        if proj.tree is None:
            # a zero wrench would claim a contact-free answer the model cannot give: the
            # scan saw no side of the object this approach presses on (often a sign error)
            raise InvalidInput(f'approach {np.round(a, 3).tolist()}: no point of the scanned '
                               'surface faces it (the approach is the direction the mesh '
                               'moves into the object, against the surface normals: '
                               '(0, 0, -1) presses down on a surface scanned from above)')
        limit = self.limits.max_memory
        count = len(positions)
        flagged = np.zeros(count, dtype=bool)
        if float(min(samples, len(proj.index))) ** 2 * BYTES_PER_CONTACT_PAIR > limit:
            under = proj.tree.query_ball_point(positions @ proj.basis, r=radius + proj.max_gap,
                                               return_length=True)
            need = np.minimum(np.asarray(under, dtype=np.float64), samples) ** 2
            flagged = need * BYTES_PER_CONTACT_PAIR > limit   # refined on the footprint below
        hit = self._facing.get(id(proj))
        if hit is None or hit[0] is not proj:
            facing = simulator.surface.points[proj.index]
            uv = facing @ proj.basis
            hit = (proj, float(np.max(facing @ a)), uv.min(axis=0) - proj.max_gap,
                   uv.max(axis=0) + proj.max_gap)
            if len(self._facing) >= 64:
                self._facing.clear()
            self._facing[id(proj)] = hit
        _, deepest, lo2, hi2 = hit
        if not flagged.any() and (float((positions @ a).max()) + radius - deepest
                                  <= self.limits.max_depth):
            return   # no vertex (within radius of its pose) can reach max_depth: a planner's
            # usual query, answered without the per-vertex pass (a tenth of a query's time)
        verts = mesh.vertices
        frame = np.column_stack([a, proj.basis])
        step = max(1, 1_000_000 // len(verts))
        for s in range(0, count, step):
            rot, pos = rotations[s:s + step], positions[s:s + step]
            coords = np.matmul(verts, rot.transpose(0, 2, 1) @ frame) + (pos @ frame)[:, None]
            over = np.all((coords[..., 1:] >= lo2) & (coords[..., 1:] <= hi2), axis=2)
            depth = np.where(over, coords[..., 0] - deepest, -np.inf).max(axis=1)
            worst = int(np.argmax(depth))
            if depth[worst] > self.limits.max_depth:
                raise InvalidInput(
                    f'{_where(count, s + worst)}: the mesh reaches {depth[worst]:.3g} m '
                    f'past the deepest point of the object along the approach (limit '
                    f'{self.limits.max_depth:g} m): it would be inside the object; check the '
                    'pose, its frame and the approach direction')
            for j in np.flatnonzero(flagged[s:s + step]):
                k = min(_under_footprint(proj, coords[j, :, 1:]), samples)
                if float(k) ** 2 * BYTES_PER_CONTACT_PAIR > limit:
                    raise InvalidInput(
                        f'{_where(count, s + j)}: up to {k} contacts under the mesh would '
                        f'need about {float(k) ** 2 * BYTES_PER_CONTACT_PAIR / _MIB:.0f} MiB to '
                        f'solve, above the service limit of {limit / _MIB:.0f} MiB; send a '
                        'smaller mesh')

    def _check_answer(self, torque_centre, radius: float, bounds: _Bounds,
                      wrenches: np.ndarray, contacts: np.ndarray, displacement: np.ndarray,
                      positions: np.ndarray) -> None:
        """Refuse an answer that is not finite or more than the model's table can give.

        The surface may be pressed in by at most ``max_depth`` (the up-front check sees mesh
        vertices only: a large flat mesh can reach deep between them). The bound on a pose's
        force is the per-contact ceiling of the table times its contact count; on its
        torque, that force times the farthest a mesh point can be from the torque centre.

        Raises:
            InvalidInput: naming the pose of the request, not the output.

        """
        count = len(wrenches)
        finite = np.isfinite(wrenches).all(axis=1) & np.isfinite(displacement)
        if not finite.all():
            i = int(np.flatnonzero(~finite)[0])
            raise InvalidInput(_NO_ANSWER.format(where=_where(count, i),
                                                 bad=int(np.sum(~finite)), count=count))
        force_cap = bounds.contact_force * np.maximum(np.asarray(contacts, float), 1.0)
        reach = np.linalg.norm(positions - np.asarray(torque_centre), axis=1) + radius
        force = np.linalg.norm(wrenches[:, :3], axis=1)
        torque = np.linalg.norm(wrenches[:, 3:], axis=1)
        deep = np.asarray(displacement, dtype=np.float64) > self.limits.max_depth
        if deep.any():
            i = int(np.flatnonzero(deep)[0])
            raise InvalidInput(
                f'{_where(count, i)}: the mesh presses the surface in by '
                f'{float(displacement[i]):.3g} m (limit {self.limits.max_depth:g} m): it would '
                'be inside the object; check the pose and the mesh')
        bad = (force > force_cap * (1 + 1e-6) + 1e-9) | (
            torque > force_cap * reach * (1 + 1e-6) + 1e-9)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InvalidInput(
                f'{_where(count, i)}: the model cannot give this answer ({force[i]:.3g} N, '
                f'{torque[i]:.3g} N m for {int(contacts[i])} contacts, at most '
                f'{bounds.contact_force:.3g} N each): the mesh is deeper than the model '
                'knows; check the pose')

    def _solve_in_time(self, simulator: ContactSimulator, query, poses, chunk: int,
                       deadline: float) -> BatchContactResult:
        """``simulator.query_batch`` chunk by chunk, refusing once ``deadline`` has passed.

        Chunks run on the server's worker threads (numpy and the KD-tree release the GIL in
        their loops, so two cores solve about twice the poses); a batch of more than 128
        poses is cut into at least one chunk per worker. Each chunk is a ``query_batch`` call
        of its own, so a row's answer does not depend on the others.
        """
        count = len(poses)
        if count > 128 and self._workers > 1:
            chunk = min(chunk, -(-count // self._workers))
        starts = range(0, count, chunk)

        def solve(start):
            self._in_time(deadline, start, count)
            return simulator.query_batch(query.mesh, poses[start:start + chunk],
                                         query.approach, query.torque_centre, chunk=chunk)
        if len(starts) == 1:
            return solve(0)
        with single_threaded_blas():
            futures = [self._pool().submit(solve, start) for start in starts]
            try:
                parts = [f.result() for f in futures]
            finally:
                for f in futures:
                    f.cancel()
        return BatchContactResult(
            wrenches=np.concatenate([p.wrenches for p in parts]),
            contact_count=np.concatenate([p.contact_count for p in parts]),
            max_displacement=np.concatenate([p.max_displacement for p in parts]),
            lcp_residual=np.concatenate([p.lcp_residual for p in parts]),
            torque_centres=np.concatenate([p.torque_centres for p in parts]),
            frame=parts[0].frame,
            deepest_contacts=np.concatenate([p.deepest_contacts for p in parts]))

    def _pool(self) -> ThreadPoolExecutor:
        with self._swap_lock:
            if self._executor is None:
                self._executor = ThreadPoolExecutor(self._workers,
                                                    thread_name_prefix='contact-batch')
            return self._executor

    def _in_time(self, deadline: float, done: int, count: int,
                 what: str = 'poses solved') -> None:
        """Raise InvalidInput when the request's time budget has run out."""
        if time.monotonic() > deadline:
            raise InvalidInput(f'request took longer than the service budget of '
                               f'{self.limits.max_seconds:g} s ({done} of {count} {what}); '
                               'send fewer poses per request')

    def _retreat(self, simulator: ContactSimulator, terms: ForwardTerms, query: ContactQuery,
                 poses, chunk: int = 1024, deadline: float = np.inf) -> np.ndarray:
        """Retreat (B,) metres of each pose along the approach under the series compliance."""
        a = normalise_approach(query.approach)
        base = _as_rows(poses, simulator.surface.frame)
        centre = np.asarray(query.torque_centre, dtype=np.float64)

        def push_back(index, shift):
            self._in_time(deadline, 0, len(base))
            rows = base[index].copy()
            rows[:, :3] -= shift[:, None] * a
            out = simulator.query_batch(query.mesh, rows, a, centre, chunk=chunk)
            return -terms.force_scale * (out.wrenches[:, :3] @ a)

        shift, _ = solve_retreat(push_back, terms.compliance, len(base))
        return shift


def _as_rows(poses, frame: str) -> np.ndarray:
    """(B, 7) ``[x, y, z, qx, qy, qz, qw]`` of ``poses`` (frames checked)."""
    poses_as_arrays(poses, frame)
    if isinstance(poses, np.ndarray):
        return np.array(poses, dtype=np.float64)
    return np.array([np.concatenate([p.position, p.orientation]) for p in poses])


class _Batch(NamedTuple):
    """The parts of a batch request the solving steps use."""

    mesh: Mesh
    approach: np.ndarray
    torque_centre: np.ndarray


def _checked_rows(rows) -> np.ndarray:
    """(B, 7) float64 copy of ``rows`` with unit quaternions, or InvalidInput naming a row."""
    rows = as_array(rows, 'poses', (None, 7))
    if len(rows) == 0:
        raise InvalidInput('poses: the batch is empty')
    norm = np.linalg.norm(rows[:, 3:], axis=1)
    bad = np.abs(norm - 1.0) > 1e-3
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise InvalidInput(f'{_where(len(rows), i)}: quaternion must be unit length, '
                           f'|q| = {norm[i]:.4g}')
    rows = rows.copy()
    rows[:, 3:] /= norm[:, None]
    return rows


def _shifted(poses, frame: str, shift: np.ndarray, a: np.ndarray) -> np.ndarray:
    rows = _as_rows(poses, frame)
    rows[:, :3] -= shift[:, None] * a
    return rows
