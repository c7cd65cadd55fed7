"""Semi-empirical contact simulator (seed 000, section IV, eq. 1-4), vectorised over poses.

Algorithm for one rigid body pose (all in ``base``, metres, newtons):

1. Sample the rigid mesh once (:func:`sample_mesh_surface`) and pose the samples.
2. Project rigid samples and surface points onto the plane normal to the approach direction
   ``a``; for each rigid sample ``p`` take its 3 nearest surface points in that plane and
   average (equally, the paper; or with weights that vanish where a point leaves the three,
   :data:`NEIGHBOUR_RULES`) their positions, normals and nominal displacements
   ``d_k = -(p - p_k)^T n_k`` (eq. 1) into the *estimated equilibrium point* ``q`` and ``d``.
3. Keep ``d > d0``, where ``d0`` is the contact onset of the learned response at those
   neighbours (the paper keeps ``d > 0``; see below). Only the front-most rigid sample counts
   per surface location: of all samples whose nearest surface point is the same, the one that
   penetrates deepest (largest ``d - d0``) is kept (the projection along ``a`` implies that
   the body's far side, which projects onto the same location, cannot touch it); candidates
   with the same 3 neighbours (hence the same ``q``: ``g = 1`` off the diagonal) are merged
   the same way, and coincident surface points are de-duplicated when the simulator is built.
4. Solve the LCP ``0 <= G d~ - (d - d0) _|_ d~ >= 0`` with ``G_ij = c / (c + |q_i - q_j|)``
   (eq. 2-3; see :mod:`pointforce_ros.contact.lcp` for the sign convention and the solver),
   optionally times a tail ``exp(-r / L)`` whose length ``L`` is one (``decay``) or grows with
   each contact's penetration (``decay_law='penetration'``).
5. ``f_i = y(q_i, d_i) - y(q_i, d_i - d~_i)`` with ``y`` the baked point response interpolated
   over the 3 neighbours with the weights of step 2 (as ``q`` is averaged), ``F = sum f_i n_i``
   and ``tau = sum (p_i - centre) x f_i n_i`` (eq. 4): the wrench the object exerts on the rigid
   body.

Two restrictions beyond the paper, both stated in :class:`ContactSimulator`: only surface points
facing the approaching body (``n . a < 0``) take part, and a rigid sample whose third-nearest
surface point is farther than ``max_gap`` in the projection plane is not over the surface and
cannot touch it (the paper's projection would invent a contact with the edge of the cloud).

One correction of the paper: contact begins at the response's own onset ``d0``
(:meth:`BakedResponse.onsets`), not at ``d = 0``. A depth camera's bias puts the observed
surface millimetres inside or outside the real one, and the learned ``y(x, d)`` carries that:
its force starts at ``d0`` (-2 to -3 mm on the cell's realistic scenario, -5 to +5 mm in the
paper). Keeping only ``d > 0`` drops every contact between the real and the observed surface:
on a line probe pushed 2 mm past first touch that lost two thirds of the force. With ``e = d -
d0`` the penetration of the surface the response saw, the LCP distributes ``e`` and the force
is unchanged in form, ``y(q, d) - y(q, d - d~)`` (a lone contact, ``d~ = e``, gives ``y(q, d)``).
A response without ``onsets`` gets ``d0 = 0``, the paper's rule.

Speed: per approach direction (cached) a grid over the projected surface, with a
conservative per-cell height bound that discards rigid samples that cannot penetrate before
any neighbour search, and the facing points of each cell for a fixed-radius search of the
three nearest (compiled, :func:`~pointforce_ros.contact.single_pose.three_nearest`; equal
distances go to the lower index, in every path); the LCPs of many poses solved as padded
stacks grouped by size, each round building only the columns of ``G`` its free sets need
(:class:`~pointforce_ros.contact.lcp.PointShapeStack`); one pose on compiled kernels
(:mod:`~pointforce_ros.contact.single_pose`).
"""

import copy
import math
import weakref
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from scipy.ndimage import minimum_filter
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from pointforce_ros.contact.lcp import (bpp_dense, check_decay, check_near, lcp_residual,
                                        PointShapeStack, shape_function, solve_lcp_batch)
from pointforce_ros.contact.sampling import sample_mesh_surface
from pointforce_ros.contact import single_pose
from pointforce_ros.errors import check_choice, InvalidInput, NotConverged
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.response.blas import single_threaded_blas
from pointforce_ros.types import as_array, Mesh, Pose, Surface, Wrench
from pointforce_ros.rotations import quaternion_to_matrix

_NO_PROXY = np.zeros(0)
"""The compiled kernels' ``thickness`` outside the ``'layer'`` law."""

APPROACH_TOLERANCE = 1e-3
"""Largest accepted deviation of the approach direction's length from one."""

MAX_PIVOTING = 200
"""Most pivoting rounds of one pose's LCP (as :func:`~pointforce_ros.contact.lcp.bpp_dense`)."""

PIVOTING_TOL = 1e-12
"""Feasibility tolerance of the pivoting, relative to the deepest penetration."""

WARM_START = 0.65
"""The LCP's first guess of the touching set: candidates at least this fraction of the deepest
candidate's penetration deep. The solution is unique (``G`` is positive definite), so the guess
changes only the work: on sphere queries 2.3 pivoting rounds instead of 3.6 (the paper's guess,
every candidate), half the LCP time, answers equal within 2e-15 N. On the contact bench's
10000 sphere poses (issue 16) 0.65 needs 2.25 rounds per problem against 2.67 at 0.5, and the
first round's free sets are smaller (0.3-0.9: fewest rounds and least time at 0.65-0.7; a
dome with ``c`` = 8 mm agrees)."""

SAMPLE_CACHE_BYTES = 64 * 2 ** 20
"""Most bytes of mesh samples a simulator keeps for callers that resend a mesh object; a mesh
with samples above an eighth of it is sampled on each call instead. The meshes themselves are
held weakly (a request's mesh can hold 1e6 triangles of a few samples, session 38)."""

DECAY_LAWS = ('fixed', 'penetration', 'layer')
"""How the shape function's tail decay length is set (:class:`ContactSimulator` ``decay_law``):
one ``decay`` for every contact, per contact in proportion to its penetration
(:data:`DECAY_REFERENCE`), or so and times the layer proxy under the query
(:func:`layer_proxy`)."""

DECAY_LAW = 'penetration'
"""The decay law a simulator gets when none is given (issue 17): on the demo's lamb it beat
``'fixed'`` on every one of five learned models (7.2-8.9 % against 9.7-13.0 % of the largest
true force, two of them live demos), and on the foam block it was no worse (calibration there
often picks no tail, where both laws are the paper's ``g``). ``'fixed'`` restores the
simulator of before."""

NEIGHBOUR_RULES = ('equal', 'smooth')
"""How step 2 weighs a rigid sample's 3 nearest surface points (:class:`ContactSimulator`
``neighbours``): equally (the paper), or by :func:`~pointforce_ros.contact.single_pose.
neighbour_weights`, which vanish where a point leaves the three."""

NEIGHBOURS = 'equal'
"""The neighbour rule a simulator gets when none is given: the paper's. Smooth weights take
most of the steps out of the answer (on the demo's lamb, 10 mm sideways in 2 um steps: 12
steps over 20 times the median one where equal weights make 384 (a sphere), 31 for 453 (a
box), 74 for 212 (a cylinder); ``data/figures/answer_smoothness.py``), and are about as
accurate: figure 2's force RMSE better on four objects (plush 0.63 -> 0.60 N, the dome 0.34 ->
0.32 N) and worse on thin_layer (1.31 -> 1.43 N; ``data/figures/neighbour_rule.py``), the
demo's 9 planner queries on 10 stored demos 8.67 % of the largest true force (mean) against
8.53 % (``data/fem/demo_neighbour_replay.py``). So the default stays the paper's, and the
contact service's ``neighbour_weights`` parameter chooses per cell."""

