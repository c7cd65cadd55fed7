"""Contact force from the observed deformation alone (seed 001, section 5), and its baseline.

Given the identified model, a known contact point ``c`` and a depth cloud of the deformed
object, the force ``F`` (3,) on the object at ``c`` is the one whose simulated deformation best
explains the cloud. The co-rotational equilibrium reads ``K u = W F + g(u)`` (``W`` the load
patch's columns, ``g`` what co-rotation adds, :meth:`CorotationalFem.nonlinear_force`), so for a
fixed ``g`` the displacement is ``u = C F + K^-1 g`` with the compliance columns ``C = K^-1 W``
(three back-substitutions with the stored factorisation). With the point-to-plane pairs of
:mod:`.observe` the residuals are affine in ``F``: a 3-unknown linear least-squares problem.
It is iterated: re-pair on the predicted surface, update ``g`` from the predicted ``u``, solve
again, until ``F`` moves less than the tolerance.

The covariance reported with each estimate is ``s^2 (A^T A)^-1`` with ``s^2`` the residual
variance (``m - 3`` degrees of freedom): it treats the residuals as independent, which neighbouring
depth pixels are not, so it is a lower bound on the real spread (the evaluation reports how it
compares with the actual error).

The paper's method (:func:`estimate_force_nelder_mead`) minimises the same residual with
Nelder-Mead over ``F``, one co-rotational simulation per evaluation, and is the baseline.
Units SI, frame ``base``; the force is the one the probe exerts on the object.
"""

from dataclasses import dataclass, field
import time

import numpy as np
from scipy.optimize import minimize

from pointforce_ros.deformation.fem import CorotationalFem, load_columns, surface_point_load
from pointforce_ros.deformation.mesh import vertex_normals
from pointforce_ros.deformation.observe import (MatchConfig, normal_of, normal_rows,
                                                SurfaceMatcher)
from pointforce_ros.errors import InvalidInput, NotConverged


@dataclass(frozen=True)
class ForceConfig:
    """Settings of the force estimate.

    Attributes:
        load_radius: radius of the load patch the point force is spread over, metres.
        match: cloud pairing settings.
        corotational: iterate the co-rotation (default False: the linear model, which on the
            cell's pushes of 3-8 mm into 40 mm objects was as accurate (foam block: held-out
            error 6.5 % linear, 7-10 % co-rotational) at a quarter of the time; deeper pushes
            into thinner objects want True).
        max_iter: outer iterations (re-pairing, co-rotation update).
        tol: stop when ``|dF| <= tol |F| + 1e-4`` N.

    Raises:
        InvalidInput: non-positive radius, iterations or tolerance.

    """

    load_radius: float = 0.004
    match: MatchConfig = field(default_factory=MatchConfig)
    corotational: bool = False
    max_iter: int = 10
    tol: float = 5e-3

    def __post_init__(self):
        if not self.load_radius > 0 or int(self.max_iter) < 1 or not self.tol > 0:
            raise InvalidInput(f'ForceConfig: need load_radius > 0, max_iter >= 1, tol > 0; got '
                               f'{self.load_radius}, {self.max_iter}, {self.tol}')


