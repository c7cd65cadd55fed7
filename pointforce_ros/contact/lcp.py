"""Shape function and the displacement LCP of the contact simulator (seed 000, eq. 2-3).

Sign convention. The paper writes eq. 3 as ``w = d - G d~`` with ``0 <= w _|_ d~ >= 0``. Read
literally that LCP always has the trivial solution ``d~ = 0`` (``w = d > 0``): no force. The
paper's own solution scheme ("assume equalities, drop negative actual displacements") and its
text ("non-negative actual displacements no greater than the nominal displacements") describe
the physical problem instead, with the slack taken the other way round::

    u = G d~                      surface displacement at every candidate point
    w = u - d = G d~ - d >= 0     the displaced surface clears the rigid point (no penetration)
    d~ >= 0                       no pulling
    w_i d~_i = 0                  a point carries actual displacement only where it touches

This is the KKT system of the convex QP ``min 1/2 x'Gx - d'x, x >= 0`` and, because
``g(r) = c / (c + r) = integral of c exp(-t (c + r)) dt`` is a positive mixture of exponential
kernels, ``G`` is positive definite for distinct points: the LCP has exactly one solution (so
is the flat near field's, a Matern kernel, :data:`NEARS`). It
also implies ``d~ <= d`` (``d_i = d~_i + sum_j g_ij d~_j`` on touching points, ``g > 0``).
Everything in this module uses ``w = G d~ - d``.

Solvers:

* :func:`solve_lcp_batch` / :func:`solve_lcp`: block principal pivoting (Judice & Pires; the
  NNLS variant of Kim & Park 2011) with Murty's single-pivot backup rule, which makes it finite
  for any P-matrix. It starts from the paper's guess (every candidate touching), exchanges all
  infeasible indices at once, and typically ends in 2-4 dense solves. Many problems of
  different sizes are solved together as one padded stack. Given the candidate points
  (:class:`PointShapeStack`) instead of the matrices, it builds only the columns of ``G`` that
  each round's free sets need.
* :func:`solve_lcp_paper`: the paper's scheme as written. It only ever removes points, so it
  cannot cycle; it always stops within ``m`` solves, but a point removed early is never put
  back, so the answer can violate ``w >= 0`` (the rigid body penetrates the displaced surface):
  see :attr:`LcpSolution.residual`.
"""

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np
from scipy.linalg import lapack

from pointforce_ros.errors import check_choice, InvalidInput, NotConverged


NEARS = ('paper', 'flat')
"""Near fields of the shape function (:func:`shape_function` ``near``): ``'paper'``, the seed's
``c / (c + r)`` (a dent with a point at its centre and a ``1 / r`` fall, the elastic half-space's
Green's function with a core of size ``c``), or ``'flat'``, ``(1 + r / c) exp(-r / c)`` (a
flat-topped dent that falls off over about ``2 c``: what a surface whose skin spreads a load,
or a layer on a support, shows; the Matern kernel of smoothness 3/2, positive definite in any
dimension). The tail factor ``exp(-r / decay)`` applies to either."""


def check_near(value, name: str = 'near') -> str:
    """Return ``value`` as a near field of :data:`NEARS`.

    Raises:
        InvalidInput: not one of :data:`NEARS` (the message starts with ``name``).

    """
    return check_choice(value, NEARS, name)


def _near(r: np.ndarray, c: float, near: str) -> np.ndarray:
    """Return the near field of ``r`` (a new array): ``c / (c + r)`` or ``(1 + r/c) e^(-r/c)``."""
    if near == 'flat':
        t = np.asarray(r, dtype=np.float64) / c
        return (1.0 + t) * np.exp(-t)
    return c / (c + np.asarray(r, dtype=np.float64))


