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
"""

from dataclasses import dataclass
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

from pointforce_ros.contact.lcp import check_decay, shape_function
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.types import as_array, Mesh, Pose, Surface


DECAY_GRID = (np.inf, 0.064, 0.032, 0.016, 0.008, 0.004, 0.002)
"""Decay lengths (metres) :func:`identify_shape_constant_from_probes` tries when asked to."""


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
    prepared = []
    for mesh, poses, approach, measured_force in pokes:
        a = np.asarray(approach, dtype=np.float64)
        measured = np.asarray(measured_force, dtype=np.float64)
        n = len(poses)
        if measured.shape not in ((n,), (n, 3)):
            raise InvalidInput(f'measured_force: expected ({n},) or ({n}, 3), got '
                               f'{measured.shape}')
        prepared.append((mesh, poses, a, as_array(measured, 'measured_force', measured.shape)))
    if decays is None:
        decays = (getattr(simulator, 'decay', np.inf),)
    decays = [check_decay(v, 'decays') for v in decays]
    if not decays:
        raise InvalidInput('decays: need at least one decay length (metres) or inf')

    def cost(c, decay):
        sim = simulator.with_shape_constant(c, decay)
        total = 0.0
        for mesh, poses, a, measured in prepared:
            force = sim.query_batch(mesh, poses, a, np.zeros(3)).wrenches[:, :3]
            pred = -force @ a if measured.ndim == 1 else force
            total += float(np.sum((pred - measured) ** 2))
        return total

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


def _predicted(sim, prepared) -> np.ndarray:
    out = []
    for mesh, poses, a, measured in prepared:
        force = sim.query_batch(mesh, poses, a, np.zeros(3)).wrenches[:, :3]
        out.append((-force @ a if measured.ndim == 1 else force).ravel())
    return np.concatenate(out)


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
    prepared = [(mesh, poses, np.asarray(a, dtype=np.float64),
                 np.asarray(m, dtype=np.float64)) for mesh, poses, a, m in pokes]
    measured = np.concatenate([m.ravel() for *_, m in prepared])
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
