"""Young's modulus and Poisson ratio from pokes: measured force + depth cloud (seed 001, sec. 4).

Each poke gives a contact point, the force the F/T sensor measured there and a depth cloud of
the object at static equilibrium. For the linear model the displacement under a known force is
``u = a(nu) / E`` with ``a`` the unit-modulus solution, so with the point-to-plane residuals of
:mod:`.observe` (affine in ``u``) the best ``s = 1 / E`` for a given ``nu`` has a closed form
(a one-unknown least-squares problem over every poke's points). What is left is a 1-D bounded
search over ``nu`` of the residual at its best ``E`` (variable projection), done with
``scipy.optimize.minimize_scalar`` (bounded Brent).

Every ``nu`` needs ``a(nu) = K(nu)^-1 W F`` for each poke, and a new ``nu`` would mean a new
factorisation (about 1 s at 6k unknowns with SuperLU). Instead the solutions are taken from a
reduced basis: ``K(nu) ~ K_mu + r K_lambda`` (``r = lambda / mu``) and the Krylov vectors
``(P^-1 K_lambda)^j P^-1 f`` of the factorisation ``P`` at a reference ``nu``, Galerkin-projected
(exact at the reference ``nu``, error checked by a test against direct solves). After the search
the model is factorised once at the found ``nu`` and ``E`` is refined with the co-rotation
(``u = (W F / E + K^-1 g) ...``, the same fixed point as the force estimate) and re-pairing.

The paper's baseline (:func:`identify_nelder_mead`) runs Nelder-Mead over ``(E, nu)`` on its
eq. 7 two-way nearest-neighbour error with one co-rotational simulation (and factorisation) per
evaluation. Units SI, frame ``base``.
"""

from dataclasses import dataclass, field
import time
from typing import Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from pointforce_ros.deformation.fem import (CorotationalFem, lame, load_columns,
                                            surface_point_load)
from pointforce_ros.deformation.mesh import TetMesh
from pointforce_ros.deformation.observe import (MatchConfig, normal_of, SurfaceMatcher,
                                                two_way_nn_error, visible_nodes)
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.types import as_array


@dataclass(frozen=True)
class Poke:
    """One static poke for identification.

    Attributes:
        contact_point: (3,) contact point on the rest surface, metres, ``base``.
        force: (3,) measured force on the object (the F/T reading), newtons, ``base``.
        cloud: (P, 3) depth points of the object at that equilibrium, metres, ``base``.
        tip: (3,) the probe tip (the arm's TCP) at that equilibrium, metres, ``base``, or
            None (not needed by the identification; the fused force's point calibration
            reads the point model at it, :mod:`.fusion`).

    Raises:
        InvalidInput: wrong shapes or non-finite values.

    """

    contact_point: np.ndarray
    force: np.ndarray
    cloud: np.ndarray
    tip: Optional[np.ndarray] = None

    def __post_init__(self):
        object.__setattr__(self, 'contact_point',
                           as_array(self.contact_point, 'Poke.contact_point', (3,)))
        object.__setattr__(self, 'force', as_array(self.force, 'Poke.force', (3,)))
        object.__setattr__(self, 'cloud', as_array(self.cloud, 'Poke.cloud', (None, 3)))
        if self.tip is not None:
            object.__setattr__(self, 'tip', as_array(self.tip, 'Poke.tip', (3,)))


@dataclass(frozen=True)
class IdentifyConfig:
    """Settings of the identification.

    Attributes:
        poisson_bounds: search interval of nu.
        reference_poisson: nu of the factorisation the reduced basis is built from.
        krylov: Krylov vectors per poke in the reduced basis.
        load_radius: load patch radius, metres.
        match: cloud pairing settings.
        refine_iter: co-rotation and re-pairing passes after the search.
        xatol: tolerance of the nu search.

    Raises:
        InvalidInput: bounds outside (-1, 0.5) or empty, bad counts.

    """

    poisson_bounds: Tuple[float, float] = (0.0, 0.49)
    reference_poisson: float = 0.35
    krylov: int = 10
    load_radius: float = 0.004
    match: MatchConfig = field(default_factory=MatchConfig)
    refine_iter: int = 3
    xatol: float = 1e-3

    def __post_init__(self):
        lo, hi = self.poisson_bounds
        if not -1.0 < lo < hi < 0.5 or not -1.0 < self.reference_poisson < 0.5:
            raise InvalidInput(f'IdentifyConfig: need -1 < lo < hi < 0.5 and a reference nu in '
                               f'(-1, 0.5); got {self.poisson_bounds}, {self.reference_poisson}')
        if int(self.krylov) < 1 or int(self.refine_iter) < 0 or not self.xatol > 0:
            raise InvalidInput('IdentifyConfig: krylov >= 1, refine_iter >= 0, xatol > 0')