def shape_function(r: np.ndarray, c: float, decay: float = np.inf,
                   near: str = 'paper') -> np.ndarray:
    """Return ``g(r) = c / (c + r) * exp(-r / decay)`` for distances ``r`` >= 0.

    With ``decay = inf`` (the default) this is the paper's ``g(r) = c / (c + r)`` (eq. 2). A
    finite ``decay`` (metres, > 0) cuts the ``1 / r`` tail off: on an object of finite
    thickness on a rigid support the dent of a poke dies out within a few thicknesses, and
    the paper's tail makes wide contacts (a cylinder) share too much displacement, so their
    force comes out too low. ``g`` stays a positive mixture of exponential kernels
    (``c exp(-t c) exp(-(t + 1 / decay) r)`` over ``t``), so ``G`` stays positive definite.
    ``r``, ``c`` and ``decay`` share one length unit (metres at every public interface);
    ``g(0) = 1``. ``near='flat'``: ``(1 + r / c) exp(-r / c)`` in place of ``c / (c + r)``
    (:data:`NEARS`).
    """
    r = np.asarray(r, dtype=np.float64)
    if near != 'paper':
        g = _near(r, c, check_near(near))
        if np.isfinite(decay):
            g *= np.exp(r * (-1.0 / decay))
        return g
    g = c + r
    if isinstance(g, np.ndarray):
        np.divide(c, g, out=g)   # c / (c + r) with one temporary
    else:
        g = c / g                # a 0-d input
    if np.isfinite(decay):
        g *= np.exp(r * (-1.0 / decay))
    return g


def varying_shape_function(r: np.ndarray, c: float, decay_i: np.ndarray,
                           decay_j: np.ndarray, near: str = 'paper') -> np.ndarray:
    """Return ``g_ij`` with a decay length per point: :func:`shape_function` generalised.

    ``g_ij = c / (c + r) * (2 L_i L_j / (L_i^2 + L_j^2)) ** 1.5 * exp(-r / L_ij)`` with
    ``L_ij = sqrt((L_i^2 + L_j^2) / 2)``: the exponential factor is the non-stationary
    exponential kernel of Paciorek and Schervish (2004) with isotropic lengths in 3-D, positive
    definite for any lengths, and its Schur product with the positive definite ``c / (c + r)``
    stays so; equal lengths give :func:`shape_function` exactly and ``g_ii = 1``.

    Args:
        r: distances, metres (any shape broadcasting with the lengths).
        c: shape-function constant, metres (> 0).
        decay_i: decay lengths of the rows' points, metres (> 0, finite), broadcasting with
            ``r`` (for a matrix: a column ``(m, 1)``).
        decay_j: those of the columns' points (for a matrix: a row ``(1, m)``).
        near: the near field in place of ``c / (c + r)`` (:data:`NEARS`; positive definite
            too, so the product stays so).

    """
    r = np.asarray(r, dtype=np.float64)
    li = np.asarray(decay_i, dtype=np.float64)
    lj = np.asarray(decay_j, dtype=np.float64)
    s2 = 0.5 * (li * li + lj * lj)
    g = _near(r, c, check_near(near))
    g *= (li * lj / s2) ** 1.5
    g *= np.exp(-r / np.sqrt(s2))
    return g


def _shape_in_place(r2: np.ndarray, c: float, decay: float,
                    near: str = 'paper') -> np.ndarray:
    """Return :func:`shape_function` of ``sqrt(r2)``, overwriting ``r2`` (squared distances)."""
    r = np.sqrt(r2, out=r2)
    if np.isfinite(decay) or near != 'paper':
        return shape_function(r, c, decay, near)
    r += c
    return np.divide(c, r, out=r)   # c / (c + r), as shape_function rounds it


def check_decay(value, name: str = 'decay') -> float:
    """Return ``value`` as a decay length of :func:`shape_function`: metres > 0, or ``inf``.

    Raises:
        InvalidInput: not a number, NaN, zero or negative (the message starts with ``name``).

    """
    try:
        out = float(value)
    except (TypeError, ValueError):
        out = float('nan')
    if not out > 0:  # also refuses NaN
        raise InvalidInput(f'{name}: must be a positive length in metres or inf, got {value!r}')
    return out


def shape_matrix(points: np.ndarray, c: float, decay: float = np.inf,
                 near: str = 'paper') -> np.ndarray:
    """(m, m) matrix ``G_ij = g(|q_i - q_j|)`` of candidate points ``points`` (m, 3), metres."""
    points = np.asarray(points, dtype=np.float64)
    diff = points[:, None, :] - points[None, :, :]
    return shape_function(np.sqrt(np.einsum('ijk,ijk->ij', diff, diff)), c, decay, near)


