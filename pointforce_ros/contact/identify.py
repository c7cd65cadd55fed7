"""Identify the shape-function constant ``c`` of ``g(r) = c / (c + r)`` from data.

The paper picks ``c`` by eye and suggests tracking the dent with a camera (seed 000, IV.A.2).
Two ways are implemented:

* :func:`identify_shape_constant`: from a dent profile ``u(r)`` observed around a point poke
  (``u(r) = u0 c / (c + r)``; for a single-point poke the model says ``u0`` is the poke
  depth). A least-squares fit: ``u0`` is solved in closed form for every ``c``, ``c`` is
  found by a log-spaced scan refined by a bounded scalar minimisation.
  :func:`dent_profile` turns a displaced surface (same points, displaced) or an observed
  cloud into ``(r, u)``.
* :func:`identify_shape_constant_from_probe`: from pokes with a second probe of known geometry
  (a flat punch, cylinder or paddle) once the point response is known: ``c`` sets how much
  neighbouring contacts share displacement, hence the second probe's force; it is fitted to
  the measured forces by the same scan + refinement over the contact simulator.
* :func:`shape_fit_covariance`: how well the pushes determine ``(log c, 1 / L)``: the
  Gauss-Newton (Laplace) covariance at the fit, for the wrench's uncertainty
  (:mod:`pointforce_ros.contact.uncertainty`).
* :func:`calibrate_shape`: the joint fit with every uncertainty source the service needs, the
  share of the force it misses taken from leave-one-push-out refits (how well ``(c, L)`` from
  some pushes predicts another push), not from the fit's own residual.
"""

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.stats import t as student_t
from scipy.spatial import cKDTree

from pointforce_ros.contact.lcp import check_decay, check_near, NEARS, shape_function
from pointforce_ros.contact.uncertainty import lateral_share, uncertainty_sources, Z90
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.types import as_array, Mesh, Pose, Surface


DECAY_GRID = (np.inf, 0.064, 0.032, 0.016, 0.008, 0.004, 0.002)
"""Decay lengths (metres) :func:`identify_shape_constant_from_probes` tries when asked to."""

DECAY_CAP = 1.5
"""Longest tail decay length :func:`decay_grid` offers, in multiples of the object's thickness.

The surface displacement of an elastic layer bonded to a rigid table under a point load dies
out within a distance of the order of the layer's thickness (its Green's function decays
exponentially there), so an infinite (or 64 mm) tail is not the physics of a 30-40 mm object on
a table; on figure 2's vest the other trials nevertheless chose one for its first line trial
(28 % of the peak force; 12.6 % under the cap). Every finite decay length the probe trials of
the five figure objects choose lies at or below 1.05 thicknesses (vest 32 mm at 30.4 mm,
plush 16-32 mm at 38 mm, dome 16-32 mm at 33 mm, lamb 8 mm, thin_layer 8 mm); the grid steps
by factors of 2, so a cap of one thickness would drop the member nearest it (the vest's 32 mm),
and 1.5 and 2 choose the same on all five (``data/figures/decay_cap.py``)."""


def object_thickness(surface: Surface, support_z: float = 0.0, up_deg: float = 45.0) -> float:
    """Thickness of the object above its support, metres.

    The median height of the surface's upward-facing points (normal within ``up_deg`` of
    ``+z``) over the plane ``z = support_z``. The project's frame ``base`` has the table top
    at ``z = 0`` (the simulated cell, the deformation mesh); a cell whose table lies
    elsewhere passes its height. ``nan`` when no point faces up or the median lies on or
    below the support.
    """
    up = surface.normals[:, 2] >= np.cos(np.radians(up_deg))
    if not np.any(up):
        return float('nan')
    h = float(np.median(surface.points[up, 2])) - float(support_z)
    return h if h > 0 else float('nan')


def decay_grid(surface: Surface, decays: Sequence[float] = DECAY_GRID,
               cap: Optional[float] = DECAY_CAP, support_z: float = 0.0) -> Tuple[float, ...]:
    """Return the decay lengths of ``decays`` up to ``cap`` times the object's thickness.

    :data:`DECAY_CAP` says why. ``cap=None``, or a surface whose thickness is unknown
    (:func:`object_thickness`), keeps ``decays`` whole; a cap below every length keeps the
    shortest one.
    """
    decays = tuple(float(v) for v in decays)
    h = object_thickness(surface, support_z)
    if cap is None or not np.isfinite(h) or not decays:
        return decays
    kept = tuple(v for v in decays if v <= cap * h)
    return kept or (min(decays),)