@dataclass(frozen=True)
class ElasticityFit:
    """Identified material.

    Attributes:
        young: Young's modulus, Pa.
        poisson: Poisson ratio.
        residual_rms: RMS point-to-plane residual over every poke at the fit, metres.
        points: cloud points used.
        evaluations: objective evaluations (nu values tried, or Nelder-Mead calls).
        seconds: wall time, all included.
        error: the minimised objective (method-specific: sum of squares m^2 or eq. 7).
        factorise_seconds: of ``seconds``, the time spent factorising the stiffness (the model
            built for the call when none was given, and the final model at the found nu).
        poisson_interval: (lo, hi) of the nu values whose best fit is within one unit of
            chi-square of the best (``(SSE(nu) - SSE_min) / sigma^2 <= 1``), clipped to the
            search bounds; ``sigma^2`` is the residual variance at the fit scaled by points per
            paired surface node (points on the same elements share their discretisation
            error, so the nodes, not the points, count as independent). About a 68 %
            interval; an interval reaching a bound says the data does not pin nu.
        young_interval: (lo, hi) of E over the same nu interval, widened by E's own
            standard error at each nu (same ``sigma^2``), Pa.
        young_std: standard deviation of E at the fitted nu (same ``sigma^2``), Pa: what a
            force estimate inherits (a top view pins the compliance ``(1 - nu^2) / E`` that a
            top-view force estimate uses, not E and nu apart, so the E interval over the nu
            interval overstates it).
        local_young: (n,) each poke's own best E at the fitted nu and field (its points
            alone), Pa: where the pokes disagree the object is not what the field says (the
            samples that seed a heterogeneous field, :func:`.wide_contacts.modulus_field`).

    """

    young: float
    poisson: float
    residual_rms: float
    points: int
    evaluations: int
    seconds: float
    error: float
    factorise_seconds: float = 0.0
    poisson_interval: Tuple[float, float] = (float('nan'), float('nan'))
    young_interval: Tuple[float, float] = (float('nan'), float('nan'))
    local_young: Tuple[float, ...] = ()
    young_std: float = float('nan')

    @property
    def young_relative_std(self) -> float:
        """Half the width of :attr:`young_interval` over E (about one standard deviation)."""
        lo, hi = self.young_interval
        return float((hi - lo) / (2.0 * self.young)) if np.isfinite(hi - lo) else float('nan')


def _loads(mesh: TetMesh, pokes: Sequence[Poke], radius: float) -> np.ndarray:
    """(ndof, n) nodal load vector of each poke's measured force."""
    cols = []
    for p in pokes:
        nodes, w = surface_point_load(mesh, p.contact_point, radius)
        cols.append(load_columns(mesh, nodes, w) @ p.force)
    return np.column_stack(cols)


def _check_pokes(pokes) -> list:
    pokes = list(pokes)
    if not pokes:
        raise InvalidInput('identify: no pokes given (need at least one force + cloud)')
    for i, p in enumerate(pokes):
        if not isinstance(p, Poke):
            raise InvalidInput(f'identify: poke {i} is not a deformation.identify.Poke')
        if not np.linalg.norm(p.force) > 0:
            raise InvalidInput(f'identify: poke {i} has a zero force')
    return pokes