class PointShapeStack:
    """The stack ``G_bij = g(|q_bi - q_bj|)`` (B, m, m) of candidate points, built by columns.

    :func:`solve_lcp_batch` given one builds, in each pivoting round, only the columns of the
    free sets: after the warm start about half the candidates, then the touching ones (a fifth
    on sphere queries), instead of every problem's whole matrix once and sub-matrices gathered
    from it every round. The free points are put first, so ``G[F, F]`` is a slice of the
    columns. Squared distances ``|q_i|^2 + |q_j|^2 - 2 q_i . q_j`` come from one small matrix
    product per problem, ``[q_i, |q_i|^2, 1] . [-2 q_j, 1, |q_j|^2]``, exactly zero on the
    diagonal.

    Args:
        points: (B, m, 3) candidate points, metres; centre each problem's points (the Gram
            identity cancels digits far from the origin). Padding rows may hold anything
            finite.
        c: shape-function constant, metres (> 0).
        decay: decay length of the shape function, metres (> 0 or ``inf``).
        decays: optional (B, m) decay length per point, metres (> 0, finite; padding rows
            any positive value): :func:`varying_shape_function` instead of ``decay``.
        near: the shape function's near field (:data:`NEARS`).

    """

    def __init__(self, points: np.ndarray, c: float, decay: float = np.inf,
                 decays: Optional[np.ndarray] = None, near: str = 'paper'):
        points = np.asarray(points, dtype=np.float64)
        B, m = points.shape[:2]
        self.points = points
        self.c = float(c)
        self.decay = float(decay)
        self.decays = None if decays is None else np.asarray(decays, dtype=np.float64)
        self.near = check_near(near)
        sq = np.einsum('bij,bij->bi', points, points)
        self._left = np.empty((B, m, 5))     # [q, |q|^2, 1]
        self._left[..., :3] = points
        self._left[..., 3] = sq
        self._left[..., 4] = 1.0
        self._right = np.empty((B, m, 5))    # [-2 q, 1, |q|^2]
        np.multiply(points, -2.0, out=self._right[..., :3])
        self._right[..., 3] = 1.0
        self._right[..., 4] = sq

    @property
    def shape(self) -> Tuple[int, int, int]:
        """``(B, m, m)``."""
        B, m = self.points.shape[:2]
        return B, m, m

    def columns(self, problems: np.ndarray, order: np.ndarray, k: int) -> np.ndarray:
        """(n, m, k) ``G[problems]`` with rows in ``order`` (n, m) and columns ``order[:, :k]``.

        Entry ``[b, i, j]`` is ``g(|q_pi - q_pj|)``, ``p = problems[b]``, ``pi = order[b, i]``,
        ``pj = order[b, j]``.
        """
        left = self._left[problems[:, None], order]
        right = self._right[problems[:, None], order[:, :k]]
        r2 = np.matmul(left, right.transpose(0, 2, 1))
        diag = np.arange(k)
        r2[:, diag, diag] = 0.0   # exact: rounding there would put 1 - 3e-8 on the diagonal
        np.maximum(r2, 0.0, out=r2)
        if self.decays is not None:
            lengths = self.decays[problems[:, None], order]
            return varying_shape_function(np.sqrt(r2, out=r2), self.c, lengths[:, :, None],
                                          lengths[:, None, :k], self.near)
        return _shape_in_place(r2, self.c, self.decay, self.near)

    def dense(self) -> np.ndarray:
        """Return the whole stack (B, m, m)."""
        B, m = self.points.shape[:2]
        return self.columns(np.arange(B), np.broadcast_to(np.arange(m), (B, m)), m)


@dataclass(frozen=True)
class LcpSolution:
    """Solution of ``0 <= G x - d _|_ x >= 0``.

    Attributes:
        x: (m,) actual displacements ``d~``, metres, >= 0.
        w: (m,) ``G x - d``, metres: the gap between the displaced surface and the rigid point.
        residual: ``max_i |min(x_i, w_i)|``, metres: zero exactly at a complementary solution
            (it catches a negative ``x``, a negative ``w`` and ``x_i w_i != 0`` alike).
        iterations: number of dense solves.
        converged: ``residual <= tol`` of the call.
        method: ``'bpp'`` or ``'paper'``.

    """

    x: np.ndarray
    w: np.ndarray
    residual: float
    iterations: int
    converged: bool
    method: str