def best_capped_fit(fits: Sequence['ShapeFit'], surface: Surface,
                    support_z: float = 0.0) -> Optional['ShapeFit']:
    """Return the fit of ``fits`` with the lowest residual among those :func:`decay_grid` keeps.

    ``fits`` as :func:`shape_fits_from_probes` returns them over the whole grid (so a caller
    that also wants the paper's ``g``, ``L`` = inf, reads it from the same scan). Where no
    fit lies within the cap, the best of all; ``None`` for no fits.
    """
    fits = list(fits)
    longest = max(decay_grid(surface, support_z=support_z), default=np.inf)
    kept = [f for f in fits if f.decay <= longest] or fits
    return min(kept, key=lambda f: f.rmse) if kept else None


@dataclass(frozen=True)
class ShapeFit:
    """Result of a shape-constant fit.

    Attributes:
        c: fitted constant, metres.
        u0: fitted dent depth at ``r = 0``, metres (``nan`` for a probe fit).
        rmse: root-mean-square residual, metres (dent) or newtons (probe).
        n_points: number of samples fitted.
        method: ``'dent'`` or ``'probe'``.
        decay: fitted decay length of the shape function's tail, metres (``inf``: the paper's
            ``g``, or not fitted).

    """

    c: float
    u0: float
    rmse: float
    n_points: int
    method: str
    decay: float = float('inf')


def _scan_then_refine(cost: Callable[[float], float], bounds: Tuple[float, float],
                      what: str) -> float:
    lo, hi = np.log(bounds[0]), np.log(bounds[1])
    grid = np.linspace(lo, hi, 41)
    values = np.array([cost(np.exp(v)) for v in grid])
    best = int(np.argmin(values))
    left, right = grid[max(best - 1, 0)], grid[min(best + 1, len(grid) - 1)]
    res = minimize_scalar(lambda v: cost(np.exp(v)), bounds=(left, right), method='bounded',
                          options={'xatol': 1e-6})
    log_c = float(res.x) if res.fun <= values[best] else float(grid[best])
    edge = 0.02 * (hi - lo)
    if log_c <= lo + edge or log_c >= hi - edge:
        raise NotConverged(f'{what}: best c = {np.exp(log_c):.3g} m lies at the search bound '
                           f'[{bounds[0]:.3g}, {bounds[1]:.3g}] m; the data do not determine c '
                           '(widen c_bounds or use a deeper poke / larger field of view)')
    return float(np.exp(log_c))


def _check_bounds(c_bounds) -> Tuple[float, float]:
    lo, hi = (float(v) for v in c_bounds)
    if not (0 < lo < hi and np.isfinite(hi)):
        raise InvalidInput(f'c_bounds: need 0 < low < high (metres), got {c_bounds}')
    return lo, hi


class _Push(tuple):
    """A push ``(mesh, poses, approach, measured_force)`` with its contact candidates kept.

    A fit of ``(c, L)`` solves the same poses under hundreds of ``(c, L)``; which rigid samples
    touch where does not change with them (:meth:`~pointforce_ros.contact.simulator.
    ContactSimulator.prepare_batch`), so each push is prepared once (it unpacks as the
    4-tuple it was made from).
    """

    def __new__(cls, simulator, poke):
        """Validate ``poke`` and prepare it on ``simulator`` (where it can prepare)."""
        mesh, poses, approach, measured_force = poke
        self = super().__new__(cls, (mesh, poses, approach, measured_force))
        self.approach = np.asarray(approach, dtype=np.float64)
        measured = np.asarray(measured_force, dtype=np.float64)
        n = len(poses)
        if measured.shape not in ((n,), (n, 3)):
            raise InvalidInput(f'measured_force: expected ({n},) or ({n}, 3), got '
                               f'{measured.shape}')
        self.measured = as_array(measured, 'measured_force', measured.shape)
        self.prepared = (simulator.prepare_batch(mesh, poses, self.approach, np.zeros(3))
                         if hasattr(simulator, 'prepare_batch') else None)
        return self

    def forces(self, sim) -> np.ndarray:
        """Return the (T, 3) force vectors ``sim`` predicts at the push's poses, N."""
        if self.prepared is not None and self.prepared.table is getattr(sim, '_table', None):
            return sim.solve_prepared(self.prepared)[:, :3]
        return sim.query_batch(self[0], self[1], self.approach, np.zeros(3)).wrenches[:, :3]

    def predicted(self, sim) -> np.ndarray:
        """Return the prediction in the measurement's form: along ``-approach`` or (T, 3)."""
        force = self.forces(sim)
        return -force @ self.approach if self.measured.ndim == 1 else force


def _pushes(simulator, pokes: Sequence[tuple]) -> List[_Push]:
    """``pokes`` as :class:`_Push` on ``simulator`` (one already prepared on it is kept)."""
    table = getattr(simulator, '_table', None)
    return [p if isinstance(p, _Push) and (p.prepared is None or p.prepared.table is table)
            else _Push(simulator, p) for p in pokes]


