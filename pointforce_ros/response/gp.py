"""A small Gaussian process over surface features, built for few points and fast refits.

Kernel over ``x = [p, rgb, n]`` (position centred and divided by the object size ``scale``)::

    k(x, x') = s2 * ( exp(-|dp|^2 / (2 lp^2) - |drgb|^2 / (2 lc^2) - |dn|^2 / (2 ln^2))
                      + tau * phi(x) . phi(x')  +  nugget * [x == x'] )

The optional linear term is Bayesian linear regression on a named basis ``phi``:

- ``rigid``: ``[n, p x n]`` (p centred and scaled). A hand-eye or camera extrinsic error
  ``(dt, dw)`` moves every surface point by ``dt + dw x p``, i.e. its contact onset along the
  normal by ``-(dt . n + dw . (p x n))``: exactly linear in this basis. Used for the onset.
- ``colour``: standardised RGB (stiffness that goes with the look of the material).
- ``none``.

An unknown constant mean is estimated by generalised least squares and its uncertainty is part
of the predictive variance (ordinary kriging). Hyperparameters ``(lp, lc, ln, tau, nugget)`` are
chosen on a fixed grid by the restricted (REML) likelihood plus weak log-normal priors on ``lp``
and ``nugget``; ``s2`` is profiled out in closed form under a scaled inverse-chi-square prior
``(prior_dof, prior_scale)``, so one point already gives a usable, prior-dominated answer. The
grid is evaluated as batched Choleskys: a refit takes milliseconds for tens of pokes and has no
random restarts (deterministic).
"""

from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

import numpy as np

from pointforce_ros.errors import InvalidInput, ModelNotReady

GROUPS = (slice(0, 3), slice(3, 6), slice(6, 9))
"""Feature groups of ``x``: position, colour, normal."""

BASES = ('none', 'rigid', 'colour')

GRID_CHUNK_ELEMENTS = 2_000_000
"""Most elements of one (chunk, n, n) array of the grid search (16 MB): :meth:`FeatureGp.fit`
evaluates fewer grid points at once for many training points, not more memory."""


@dataclass(frozen=True)
class GpGrid:
    """Hyperparameter grid and priors.

    Attributes:
        position: length scales, as fractions of the object size ``scale``.
        colour: length scales in RGB units (``inf`` = colour ignored by the RBF part).
        normal: length scales in unit-normal units (``inf`` = normal ignored by the RBF part).
        linear: weights ``tau`` of the linear-basis term (0 = off).
        nugget: white-noise variance as a fraction of ``s2``.
        position_prior: (median fraction, log-sd) of the log-normal prior on ``lp``.
        nugget_prior: (median, log-sd) of the log-normal prior on the nugget.

    """

    position: Sequence[float] = tuple(np.geomspace(0.04, 3.0, 12))
    colour: Sequence[float] = (np.inf, 0.3)
    normal: Sequence[float] = (np.inf, 0.5)
    linear: Sequence[float] = (0.0, 0.3, 3.0)
    nugget: Sequence[float] = (1e-4, 1e-3, 1e-2, 0.05, 0.2, 1.0)
    position_prior: tuple = (0.3, 1.5)
    nugget_prior: tuple = (0.01, 3.0)

    def combos(self) -> np.ndarray:
        """(C, 5) rows ``(lp, lc, ln, tau, nugget)``."""
        return np.array([(lp, lc, ln, tau, nug) for lp in self.position for lc in self.colour
                         for ln in self.normal for tau in self.linear for nug in self.nugget],
                        dtype=float)


@dataclass(frozen=True)
class GpState:
    """Hyperparameters of a fitted process (JSON-serialisable via :meth:`to_dict`)."""

    lp: float
    lc: float
    ln: float
    tau: float
    nugget: float
    s2: float
    beta: float

    def to_dict(self) -> dict:
        """Return plain floats; ``inf`` is written as ``None``."""
        return {k: (None if not np.isfinite(v) else float(v)) for k, v in self.__dict__.items()}

    @classmethod
    def from_dict(cls, data: Mapping) -> 'GpState':
        """Inverse of :meth:`to_dict`."""
        return cls(**{k: (np.inf if data[k] is None else float(data[k]))
                      for k in ('lp', 'lc', 'ln', 'tau', 'nugget', 's2', 'beta')})