def lcp_residual(G: np.ndarray, d: np.ndarray, x: np.ndarray) -> float:
    """Return ``max |min(x, G x - d)|`` in the units of ``d`` (0 for an empty problem)."""
    if len(d) == 0:
        return 0.0
    w = G @ x - d
    return float(np.max(np.abs(np.minimum(x, w))))


def _check_problem(G, d) -> Tuple[np.ndarray, np.ndarray]:
    G = np.asarray(G, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    if d.ndim != 1 or G.shape != (len(d), len(d)):
        raise InvalidInput(f'LCP: G must be (m, m) and d (m,), got {G.shape} and {d.shape}')
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(d))):
        raise InvalidInput('LCP: G and d must be finite')
    return G, d


def _batched_solve(A: np.ndarray, b: np.ndarray) -> Tuple[np.ndarray, int]:
    """Solve the stack ``A x = b``; singular members (duplicate points) get a tiny ridge."""
    try:
        return np.linalg.solve(A, b[..., None])[..., 0], 0
    except np.linalg.LinAlgError:
        out = np.empty_like(b)
        ridged = 0
        for k in range(len(A)):
            try:
                out[k] = np.linalg.solve(A[k], b[k])
            except np.linalg.LinAlgError:
                scale = max(float(np.abs(np.diagonal(A[k])).max()), 1.0)
                out[k] = np.linalg.solve(A[k] + 1e-9 * scale * np.eye(len(b[k])), b[k])
                ridged += 1
        return out, ridged