def identify_shape_constant(r: np.ndarray, u: np.ndarray, u0: Optional[float] = None,
                            r_min: float = 0.0,
                            c_bounds: Tuple[float, float] = (1e-5, 1.0)) -> ShapeFit:
    """Fit ``u(r) = u0 c / (c + r)`` to a dent profile by least squares.

    Args:
        r: (M,) distance of each sample from the poke point, metres (>= 0).
        u: (M,) displacement of each sample along ``-n``, metres.
        u0: dent depth at the poke point if known (the poke depth for a point probe), else
            fitted.
        r_min: ignore samples closer than this (under a probe of finite size).
        c_bounds: search interval for ``c``, metres.

    Returns:
        :class:`ShapeFit` with ``method='dent'``.

    Raises:
        InvalidInput: mismatched/non-finite arrays, negative distances, fewer than 3 samples
            beyond ``r_min``, or no positive displacement.
        NotConverged: the optimum lies on a search bound (``c`` not determined by the data).

    """
    r = as_array(r, 'r', (None,))
    u = as_array(u, 'u', (len(r),))
    if np.any(r < 0):
        raise InvalidInput('r: distances must be >= 0')
    lo, hi = _check_bounds(c_bounds)
    keep = r >= r_min
    r, u = r[keep], u[keep]
    if len(r) < 3:
        raise InvalidInput(f'identify_shape_constant: need >= 3 samples beyond r_min, got '
                           f'{len(r)}')
    if not np.any(u > 0):
        raise InvalidInput('identify_shape_constant: no positive displacement in the profile')
    if u0 is not None and not (np.isfinite(u0) and u0 > 0):
        raise InvalidInput(f'u0: must be a positive depth in metres, got {u0}')

    def amplitude(c):
        g = shape_function(r, c)
        return float(u0) if u0 is not None else float(g @ u / (g @ g))

    def cost(c):
        return float(np.sum((u - amplitude(c) * shape_function(r, c)) ** 2))

    c = _scan_then_refine(cost, (lo, hi), 'identify_shape_constant')
    return ShapeFit(c=c, u0=amplitude(c), rmse=float(np.sqrt(cost(c) / len(r))),
                    n_points=len(r), method='dent')