@dataclass(frozen=True)
class FeatureFrame:
    """How raw features are centred and scaled (fixed at fit time, saved with the model).

    Attributes:
        centre: (3,) metres, subtracted from positions.
        scale: metres, positions are divided by it (the object size).
        colour_mean: (3,) subtracted from colours for the ``colour`` basis.
        colour_scale: colours are divided by it for the ``colour`` basis.

    """

    centre: tuple
    scale: float
    colour_mean: tuple = (0.5, 0.5, 0.5)
    colour_scale: float = 0.25

    def to_dict(self) -> dict:
        """Plain JSON types."""
        return {'centre': [float(v) for v in self.centre], 'scale': float(self.scale),
                'colour_mean': [float(v) for v in self.colour_mean],
                'colour_scale': float(self.colour_scale)}

    @classmethod
    def from_dict(cls, data: Mapping) -> 'FeatureFrame':
        """Inverse of :meth:`to_dict`."""
        return cls(centre=tuple(data['centre']), scale=float(data['scale']),
                   colour_mean=tuple(data['colour_mean']),
                   colour_scale=float(data['colour_scale']))

    @classmethod
    def of_surface(cls, points: np.ndarray, colors: np.ndarray) -> 'FeatureFrame':
        """Frame of a surface: centroid, bounding-box diagonal, colour mean and spread."""
        ext = points.max(axis=0) - points.min(axis=0) if len(points) else np.zeros(3)
        cstd = float(colors.std()) if len(colors) else 0.0
        return cls(centre=tuple(points.mean(axis=0)) if len(points) else (0.0, 0.0, 0.0),
                   scale=float(max(np.linalg.norm(ext), 1e-3)),
                   colour_mean=tuple(colors.mean(axis=0)) if len(colors) else (0.5,) * 3,
                   colour_scale=max(cstd, 0.05))