def _solve_free(G: np.ndarray, d: np.ndarray, F: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """(B, m) solution of ``G[F, F] x[F] = d[F]`` per problem, ``x`` 0 off the free set ``F``.

    After the first round of pivoting the free sets are small (a fifth of the candidates on a
    sphere query), so the stack is compressed to the largest free count ``k``: each problem's
    free indices first, the rest of its ``k`` rows the identity. The dense solves then cost
    ``k^3`` instead of ``m^3`` (the same linear systems; only padding rows differ).
    """
    B, m = F.shape
    k = int(F.sum(axis=1).max()) if B else 0
    if k >= m or k == 0:
        A = np.where(F[:, :, None] & F[:, None, :], G, eye)
        return _batched_solve(A, np.where(F, d, 0.0))[0]
    order = np.argsort(~F, axis=1, kind='stable')[:, :k]      # free indices first
    rows = np.arange(B)[:, None]
    Fk = F[rows, order]
    Gk = G[rows[:, :, None], order[:, :, None], order[:, None, :]]
    A = np.where(Fk[:, :, None] & Fk[:, None, :], Gk, eye[:k, :k])
    y = _batched_solve(A, np.where(Fk, d[rows, order], 0.0))[0]
    x = np.zeros((B, m))
    x[rows, order] = np.where(Fk, y, 0.0)
    return x


def solve_lcp_batch(G, d: np.ndarray, valid: Optional[np.ndarray] = None,
                    free: Optional[np.ndarray] = None, max_iter: int = 200,
                    tol: float = 1e-12, product: Optional[np.ndarray] = None
                    ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve a stack of LCPs ``0 <= G_b x_b - d_b _|_ x_b >= 0`` by block principal pivoting.

    Args:
        G: (B, m, m) symmetric positive definite matrices (entries of padding ignored), or a
            :class:`PointShapeStack` of the candidate points (only the columns each round
            needs are built; the same pivoting, the same solutions to round-off).
        d: (B, m) nominal displacements (any length unit).
        valid: (B, m) bool, ``False`` marks padding (its ``x`` is 0); default all valid.
        free: (B, m) bool initial guess of the touching set (warm start); default ``valid``
            (the paper's guess: every candidate touches).
        max_iter: most pivoting rounds.
        tol: relative feasibility tolerance (times ``max |d_b|``).
        product: optional (B, m) float array that receives ``G_b x_b`` (the surface
            displacement at every candidate; padding entries undefined).

    Returns:
        ``(x, residual, iterations)``: (B, m) actual displacements (0 on padding), (B,)
        ``max |min(x, w)|`` per problem and (B,) number of dense solves per problem.

    Raises:
        NotConverged: a problem still infeasible after ``max_iter`` rounds (cannot happen for
            a positive definite ``G`` short of round-off; the message gives the residual).

    """
    d = np.asarray(d, dtype=np.float64)
    B, m = d.shape
    valid = np.ones((B, m), dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    F = valid.copy() if free is None else (np.asarray(free, dtype=bool) & valid)
    x = np.zeros((B, m))
    iterations = np.zeros(B, dtype=np.int64)
    if B == 0 or m == 0:
        return x, np.zeros(B), iterations
    if isinstance(G, PointShapeStack):
        return _solve_points(G, d, valid, F, max_iter, tol, product)
    G = np.asarray(G, dtype=np.float64)
    eye = np.eye(m, dtype=bool)
    pair = valid[:, :, None] & valid[:, None, :]
    Gv = np.where(pair, G, 0.0)
    scale = np.maximum(np.abs(np.where(valid, d, 0.0)).max(axis=1), 1e-300)
    eps = tol * scale
    best = np.full(B, m + 1)
    chances = np.full(B, 3)
    todo = np.flatnonzero(valid.any(axis=1))
    for _ in range(max_iter):
        if len(todo) == 0:
            break
        whole = len(todo) == B
        Gt = Gv if whole else Gv[todo]
        dt = d if whole else d[todo]
        vt = valid if whole else valid[todo]
        Ft = F if whole else F[todo]
        xt = _solve_free(Gt, dt, Ft, eye)
        iterations[todo] += 1
        wt = (Gt @ xt[:, :, None])[:, :, 0] - dt
        e = eps[todo, None]
        bad = vt & ((Ft & (xt < -e)) | (~Ft & (wt < -e)))
        x[todo] = np.where(Ft, xt, 0.0)
        done = ~bad.any(axis=1)
        todo = _next_round(F, todo, done, bad, best, chances)
        if not len(todo):
            break
    if len(todo):
        _not_converged((Gv[todo] @ x[todo][:, :, None])[:, :, 0] - d[todo], x[todo],
                       valid[todo], max_iter)
    x = np.maximum(x, 0.0)
    u = (Gv @ x[:, :, None])[:, :, 0]
    if product is not None:
        product[...] = u
    return x, _residuals(u - d, x, valid), iterations


def _residuals(w, x, valid) -> np.ndarray:
    """(B,) ``max |min(x, w)|`` over the valid entries of each row."""
    r = np.where(valid, np.abs(np.minimum(x, w)), 0.0)
    return r.max(axis=1) if r.shape[1] else np.zeros(len(r))


def _next_round(F, todo, done, bad, best, chances) -> np.ndarray:
    """Pivot the problems of ``todo`` not ``done``; return them (empty when all are done)."""
    if np.all(done):
        return todo[:0]
    keep = ~done
    idx = todo[keep]
    _pivot(F, idx, bad[keep], best, chances)
    return idx


def _not_converged(w, x, valid, max_iter: int) -> None:
    """Raise NotConverged for the ``len(x)`` problems still infeasible (``w = G x - d``)."""
    worst = max(_residuals(w, x, valid))
    raise NotConverged(f'LCP: {len(x)} problem(s) still infeasible after {max_iter} '
                       f'pivoting rounds (residual {worst:.3g})')


def _pivot(F, idx, bad, best, chances) -> None:
    """Exchange the infeasible indices ``bad`` (n, m) of problems ``idx`` in ``F``, in place.

    Block exchange while the count of infeasible indices falls (or within three chances);
    then Murty's backup: exchange only the largest infeasible index.
    """
    n_bad = bad.sum(axis=1)
    better = n_bad < best[idx]
    best[idx] = np.where(better, n_bad, best[idx])
    chances[idx] = np.where(better, 3, chances[idx] - (~better))
    full = better | (chances[idx] >= 0)
    flip = bad.copy()
    single = np.flatnonzero(~full)
    if len(single):
        last = bad.shape[1] - 1 - np.argmax(bad[single][:, ::-1], axis=1)
        flip[single] = False
        flip[single, last] = True
    F[idx] ^= flip


def _solve_points(G: PointShapeStack, d: np.ndarray, valid: np.ndarray, F: np.ndarray,
                  max_iter: int, tol: float, product: Optional[np.ndarray]
                  ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`solve_lcp_batch` on a :class:`PointShapeStack` (``F`` is the warm start).

    Each round sorts every problem's candidates free first (index order kept within both
    parts), builds the columns of its ``k`` (largest free count) first points, solves the
    leading ``k x k`` block (identity rows for the padding of problems with fewer free
    indices) and takes ``w = G x - d`` from the same columns.
    """
    B, m = d.shape
    x = np.zeros((B, m))
    u = np.zeros((B, m))
    iterations = np.zeros(B, dtype=np.int64)
    eps = tol * np.maximum(np.abs(np.where(valid, d, 0.0)).max(axis=1), 1e-300)
    best = np.full(B, m + 1)
    chances = np.full(B, 3)
    eye = np.eye(m, dtype=bool)
    todo = np.flatnonzero(valid.any(axis=1))
    for _ in range(max_iter):
        if len(todo) == 0:
            break
        n = len(todo)
        Ft = F[todo]
        k = max(int(Ft.sum(axis=1).max()), 1)
        perm = np.argsort(~Ft, axis=1, kind='stable')        # free indices first
        rows = np.arange(n)[:, None]
        dp = d[todo[:, None], perm]
        Fk = Ft[rows, perm[:, :k]]
        cols = G.columns(todo, perm, k)                      # (n, m, k)
        A = cols[:, :k]
        if not Fk.all():
            A = np.where(Fk[:, :, None] & Fk[:, None, :], A, eye[:k, :k])
        y = _batched_solve(A, np.where(Fk, dp[:, :k], 0.0))[0]
        y[~Fk] = 0.0
        up = (cols @ y[:, :, None])[:, :, 0]
        iterations[todo] += 1
        xp = np.zeros((n, m))
        xp[:, :k] = y
        e = eps[todo, None]
        bad_p = np.zeros((n, m), dtype=bool)
        bad_p[:, :k] = Fk & (y < -e)
        bad_p[:, k:] = (up[:, k:] - dp[:, k:]) < -e   # not free (free ones all lie in :k)
        bad_p[:, :k] |= ~Fk & (up[:, :k] - dp[:, :k] < -e)
        bad = np.empty_like(bad_p)
        bad[rows, perm] = bad_p
        bad &= valid[todo]
        x[todo[:, None], perm] = xp
        done = ~bad.any(axis=1)
        if np.any(done):
            fin = np.flatnonzero(done)
            yc = np.maximum(y[fin], 0.0)
            uf = up[fin] if np.all(yc == y[fin]) else (cols[fin] @ yc[:, :, None])[:, :, 0]
            u[todo[fin][:, None], perm[fin]] = uf
        todo = _next_round(F, todo, done, bad, best, chances)
        if not len(todo):
            break
    if len(todo):
        dense = PointShapeStack(G.points[todo], G.c, G.decay,
                                None if G.decays is None else G.decays[todo], G.near).dense()
        _not_converged((dense @ x[todo][:, :, None])[:, :, 0] - d[todo], x[todo], valid[todo],
                       max_iter)
    x = np.maximum(x, 0.0)
    if product is not None:
        product[...] = u
    return x, _residuals(u - d, x, valid), iterations


def bpp_dense(G: np.ndarray, d: np.ndarray, free: Optional[np.ndarray] = None,
              max_iter: int = 200, tol: float = 1e-12) -> Tuple[np.ndarray, int]:
    """Block principal pivoting for one problem, without the padding of the stacked solver.

    Same pivoting rules as :func:`solve_lcp_batch`; returns ``(x, solves)``. No input checks
    (see :func:`solve_lcp`).

    Raises:
        NotConverged: still infeasible after ``max_iter`` rounds.

    """
    m = len(d)
    F = np.ones(m, dtype=bool) if free is None else np.asarray(free, dtype=bool).copy()
    eps = tol * max(float(np.abs(d).max()) if m else 0.0, 1e-300)
    best, chances = m + 1, 3
    x = np.zeros(m)
    for it in range(1, max_iter + 1):
        x = np.zeros(m)
        idx = np.flatnonzero(F)
        if len(idx):
            sub = G[idx[:, None], idx]
            # LAPACK's Cholesky solve directly: 2-4x less overhead than numpy.linalg.solve at
            # these sizes. Not positive definite (duplicate points): a tiny ridge.
            _, xf, info = lapack.dposv(sub, d[idx])
            if info != 0:
                scale = max(float(np.abs(np.diagonal(sub)).max()), 1.0)
                xf = np.linalg.solve(sub + 1e-9 * scale * np.eye(len(sub)), d[idx])
            x[idx] = xf
        w = G @ x - d
        bad = np.flatnonzero((F & (x < -eps)) | (~F & (w < -eps)))
        if len(bad) == 0:
            return np.maximum(x, 0.0), it
        if len(bad) < best:
            best, chances = len(bad), 3
            F[bad] ^= True
        elif chances > 0:
            chances -= 1
            F[bad] ^= True
        else:
            F[bad[-1]] ^= True
    raise NotConverged(f'LCP: still infeasible after {max_iter} pivoting rounds '
                       f'(residual {lcp_residual(G, d, np.maximum(x, 0.0)):.3g})')


def solve_lcp(G: np.ndarray, d: np.ndarray, free: Optional[np.ndarray] = None,
              tol: float = 1e-12) -> LcpSolution:
    """Solve ``0 <= G x - d _|_ x >= 0`` for one positive definite ``G`` (m, m), ``d`` (m,).

    Block principal pivoting with a backup rule (see :func:`solve_lcp_batch`). ``free`` (m,)
    bool optionally warm-starts the touching set.

    Raises:
        InvalidInput: shapes that disagree or non-finite entries.
        NotConverged: see :func:`solve_lcp_batch`.

    """
    G, d = _check_problem(G, d)
    x, it = bpp_dense(G, d, free=free, tol=tol)
    res = lcp_residual(G, d, x)
    scale = max(float(np.abs(d).max()) if len(d) else 0.0, 1e-300)
    return LcpSolution(x=x, w=G @ x - d, residual=res, iterations=it,
                       converged=bool(res <= 1e-9 * scale), method='bpp')


def solve_lcp_paper(G: np.ndarray, d: np.ndarray) -> LcpSolution:
    """Solve by the paper's scheme: assume every point touches, invert, drop negatives, repeat.

    Each round inverts ``G`` over the remaining points (``numpy.linalg.inv``, as described),
    removes every point whose actual displacement came out negative and repeats until none is
    negative. It stops within ``m`` rounds. Removed points are never re-admitted, so
    ``converged`` is ``False`` (and ``residual`` > 0) where a removed point ends up penetrated
    (``w < 0``).

    Raises:
        InvalidInput: shapes that disagree or non-finite entries.
        NotConverged: ``G`` singular over the remaining points (duplicate contact points:
            ``g = 1`` off the diagonal), which the scheme as written cannot handle.

    """
    G, d = _check_problem(G, d)
    m = len(d)
    active = np.ones(m, dtype=bool)
    x = np.zeros(m)
    rounds = 0
    while active.any():
        rounds += 1
        sub = np.ix_(active, active)
        try:
            xa = np.linalg.inv(G[sub]) @ d[active]
        except np.linalg.LinAlgError as exc:
            raise NotConverged('paper LCP scheme: G is singular over the touching points '
                               f'(duplicate contact points?): {exc}')
        x[:] = 0.0
        x[active] = xa
        negative = xa < 0.0
        if not negative.any():
            break
        idx = np.flatnonzero(active)
        active[idx[negative]] = False
    x[~active] = 0.0
    res = lcp_residual(G, d, x)
    scale = max(float(np.abs(d).max()) if m else 0.0, 1e-300)
    return LcpSolution(x=x, w=G @ x - d, residual=res, iterations=rounds,
                       converged=bool(res <= 1e-9 * scale), method='paper')