class ReducedPoissonFamily:
    """Unit-modulus displacements ``a(nu) = K_1(nu)^-1 f`` for fixed loads, from a reduced basis.

    Args:
        fem: the model, factorised at the reference nu (its ``young`` is ignored).
        loads: (ndof, n) load vectors, newtons.
        krylov: Krylov vectors per load.

    """

    def __init__(self, fem: CorotationalFem, loads: np.ndarray, krylov: int):
        free = fem.free
        k_lam = fem._k_lam_ff
        k_mu = fem._k_mu_ff
        scale = fem.young
        vecs = []
        v = fem.solve_linear(loads)[free] * scale  # every load at once: (n_free, n)
        full = np.zeros((fem.ndof, loads.shape[1]))
        for _ in range(int(krylov)):
            vecs.append(v)
            full[free] = k_lam @ v
            v = fem.solve_linear(full)[free] * scale
        basis, _ = np.linalg.qr(np.column_stack(vecs))
        self.basis = basis
        self.k_lam = basis.T @ (k_lam @ basis)
        self.k_mu = basis.T @ (k_mu @ basis)
        self.rhs = basis.T @ loads[free]
        self.free = free
        self.ndof = fem.ndof

    def displacements(self, poisson: float) -> np.ndarray:
        """(ndof, n) displacements at unit Young's modulus (1 Pa), metres."""
        lam, mu = lame(1.0, poisson)
        y = np.linalg.solve(lam * self.k_lam + mu * self.k_mu, self.rhs)
        out = np.zeros((self.ndof, self.rhs.shape[1]))
        out[self.free] = self.basis @ y
        return out


def _best_compliance(matches, unit, corr, with_information: bool = False):
    """Closed-form ``s = 1/E`` over all pokes; returns (s, sum of squares, points).

    With ``with_information`` also ``sum a^2`` (the information on ``s`` per unit noise
    variance: ``var(s) = sigma^2 / sum a^2``).
    """
    num = den = 0.0
    parts = []
    for j, m in enumerate(matches):
        a = normal_of(m, unit[:, j])
        b = m.gap - normal_of(m, corr[:, j])
        num += float(a @ b)
        den += float(a @ a)
        parts.append((a, b))
    if not den > 0:
        raise InvalidInput('identify: the clouds do not see the poke displacements')
    s = num / den
    sse = sum(float(np.sum((b - s * a) ** 2)) for a, b in parts)
    if with_information:
        return s, sse, sum(len(a) for a, _ in parts), den
    return s, sse, sum(len(a) for a, _ in parts)


MAX_COMPLIANCE_RELATIVE_STD = 1.0
"""A fitted compliance ``1/E`` less than one standard error from zero is refused: the clouds
did not see the push. Measured on the foam block (one push each): the rest scan given as the
pushed cloud, 1.5-2.3 (it "identified" E 0.9-1.3 MPa, 17-26x the truth); real 3 mm pushes,
0.10-0.18."""

PROFILE_POINTS = 13
"""nu values of the profile that gives :attr:`ElasticityFit.poisson_interval`."""


def _poisson_profile(matches, family: 'ReducedPoissonFamily', corr, bounds, nu: float
                     ) -> Tuple[Tuple[float, float], Tuple[float, float], float]:
    """(nu interval, E interval, E's relative std at ``nu``) from the residual's profile.

    The profile is evaluated on a grid over the bounds plus the fitted nu (reduced-basis
    solutions, each a few milliseconds); the interval ends are interpolated linearly where the
    profile crosses one unit of chi-square.
    """
    grid = np.union1d(np.linspace(bounds[0], bounds[1], PROFILE_POINTS), [nu])
    rows = []
    for v in grid:
        s, sse, npts, den = _best_compliance(matches, family.displacements(v), corr,
                                             with_information=True)
        rows.append((v, s, sse, den))
    v, s, sse, den = (np.array(c) for c in zip(*rows))
    best = int(np.argmin(sse))
    sigma2 = sse[best] / max(npts - 2, 1)
    # points paired with the same surface nodes share those nodes' discretisation error:
    # count the nodes, not the points, as the independent measurements
    independent = sum(len(np.unique(m.nodes)) for m in matches)
    share = min(1.0, independent / max(npts, 1))
    sigma2 /= share
    chi = (sse - sse[best]) / sigma2
    inside = chi <= 1.0

    def crossing(i, k):  # linear interpolation between grid index i (inside) and k (outside)
        return float(v[i] + (v[k] - v[i]) * (1.0 - chi[i]) / (chi[k] - chi[i]))
    lo_i = best
    while lo_i > 0 and inside[lo_i - 1]:
        lo_i -= 1
    hi_i = best
    while hi_i < len(v) - 1 and inside[hi_i + 1]:
        hi_i += 1
    lo = float(v[0]) if lo_i == 0 else crossing(lo_i, lo_i - 1)
    hi = float(v[-1]) if hi_i == len(v) - 1 else crossing(hi_i, hi_i + 1)
    keep = slice(max(lo_i - 1, 0), min(hi_i + 2, len(v)))
    s_std = np.sqrt(sigma2 / np.maximum(den[keep], 1e-300))
    s_lo = np.clip(s[keep] - s_std, 1e-300, None)
    young = (float(np.min(1.0 / (s[keep] + s_std))), float(np.max(1.0 / s_lo)))
    at = int(np.argmin(np.abs(v - nu)))
    return (lo, hi), young, float(np.sqrt(sigma2 / max(den[at], 1e-300)) / s[at])