@dataclass(frozen=True)
class ForceEstimate:
    """A camera-only contact force estimate.

    Attributes:
        force: (3,) force on the object at the contact point, newtons, ``base``.
        covariance: (3, 3) covariance of ``force`` from the fit residual, N^2.
        residual_rms: RMS point-to-plane residual of the fit, metres.
        points: cloud points used.
        iterations: outer iterations spent.
        seconds: wall time of the estimate.
        displacement: (ndof,) predicted displacement, metres.

    """

    force: np.ndarray
    covariance: np.ndarray
    residual_rms: float
    points: int
    iterations: int
    seconds: float
    displacement: np.ndarray

    @property
    def uncertainty(self) -> np.ndarray:
        """(3,) standard deviation of each force component, newtons."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def magnitude_std(self) -> float:
        """Standard deviation of ``|force|`` (first order), newtons."""
        n = np.linalg.norm(self.force)
        if n == 0:
            return float(np.sqrt(np.trace(self.covariance)))
        d = self.force / n
        return float(np.sqrt(max(d @ self.covariance @ d, 0.0)))


def compliance_columns(fem: CorotationalFem, contact_point, config: ForceConfig):
    """``(W (ndof, 3), C = K^-1 W (ndof, 3))`` of a point force at ``contact_point``.

    Raises:
        InvalidInput: the point is not on the object's surface.

    """
    nodes, weights = surface_point_load(fem.mesh, contact_point, config.load_radius)
    w = load_columns(fem.mesh, nodes, weights)
    return w, fem.solve_linear(w)


def estimate_force(fem: CorotationalFem, contact_point, cloud,
                   config: ForceConfig = ForceConfig(), rest_offset=None) -> ForceEstimate:
    """Contact force from one cloud: iterated least squares over compliance columns.

    Args:
        fem: identified model (factorised).
        contact_point: (3,) known contact point on the surface, metres, ``base``.
        cloud: (P, 3) depth points of the deformed object at equilibrium, metres, ``base``.
        config: settings.
        rest_offset: (N,) rest-scan offsets of the surface nodes (:func:`.observe.rest_offsets`).

    Raises:
        InvalidInput: empty or non-finite cloud, a contact point off the surface, too few
            usable points, or a degenerate fit (the cloud does not see the deformation).

    """
    t0 = time.perf_counter()
    matcher = SurfaceMatcher(fem.mesh, contact_point, cloud, config.match,
                             rest_offset=rest_offset)
    _, comp = compliance_columns(fem, contact_point, config)
    u_g = np.zeros(fem.ndof)
    f = np.zeros(3)
    u = None
    it = 0
    for it in range(1, int(config.max_iter) + 1):
        m = matcher.match(u)
        a = normal_rows(m, comp)
        b = m.gap - normal_of(m, u_g)
        f_new, *_ = np.linalg.lstsq(a, b, rcond=None)
        u = comp @ f_new + u_g
        if config.corotational:
            u_g = fem.solve_linear(fem.nonlinear_force(u))
            u = comp @ f_new + u_g
        done = np.linalg.norm(f_new - f) <= config.tol * np.linalg.norm(f_new) + 1e-4
        f = f_new
        if done and it > 1:
            break
    r = b - a @ f
    dof = max(len(r) - 3, 1)
    ata = a.T @ a
    if np.linalg.cond(ata) > 1e12:
        raise InvalidInput('estimate_force: the cloud does not constrain the force (degenerate '
                           'fit: too few points near the contact, or none displaced)')
    cov = float(r @ r) / dof * np.linalg.inv(ata)
    return ForceEstimate(force=f, covariance=cov, residual_rms=float(np.sqrt(np.mean(r ** 2))),
                         points=len(r), iterations=it, seconds=time.perf_counter() - t0,
                         displacement=u)


PULL_SIGMAS = 3.0
"""An estimate pulls when its outward component exceeds this many of its standard deviations
(and :data:`PULL_FLOOR`): a probe presses, it cannot pull the surface out."""
PULL_FLOOR = 0.25
"""Smallest outward component, newtons, refused as a pull (a light touch's estimate can lean
outward by its noise)."""


def pull_reason(fem: CorotationalFem, contact_point, estimate: ForceEstimate,
                config: ForceConfig = ForceConfig()):
    """Return why ``estimate`` is a pull no probe can exert at ``contact_point``, or None.

    The outward normal is the load patch's weighted vertex normal of the rest surface. An
    outward component over :data:`PULL_SIGMAS` standard deviations and over
    :data:`PULL_FLOOR` N means the cloud bulged out where the probe touched (a cloud of
    another object or state, a wrong contact point): the estimate explains the cloud, not a
    push, and a caller must not take it as a contact force.
    """
    nodes, weights = surface_point_load(fem.mesh, contact_point, config.load_radius)
    normal = weights @ vertex_normals(fem.mesh.nodes, fem.mesh.surface_triangles)[nodes]
    size = np.linalg.norm(normal)
    if not size > 0:
        return None
    normal = normal / size
    outward = float(estimate.force @ normal)
    std = float(np.sqrt(max(normal @ estimate.covariance @ normal, 0.0)))
    if outward > PULL_FLOOR and outward > PULL_SIGMAS * std:
        return (f'the cloud moved out of the surface at the contact point: the force that '
                f'explains it pulls {outward:.2f} N outward ({outward / max(std, 1e-12):.0f} '
                f'standard deviations), which a probe cannot exert (a cloud of another object '
                f'or time, or a wrong contact point?)')
    return None


def estimate_force_nelder_mead(fem: CorotationalFem, contact_point, cloud,
                               config: ForceConfig = ForceConfig(), rest_offset=None,
                               start=(0.0, 0.0, -1.0),
                               xatol: float = 1e-3, fatol: float = 1e-12,
                               max_evaluations: int = 600) -> ForceEstimate:
    """Seed 001's method: Nelder-Mead over ``F``, one co-rotational simulation per evaluation.

    Each evaluation solves the co-rotational equilibrium under ``W F`` (warm-started from the
    previous evaluation's state, as the paper starts from the registered state), re-pairs the
    cloud with the simulated surface and returns the sum of squared point-to-plane residuals.

    Args:
        start: initial force, newtons (the paper starts without a guess).
        xatol, fatol: Nelder-Mead tolerances on the force (N) and the error (m^2).
        max_evaluations: evaluation budget.

    Raises:
        InvalidInput: as :func:`estimate_force`.

    """
    t0 = time.perf_counter()
    matcher = SurfaceMatcher(fem.mesh, contact_point, cloud, config.match,
                             rest_offset=rest_offset)
    w, _ = compliance_columns(fem, contact_point, config)
    state = dict(u=None, evals=0)

    def simulate(f):
        try:
            u = (fem.solve(w @ f, u0=state['u']) if config.corotational
                 else fem.solve_linear(w @ f))
        except NotConverged:
            return None
        state['u'] = u
        return u

    def error(f):
        state['evals'] += 1
        u = simulate(np.asarray(f))
        if u is None:
            return 1e3
        try:
            m = matcher.match(u)
        except InvalidInput:
            return 1e3
        r = m.gap - normal_of(m, u)
        return float(r @ r)

    res = minimize(error, np.asarray(start, dtype=float), method='Nelder-Mead',
                   options=dict(xatol=xatol, fatol=fatol, maxfev=int(max_evaluations),
                                initial_simplex=np.asarray(start) + np.vstack(
                                    [np.zeros(3), np.eye(3)])))
    f = res.x
    u = simulate(f)
    m = matcher.match(u)
    r = m.gap - normal_of(m, u)
    return ForceEstimate(force=f, covariance=np.full((3, 3), np.nan),
                         residual_rms=float(np.sqrt(np.mean(r ** 2))), points=len(r),
                         iterations=state['evals'], seconds=time.perf_counter() - t0,
                         displacement=u)