def _sqdist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) squared distances; put the longer set second (numpy inner loops)."""
    d2 = np.einsum('ij,ij->i', a, a)[:, None] - 2.0 * (a @ b.T)
    d2 += np.einsum('ij,ij->i', b, b)[None, :]
    return np.maximum(d2, 0.0, out=d2)


def _inv_len2(length) -> np.ndarray:
    if isinstance(length, float):       # scalar fast path (conditioning, prediction)
        return 1.0 / (length * length) if np.isfinite(length) else 0.0
    length = np.asarray(length, dtype=float)
    return np.where(np.isfinite(length), 1.0 / np.where(np.isfinite(length), length, 1.0) ** 2,
                    0.0)


class FeatureGp:
    """Scalar GP ``y(x)`` over (N, 9) surface features; see the module docstring.

    Args:
        frame: centring and scaling of the features.
        prior_scale: prior standard deviation of ``y`` about its mean (its units).
        prior_dof: pseudo-count of that prior (0 = none; needs >= 2 points then).
        basis: linear-term basis, one of ``none``, ``rigid``, ``colour``.
        grid: hyperparameter grid.

    Raises:
        InvalidInput: non-positive ``prior_scale``, negative ``prior_dof``, unknown basis.

    """

    def __init__(self, frame: FeatureFrame, prior_scale: float, prior_dof: float = 1.0,
                 basis: str = 'none', grid: Optional[GpGrid] = None):
        if not (np.isfinite(prior_scale) and prior_scale > 0):
            raise InvalidInput(f'FeatureGp: prior_scale must be > 0, got {prior_scale}')
        if not prior_dof >= 0:
            raise InvalidInput(f'FeatureGp: prior_dof must be >= 0, got {prior_dof}')
        if basis not in BASES:
            raise InvalidInput(f'FeatureGp: basis must be one of {BASES}, got {basis!r}')
        self.frame = frame
        self.prior_scale = float(prior_scale)
        self.prior_dof = float(prior_dof)
        self.basis = basis
        self.grid = grid or GpGrid()
        self.state: Optional[GpState] = None
        self._z = None
        self._phi = None
        self._chol = None
        self._chol_inv = None
        self._alpha = None
        self._rinv1 = None
        self._one_rinv_one = None

    def _prepare(self, features: np.ndarray, groups: bool = True, basis: bool = True):
        """Scaled (position, colour, normal) arrays and the linear basis (M, B) of features."""
        f = np.asarray(features, dtype=float)
        pos = (f[:, 0:3] - np.asarray(self.frame.centre)) / self.frame.scale
        col = f[:, 3:6]
        nor = f[:, 6:9]
        phi = None
        if basis:
            if self.basis == 'rigid':
                phi = np.hstack([nor, np.cross(pos, nor)])
            elif self.basis == 'colour':
                phi = (col - np.asarray(self.frame.colour_mean)) / self.frame.colour_scale \
                    / np.sqrt(3.0)
            else:
                phi = np.zeros((len(f), 0))
        return ((pos, col, nor) if groups else None), phi

    def fit(self, features: np.ndarray, y: np.ndarray, chunk: int = 512,
            noise: Optional[np.ndarray] = None) -> GpState:
        """Choose hyperparameters on the grid and condition on ``(features, y)``.

        ``noise``: optional (n,) factors >= 1 on each point's nugget (a point known to
        scatter more about the smooth field pulls its neighbours less); ``None``: all 1.

        Raises:
            InvalidInput: shapes disagree, NaN, no points, or one point without a prior.

        """
        features = np.asarray(features, dtype=float)
        y = np.asarray(y, dtype=float)
        if features.ndim != 2 or features.shape[1] != 9 or len(features) != len(y) \
                or len(y) == 0:
            raise InvalidInput(f'FeatureGp.fit: need (n, 9) features and (n,) targets, got '
                               f'{features.shape} and {y.shape}')
        if not (np.all(np.isfinite(features)) and np.all(np.isfinite(y))):
            raise InvalidInput('FeatureGp.fit: non-finite features or targets')
        n = len(y)
        dof = n - 1 + self.prior_dof
        if dof <= 0:
            raise InvalidInput('FeatureGp.fit: one point and no prior (prior_dof = 0)')
        groups, phi = self._prepare(features)
        d2 = np.stack([_sqdist(g, g) for g in groups], axis=-1)              # (n, n, 3)
        lin = phi @ phi.T
        combos = self.grid.combos()
        if phi.shape[1] == 0:
            combos = combos[combos[:, 3] == combos[0, 3]]
            combos[:, 3] = 0.0
        best_val, best = -np.inf, None
        eye = np.diag(self._noise(noise, n))
        rhs = np.stack([np.ones(n), y], axis=1)
        # a chunk holds a few (chunk, n, n) arrays: at most GRID_CHUNK_ELEMENTS each
        chunk = max(1, min(int(chunk), GRID_CHUNK_ELEMENTS // (n * n)))
        for extra, fields in self._kernel_terms(d2):
            for lo in range(0, len(combos), chunk):
                c = combos[lo:lo + chunk]
                scored = self._score_grid(c, d2, lin, eye, rhs, dof, extra)
                if scored is None:
                    continue
                val, s2, beta = scored
                j = int(np.argmax(val))
                if val[j] > best_val:
                    best_val = float(val[j])
                    best = self._state(c[j], float(s2[j]), float(beta[j]), fields)
        if best is None:
            raise InvalidInput('FeatureGp.fit: no hyperparameters give a positive-definite '
                               'kernel (duplicate pokes with different values?)')
        self.condition(features, y, best, noise)
        return best

    def _kernel_terms(self, d2: np.ndarray):
        """``(term, fields)`` pairs :meth:`fit` scores the whole grid with.

        ``term`` is added to every grid row's correlation matrix (``d2``: the training points'
        (n, n, 3) squared distances per feature group), ``fields`` go to :meth:`_state`. One
        pair, no term: the kernel of the module docstring (a study may offer more).
        """
        return ((0.0, {}),)

    @staticmethod
    def _state(row: np.ndarray, s2: float, beta: float, fields: Mapping) -> GpState:
        """Return the state of grid row ``(lp, lc, ln, tau, nugget)`` (``fields``: none here)."""
        return GpState(*(float(v) for v in row[:5]), s2=s2, beta=beta, **fields)

    def _score_grid(self, c: np.ndarray, d2: np.ndarray, lin: np.ndarray, eye: np.ndarray,
                    rhs: np.ndarray, dof: float, extra=0.0):
        """``(value, s2, beta)`` (C,) of the grid rows ``c``, or ``None`` (not positive-definite).

        ``value``: the restricted log likelihood plus the priors of :meth:`fit`; ``extra``: a
        correlation term added to every row's kernel (0: none).
        """
        n = len(rhs)
        inv = np.stack([_inv_len2(c[:, 0]), _inv_len2(c[:, 1]), _inv_len2(c[:, 2])], axis=1)
        r = np.exp(-0.5 * np.einsum('ijg,cg->cij', d2, inv))
        r += c[:, 3, None, None] * lin[None] + c[:, 4, None, None] * eye[None]
        r += extra
        try:
            chol = np.linalg.cholesky(r)
        except np.linalg.LinAlgError:
            return None
        # One batched forward solve: w = L^-1 [1, y] gives every quadratic form needed.
        w = np.linalg.solve(chol, np.broadcast_to(rhs, (len(c), n, 2)))
        one_r_one = (w[:, :, 0] ** 2).sum(axis=1)
        one_r_y = (w[:, :, 0] * w[:, :, 1]).sum(axis=1)
        beta = one_r_y / one_r_one
        quad = np.maximum((w[:, :, 1] ** 2).sum(axis=1) - beta * one_r_y, 0.0)
        s2 = (quad + self.prior_dof * self.prior_scale ** 2) / dof
        logdet = 2.0 * np.log(np.diagonal(chol, axis1=1, axis2=2)).sum(axis=1)
        val = -0.5 * (dof * np.log(s2) + logdet + np.log(one_r_one))
        mu_p, sd_p = self.grid.position_prior
        mu_n, sd_n = self.grid.nugget_prior
        val -= 0.5 * ((np.log(c[:, 0] / mu_p) / sd_p) ** 2
                      + (np.log(c[:, 4] / mu_n) / sd_n) ** 2)
        return val, s2, beta

    @staticmethod
    def _noise(noise: Optional[np.ndarray], n: int) -> np.ndarray:
        if noise is None:
            return np.ones(n)
        noise = np.asarray(noise, dtype=float)
        if noise.shape != (n,) or not np.all(np.isfinite(noise)) or np.any(noise < 1.0):
            raise InvalidInput(f'FeatureGp: noise factors must be ({n},) finite and >= 1')
        return noise

    def condition(self, features: np.ndarray, y: np.ndarray, state: GpState,
                  noise: Optional[np.ndarray] = None) -> None:
        """Condition on data with given hyperparameters (used by fit and by loading).

        ``noise``: the per-point nugget factors of :meth:`fit`.
        """
        features = np.asarray(features, dtype=float)
        y = np.asarray(y, dtype=float)
        self.state = state
        groups, phi = self._prepare(features)
        self._z = groups
        self._phi = phi
        noise = self._noise(noise, len(y))
        r = self._corr(groups, phi, groups, phi) + state.nugget * np.diag(noise)
        chol = np.linalg.cholesky(r)
        self._chol = chol
        inv = np.linalg.inv(chol)                        # n is small (pokes): explicit is fine
        self._chol_inv = inv
        self._rinv1 = inv.T @ (inv @ np.ones(len(y)))
        self._one_rinv_one = float(self._rinv1.sum())
        self._alpha = inv.T @ (inv @ (y - state.beta))

    def loo_z2(self) -> np.ndarray:
        """(n,) squared standardised leave-one-out residuals of the conditioned targets.

        Closed form for fixed hyperparameters and the fitted constant mean: with
        ``K`` the correlation (nugget included), the residual of point ``i`` predicted from the
        others is ``[K^-1 (y - beta)]_i / [K^-1]_ii`` with variance ``s2 / [K^-1]_ii``. Their
        mean is about 1 when the predictive spread is calibrated.

        Raises:
            ModelNotReady: not conditioned yet.

        """
        if self._chol_inv is None:
            raise ModelNotReady('FeatureGp: not conditioned')
        kinv_diag = np.einsum('ij,ij->j', self._chol_inv, self._chol_inv)
        return self._alpha ** 2 / (kinv_diag * self.state.s2)

    def gls_mean_scale(self, y: np.ndarray):
        """``(beta, s2)`` of other targets ``y`` on the points this process is conditioned on.

        The generalised-least-squares constant mean and the profiled signal variance (with
        this process's prior), as :meth:`fit` computes them, for targets that share the
        kernel: several outputs then need one Cholesky.

        Raises:
            ModelNotReady: not conditioned yet.

        """
        if self._chol_inv is None:
            raise ModelNotReady('FeatureGp: not conditioned')
        y = np.asarray(y, dtype=float)
        beta = float(self._rinv1 @ y / self._one_rinv_one)
        w = self._chol_inv @ (y - beta)
        s2 = float((w @ w + self.prior_dof * self.prior_scale ** 2)
                   / (len(y) - 1 + self.prior_dof))
        return beta, s2

    def _corr(self, ga, pa, gb, pb) -> np.ndarray:
        st = self.state
        expo = np.zeros((len(ga[0]), len(gb[0])))
        for a, b, length in zip(ga, gb, (st.lp, st.lc, st.ln)):
            w = float(_inv_len2(length))
            if w:
                expo -= 0.5 * w * _sqdist(a, b)
        out = np.exp(expo)
        if st.tau and pa.shape[1]:
            out += st.tau * (pa @ pb.T)
        return out

    def needs(self) -> tuple:
        """Feature groups (0 position, 1 colour, 2 normal) the RBF part of the kernel uses."""
        st = self.state
        return tuple(g for g, length in enumerate((st.lp, st.lc, st.ln)) if np.isfinite(length))

    def cross_sqdist(self, features: np.ndarray, groups: Sequence[int] = (0, 1, 2)) -> dict:
        """``{group: (n, M) squared distances}`` of the n training points to ``features``.

        Laid out training-point-major so numpy's inner loops run over the M queries.
        Processes conditioned on the same features and frame can share it (see
        :meth:`predict`'s ``sq``); missing groups are filled in on demand.
        """
        scaled, _ = self._prepare(features, basis=False)
        return {g: _sqdist(self._z[g], scaled[g]) for g in groups}

    def predict(self, features: np.ndarray, return_std: bool = False, *,
                include_nugget: bool = True, sq: Optional[dict] = None):
        """Mean (M,) and optionally standard deviation (M,) of ``y`` at (M, 9) ``features``.

        The variance includes the uncertainty of the constant mean and, with
        ``include_nugget``, the white-noise term (a new poke's parameter scatters about the
        smooth field by that much). ``sq`` is an optional cache of :meth:`cross_sqdist`
        shared by processes conditioned on the same points; it is filled in as needed.

        Raises:
            ModelNotReady: not fitted.

        """
        if self.state is None:
            raise ModelNotReady('FeatureGp: not fitted')
        st = self.state
        features = np.asarray(features, dtype=float)
        _, phi = self._prepare(features, groups=False)
        sq = {} if sq is None else sq
        missing = [g for g in self.needs() if g not in sq]
        if missing:
            sq.update(self.cross_sqdist(features, missing))
        kt = np.zeros((len(self._alpha), len(features)))                 # (n, M)
        for g in self.needs():
            kt -= (0.5 * float(_inv_len2((st.lp, st.lc, st.ln)[g]))) * sq[g]
        np.exp(kt, out=kt)
        if st.tau and phi.shape[1]:
            kt += st.tau * (self._phi @ phi.T)
        mean = st.beta + self._alpha @ kt
        if not return_std:
            return mean
        v = self._chol_inv @ kt                                              # (n, M)
        u = 1.0 - self._rinv1 @ kt
        prior = 1.0 + (st.tau * np.einsum('ij,ij->i', phi, phi) if phi.shape[1] else 0.0)
        var = prior - np.einsum('ij,ij->j', v, v) + u * u / self._one_rinv_one
        if include_nugget:
            var = var + st.nugget
        return mean, np.sqrt(np.maximum(var, 0.0) * st.s2)