def identify_elasticity(mesh: TetMesh, pokes: Sequence[Poke],
                        config: IdentifyConfig = IdentifyConfig(), rest_offset=None,
                        young_guess: float = 5e4, fem: Optional[CorotationalFem] = None,
                        young_field=None) -> Tuple[ElasticityFit, CorotationalFem]:
    """Identify (E, nu): closed-form E per nu, bounded 1-D search over nu, co-rotation refine.

    Args:
        mesh: volume mesh of the object.
        pokes: one or more pokes with force and cloud.
        config: settings.
        rest_offset: (N,) rest-scan offsets (:func:`.observe.rest_offsets`).
        young_guess: scale of the reference factorisation, Pa (only conditions the numbers).
        fem: the object's model as built when its surface was scanned (factorised at its
            own nu, which becomes the reference nu); built here at ``reference_poisson`` when
            None. It is refactorised at the found (E, nu) and returned.
        young_field: optional (M,) relative element modulus (a heterogeneous object: the
            shape of the field is given, its scale E and nu are identified; the returned
            ``young`` is the field's mean). Default: the given model's field, else uniform.

    Returns:
        ``(fit, fem)``: the fit and the model factorised at it (for force estimates).

    Raises:
        InvalidInput: no pokes, a zero force, bad clouds, contact points off the surface, a
            non-positive fitted modulus (the clouds move against the forces), or a compliance
            within :data:`MAX_COMPLIANCE_RELATIVE_STD` standard errors of zero (the clouds
            do not see the push).

    """
    t0 = time.perf_counter()
    pokes = _check_pokes(pokes)
    matchers = [SurfaceMatcher(mesh, p.contact_point, p.cloud, config.match,
                               rest_offset=rest_offset) for p in pokes]
    t_fact = 0.0
    field = None
    if young_field is not None:
        field = as_array(young_field, 'young_field', (len(mesh.tets),))
        if not np.all(field > 0):
            raise InvalidInput('identify: young_field must be positive everywhere')
        field = field / field.mean()
    if fem is None:
        t1 = time.perf_counter()
        fem = CorotationalFem(mesh, young_guess * (1.0 if field is None else field),
                              config.reference_poisson)
        t_fact += time.perf_counter() - t1
    elif fem.mesh is not mesh:
        raise InvalidInput('identify: the given model was built on another mesh')
    elif field is not None:
        t1 = time.perf_counter()
        fem.set_material(fem.young * field, fem.poisson)
        t_fact += time.perf_counter() - t1
    field = fem.element_young / fem.young
    loads = _loads(mesh, pokes, config.load_radius)
    family = ReducedPoissonFamily(fem, loads, config.krylov)
    corr = np.zeros_like(loads)
    state = dict(evals=0, matches=[m.match() for m in matchers])

    def objective(nu):
        state['evals'] += 1
        _, sse, _ = _best_compliance(state['matches'], family.displacements(nu), corr)
        return sse

    lo, hi = config.poisson_bounds
    nu = config.reference_poisson
    for _ in range(2):  # search, re-pair on the predicted surfaces, search again
        nu = float(minimize_scalar(objective, bounds=(lo, hi), method='bounded',
                                   options=dict(xatol=config.xatol)).x)
        unit = family.displacements(nu)
        s, _, _ = _best_compliance(state['matches'], unit, corr)
        if not s > 0:
            raise InvalidInput(f'identify: fitted compliance {s:.3g} 1/Pa is not positive: the '
                               f'clouds do not move with the measured forces')
        state['matches'] = [m.match(unit[:, j] * s) for j, m in enumerate(matchers)]
    t1 = time.perf_counter()
    fem.set_material(field / s, nu)
    t_fact += time.perf_counter() - t1
    unit = fem.solve_linear(loads) * fem.young  # exact unit-modulus solutions at nu
    for _ in range(int(config.refine_iter)):
        u = unit * s + corr
        state['matches'] = [m.match(u[:, j]) for j, m in enumerate(matchers)]
        s, sse, npts = _best_compliance(state['matches'], unit, corr)
        if not s > 0:
            raise InvalidInput('identify: fitted compliance is not positive')
        # co-rotation: E K_1 u = f + E g_1(u)  ->  u = s K_1^-1 f + K_1^-1 g_1(u), and
        # K_1^-1 g_1 = K^-1 g at any E, so the correction does not depend on s
        corr = np.column_stack([fem.solve_linear(fem.nonlinear_force(u[:, j]))
                                for j in range(len(pokes))])
    s, sse, npts = _best_compliance(state['matches'], unit, corr)
    nu_interval, young_interval, young_rel = _poisson_profile(state['matches'], family, corr,
                                                              config.poisson_bounds, nu)
    local = tuple(1.0 / _best_compliance([m], unit[:, [j]], corr[:, [j]])[0]
                  for j, m in enumerate(state['matches']))
    if not young_rel < MAX_COMPLIANCE_RELATIVE_STD:
        raise InvalidInput(f'identify: the clouds do not resolve a displacement under the '
                           f'measured forces (best E {1.0 / s:.3g} Pa, but its compliance is '
                           f'{young_rel:.2f} standard errors wide of zero): are they clouds of '
                           f'the pushed object while pushed?')
    fem.set_material(field / s, nu)
    fit = ElasticityFit(young=1.0 / s, poisson=nu, residual_rms=float(np.sqrt(sse / npts)),
                        points=npts, evaluations=state['evals'],
                        seconds=time.perf_counter() - t0, error=sse, factorise_seconds=t_fact,
                        poisson_interval=nu_interval, young_interval=young_interval,
                        local_young=local, young_std=young_rel / s)
    return fit, fem