def dent_profile(surface: Surface, displaced: np.ndarray, poke_point: np.ndarray,
                 search_radius: Optional[float] = None) -> Tuple[np.ndarray, np.ndarray]:
    """Return ``(r, u)`` of a dent: distance from ``poke_point`` and displacement along ``-n``.

    Args:
        surface: equilibrium surface (``N`` points, ``base``).
        displaced: either (N, 3) the same points after the poke (tracked correspondence), or
            (M, 3) an observed cloud of the dented surface in ``base`` (any M != N): each
            surface point then takes the observed point nearest to its normal line among its 8
            nearest observed points, accepted within ``search_radius`` of that line.
        poke_point: (3,) the poke location on the equilibrium surface, metres, ``base``.
        search_radius: largest distance from the normal line for the cloud case, metres;
            default 1.5 times the median spacing of the observed cloud.

    Returns:
        ``r`` (K,) metres and ``u`` (K,) metres (positive = pushed in) for the K surface points
        with a displacement.

    Raises:
        InvalidInput: malformed arrays.

    """
    displaced = as_array(displaced, 'displaced', (None, 3))
    poke = as_array(poke_point, 'poke_point', (3,))
    p, n = surface.points, surface.normals
    if len(displaced) == len(p):
        u = -np.einsum('ij,ij->i', displaced - p, n)
        return np.linalg.norm(p - poke, axis=1), u
    if len(displaced) < 8:
        raise InvalidInput('dent_profile: an observed cloud needs at least 8 points')
    tree = cKDTree(displaced)
    if search_radius is None:
        spacing, _ = tree.query(displaced[:: max(len(displaced) // 2000, 1)], k=2)
        search_radius = 1.5 * float(np.median(spacing[:, 1]))
    _, idx = tree.query(p, k=8)
    off = displaced[idx] - p[:, None, :]
    along = np.einsum('kji,ki->kj', off, n)
    lateral = np.linalg.norm(off - along[..., None] * n[:, None, :], axis=2)
    best = np.argmin(lateral, axis=1)
    rows = np.arange(len(p))
    ok = lateral[rows, best] <= search_radius
    return np.linalg.norm(p[ok] - poke, axis=1), -along[rows, best][ok]


def identify_shape_constant_from_probe(simulator, mesh: Mesh, poses: Sequence[Pose], approach,
                                       measured_force: np.ndarray,
                                       c_bounds: Tuple[float, float] = (1e-4, 0.1)) -> ShapeFit:
    """Fit ``c`` so the simulated forces of a second probe match measured ones.

    Args:
        simulator: a :class:`ContactSimulator` built on the equilibrium surface with the point
            response already learned (its own ``c`` is ignored).
        mesh: the second probe's mesh (known geometry).
        poses: the probe poses of the poke(s), ``base`` (T poses).
        approach: (3,) unit push direction, ``base``.
        measured_force: (T,) force along ``-approach`` (push-back, N) or (T, 3) force vectors.

    Returns:
        :class:`ShapeFit` with ``method='probe'`` (``rmse`` in newtons).

    Raises:
        InvalidInput: mismatched lengths or non-finite forces.
        NotConverged: the optimum lies on a search bound (the forces do not determine ``c``,
            e.g. a probe that touches at a single point).

    """
    poke = (mesh, poses, approach, measured_force)
    return identify_shape_constant_from_probes(simulator, [poke], c_bounds)


def identify_shape_constant_from_probes(simulator, pokes: Sequence[tuple],
                                        c_bounds: Tuple[float, float] = (1e-4, 0.1),
                                        decays: Optional[Sequence[float]] = None
                                        ) -> ShapeFit:
    """Fit one ``c`` (and a tail ``decay``) to several second-probe pokes at once.

    The fit minimises the summed squared force error. With ``decays`` of more than one value
    (for example :data:`DECAY_GRID`) ``c`` is fitted at each decay length and the pair with
    the smallest error wins (:func:`shape_fits_from_probes`): on a layer over a rigid support
    the paper's ``1 / r`` tail makes a wide probe share too much displacement, and no single
    ``c`` then fits both a line and a cylinder (see
    :func:`~pointforce_ros.contact.lcp.shape_function`).

    One poke of a line or cylinder can pull ``c`` far off: where the point model is wrong
    under that probe, ``c`` absorbs the error (a point model 30 % too stiff at the spot asks
    for more coupling). Pokes at other places and orientations disagree about that error but
    agree about ``c``, so a joint fit is far more stable.

    Args:
        simulator: as for :func:`identify_shape_constant_from_probe`.
        pokes: ``(mesh, poses, approach, measured_force)`` per poke, each as
            :func:`identify_shape_constant_from_probe` takes them.
        c_bounds: search interval for ``c``, metres.
        decays: decay lengths to try, metres (``inf``: the paper's ``g``); ``None`` (the
            default) fits ``c`` alone at the simulator's own decay length.

    Returns:
        :class:`ShapeFit` with ``method='probe'``; ``rmse`` over every pose of every poke, N;
        ``n_points`` the number of poses; ``decay`` the chosen decay length.

    Raises:
        InvalidInput: no pokes, mismatched lengths, non-finite forces, or a decay that is not
            a positive length or ``inf``.
        NotConverged: at every decay length the optimum of ``c`` lies on a search bound.

    """
    return min(shape_fits_from_probes(simulator, pokes, c_bounds, decays),
               key=lambda fit: fit.rmse)


def shape_fits_from_probes(simulator, pokes: Sequence[tuple],
                           c_bounds: Tuple[float, float] = (1e-4, 0.1),
                           decays: Optional[Sequence[float]] = None) -> List[ShapeFit]:
    """Fit the best ``c`` at each decay length, as :func:`identify_shape_constant_from_probes`.

    Returns:
        one :class:`ShapeFit` per decay length whose ``c`` has an interior optimum, in the
        order of ``decays`` (a caller comparing the paper's ``g`` with the decayed one reads
        both from one scan).

    Raises:
        as :func:`identify_shape_constant_from_probes`.

    """
    lo, hi = _check_bounds(c_bounds)
    pokes = list(pokes)
    if not pokes:
        raise InvalidInput('identify_shape_constant_from_probes: no pokes')
    prepared = _pushes(simulator, pokes)
    if decays is None:
        decays = (getattr(simulator, 'decay', np.inf),)
    decays = [check_decay(v, 'decays') for v in decays]
    if not decays:
        raise InvalidInput('decays: need at least one decay length (metres) or inf')

    def cost(c, decay):
        sim = simulator.with_shape_constant(c, decay)
        return sum(float(np.sum((p.predicted(sim) - p.measured) ** 2)) for p in prepared)

    count = sum(len(p[1]) for p in prepared)
    fits, failure = [], None
    for decay in decays:
        try:
            c = _scan_then_refine(lambda v: cost(v, decay), (lo, hi),
                                  'identify_shape_constant_from_probe')
        except NotConverged as exc:
            failure = exc
            continue
        fits.append(ShapeFit(c=c, u0=float('nan'), rmse=float(np.sqrt(cost(c, decay) / count)),
                             n_points=count, method='probe', decay=decay))
    if not fits:
        raise failure
    return fits


SHAPE_PRIOR_STD = (1.0, 200.0)
"""Prior standard deviations of ``(log c, 1 / L [1/m])`` that keep the covariance finite
where the pushes do not determine a direction (``1 / L`` = 200 /m is a 5 mm decay length)."""


def _predicted(sim, prepared: Sequence[_Push]) -> np.ndarray:
    return np.concatenate([p.predicted(sim).ravel() for p in prepared])


def shape_fit_covariance(simulator, pokes: Sequence[tuple], fit: ShapeFit,
                         steps: Tuple[float, float] = (0.05, 5.0),
                         prior_std: Tuple[float, float] = SHAPE_PRIOR_STD) -> np.ndarray:
    """Covariance (2, 2) of ``(log c, 1 / L [1/m])`` at a probe fit (Gauss-Newton).

    ``sigma^2 (J^T J + sigma^2 P)^-1`` with ``J`` the derivative of the predicted forces by
    forward differences of ``steps``, ``sigma^2`` the fit's residual variance over its degrees
    of freedom (at least 1 % of the mean measured force, squared) and ``P`` the precision of
    ``prior_std``. ``1 / L = 0`` is the paper's ``g``.

    Args:
        simulator: as for :func:`identify_shape_constant_from_probes`.
        pokes: the pokes the fit was made on, as there.
        fit: the fit (its ``c`` and ``decay``).
        steps: finite-difference steps of ``log c`` and ``1 / L`` (1/m).
        prior_std: prior standard deviations of ``log c`` and ``1 / L``.

    Raises:
        InvalidInput: no pokes, non-positive steps or prior.

    """
    if not pokes:
        raise InvalidInput('shape_fit_covariance: no pokes')
    if min(steps) <= 0 or min(prior_std) <= 0:
        raise InvalidInput('shape_fit_covariance: steps and prior_std must be > 0')
    prepared = _pushes(simulator, pokes)
    measured = np.concatenate([p.measured.ravel() for p in prepared])
    inv = 0.0 if not np.isfinite(fit.decay) else 1.0 / fit.decay
    base = _predicted(simulator.with_shape_constant(fit.c, fit.decay), prepared)
    jac = np.column_stack([
        (_predicted(simulator.with_shape_constant(fit.c * np.exp(steps[0]), fit.decay),
                    prepared) - base) / steps[0],
        (_predicted(simulator.with_shape_constant(fit.c, 1.0 / (inv + steps[1])), prepared)
         - base) / steps[1]])
    dof = max(len(measured) - 2, 1)
    sigma2 = max(float(np.sum((base - measured) ** 2)) / dof,
                 (0.01 * float(np.mean(np.abs(measured)))) ** 2)
    precision = np.diag(1.0 / np.asarray(prior_std, dtype=np.float64) ** 2)
    return sigma2 * np.linalg.inv(jac.T @ jac + sigma2 * precision)


@dataclass(frozen=True)
class ShapeCalibration:
    """``(c, L)`` from calibration pushes with the wrench's uncertainty sources.

    Attributes:
        fit: the joint fit on every push (:func:`identify_shape_constant_from_probes`).
        shape_cov: (2, 2) covariance of ``(log c, 1 / L [1/m])``: the joint fit's
            (:func:`shape_fit_covariance`) plus, on ``log c``, the spread between the pushes'
            own ``c`` (``per_push``): ``(1 + 1/m)`` times their sample variance over the
            ``m >= 2`` pushes that determine one (what a new probe's ``c`` may differ by).
        relative_std: share of the force along the push that the model misses on a push it
            was not fitted to: the root mean square, over the pushes, of each push's relative
            RMS error predicted by ``(c, L)`` refitted on the other pushes (with three or more
            pushes ``L`` is refitted too, over the decay lengths the joint fit tried; with two,
            one push cannot choose ``L`` and ``c`` is refitted at ``fit.decay``), times
            :func:`small_sample_factor` of their number (a share estimated from two or three
            pushes is itself uncertain); never below ``in_sample_std``, which it is with one
            push or where no refit converged.
        lateral_std: RMS force across the push not predicted, over the RMS normal force
            (:func:`~pointforce_ros.contact.uncertainty.lateral_share`; 0 where no push has
            force vectors).
        in_sample_std: the joint fit's RMS residual along the push over the pushes' RMS force.
        per_push: ``c`` (metres) fitted to each push alone at ``fit.decay``, ``nan`` where
            that push does not determine it (its optimum on a search bound).
        held_out: per push, in order, ``(c refitted on the others or nan, relative RMS error
            of that push predicted with it or nan)``; where a near field was chosen from more
            than :data:`NEAR_PUSHES` pushes, under the near field chosen without that push.
        held_out_decays: per push, the decay length ``L`` (metres, ``inf``: none) it was
            predicted with: refitted on the others with three or more pushes, else
            ``fit.decay`` (``nan`` where no refit converged).
        near: the shape function's near field ``(c, L)`` apply with
            (:data:`~pointforce_ros.contact.lcp.NEARS`; chosen by :func:`choose_near` where
            several were offered).
        near_errors: per near field offered, the root-mean-square held-out relative error
            :func:`choose_near` chose by (empty where nothing was chosen).

    """

    fit: ShapeFit
    shape_cov: np.ndarray
    relative_std: float
    lateral_std: float
    in_sample_std: float
    per_push: Tuple[float, ...] = ()
    held_out: Tuple[Tuple[float, float], ...] = ()
    held_out_decays: Tuple[float, ...] = ()
    near: str = 'paper'
    near_errors: Dict[str, float] = field(default_factory=dict)

    def sources(self) -> Dict:
        """Return the sources in the model-``meta`` form (the learner stores them)."""
        return uncertainty_sources(shape_cov=self.shape_cov, relative_std=self.relative_std,
                                   lateral_std=self.lateral_std)


def small_sample_factor(n: int) -> float:
    """Widening of a share estimated from ``n`` held-out errors, for a nominal 90 % interval.

    A new push's error over the root mean square ``s`` of ``n`` earlier ones (zero-mean
    normal errors) follows Student's t with ``n`` degrees of freedom, so its 90 % interval is
    ``+- t_0.95(n) s``; the uncertainty sources are standard deviations read as ``+- Z90``
    intervals, so ``s`` is stored times ``t_0.95(n) / Z90``: 1.78 with two pushes, 1.43 with
    three, 1.10 with ten, 1 in the limit.

    Raises:
        InvalidInput: ``n < 1``.

    """
    if int(n) < 1:
        raise InvalidInput(f'small_sample_factor: need >= 1 held-out error, got {n}')
    return float(student_t.ppf(0.95, int(n))) / Z90


def _along(sim, poke) -> Tuple[np.ndarray, np.ndarray]:
    """Predicted and measured force along the push (``-approach``), N, of one push."""
    push = _pushes(sim, [poke])[0]
    a, measured = push.approach, push.measured
    return -push.forces(sim) @ a, (measured if measured.ndim == 1 else -measured @ a)


def _relative_error(sim, poke) -> float:
    pred, measured = _along(sim, poke)
    size = float(np.sqrt(np.mean(measured ** 2)))       # a push with no force has no share
    return float(np.sqrt(np.mean((pred - measured) ** 2))) / size if size > 0 else float('nan')


NEAR_PUSHES = 3
"""Fewest calibration pushes :func:`choose_near` chooses the near field from: with two, each
push is predicted with ``c`` refitted on the other at the joint ``L``, which the held-out push
helped choose, so the test does not reach the shape's spread. On the demo's lamb (two pushes
beside a bone) that test prefers the flat near field on eight stored runs (held-out share
2.1-5.0 against 4.2-9.6 %) where the planner queries over the bone prefer the paper's (8.4-9.3
against 8.9-10.5 % of the largest true force; ``data/fem/demo_near_replay.py``)."""


def _held_out_refits(simulator, pokes: Sequence[tuple], decays, c_bounds
                     ) -> List[Tuple[float, float, float]]:
    """Return per push ``(c, L)`` refitted on the other pushes and its relative error.

    The refit is over ``decays`` as :func:`identify_shape_constant_from_probes`; the error is
    the push's relative RMS error predicted with that ``(c, L)``; ``nan`` all three where the
    refit did not converge.
    """
    out = []
    for i, poke in enumerate(pokes):
        try:
            fit = identify_shape_constant_from_probes(simulator, pokes[:i] + pokes[i + 1:],
                                                      c_bounds, decays)
        except NotConverged:
            out.append((float('nan'),) * 3)
            continue
        error = _relative_error(simulator.with_shape_constant(fit.c, fit.decay), poke)
        out.append((fit.c, fit.decay, error))
    return out


def choose_near(simulator, pokes: Sequence[tuple], decays: Optional[Sequence[float]] = DECAY_GRID,
                c_bounds: Tuple[float, float] = (1e-4, 0.1),
                nears: Sequence[str] = NEARS) -> Tuple[str, Dict[str, float]]:
    """Return the near field whose ``(c, L)`` predicts the pushes best held out, and the errors.

    For each near field of ``nears`` (:data:`~pointforce_ros.contact.lcp.NEARS`) every push is
    predicted with ``(c, L)`` refitted on the other pushes (over ``decays``, as
    :func:`identify_shape_constant_from_probes`), and the near field with the smallest root
    mean square of those relative errors wins (a refit that does not converge counts as a
    relative error of 1). The response law is chosen per object by held-out error too; here
    the simulator's family is. With fewer than :data:`NEAR_PUSHES` pushes, or one near field
    offered, nothing is chosen: ``(simulator.near, {})``.

    On figure 2's probe trials (each scored from its object's other four trials) the flat near
    field is chosen for 21 of 24 trials, all five of the vest's (a stiff skin over padding
    spreads a dent flat), and the force RMSE goes from 4.5-11.7 to 3.6-8.7 % of the peak on
    the five objects, the vest's from 11.7 to 8.4 % (``python -m pointforce_ros.lab.figures``,
    ``docs/STATUS.md``).

    Raises:
        InvalidInput: an unknown near field, or as :func:`identify_shape_constant_from_probes`.

    """
    near, errors, _ = _choose_near(simulator, _pushes(simulator, pokes), decays, c_bounds,
                                   nears)
    return near, errors


def _choose_near(simulator, pokes: List[tuple], decays, c_bounds, nears):
    """:func:`choose_near`, also returning every offered near field's held-out refits.

    Returns ``(near, errors, refits)``, ``refits`` ``{near: _held_out_refits(...)}`` (empty
    where nothing was chosen).
    """
    nears = [check_near(n, 'nears') for n in nears]
    own = getattr(simulator, 'near', 'paper')
    if len(pokes) < NEAR_PUSHES or len(set(nears)) < 2:
        return own, {}, {}
    errors, refits = {}, {}
    for near in dict.fromkeys(nears):
        refits[near] = _held_out_refits(simulator.with_shape_constant(simulator.c, near=near),
                                        pokes, decays, c_bounds)
        errors[near] = _near_score([e for _, _, e in refits[near]])
    best = min(errors, key=errors.get)
    return best, errors, refits


def _chosen_held_out(simulator, pokes: List[tuple], decays, c_bounds, refits):
    """Per push, its held-out refit under the near field chosen WITHOUT it (nested).

    The chosen near field's own held-out errors are the smallest of those offered, so they
    understate what the choice meets on a new push: each push is predicted under the near
    field :func:`choose_near` picks from the other pushes (their own leave-one-out), with
    ``(c, L)`` refitted on those others (``refits[near][i]``, already made). A fit on the
    pushes but ``i`` and ``j`` serves both ``i``'s choice and ``j``'s, so it is made once.
    """
    pairs = {}

    def without(near, i, j):
        key = (near, min(i, j), max(i, j))
        if key not in pairs:
            sim = simulator.with_shape_constant(simulator.c, near=near)
            rest = [p for k, p in enumerate(pokes) if k not in (i, j)]
            try:
                fit = identify_shape_constant_from_probes(sim, rest, c_bounds, decays)
                pairs[key] = sim.with_shape_constant(fit.c, fit.decay)
            except NotConverged:
                pairs[key] = None
        return pairs[key]

    out = []
    for i in range(len(pokes)):
        scores = {}
        for near in refits:
            errors = []
            for j in range(len(pokes)):
                if j != i:
                    sim = without(near, i, j)
                    errors.append(_relative_error(sim, pokes[j]) if sim is not None
                                  else float('nan'))
            scores[near] = _near_score(errors)
        out.append(refits[min(scores, key=scores.get)][i])
    return out


def _near_score(errors) -> float:
    """Root mean square of held-out relative errors, a refit that failed counting as 1."""
    return float(np.sqrt(np.mean([e ** 2 if np.isfinite(e) else 1.0 for e in errors])))


def calibrate_shape(simulator, pokes: Sequence[tuple],
                    decays: Optional[Sequence[float]] = DECAY_GRID,
                    c_bounds: Tuple[float, float] = (1e-4, 0.1),
                    decay_law: Optional[str] = None,
                    nears: Optional[Sequence[str]] = None) -> ShapeCalibration:
    """Identify ``(c, L)`` from calibration pushes with the wrench's uncertainty sources.

    The joint fit is :func:`identify_shape_constant_from_probes`. Its residual and its
    covariance understate the error on a new probe: ``c`` absorbs the point model's error
    under the pushes it was fitted to, and a line and a cylinder want different ``c`` (on the
    figure objects the fits from one object's probe trials scatter by a factor 2-4 in ``c``,
    far more than the joint fit's covariance says). So (one push rarely determines ``L``:
    ``c`` and ``L`` trade off along a ridge):

    * each push is predicted by ``(c, L)`` refitted on the other pushes, and
      ``relative_std`` is the root mean square of those held-out relative errors. With three
      or more pushes the refit chooses ``L`` as well: held at the joint ``L``, which the
      held-out push helped choose, the errors understated what a new probe meets (on figure
      2's probe trials, each scored from its object's other four: 84 % of 76 steps inside
      the 90 % intervals, 89.5 % with ``L`` refitted; ``data/figures/share_prior.py``). With
      two, one push cannot choose ``L``: ``c`` alone is refitted at the joint ``L``;
    * ``c`` is fitted to each push alone at the joint ``L``, and their spread is added to the
      covariance of ``log c`` (:class:`ShapeCalibration`);
    * where the near field is chosen (``nears``, more than :data:`NEAR_PUSHES` pushes), each
      push is predicted under the near field chosen from the other pushes alone (nested):
      the chosen near field's own held-out errors are the smallest of those offered and so
      understate what the choice meets on a new push (figure 2's probe trials, where the
      choice flips for some pushes: lamb's median share 16 -> 19 %, its force components
      inside their 90 % intervals 87 -> 89 %, torque 84 -> 89 %; the steps as before, 66 of
      76; ``data/figures/coverage_s45.log``).

    Everything comes from the calibration pushes alone. ``n`` pushes cost one fit over the
    decay lengths and ``n`` fits of ``c`` alone, and ``n`` more fits over the decay lengths
    with three or more pushes (none with two); with ``nears`` those are the refits
    :func:`choose_near` made for each near field offered (the chosen one's are reused), and
    with more than :data:`NEAR_PUSHES` pushes ``n (n - 1) / 2`` more per near field for the
    nested choice (12 for figure 2's four pushes and two near fields).

    Args:
        simulator: as for :func:`identify_shape_constant_from_probes`.
        pokes: ``(mesh, poses, approach, measured_force)`` per push, ``measured_force`` (T,)
            along ``-approach`` or (T, 3) vectors (these also give ``lateral_std``).
        decays: decay lengths to try, metres (default :data:`DECAY_GRID`; ``None``: the
            simulator's own).
        c_bounds: search interval for ``c``, metres.
        decay_law: the simulator's decay law to identify ``(c, L)`` under (``'fixed'`` or
            ``'penetration'``, :class:`~pointforce_ros.contact.simulator.ContactSimulator`);
            ``None``: the simulator's own. The pushes do not choose the law: on the demo's
            lamb both fit them alike, and the planner queries preferred ``'penetration'``
            (``data/fem/demo_floor_law.py``).
        nears: near fields to choose from (:func:`choose_near`, with three or more pushes);
            ``None``: the simulator's own.

    Returns:
        :class:`ShapeCalibration`.

    Raises:
        InvalidInput: as :func:`identify_shape_constant_from_probes`, or an unknown law.
        NotConverged: the joint fit's ``c`` lies on a search bound at every decay length.

    """
    pokes = _pushes(simulator, pokes)   # the copies below share what they were prepared on
    if decay_law is not None:
        simulator = simulator.with_shape_constant(simulator.c, decay_law=decay_law)
    near_errors, refits = {}, None
    if nears is not None:
        near, near_errors, every = _choose_near(simulator, pokes, decays, c_bounds, nears)
        if near_errors:
            refits = (_chosen_held_out(simulator, pokes, decays, c_bounds, every)
                      if len(pokes) > NEAR_PUSHES else every[near])
        simulator = simulator.with_shape_constant(simulator.c, near=near)
    fit = identify_shape_constant_from_probes(simulator, pokes, c_bounds, decays)
    calibrated = simulator.with_shape_constant(fit.c, fit.decay)
    pred, measured = zip(*(_along(calibrated, p) for p in pokes))
    pred, measured = np.concatenate(pred), np.concatenate(measured)
    scale = max(float(np.sqrt(np.mean(measured ** 2))), 1e-12)
    in_sample = float(np.sqrt(np.mean((pred - measured) ** 2))) / scale

    def c_alone(subset) -> float:
        try:
            return identify_shape_constant_from_probes(simulator, subset, c_bounds,
                                                       (fit.decay,)).c
        except NotConverged:
            return float('nan')

    per_push = [c_alone([p]) for p in pokes] if len(pokes) > 1 else []
    if len(pokes) == 1:
        refits = [(float('nan'),) * 3]
    elif len(pokes) == 2:       # one push cannot choose L: the other's c at the joint L
        refits = []
        for c, poke in zip(per_push[::-1], pokes):
            error = (_relative_error(simulator.with_shape_constant(c, fit.decay), poke)
                     if np.isfinite(c) else float('nan'))
            refits.append((c, fit.decay, error))
    elif refits is None:        # three or more pushes, not refitted yet by choose_near
        refits = _held_out_refits(simulator, pokes, decays, c_bounds)
    held_out = [(c, e if np.isfinite(c) else float('nan')) for c, _, e in refits]
    held_out_decays = [decay if np.isfinite(c) else float('nan') for c, decay, _ in refits]
    errors = np.array([e for _, e in held_out if np.isfinite(e)])
    relative = max(float(np.sqrt(np.mean(errors ** 2))) * small_sample_factor(len(errors))
                   if len(errors) else 0.0, in_sample)
    cov = shape_fit_covariance(simulator, pokes, fit)
    alone = np.log([c for c in per_push if np.isfinite(c)])
    if len(alone) >= 2:
        cov[0, 0] += (1.0 + 1.0 / len(alone)) * float(np.var(alone, ddof=1))
    vectors = [p for p in pokes if np.asarray(p[3]).ndim == 2]
    lateral = lateral_share(calibrated, vectors) if vectors else 0.0
    return ShapeCalibration(fit=fit, shape_cov=cov, relative_std=relative, lateral_std=lateral,
                            in_sample_std=in_sample, per_push=tuple(per_push),
                            held_out=tuple(held_out), held_out_decays=tuple(held_out_decays),
                            near=getattr(simulator, 'near', 'paper'), near_errors=near_errors)