DECAY_REFERENCE = 0.004
"""Penetration (past the response's onset) at which a contact's decay length is ``decay`` under
the ``'penetration'`` law, metres: ``L_i = decay * max(e_i, DECAY_FLOOR * DECAY_REFERENCE) /
DECAY_REFERENCE``."""

DECAY_FLOOR = 0.1
"""Smallest penetration the ``'penetration'`` law scales by, as a share of
:data:`DECAY_REFERENCE` (a contact at its rim still spreads its dent)."""


LAYER_DEPTHS = (0.003, 0.008)
"""Depths past the onset, metres, whose point forces' ratio ``F(deep) / F(shallow)`` is a
point's stiffening in :func:`layer_proxy`."""

LAYER_CLIP = (0.25, 4.0)
"""Bounds of :func:`layer_proxy`'s ratio (a point whose response barely rises is not read as a
layer a hundred times thicker)."""


def layer_stiffening(response, onsets: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Return ``(s, ok)``: each point's stiffening (N,) and where it is read (N,) bool.

    ``s_i = F(d0 + 8 mm) / F(d0 + 3 mm)`` (:data:`LAYER_DEPTHS`, ``d0`` the point's onset); read
    where the shallow force is at least 5 % of the median positive one and the ratio finite
    and positive.
    """
    every = np.arange(len(onsets))
    shallow = np.asarray(response.force(every, onsets + LAYER_DEPTHS[0]), dtype=np.float64)
    deep = np.asarray(response.force(every, onsets + LAYER_DEPTHS[1]), dtype=np.float64)
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = deep / np.maximum(shallow, 1e-3)
    positive = shallow[np.isfinite(shallow) & (shallow > 0.0)]
    if len(positive) == 0:
        return ratio, np.zeros(len(onsets), dtype=bool)
    ok = (shallow > 0.05 * float(np.median(positive))) & np.isfinite(ratio) & (ratio > 0.0)
    return ratio, ok


def layer_proxy(response, onsets: np.ndarray, reference: Optional[float] = None) -> np.ndarray:
    """(N,) each surface point's layer proxy ``t_i = s_ref / s_i`` read off the point response.

    ``s_i`` (:func:`layer_stiffening`) is how much the response stiffens: soft material over a
    stiff substrate stiffens more the thinner it is, so a thinner layer gives a smaller ``t``.
    ``s_ref`` is the median over the points where ``s`` is read (the rest get ``t = 1``); ``t``
    is clipped to :data:`LAYER_CLIP`. A surface where no point qualifies gets ones (the
    ``'penetration'`` law). ``reference``: a given ``s_ref`` instead.
    """
    ratio, ok = layer_stiffening(response, onsets)
    if not np.any(ok):
        return np.ones(len(onsets))
    if reference is None:
        reference = float(np.median(ratio[ok]))
    return np.clip(np.where(ok, reference / np.where(ok, ratio, 1.0), 1.0), *LAYER_CLIP)


def check_neighbours(value, name: str = 'neighbours') -> str:
    """Return ``value`` as a neighbour rule, one of :data:`NEIGHBOUR_RULES`.

    Raises:
        InvalidInput: not one of them (the message starts with ``name`` and lists them).

    """
    return check_choice(value, NEIGHBOUR_RULES, name)


def check_decay_law(value, name: str = 'decay_law') -> str:
    """Return ``value`` as a decay law of :class:`ContactSimulator`, one of :data:`DECAY_LAWS`.

    Raises:
        InvalidInput: not one of :data:`DECAY_LAWS` (the message starts with ``name`` and
            lists them).

    """
    return check_choice(value, DECAY_LAWS, name)


@dataclass(frozen=True)
class ContactResult:
    """Contact between a rigid body and the equilibrium surface for one pose (``base``).

    ``K = contact_count`` touching points (actual displacement > 0); the per-contact arrays are
    aligned.

    Attributes:
        wrench: force (N) and torque (N m) the object exerts on the rigid body, torque about
            ``wrench.torque_centre``.
        contact_count: ``K``.
        max_displacement: largest surface displacement ``(G d~)_i`` over all candidate points,
            metres (0 without contact).
        displaced_indices: surface indices whose displacement is reported: the nearest surface
            point of each contact (K,), or every surface point (N,) when the query asked for
            displacements.
        displacements: (K,) or (N,) surface displacement along ``-n`` at those indices, metres;
            for the whole surface ``u(x) = sum_i g(|x - q_i|) d~_i`` (the paper's display
            formula after eq. 4).
        rigid_points_in_contact: (K, 3) rigid samples that touch, metres.
        lcp_residual: ``max |min(d~, G d~ - d)|`` over all candidates, metres.
        contact_points: (K, 3) estimated equilibrium points ``q_i``, metres.
        contact_normals: (K, 3) unit normals ``n_i`` at ``q_i``.
        nominal_displacements: (K,) ``d_i``, metres.
        actual_displacements: (K,) ``d~_i``, metres.
        contact_forces: (K,) ``f_i``, newtons.
        candidate_count: number of candidates (``d > 0``) the LCP was solved over.

    """

    wrench: Wrench
    contact_count: int
    max_displacement: float
    displaced_indices: np.ndarray
    displacements: np.ndarray
    rigid_points_in_contact: np.ndarray
    lcp_residual: float
    contact_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    contact_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    nominal_displacements: np.ndarray = field(default_factory=lambda: np.zeros(0))
    actual_displacements: np.ndarray = field(default_factory=lambda: np.zeros(0))
    contact_forces: np.ndarray = field(default_factory=lambda: np.zeros(0))
    candidate_count: int = 0


@dataclass(frozen=True)
class BatchContactResult:
    """Contact results for ``B`` poses of one rigid body (``base``).

    Attributes:
        wrenches: (B, 6) ``[fx, fy, fz, tx, ty, tz]``, newtons and newton-metres, torque about
            ``torque_centres``.
        contact_count: (B,) touching points per pose.
        max_displacement: (B,) metres.
        lcp_residual: (B,) metres.
        torque_centres: (B, 3) metres.
        frame: frame of everything above.
        centres_of_pressure: (B, 3) metres, where the force acts: the contacts' positions
            weighted by their force (the torque centre where a pose has no contact force);
            ``None`` unless asked for (``query_batch(..., centre_of_pressure=True)``).
        pressure_spreads: (B, 3, 3) square metres, the second moment of the contacts'
            positions about the centre of pressure, weighted by their force (how far the
            force is spread; zero where a pose has no contact force); with
            ``centres_of_pressure``.
        deepest_contacts: (B,) metres, the largest nominal displacement ``d`` of a touching
            contact per pose (0 without contact): how far past the scanned surface the body
            presses (the contact service's extrapolation note).

    """

    wrenches: np.ndarray
    contact_count: np.ndarray
    max_displacement: np.ndarray
    lcp_residual: np.ndarray
    torque_centres: np.ndarray
    frame: str = 'base'
    centres_of_pressure: Optional[np.ndarray] = None
    pressure_spreads: Optional[np.ndarray] = None
    deepest_contacts: Optional[np.ndarray] = None

    def __len__(self) -> int:
        """Return the number of poses ``B``."""
        return len(self.wrenches)

    def wrench(self, i: int) -> Wrench:
        """Return the :class:`Wrench` of pose ``i``."""
        return Wrench(force=self.wrenches[i, :3], torque=self.wrenches[i, 3:], frame=self.frame,
                      torque_centre=self.torque_centres[i])


@dataclass(frozen=True)
class PreparedBatch:
    """Contact candidates of one body at ``count`` poses (:meth:`ContactSimulator.prepare_batch`).

    Attributes:
        table: the preparing simulator's per-point table (its surface and response).
        count: number of poses.
        centres: (count, 3) torque centres, metres.
        candidates: the candidates (``None``: no pose touches).

    """

    table: np.ndarray = field(repr=False)
    count: int
    centres: np.ndarray = field(repr=False)
    candidates: Optional[dict] = field(repr=False)


@dataclass
class _Projection:
    """Per-approach cache: plane basis, KD-tree, the penetration bound grid and its cells."""

    approach: np.ndarray
    basis: np.ndarray            # (3, 2) in-plane axes
    index: np.ndarray            # (F,) surface indices of the facing points
    tree: cKDTree
    max_gap: float
    origin: np.ndarray           # (2,) grid corner
    cell: float
    bound: np.ndarray            # (nx, ny) a sample at height t <= bound cannot touch
    last: np.ndarray             # (2,) largest cell index per axis (a border of +inf)
    floor: float = np.inf        # smallest finite bound: no sample at or below it can touch
    cells: Optional[Tuple[np.ndarray, np.ndarray]] = None   # the facing points per grid cell
    # (single_pose.cell_members), built by the first query of this approach


def normalise_approach(approach) -> np.ndarray:
    """Return ``approach`` (3,) as a unit vector or raise.

    Raises:
        InvalidInput: wrong shape, non-finite, or a length that differs from one by more than
            ``APPROACH_TOLERANCE`` (a direction that is not unit usually means a units or
            frame mistake upstream, so it is refused rather than silently normalised).

    """
    a = as_array(approach, 'approach', (3,))
    norm = math.sqrt(float(a @ a))   # as np.linalg.norm computes it, less its overhead
    if abs(norm - 1.0) > APPROACH_TOLERANCE:
        raise InvalidInput(f'approach: must be a unit direction in base, |a| = {norm:.6g}')
    return a / norm


def poses_as_arrays(poses, frame: str) -> Tuple[np.ndarray, np.ndarray]:
    """Return positions (B, 3) and rotations (B, 3, 3) of ``poses``.

    ``poses`` is a sequence of :class:`Pose` (all in ``frame``) or a (B, 7) array
    ``[x, y, z, qx, qy, qz, qw]`` in ``frame``.

    Raises:
        InvalidInput: a pose in another frame, a malformed array or a non-unit quaternion.

    """
    if isinstance(poses, Pose):
        poses = [poses]
    if isinstance(poses, np.ndarray):
        arr = as_array(poses, 'poses', (None, 7))
        quat = arr[:, 3:]
        norm = np.linalg.norm(quat, axis=1)
        if np.any(np.abs(norm - 1.0) > 1e-3):
            raise InvalidInput('poses: quaternion columns 3:7 must be unit length')
        return arr[:, :3], quaternion_to_matrix(quat)
    poses = list(poses)
    for i, pose in enumerate(poses):
        if not isinstance(pose, Pose):
            raise InvalidInput(f'poses[{i}]: expected a types.Pose, got {type(pose).__name__}')
        if pose.frame != frame:
            raise InvalidInput(f'poses[{i}]: frame {pose.frame!r} differs from the surface frame '
                               f'{frame!r}; transform the pose first')
    if not poses:
        return np.zeros((0, 3)), np.zeros((0, 3, 3))
    pos = np.array([p.position for p in poses])
    quat = np.array([p.orientation for p in poses])
    return pos, quaternion_to_matrix(quat)


class ContactSimulator:
    """Contact wrench of a rigid mesh against a learned equilibrium surface (seed 000, IV).

    Args:
        surface: the equilibrium surface (``N`` points, ``base``).
        response: the point force response, an object with ``force(indices, d) -> forces``
            over the surface's indices (a :class:`BakedResponse`), newtons at displacement
            ``d`` metres.
        c: shape-function constant of ``g(r) = c / (c + r)``, metres (> 0).
        decay: decay length of the shape function's tail, metres (> 0; ``inf``, the default,
            is the paper's ``g``; see :func:`~pointforce_ros.contact.lcp.shape_function`).
        spacing: rigid-mesh sampling step, metres (the paper uses 3 mm).
        max_gap: largest in-plane distance, metres, from a rigid sample to its third-nearest
            surface point for the sample to count as over the surface; default three times the
            median such distance of the surface itself (computed per approach direction).
        decay_law: ``'fixed'`` (one ``decay`` for all contacts) or ``'penetration'``: contact
            ``i`` gets ``L_i = decay * e_i / DECAY_REFERENCE`` (``e_i`` its penetration past the
            response's onset, at least ``DECAY_FLOOR * DECAY_REFERENCE``) and a pair the
            positive definite :func:`~pointforce_ros.contact.lcp.varying_shape_function`; with
            ``decay = inf`` both laws are the paper's ``g``. ``None``: :data:`DECAY_LAW`. A dent
            spreads farther the deeper it is pressed: with the cone tip's point response, a
            deep contact (a paddle pressed deep at one end over a crest) shares more
            displacement and a shallow wide one (a cylinder) less. On the demo's lamb (soft
            tissue over a bone), ``(c, L)`` fitted on the calibration pushes alone, the planner
            queries' force RMSE went from 11.5-12.0 % to 7.7-8.2 % of the largest true force
            with the true point response and from 9.7-13.0 % to 7.2-8.6 % with the learned
            one; in two live demos 9.1 % and 8.7 % against 11.2 % and 11.4 % for the fixed law
            on the same models (7 of 9 still below the truth: the cylinders beside the bone
            stay at 0.77-0.85). The foam block stayed at 8.6-9.1 % (true response) and went
            from 4.5-7.2 % to 4.2-6.1 % (learned) (``data/fem/demo_floor_law.py``).
            ``'layer'``: the ``'penetration'`` lengths of a query times the median over its
            candidates of :func:`layer_proxy` (:meth:`layer_scales`): a contact over a thinner
            layer spreads its dent less far. On 15 stored lamb demos it lowered the queries'
            RMSE from 8.68 % to 7.37 % (mean; ``data/fem/demo_layer_replay.py``), but it costs
            figure 2 wherever the model that answers reads the proxy differently from the one
            ``(c, L)`` were identified with (dome 0.31 -> 0.76 N, thin layer 1.43 -> 2.36 N;
            ``data/figures/probe_layer_law.py``): a choice, not the default.
        near: the shape function's near field, ``'paper'`` (``c / (c + r)``, the default) or
            ``'flat'`` (``(1 + r / c) exp(-r / c)``; :data:`~pointforce_ros.contact.lcp.NEARS`).
        neighbours: how a rigid sample's 3 nearest surface points are averaged in steps 2
            and 5, ``'equal'`` (the paper) or ``'smooth'`` (``None``: :data:`NEIGHBOURS`).
            Equal weights make the answer step each time a sample's third and fourth nearest
            points swap, 20-45 times per millimetre of sideways travel on the demo's lamb
            (``data/figures/answer_smoothness.py``); smooth weights,
            ``w_k = (r_4 - r_k) / sum`` over the in-plane distances (:func:`~pointforce_ros.
            contact.single_pose.neighbour_weights`), vanish where a point leaves the three,
            so the answer moves continuously but where the kept samples change (step 3).

    Raises:
        InvalidInput: a response whose length differs from the surface's, a non-positive
            ``c``/``spacing``/``max_gap``/``decay``, an unknown ``decay_law``, ``near`` or
            ``neighbours``, or a surface with fewer than 3 points.

    """

    def __init__(self, surface: Surface, response, c: float, spacing: float = 0.003,
                 max_gap: Optional[float] = None, decay: float = np.inf,
                 decay_law: Optional[str] = None, near: str = 'paper',
                 neighbours: Optional[str] = None):
        if not isinstance(surface, Surface):
            raise InvalidInput(f'ContactSimulator: surface must be a types.Surface, got '
                               f'{type(surface).__name__}')
        if len(surface) < 3:
            raise InvalidInput('ContactSimulator: the surface needs at least 3 points')
        if not callable(getattr(response, 'force', None)):
            raise InvalidInput('ContactSimulator: response must have force(indices, d)')
        if hasattr(response, '__len__') and len(response) != len(surface):
            raise InvalidInput(f'ContactSimulator: response covers {len(response)} points, the '
                               f'surface has {len(surface)}; bake the model on this surface')
        self.surface = surface
        self.response = response
        self.c = _positive('c', c)
        self.decay = check_decay(decay)
        self.decay_law = check_decay_law(DECAY_LAW if decay_law is None else decay_law)
        self.near = check_near(near)
        self.neighbours = check_neighbours(NEIGHBOURS if neighbours is None else neighbours)
        self.spacing = _positive('spacing', spacing)
        self.max_gap = None if max_gap is None else _positive('max_gap', max_gap)
        self._points = surface.points
        self._normals = surface.normals
        self._pn = np.einsum('ij,ij->i', surface.points, surface.normals)
        onsets = getattr(response, 'onsets', None)
        onset = np.asarray(onsets(), dtype=np.float64) if callable(onsets) else np.zeros(
            len(surface))
        # a row that never reaches contact force keeps the paper's rule (geometry only)
        self._onset = np.where(np.isfinite(onset), onset, 0.0)
        # what step 2 sums over a sample's 3 neighbours, one row per point: one gather
        self._table = np.column_stack([self._normals, self._pn, self._onset, self._points])
        # one pose at a time: the compiled kernels (single_pose), with their own interpolation
        # of a baked table where the response's force is the table's (not overridden)
        self._compiled = len(surface) < single_pose.MAX_KEY_POINTS
        self._baked = (single_pose.baked_tables(response)
                       if getattr(type(response), 'force', None) is BakedResponse.force else None)
        _, first = np.unique(surface.points, axis=0, return_index=True)
        self._unique = np.sort(first)
        self.duplicates_removed = len(surface) - len(self._unique)
        self._projections: Dict[Tuple[float, ...], _Projection] = {}
        self._meshes: Dict[Tuple[int, float], Tuple[weakref.ref, np.ndarray]] = {}
        self._proxy: Dict[str, np.ndarray] = {}   # layer_proxy of the response, on first use

    def with_shape_constant(self, c: float, decay: Optional[float] = None,
                            decay_law: Optional[str] = None,
                            near: Optional[str] = None,
                            neighbours: Optional[str] = None) -> 'ContactSimulator':
        """Return a simulator identical but for ``c`` (and each other argument not ``None``).

        The copy shares the cached spatial structures.

        Raises:
            InvalidInput: as the constructor.

        """
        other = copy.copy(self)
        other.c = _positive('c', c)
        if decay is not None:
            other.decay = check_decay(decay)
        if decay_law is not None:
            other.decay_law = check_decay_law(decay_law)
        if near is not None:
            other.near = check_near(near)
        if neighbours is not None:
            other.neighbours = check_neighbours(neighbours)
        return other

    # ----------------------------------------------------------------------------- public API
    def query(self, mesh: Mesh, pose: Pose, approach, torque_centre,
              return_displacements: bool = False) -> ContactResult:
        """Contact of ``mesh`` at ``pose`` moving along ``approach``.

        Args:
            mesh: rigid mesh in its own frame.
            pose: mesh frame -> ``base``.
            approach: (3,) unit direction the body moves along, ``base`` (into the object).
            torque_centre: (3,) point the torque is taken about, metres, ``base``.
            return_displacements: also return the displacement of every surface point.

        Returns:
            A :class:`ContactResult`; no contact gives a zero wrench and ``contact_count`` 0.

        Raises:
            InvalidInput: non-unit approach, malformed centre or pose, pose in another frame.

        """
        if isinstance(pose, Pose) and pose.frame == self.surface.frame:
            pos, rot = pose.position[None], pose.rotation()[None]
        else:
            pos, rot = poses_as_arrays([pose], self.surface.frame)
        a = normalise_approach(approach)
        centre = as_array(torque_centre, 'torque_centre', (3,))
        run = self._run(self._samples(mesh), rot, pos, a, centre[None], detail=True)
        return self._result(run, a, centre, return_displacements)

    def query_points(self, points: np.ndarray, approach, torque_centre,
                     return_displacements: bool = False) -> ContactResult:
        """Contact of already-sampled rigid points ``points`` (R, 3), metres, ``base``.

        Same as :meth:`query` for a body given as its surface samples (a point probe, a test
        grid).

        Raises:
            InvalidInput: as :meth:`query`, or ``points`` not (R, 3) finite.

        """
        a = normalise_approach(approach)
        centre = as_array(torque_centre, 'torque_centre', (3,))
        world = np.ascontiguousarray(as_array(points, 'points', (None, 3)))
        run = self._run(world, np.eye(3)[None], np.zeros((1, 3)), a, centre[None], detail=True)
        return self._result(run, a, centre, return_displacements)

    def query_batch(self, mesh: Mesh, poses: Union[Sequence[Pose], np.ndarray], approach,
                    torque_centre, chunk: int = 1024,
                    centre_of_pressure: bool = False) -> BatchContactResult:
        """Contact of ``mesh`` at many ``poses`` (one approach direction).

        Args:
            mesh: rigid mesh in its own frame (sampled once).
            poses: ``B`` :class:`Pose` or a (B, 7) array ``[x, y, z, qx, qy, qz, qw]``, ``base``.
            approach: (3,) unit direction, ``base``.
            torque_centre: (3,) for every pose or (B, 3) per pose, metres, ``base``.
            chunk: poses handled together (memory ~ chunk x samples).
            centre_of_pressure: also return each pose's centre of pressure.

        Returns:
            :class:`BatchContactResult`; row ``i`` equals ``query(mesh, poses[i], ...)``.

        Raises:
            InvalidInput: as :meth:`query`.

        """
        a, pos, rot, centres = self._batch_arguments(poses, approach, torque_centre)
        n = len(pos)
        local = self._samples(mesh)
        out = np.zeros((n, 6))
        count = np.zeros(n, dtype=np.int64)
        umax = np.zeros(n)
        deepest = np.zeros(n)
        resid = np.zeros(n)
        cop = centres.copy() if centre_of_pressure else None
        spread = np.zeros((n, 3, 3)) if centre_of_pressure else None
        chunk = max(int(chunk), 1)
        with single_threaded_blas():
            for s in range(0, n, chunk):
                sl = slice(s, min(s + chunk, n))
                run = self._run(local, rot[sl], pos[sl], a, centres[sl],
                                detail=centre_of_pressure)
                out[sl], count[sl] = run['wrench'], run['count']
                umax[sl], resid[sl] = run['umax'], run['residual']
                deepest[sl] = run['deepest']
                if centre_of_pressure and 'f' in run:
                    _centres_of_pressure(run, cop[sl], spread[sl])
        return BatchContactResult(wrenches=out, contact_count=count, max_displacement=umax,
                                  lcp_residual=resid, torque_centres=centres.copy(),
                                  deepest_contacts=deepest,
                                  frame=self.surface.frame, centres_of_pressure=cop,
                                  pressure_spreads=spread)

    def _batch_arguments(self, poses, approach, torque_centre) -> Tuple[np.ndarray, ...]:
        """Return ``(approach, positions (B, 3), rotations (B, 3, 3), centres (B, 3))``."""
        a = normalise_approach(approach)
        pos, rot = poses_as_arrays(poses, self.surface.frame)
        n = len(pos)
        centre = np.asarray(torque_centre, dtype=np.float64)
        centres = as_array(np.broadcast_to(centre, (n, 3)) if centre.shape == (3,) else centre,
                           'torque_centre', (n, 3))
        return a, pos, rot, centres

    def prepare_batch(self, mesh: Mesh, poses: Union[Sequence[Pose], np.ndarray], approach,
                      torque_centre) -> 'PreparedBatch':
        """Return the contact candidates of :meth:`query_batch`'s arguments, to solve again.

        What the candidates are (which rigid samples touch where, and how deep) depends on the
        surface, the response's onsets and the body, not on ``c``, the decay length, its law or
        the near field: a fit of those solves the same poses many times, and keeps them here.

        Raises:
            InvalidInput: as :meth:`query_batch`.

        """
        a, pos, rot, centres = self._batch_arguments(poses, approach, torque_centre)
        n = len(pos)
        with single_threaded_blas():
            cand = self._candidates(self._samples(mesh), rot, pos, a)
        return PreparedBatch(table=self._table, count=n, centres=centres.copy(),
                             candidates=cand)

    def solve_prepared(self, prepared: 'PreparedBatch') -> np.ndarray:
        """Return the (B, 6) wrenches of a :meth:`prepare_batch` under this ``c`` and ``L``.

        Equal (to round-off) to ``query_batch(...).wrenches`` with the same arguments.

        Raises:
            InvalidInput: ``prepared`` was made by a simulator of another surface or response
                (one :meth:`with_shape_constant` copies share theirs).

        """
        if prepared.table is not self._table:
            raise InvalidInput('solve_prepared: the candidates were prepared on another '
                               'surface or response; prepare them with this simulator')
        with single_threaded_blas():
            return self._solve_candidates(prepared.candidates, prepared.count,
                                          prepared.centres, False)['wrench']

    def surface_displacement(self, contact_points: np.ndarray, actual: np.ndarray,
                             penetrations: Optional[np.ndarray] = None,
                             scale: float = 1.0) -> np.ndarray:
        """(N,) displacement along ``-n`` of every surface point, ``sum_i g(|x - q_i|) d~_i``.

        Under the ``'penetration'`` and ``'layer'`` decay laws each contact's dent decays over
        its own length (``penetrations`` (K,), metres, past the onset; without them the law's
        reference), times ``scale`` (the ``'layer'`` law's factor of the pose).
        """
        out = np.zeros(len(self._points))
        lengths = self.decay_lengths(np.full(len(actual), DECAY_REFERENCE)
                                     if penetrations is None else penetrations, scale)
        for s in range(0, len(contact_points), 256):
            r = cdist(self._points, contact_points[s:s + 256])
            if lengths is None:
                g = shape_function(r, self.c, self.decay, self.near)
            else:
                g = shape_function(r, self.c, near=self.near) * np.exp(-r / lengths[s:s + 256])
            out += g @ actual[s:s + 256]
        return out

    def decay_lengths(self, penetrations: np.ndarray,
                      scale: Union[float, np.ndarray] = 1.0) -> Optional[np.ndarray]:
        """Per-contact decay lengths (K,), metres, of ``penetrations`` (K,), metres.

        ``scale``: the ``'layer'`` law's factor (:meth:`layer_scales`), one or per contact.
        ``None`` under the ``'fixed'`` law or without a tail (``decay = inf``): one ``decay``.
        """
        if self.decay_law == 'fixed' or not np.isfinite(self.decay):
            return None
        e = np.maximum(np.asarray(penetrations, dtype=np.float64),
                       DECAY_FLOOR * DECAY_REFERENCE)
        return scale * (self.decay * e / DECAY_REFERENCE)

    def layer_thickness(self) -> np.ndarray:
        """(N,) the response's :func:`layer_proxy` (computed once, shared with copies)."""
        proxy = self._proxy.get('t')
        if proxy is None:
            proxy = self._proxy['t'] = np.ascontiguousarray(
                layer_proxy(self.response, self._onset), dtype=np.float64)
        return proxy

    def layer_scales(self, b_idx: np.ndarray, nbr: np.ndarray,
                     w: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
        """(K,) the ``'layer'`` law's factor of each candidate: its pose's median proxy.

        ``b_idx`` (K,) the candidates' poses (sorted), ``nbr`` (K, 3) their neighbours and
        ``w`` (K, 3) their weights (``None``: equal); each candidate's proxy is its neighbours'
        weighted mean :meth:`layer_thickness`. ``None`` under the other laws (no factor).
        """
        if self.decay_law != 'layer':
            return None
        if len(b_idx) == 0:
            return np.ones(0)
        t = (self.layer_thickness()[nbr].mean(axis=1) if w is None
             else np.einsum('kj,kj->k', self.layer_thickness()[nbr], w))
        order = np.lexsort((t, b_idx))
        ts = t[order]
        starts = np.flatnonzero(np.concatenate([[True], b_idx[1:] != b_idx[:-1]]))
        counts = np.diff(np.append(starts, len(b_idx)))
        median = 0.5 * (ts[starts + (counts - 1) // 2] + ts[starts + counts // 2])
        return np.repeat(median, counts)

    # ------------------------------------------------------------------------------ internals
    def _samples(self, mesh: Mesh) -> np.ndarray:
        # by identity, holding the mesh weakly: a request's mesh (1e6 triangles of a few
        # samples, say) is not kept alive by the cache; whoever resends it keeps it
        key = (id(mesh), self.spacing)
        hit = self._meshes.get(key)
        if hit is not None and hit[0]() is mesh:
            return hit[1]
        pts, _ = sample_mesh_surface(mesh, self.spacing)
        pts = np.ascontiguousarray(pts, dtype=np.float64)   # for the compiled kernels
        if pts.nbytes > SAMPLE_CACHE_BYTES // 8:
            return pts          # one mesh of this size would crowd out the others
        live = {k: v for k, v in self._meshes.items() if v[0]() is not None}
        held = sum(v[1].nbytes for v in live.values())
        self._meshes.clear()    # in place: shared with the with_shape_constant copies
        if len(live) <= 16 and held + pts.nbytes <= SAMPLE_CACHE_BYTES:
            self._meshes.update(live)
        self._meshes[key] = (weakref.ref(mesh), pts)
        return pts

    def projection(self, a: np.ndarray) -> _Projection:
        """Return the cached projection structures for unit approach ``a`` (3,)."""
        key = tuple(np.round(a, 12))
        proj = self._projections.get(key)
        if proj is None:
            if len(self._projections) > 32:
                self._projections.clear()
            proj = self._projections[key] = self._build_projection(a)
        return proj

    def _build_projection(self, a: np.ndarray) -> _Projection:
        helper = np.eye(3)[int(np.argmin(np.abs(a)))]
        e1 = np.cross(a, helper)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(a, e1)
        basis = np.column_stack([e1, e2])
        idx = self._unique
        cos = -(self._normals[idx] @ a)
        idx = idx[cos > 0.0]
        cos = cos[cos > 0.0]
        if len(idx) < 3:
            empty = np.full((1, 1), np.inf)
            return _Projection(a, basis, idx, None, 0.0, np.zeros(2), 1.0, empty,
                               np.zeros(2, dtype=np.int64))
        uv = self._points[idx] @ basis
        tree = cKDTree(uv)
        max_gap = self.max_gap
        if max_gap is None:
            probe = idx if len(idx) <= 20000 else idx[:: len(idx) // 20000 + 1]
            dist, _ = tree.query(self._points[probe] @ basis, k=4)
            max_gap = 3.0 * float(np.median(dist[:, 3]))
            max_gap = max(max_gap, 1e-9)
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        cell = max(max_gap, float(np.max(hi - lo)) / 1000.0)
        origin = lo - cell
        shape = np.floor((hi - origin) / cell).astype(np.int64) + 2
        cij = np.floor((uv - origin) / cell).astype(np.int64)
        height = self._points[idx] @ a
        tan = np.sqrt(np.clip(1.0 - cos * cos, 0.0, None)) / cos
        reach = np.maximum(-self._onset[idx], 0.0) / cos   # contact before the surface
        tau = height - max_gap * tan - reach - 1e-9
        per_cell = np.full(tuple(shape), np.inf)
        np.minimum.at(per_cell, (cij[:, 0], cij[:, 1]), tau)
        bound = minimum_filter(per_cell, size=3, mode='constant', cval=np.inf)
        bound = np.pad(bound, 1, constant_values=np.inf)
        return _Projection(a, basis, idx, tree, max_gap, origin - cell, cell, bound,
                           np.array(bound.shape) - 1, float(np.min(bound)))

    def _run(self, local: np.ndarray, rot: np.ndarray, pos: np.ndarray, a: np.ndarray,
             centres: np.ndarray, detail: bool) -> dict:
        """Solve ``B`` poses of the rigid samples ``local`` (R, 3).

        ``rot`` (B, 3, 3) and ``pos`` (B, 3) map the samples to ``base``.
        """
        B = len(rot)
        proj = self.projection(a)
        if B == 1 and self._compiled and proj.tree is not None and len(local):
            return self._run_single(local, rot[0], pos[0], a, centres[0], detail, proj,
                                    _empty_run(1))
        return self._solve_candidates(self._candidates(local, rot, pos, a), B, centres, detail)

    def _candidates(self, local: np.ndarray, rot: np.ndarray, pos: np.ndarray,
                    a: np.ndarray) -> Optional[dict]:
        """Return the contact candidates of ``B`` poses (steps 1-3 of :meth:`_run`), or ``None``.

        Nothing here depends on ``c``, the decay length, its law or the near field (only on
        the surface, the response's onsets and the body): :meth:`prepare_batch` keeps it for
        fits that solve the same poses under many of those.
        """
        B = len(rot)
        proj = self.projection(a)
        if proj.tree is None or len(local) == 0 or B == 0:
            return None
        # 1. Discard samples that cannot penetrate (conservative per-cell height bound). The
        # height along the approach comes first: a sample below the lowest bound of the whole
        # grid cannot penetrate anywhere (on a planner's query most of the body), so the
        # in-plane coordinates and cells are computed for the rest only.
        frame = np.column_stack([a, proj.basis])
        to_frame = rot.transpose(0, 2, 1) @ frame           # (B, 3, 3) mesh -> (a, e1, e2)
        offset = pos @ frame                                  # (B, 3)
        # heights less the pose's offset (B, R), against the floor less it: one pass fewer
        # over B x R than adding the offset (a test that rounds differently only for samples
        # within round-off of the floor, which lies 1e-9 m below any penetration)
        if np.all(to_frame[1:, :, 0] == to_frame[0, :, 0]):
            rise = np.broadcast_to(local @ to_frame[0, :, 0], (B, len(local)))  # one rotation
        else:
            rise = np.matmul(to_frame[:, :, 0], local.T)
        b_idx, r_idx = np.nonzero(rise > (proj.floor - offset[:, 0])[:, None])
        if len(b_idx) == 0:
            return None
        # in-plane (0:2) and base (2:5) coordinates of the samples, one product per sample
        maps = np.concatenate([to_frame[:, :, 1:], rot.transpose(0, 2, 1)], axis=2)
        posed = np.einsum('kj,kji->ki', local[r_idx], maps[b_idx])
        uv = posed[:, :2] + offset[b_idx, 1:]
        cij = np.floor((uv - proj.origin) / proj.cell).astype(np.int64)
        np.maximum(cij, 0, out=cij)            # outside the grid: its border of +inf
        np.minimum(cij, proj.last, out=cij)    # (two ufuncs: np.clip's wrapper costs 20 us)
        near = rise[b_idx, r_idx] + offset[b_idx, 0] > proj.bound[cij[:, 0], cij[:, 1]]
        b_idx, uv, posed = b_idx[near], uv[near], posed[near]
        if len(b_idx) == 0:
            return None
        # 2. Three nearest surface points in the projection plane (eq. 1), within max_gap: the
        # single-pose path's search, so that ties (a sample equidistant from grid points) go
        # the same way in both
        nn, w, rows = single_pose.three_nearest(uv, proj.origin, proj.cell, proj.last,
                                                *self._cells(proj), proj.tree.data,
                                                proj.max_gap, self.neighbours == 'smooth')
        nbr = proj.index[nn]
        b_idx = b_idx[rows]
        p = posed[rows, 2:] + pos[b_idx]
        # weighted sums over the 3 neighbours: normal (0:3), n . x (3), onset (4), position
        # (5:8), in the compiled kernel's order (row gathers: 10x faster than one (K, 3, 8))
        cols = np.ascontiguousarray(nbr.T)
        sums = np.take(self._table, cols[0], axis=0) * w[:, 0:1]
        sums += np.take(self._table, cols[1], axis=0) * w[:, 1:2]
        sums += np.take(self._table, cols[2], axis=0) * w[:, 2:3]
        d = sums[:, 3] - np.einsum('ki,ki->k', p, sums[:, :3])
        e = d - sums[:, 4]       # penetration past the response's onset (their mean)
        # 3. Front-most (deepest) sample per surface location, then per neighbour triple;
        # the selections are composed on indices and applied to the arrays once.
        idx = np.flatnonzero(e > 0.0)
        if len(idx) == 0:
            return None
        sel = _deepest_per_key(b_idx[idx] * len(self._points) + nbr[idx, 0], e[idx])
        if sel is not None:
            idx = idx[sel]
        sel = _deepest_per_triple(b_idx[idx], _sorted_triples(nbr[idx]), e[idx])
        if sel is not None:
            idx = idx[sel]
        b_idx, p, nbr, w, sums = b_idx[idx], p[idx], nbr[idx], w[idx], sums[idx]
        d, e = d[idx], e[idx]
        nsum = sums[:, :3]
        return dict(b=b_idx, p=p, nbr=nbr, w=w, q=sums[:, 5:],
                    nq=nsum / np.linalg.norm(nsum, axis=1, keepdims=True), d=d, e=e)

    def _solve_candidates(self, cand: Optional[dict], B: int, centres: np.ndarray,
                          detail: bool) -> dict:
        """Solve :meth:`_candidates` (steps 4-5 of :meth:`_run`; ``None``: no contact)."""
        if cand is None:
            return _empty_run(B)
        b_idx, p, nbr, w, q, nq, d, e = (cand[k] for k in ('b', 'p', 'nbr', 'w', 'q', 'nq', 'd',
                                                           'e'))
        # 4. LCP per pose, padded stacks of similar size.
        x, u, residual = self._solve_grouped(b_idx, q, e, B, self.layer_scales(b_idx, nbr, w))
        # 5. Forces and wrench (eq. 4).
        f = self._contact_forces(nbr, w, d, x)
        # b_idx is sorted: per-pose sums over runs, in the order add.at would take
        both = _force_torque(f, nq, p - centres[b_idx])
        wrench = np.zeros((B, 6))
        starts = np.flatnonzero(np.concatenate([[True], b_idx[1:] != b_idx[:-1]]))
        poses = b_idx[starts]
        wrench[poses] = np.add.reduceat(both, starts, axis=0)
        count = np.bincount(b_idx[x > 0.0], minlength=B)
        umax = np.zeros(B)
        umax[poses] = np.maximum(np.maximum.reduceat(u, starts), 0.0)
        deepest = np.zeros(B)
        deepest[poses] = np.maximum(np.maximum.reduceat(np.where(x > 0.0, d, 0.0), starts), 0.0)
        run = dict(wrench=wrench, count=count, umax=umax, residual=residual, deepest=deepest)
        if detail:
            run.update(b=b_idx, p=p, nbr=nbr, w=w, q=q, nq=nq, d=d, e=e, x=x, f=f)
        return run

    def _contact_forces(self, nbr: np.ndarray, w: np.ndarray, d: np.ndarray,
                        x: np.ndarray) -> np.ndarray:
        """Step 5's ``f`` (K,): the neighbours' ``y(d) - y(d - x)`` weighted by ``w`` (K, 3).

        Zero where ``x <= 0``.
        """
        f = np.zeros(len(d))
        act = np.flatnonzero(x > 0.0)
        if len(act):
            ia = nbr[act].ravel()
            da = np.repeat(d[act], 3)
            xa = np.repeat(x[act], 3)
            both = np.asarray(self.response.force(np.concatenate([ia, ia]),
                                                  np.concatenate([da, da - xa])),
                              dtype=np.float64)
            f[act] = np.einsum('kj,kj->k', (both[:len(ia)] - both[len(ia):]).reshape(-1, 3),
                               w[act])
        return f

    @staticmethod
    def _cells(proj: _Projection) -> Tuple[np.ndarray, np.ndarray]:
        """Return the projection's facing points per grid cell (built on first use, then kept)."""
        if proj.cells is None:
            proj.cells = single_pose.cell_members(proj.tree.data, proj.origin, proj.cell,
                                                  proj.last)
        return proj.cells

    def _run_single(self, local: np.ndarray, rot: np.ndarray, pos: np.ndarray, a: np.ndarray,
                    centre: np.ndarray, detail: bool, proj: _Projection, empty: dict) -> dict:
        """:meth:`_run` for one pose (``rot`` (3, 3), ``pos`` (3,)) on the compiled kernels.

        The same steps and answers as the stacked numpy path (to round-off), without its fixed
        cost of some 80 numpy calls: a planner's single query (issue 21).
        """
        frame = np.column_stack([a, proj.basis])
        (nbr, w, keep, p, q, nq, d, e, G, x, u, residual,
         status) = single_pose.single_query(
            local, rot.T @ frame, pos @ frame, np.ascontiguousarray(rot), proj.floor,
            proj.origin, proj.cell, proj.last, proj.bound, *self._cells(proj), proj.tree.data,
            proj.index, proj.max_gap, self.neighbours == 'smooth', pos, self._table, self.c,
            self.decay,
            self.decay_law != 'fixed',
            self.layer_thickness() if self.decay_law == 'layer' else _NO_PROXY,
            self.near == 'flat', DECAY_REFERENCE, DECAY_FLOOR,
            WARM_START, MAX_PIVOTING, PIVOTING_TOL)
        if len(keep) == 0:
            return empty
        if status == single_pose.SINGULAR:      # the dense solver's own fallback decides
            x, _ = bpp_dense(G, e, free=e >= WARM_START * e.max())
            u = G @ x
            residual = lcp_residual(G, e, x)
        elif status == single_pose.NOT_CONVERGED:
            raise NotConverged(f'LCP: still infeasible after {MAX_PIVOTING} pivoting rounds '
                               f'(residual {residual:.3g})')
        nbr, w = nbr[keep], w[keep]
        if self._baked is not None:
            f, wrench = single_pose.baked_wrench(nbr, w, d, x, nq, p, centre, *self._baked)
        else:
            f = self._contact_forces(nbr, w, d, x)
            wrench = _force_torque(f, nq, p - centre).sum(axis=0)
        touching = d[x > 0.0]
        run = dict(wrench=wrench[None], count=np.array([np.count_nonzero(x > 0.0)]),
                   umax=np.array([max(float(u.max()), 0.0)]), residual=np.array([residual]),
                   deepest=np.array([max(float(touching.max()), 0.0) if len(touching)
                                     else 0.0]))
        if detail:
            run.update(b=np.zeros(len(d), dtype=np.int64), p=p, nbr=nbr, w=w, q=q, nq=nq, d=d,
                       e=e, x=x, f=f)
        return run

    def _solve_grouped(self, b_idx: np.ndarray, q: np.ndarray, d: np.ndarray, B: int,
                       scale: Optional[np.ndarray]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Solve every pose's LCP; candidates are sorted by pose. Returns x, u = G x, residual.

        ``scale`` (K,): each candidate's decay-length factor (:meth:`layer_scales`; ``None``:
        none).
        """
        counts = np.bincount(b_idx, minlength=B)
        start = np.concatenate([[0], np.cumsum(counts)[:-1]])
        x = np.zeros(len(d))
        u = np.zeros(len(d))
        residual = np.zeros(B)
        busy = np.flatnonzero(counts)
        busy = busy[np.argsort(counts[busy], kind='stable')]
        sizes = counts[busy]                    # ascending
        budget = 2_000_000  # padded matrix entries per stack
        s = 0
        while s < len(busy):
            # Stack problems whose sizes lie within 25 % of each other, so padding stays cheap,
            # and at most `budget` padded entries: the first size past either ends the stack.
            top = int(np.ceil(1.25 * sizes[s])) + 1
            e = int(np.searchsorted(sizes, top, side='right'))
            ahead = sizes[s + 1:e].astype(np.int64)
            past = np.flatnonzero((np.arange(2, len(ahead) + 2) * ahead ** 2) > budget)
            e = s + 1 + int(past[0]) if len(past) else e
            members = busy[s:e]
            m = int(sizes[e - 1])
            # the members' candidates: contiguous runs (candidates are sorted by pose)
            own = counts[members]
            gi = np.repeat(np.arange(len(members)), own)
            si = np.arange(len(gi)) - np.repeat(np.cumsum(own) - own, own)
            rows = start[members][gi] + si
            qp = np.zeros((len(members), m, 3))
            dp = np.zeros((len(members), m))
            valid = np.zeros((len(members), m), dtype=bool)
            qp[gi, si], dp[gi, si], valid[gi, si] = q[rows], d[rows], True
            sp = 1.0
            if scale is not None:
                sp = np.ones((len(members), m))
                sp[gi, si] = scale[rows]
            # Pairwise distances by the Gram identity, centred per pose against cancellation.
            qp -= qp.sum(axis=1, keepdims=True) / np.maximum(valid.sum(axis=1), 1)[:, None, None]
            qp[~valid] = 0.0
            # G is built column by column as the pivoting needs it (lcp.PointShapeStack)
            lengths = self.decay_lengths(dp, sp)
            if lengths is not None:
                lengths[~valid] = self.decay     # padding: any positive length
            G = PointShapeStack(qp, self.c, self.decay, lengths, self.near)
            top = np.where(valid, dp, -np.inf).max(axis=1, keepdims=True)
            up = np.empty_like(dp)
            xp, res, _ = solve_lcp_batch(G, dp, valid, free=valid & (dp >= WARM_START * top),
                                         product=up)
            x[rows], u[rows] = xp[gi, si], up[gi, si]
            residual[members] = res
            s = e
        return x, u, residual

    def _result(self, run: dict, a: np.ndarray, centre: np.ndarray,
                return_displacements: bool) -> ContactResult:
        frame = self.surface.frame
        wrench = Wrench(force=run['wrench'][0, :3], torque=run['wrench'][0, 3:], frame=frame,
                        torque_centre=centre)
        if 'x' not in run:
            disp_idx = np.arange(len(self._points)) if return_displacements else np.zeros(
                0, dtype=np.int64)
            return ContactResult(wrench=wrench, contact_count=0, max_displacement=0.0,
                                 displaced_indices=disp_idx,
                                 displacements=np.zeros(len(disp_idx)),
                                 rigid_points_in_contact=np.zeros((0, 3)),
                                 lcp_residual=float(run['residual'][0]))
        act = run['x'] > 0.0
        q, x = run['q'][act], run['x'][act]
        if return_displacements:
            disp_idx = np.arange(len(self._points))
            scale = self.layer_scales(run['b'], run['nbr'], run['w'])
            disp = self.surface_displacement(q, x, run['e'][act],
                                             1.0 if scale is None else float(scale[0]))
        else:
            disp_idx = run['nbr'][act, 0]
            disp = run['d'][act]
        return ContactResult(
            wrench=wrench, contact_count=int(act.sum()),
            max_displacement=float(run['umax'][0]), displaced_indices=disp_idx,
            displacements=disp, rigid_points_in_contact=run['p'][act],
            lcp_residual=float(run['residual'][0]), contact_points=q,
            contact_normals=run['nq'][act], nominal_displacements=run['d'][act],
            actual_displacements=x, contact_forces=run['f'][act],
            candidate_count=len(run['x']))


def _empty_run(B: int) -> dict:
    """:meth:`ContactSimulator._run` of ``B`` poses without contact."""
    return dict(wrench=np.zeros((B, 6)), count=np.zeros(B, dtype=np.int64), umax=np.zeros(B),
                residual=np.zeros(B), deepest=np.zeros(B))


def _force_torque(f: np.ndarray, nq: np.ndarray, arm: np.ndarray) -> np.ndarray:
    """(K, 6) each contact's force ``f nq`` and its torque ``arm x f nq`` (eq. 4)."""
    force = f[:, None] * nq
    return np.hstack([force, np.column_stack([
        arm[:, 1] * force[:, 2] - arm[:, 2] * force[:, 1],
        arm[:, 2] * force[:, 0] - arm[:, 0] * force[:, 2],
        arm[:, 0] * force[:, 1] - arm[:, 1] * force[:, 0]])])


def _centres_of_pressure(run: dict, out: np.ndarray, spread: np.ndarray) -> None:
    """Write each pose's force-weighted contact position into ``out`` (B, 3), in place.

    ``run`` is a detailed :meth:`ContactSimulator._run` (``b``, ``p``, ``f``); a pose without
    contact force keeps its row of ``out`` (and its zero ``spread``). ``spread`` (B, 3, 3)
    gets the force-weighted second moment of the positions about that centre.
    """
    weight = np.maximum(run['f'], 0.0)
    b = run['b']
    total = np.bincount(b, weights=weight, minlength=len(out))
    moment = np.stack([np.bincount(b, weights=weight * run['p'][:, k],
                                   minlength=len(out)) for k in range(3)], axis=1)
    held = total > 0.0
    out[held] = moment[held] / total[held, None]
    arm = run['p'] - out[b]
    for i in range(3):
        for j in range(i, 3):
            m = np.bincount(b, weights=weight * arm[:, i] * arm[:, j], minlength=len(out))
            spread[held, i, j] = spread[held, j, i] = m[held] / total[held]


def _deepest_per_key(key: np.ndarray, d: np.ndarray) -> Optional[np.ndarray]:
    """Return indices keeping the largest-``d`` entry per distinct ``key``, sorted by key.

    ``None`` when every key is already distinct (nothing to drop; order kept).
    """
    if len(key) < 2:
        return None
    # Keys arrive nearly sorted (pose-major), which a stable sort (timsort) handles in close to
    # one pass; the deepest entry of each run of equal keys (the first of equal depths, as a
    # lexicographic sort by key, then depth descending, would pick) is found per run.
    order = np.argsort(key, kind='stable')
    k = key[order]
    start = np.ones(len(k), dtype=bool)
    start[1:] = k[1:] != k[:-1]
    if np.all(start):
        return None
    starts = np.flatnonzero(start)
    ds = d[order]
    top = np.maximum.reduceat(ds, starts)
    run = np.cumsum(start) - 1
    hit = np.flatnonzero(ds == top[run])
    first = np.ones(len(hit), dtype=bool)
    first[1:] = run[hit[1:]] != run[hit[:-1]]
    return order[hit[first]]


def _sorted_triples(nbr: np.ndarray) -> np.ndarray:
    """(K, 3) rows of ``nbr`` (K, 3) sorted ascending (a min/max network: 5x a row sort)."""
    a, b, c = nbr[:, 0], nbr[:, 1], nbr[:, 2]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    low, high = np.minimum(lo, c), np.maximum(hi, c)
    return np.column_stack([low, np.maximum(lo, np.minimum(hi, c)), high])


def _deepest_per_triple(b_idx: np.ndarray, tri: np.ndarray, d: np.ndarray) -> Optional[np.ndarray]:
    """Return :func:`_deepest_per_key` for the key (pose, sorted neighbour triple).

    ``None`` when no two candidates of one pose share a triple. A wrapping int64 hash screens
    for repeats; only a hash repeat (a true repeat or a collision) pays for the exact sort. The
    kept indices are sorted by pose.
    """
    if len(d) < 2:
        return None
    mix = np.array([0x9E3779B97F4A7C15 - (1 << 64), 0xC2B2AE3D27D4EB4F - (1 << 64),
                    0x165667B19E3779F9, 0x27D4EB2F165667C5], dtype=np.int64)
    with np.errstate(over='ignore'):
        h = (b_idx * mix[0] + tri[:, 0] * mix[1] + tri[:, 1] * mix[2] + tri[:, 2] * mix[3])
    hs = np.sort(h)
    if np.all(hs[1:] != hs[:-1]):
        return None
    order = np.lexsort((-d, tri[:, 2], tri[:, 1], tri[:, 0], b_idx))
    rows = np.column_stack([b_idx, tri])[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.any(rows[1:] != rows[:-1], axis=1)
    sel = order[first]
    return sel[np.argsort(b_idx[sel], kind='stable')]


def _positive(name: str, value) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f'{name}: must be a positive number, got {value!r}')
    if not (np.isfinite(value) and value > 0.0):
        raise InvalidInput(f'{name}: must be a positive finite length in metres, got {value}')
    return value


__all__: List[str] = ['APPROACH_TOLERANCE', 'BatchContactResult', 'ContactResult',
                      'ContactSimulator', 'DECAY_FLOOR', 'DECAY_LAW', 'DECAY_LAWS',
                      'DECAY_REFERENCE', 'LAYER_CLIP', 'LAYER_DEPTHS', 'NEIGHBOURS',
                      'NEIGHBOUR_RULES', 'check_decay_law', 'check_neighbours', 'layer_proxy',
                      'layer_stiffening', 'normalise_approach', 'poses_as_arrays']