def identify_nelder_mead(mesh: TetMesh, pokes: Sequence[Poke],
                         config: IdentifyConfig = IdentifyConfig(), start=(2e4, 0.25),
                         max_evaluations: int = 80, xatol: float = 1e-3,
                         fatol: float = 1e-12) -> ElasticityFit:
    """Seed 001's identification: Nelder-Mead over (E, nu) on its eq. 7 error.

    Each evaluation factorises the model at (E, nu), solves the co-rotational equilibrium
    under each measured force and sums eq. 7 (two-way nearest neighbours between the visible
    surface nodes and the cloud) over the pokes. ``E`` is searched as ``log E`` and ``nu`` is
    clipped into the bounds (the paper resets an out-of-bounds value to just inside).

    Raises:
        InvalidInput: as :func:`identify_elasticity`.

    """
    t0 = time.perf_counter()
    pokes = _check_pokes(pokes)
    matchers = [SurfaceMatcher(mesh, p.contact_point, p.cloud, config.match) for p in pokes]
    visible = [visible_nodes(mesh, m) for m in matchers]
    loads = _loads(mesh, pokes, config.load_radius)
    fem = CorotationalFem(mesh, start[0], start[1])
    lo, hi = config.poisson_bounds
    state = dict(evals=0)

    def error(x):
        state['evals'] += 1
        young = float(np.exp(x[0]))
        nu = float(np.clip(x[1], lo + 1e-4, hi - 1e-4))
        fem.set_material(young, nu)
        total = 0.0
        for j, m in enumerate(matchers):
            try:
                u = fem.solve(loads[:, j])
            except NotConverged:
                return 1.0
            total += two_way_nn_error(mesh.nodes + u.reshape(-1, 3), visible[j], m.points)
        return total

    x0 = np.array([np.log(start[0]), start[1]])
    res = minimize(error, x0, method='Nelder-Mead',
                   options=dict(xatol=xatol, fatol=fatol, maxfev=int(max_evaluations),
                                initial_simplex=np.array([x0, x0 + [0.5, 0.0],
                                                          x0 + [0.0, 0.1]])))
    young = float(np.exp(res.x[0]))
    nu = float(np.clip(res.x[1], lo + 1e-4, hi - 1e-4))
    return ElasticityFit(young=young, poisson=nu, residual_rms=float('nan'),
                         points=sum(len(m.points) for m in matchers), evaluations=state['evals'],
                         seconds=time.perf_counter() - t0, error=float(res.fun))
