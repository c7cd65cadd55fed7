"""Ours: a monotone contact law per poke whose parameters a Gaussian process spreads over x.

The seed's Extra-Trees regressor treats ``(x, d)`` as ten anonymous inputs. Three facts it does
not use are built in here:

1. **Zero before contact, monotone in depth.** Each poke's loading curve is fitted with
   ``f = F * ((d - d0)_+ / s_ref) ** p`` (``F`` = force at the reference contact depth
   ``s_ref``, ``p`` > 0), which is zero before the onset ``d0`` (where camera bias puts it)
   and increasing after it, and extrapolates beyond the poked depth like the material does
   (``p = 1.5`` is Hertz for a sphere; ``p`` is fitted).
2. **Smooth over the surface.** The parameters ``theta = (d0, log F, p)`` vary smoothly over
   the object: each is a Gaussian process over ``x = [p, rgb, n]`` (:mod:`.gp`; position
   dominates, colour and normal enter when the likelihood says they help).
3. **Uncertainty.** The processes give a mean and a standard deviation of ``theta`` anywhere;
   the force's standard deviation follows by the delta method::

       var f = f^2 var(log F) + (f log(s / s_ref))^2 var(p) + (f p / s)^2 var(d0)

   (zero before the predicted onset; the ``d0`` term dominates just after it).

4. **No extrapolation beyond the pokes.** Far from every poke (the object's sides, a corner
   the pokes never reached) a process's mean follows its basis and hyperparameters, not data.
   The predicted parameters are therefore kept within what the pokes showed: the onset within
   the pokes' detected onsets +- :data:`ONSET_MARGIN`, ``log F`` within the fitted values +-
   :data:`LOG_FORCE_MARGIN`, ``p`` within the fitted exponents. On lamb one stiffening curve
   fitted ``d0`` 2 mm before its detected onset, and the onset process spread -5 mm onsets
   over the sides: a line probe then touched them early and the predicted force tripled.

5. **The three processes spread decorrelated parameters.** One curve's ``(d0, log F, p)`` trade
   against each other (an earlier onset with a softer, steeper law fits the same curve), and
   over an object they move together: on the simulated cell's lamb and dome their pairwise
   correlations are 0.94-1.00. Spread by three independent processes, each parameter misses
   by its own error and the combination falls off the curve family the pokes showed (lamb, 10
   pokes: a held-out poke's own ``log F`` with a predicted onset and exponent scores 4.2 N
   RMSE, worse than all three predicted, 0.56 N). So the processes spread ``y = L^-1 z``: ``z``
   the parameters standardised over the training pokes, ``L`` the Cholesky factor of their
   covariance in the order ``(d0, log F, p)``, shrunk towards the identity by
   :data:`DECORRELATE_PRIOR_POKES` pseudo-pokes (a covariance from five pokes alone gave rare
   but large misses). ``y_0`` is the onset, ``y_1`` the part of ``log F`` the onset does not
   explain, ``y_2`` the rest of ``p``. A prediction maps back with ``L``; the parameters'
   standard deviations combine the components'. With fewer than
   :data:`DECORRELATE_MIN_POKES` pokes the processes are independent, as before. Measured
   by :mod:`pointforce_ros.lab.figures`, figure 1 (``ours`` against ``ours_independent``).

A refit is: one bounded least-squares fit for the new poke (cached for the others), then three
small GP fits on a fixed hyperparameter grid; baking 40 000 points is a handful of (N, K) numpy
expressions (see :mod:`.bench` for timings).
"""

import time
from typing import List, Mapping, Optional, Sequence, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import fit_power_onset, PokeCurve
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.response.common import (check_curves, check_depths, check_query,
                                            curve_features, DEFAULT_MAX_SURFACE_DISTANCE,
                                            single_threaded_blas)
from pointforce_ros.response.gp import BASES, FeatureFrame, FeatureGp, GpGrid, GpState
from pointforce_ros.types import Surface

KIND = 'pointforce.response.contact_gp'
FORMAT = 1
PARAMS = ('d0', 'log_force', 'exponent')
ONSET_MARGIN = 0.0005
"""How far (m) a predicted onset may lie outside the training pokes' detected onsets."""
LOG_FORCE_MARGIN = 0.3
"""How far a predicted ``log F`` may lie outside the training pokes' fitted values."""
DECORRELATE_MIN_POKES = 3
"""Fewest pokes whose parameter covariance the processes are decorrelated with."""
DECORRELATE_RIDGE = 1e-3
"""Added to the diagonal of the standardised parameters' covariance (keeps it invertible)."""
DECORRELATE_PRIOR_POKES = 2.0
"""Pseudo-pokes of zero correlation the parameter covariance is shrunk with."""
SCALE_FLOOR = np.array([1e-5, 1e-3, 1e-3])
"""Smallest standard deviation of ``(d0 [m], log F, p)`` used to standardise them."""


class ContactGpModel:
    """Per-poke monotone contact law + GP over the surface (see the module docstring).

    Args:
        ref_depth: reference contact depth ``s_ref`` at which ``F`` is defined, metres.
        exponent_bounds: allowed range of the contact exponent ``p``.
        prior_scales: prior standard deviations of ``(d0 [m], log F, p)`` about their mean
            over the object (they matter only with very few pokes).
        max_surface_distance: farthest a poke may be from the surface, metres.
        bases: linear-term basis of the process of each parameter ``(d0, log F, p)``:
            ``rigid`` (camera extrinsic error: the onset's natural structure), ``colour``,
            ``none`` (see :mod:`.gp`).
        grid: GP hyperparameter grid (:class:`~pointforce_ros.response.gp.GpGrid`).
        decorrelate: spread decorrelated parameters (module docstring, point 5); ``False``
            spreads ``d0``, ``log F`` and ``p`` by independent processes.

    Raises:
        InvalidInput: non-positive ``ref_depth`` or prior scales, bad exponent bounds.

    """

    kind = KIND

    def __init__(self, ref_depth: float = 0.003, exponent_bounds=(0.7, 3.5),
                 prior_scales=(0.003, 1.0, 0.4),
                 max_surface_distance: float = DEFAULT_MAX_SURFACE_DISTANCE,
                 bases=('rigid', 'colour', 'none'), grid: Optional[GpGrid] = None,
                 decorrelate: bool = True):
        if not (np.isfinite(ref_depth) and ref_depth > 0):
            raise InvalidInput(f'ContactGpModel: ref_depth must be > 0 m, got {ref_depth}')
        lo, hi = (float(v) for v in exponent_bounds)
        if not (0 < lo < hi):
            raise InvalidInput(f'ContactGpModel: exponent_bounds must satisfy 0 < lo < hi, got '
                               f'{exponent_bounds}')
        scales = np.asarray(prior_scales, dtype=float)
        if scales.shape != (3,) or not np.all(scales > 0):
            raise InvalidInput('ContactGpModel: prior_scales must be three positive numbers')
        self.ref_depth = float(ref_depth)
        self.exponent_bounds = (lo, hi)
        self.prior_scales = tuple(float(s) for s in scales)
        self.max_surface_distance = float(max_surface_distance)
        bases = tuple(bases)
        if len(bases) != 3 or any(b not in BASES for b in bases):
            raise InvalidInput(f'ContactGpModel: bases must be three of {BASES}, got {bases}')
        self.bases = bases
        self.grid = grid or GpGrid()
        self.decorrelate = bool(decorrelate)
        self.version = 0
        self._ids: List[str] = []
        self._features = np.zeros((0, 9))
        self._theta = np.zeros((0, 3))
        self._onsets = np.zeros(0)
        self._fit_rms = np.zeros(0)
        self._frame: Optional[FeatureFrame] = None
        self._gps: Optional[List[FeatureGp]] = None
        self._mix: Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]] = None
        self._surface: Optional[Surface] = None
        self.fit_seconds = 0.0

    # ----------------------------------------------------------------------------- fitting
    @property
    def poke_ids(self) -> List[str]:
        """Ids of the training pokes, in training order."""
        return list(self._ids)

    @property
    def poke_points(self) -> np.ndarray:
        """(n, 3) surface positions of the training pokes, metres, ``base``."""
        return self._features[:, :3].copy()

    @property
    def poke_params(self) -> np.ndarray:
        """(n, 3) per-poke ``(d0 [m], log F [log N], p)`` fitted to each training curve."""
        return self._theta.copy()

    def fit_curve(self, curve: PokeCurve) -> Tuple[np.ndarray, float]:
        """Fit the contact law to one curve; return ``((d0, log F, p), rms)``; stores nothing.

        Raises:
            InvalidInput: the curve has no force above zero (nothing to fit).

        """
        if not np.any(curve.f > 0):
            raise InvalidInput(f'poke {curve.poke_id}: no positive force, cannot fit a contact '
                               'law')
        with single_threaded_blas():
            fit = fit_power_onset(curve.d, curve.f, with_bias=False,
                                  exponent_bounds=self.exponent_bounds, max_samples=600)
        force_ref = max(fit.a * self.ref_depth ** fit.p, 1e-9)
        return np.array([fit.d0, np.log(force_ref), fit.p]), float(fit.rms)

    def fit(self, curves: Sequence[PokeCurve], surface: Surface) -> 'ContactGpModel':
        """Fit from scratch on ``curves`` poked on ``surface``; returns ``self``.

        Raises:
            InvalidInput: no curves, duplicate ids, pokes off the surface, curves without force.

        """
        start = time.perf_counter()
        curves = check_curves(curves, surface)
        feats = curve_features(curves, surface, self.max_surface_distance)
        fits = [self.fit_curve(c) for c in curves]
        self._ids = [c.poke_id for c in curves]
        self._features = feats
        self._theta = np.stack([th for th, _ in fits])
        self._onsets = np.array([c.onset_d for c in curves], dtype=float)
        self._fit_rms = np.array([rms for _, rms in fits])
        self._frame = FeatureFrame.of_surface(surface.points, surface.colors)
        self._surface = surface
        self._fit_processes()
        self.fit_seconds = time.perf_counter() - start
        return self

    def partial_fit(self, curve: PokeCurve, surface: Optional[Surface] = None
                    ) -> 'ContactGpModel':
        """Add one poke (earlier per-poke fits are reused) and refit the processes.

        Raises:
            InvalidInput: duplicate poke id, no surface known yet, poke off the surface.

        """
        start = time.perf_counter()
        surface = surface if surface is not None else self._surface
        if surface is None:
            raise InvalidInput('partial_fit: pass the surface (the model has not seen one)')
        check_curves([curve], surface)
        if curve.poke_id in self._ids:
            raise InvalidInput(f'partial_fit: poke {curve.poke_id} is already in the model')
        feat = curve_features([curve], surface, self.max_surface_distance)
        theta, rms = self.fit_curve(curve)
        self._ids.append(curve.poke_id)
        self._features = np.vstack([self._features, feat])
        self._theta = np.vstack([self._theta, theta[None]])
        self._onsets = np.append(self._onsets, float(curve.onset_d))
        self._fit_rms = np.append(self._fit_rms, rms)
        if self._frame is None or surface is not self._surface:
            self._frame = FeatureFrame.of_surface(surface.points, surface.colors)
        self._surface = surface
        self._fit_processes()
        self.fit_seconds = time.perf_counter() - start
        return self

    def _fit_processes(self, states: Optional[Sequence[GpState]] = None) -> None:
        with single_threaded_blas():
            self._fit_processes_inner(states)

    def _decorrelation(self) -> Tuple[np.ndarray, np.ndarray, np.ndarray, Tuple[float, ...]]:
        """``(mu, scale, L, priors)``: ``theta = mu + scale * (L @ y)`` (module docstring, 5).

        ``priors``: the prior scale of each process of ``y``. A function of the training
        parameters only, so a loaded model recomputes it. Independent processes (``L = I``)
        keep ``theta`` itself as the targets (``mu = 0``, ``scale = 1``, the configured prior
        scales), as models saved before decorrelation expect.
        """
        theta = self._theta
        if not self.decorrelate or len(theta) < DECORRELATE_MIN_POKES:
            return np.zeros(3), np.ones(3), np.eye(3), self.prior_scales
        mu = theta.mean(axis=0)
        scale = np.maximum(theta.std(axis=0), SCALE_FLOOR)
        z = (theta - mu) / scale
        n = len(z)
        cov = (z.T @ z + DECORRELATE_PRIOR_POKES * np.eye(3)) / (n + DECORRELATE_PRIOR_POKES)
        cov += DECORRELATE_RIDGE * np.eye(3)
        return mu, scale, np.linalg.cholesky(cov), (1.0, 1.0, 1.0)

    def _fit_processes_inner(self, states: Optional[Sequence[GpState]]) -> None:
        mu, scale, chol, priors = self._decorrelation()
        y = np.linalg.solve(chol, ((self._theta - mu) / scale).T).T
        gps = []
        for j in range(3):
            gp = FeatureGp(self._frame, priors[j], basis=self.bases[j], grid=self.grid)
            if states is None:
                gp.fit(self._features, y[:, j])
            else:
                gp.condition(self._features, y[:, j], states[j])
            gps.append(gp)
        self._gps = gps
        self._mix = (mu, scale, chol)
        lo, hi = self._theta.min(axis=0), self._theta.max(axis=0)
        self._param_bounds = (
            np.array([self._onsets.min() - ONSET_MARGIN, lo[1] - LOG_FORCE_MARGIN,
                      max(lo[2], self.exponent_bounds[0])]),
            np.array([self._onsets.max() + ONSET_MARGIN, hi[1] + LOG_FORCE_MARGIN,
                      min(hi[2], self.exponent_bounds[1])]))
        if states is None:
            self.version += 1

    # ---------------------------------------------------------------------------- prediction
    def _require(self) -> None:
        if self._gps is None:
            raise ModelNotReady('ContactGpModel: no pokes yet; fit the model first')

    def predict_params(self, features: np.ndarray, return_std: bool = False):
        """Mean (M, 3) and optionally std (M, 3) of ``(d0 [m], log F, p)`` at ``features``.

        The means are kept within the training pokes' range (module docstring, point 4); the
        std is the process's own (it still grows away from the pokes).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: features not (M, 9) or not finite.

        """
        self._require()
        features, _ = check_query(features, 0.0)
        sq = {}
        with single_threaded_blas():
            out = [gp.predict(features, return_std=return_std, sq=sq) for gp in self._gps]
        mu, scale, chol = self._mix
        y = np.stack([o[0] for o in out] if return_std else out, axis=1)
        mean = np.clip(mu + scale * (y @ chol.T), *self._param_bounds)
        if not return_std:
            return mean
        var_y = np.stack([o[1] for o in out], axis=1) ** 2
        return mean, scale * np.sqrt(var_y @ (chol ** 2).T)

    def _law(self, d0, log_f, p, d, dtype=np.float64):
        """Force ``f``, ``s = d - d0`` and ``log(s / s_ref)`` of the contact law.

        All arguments broadcast against each other (queries: all (M,); bake: parameters
        (1, N) against depths (K, 1), so numpy's inner loops run over the N points). Where
        ``s <= 0`` the force is 0 (the log is then meaningless but finite). ``dtype`` float32
        halves the work of a bake.
        """
        s = np.asarray(d, dtype=dtype) - np.asarray(d0, dtype=dtype)
        log_rel = np.maximum(s, dtype(1e-9))
        log_rel *= dtype(1.0 / self.ref_depth)
        np.log(log_rel, out=log_rel)
        f = np.asarray(p, dtype=dtype) * log_rel
        f += np.asarray(log_f, dtype=dtype)
        np.exp(f, out=f)
        f *= s > 0
        return f, s, log_rel

    def _std(self, p, sd_d0, sd_log_f, sd_p, f, s, log_rel):
        """Delta-method force std (same shape as ``f``) from the parameters' std."""
        dtype = f.dtype.type
        var = np.asarray(p, dtype=dtype) / np.maximum(s, dtype(1e-9))
        var *= np.asarray(sd_d0, dtype=dtype)
        var *= var
        term = log_rel * np.asarray(sd_p, dtype=dtype)
        term *= term
        var += term
        var += np.asarray(sd_log_f, dtype=dtype) ** 2
        np.sqrt(var, out=var)
        var *= f
        return var

    def predict(self, features: np.ndarray, d) -> np.ndarray:
        """Mean force (M,), newtons, at ``features`` (M, 9) and depths ``d`` (M,) metres.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        self._require()
        features, d = check_query(features, d)
        theta = self.predict_params(features)
        f, _, _ = self._law(theta[:, 0], theta[:, 1], theta[:, 2], d)
        return f

    def force_from_params(self, params, d) -> np.ndarray:
        """Force (M,), newtons, of the contact law with per-row ``params`` (M, 3) at ``d`` (M,).

        ``params`` are ``(d0 [m], log F, p)`` as :attr:`poke_params` and :meth:`predict_params`
        give them (for example a held-out poke's own fit, in an error budget).

        Raises:
            InvalidInput: shapes disagree or values are not finite.

        """
        params = np.asarray(params, dtype=float)
        d = np.asarray(d, dtype=float)
        if params.ndim != 2 or params.shape[1] != 3 or d.shape != (len(params),) \
                or not (np.all(np.isfinite(params)) and np.all(np.isfinite(d))):
            raise InvalidInput(f'force_from_params: need finite (M, 3) params and (M,) depths, '
                               f'got {params.shape} and {d.shape}')
        f, _, _ = self._law(params[:, 0], params[:, 1], params[:, 2], d)
        return f

    def predict_std(self, features: np.ndarray, d) -> np.ndarray:
        """Predictive standard deviation (M,) of the force curve, newtons (delta method).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        self._require()
        features, d = check_query(features, d)
        theta, sd = self.predict_params(features, return_std=True)
        f, s, log_rel = self._law(theta[:, 0], theta[:, 1], theta[:, 2], d)
        return self._std(theta[:, 2], sd[:, 0], sd[:, 1], sd[:, 2], f, s, log_rel)

    def bake(self, surface: Surface, depths) -> BakedResponse:
        """Tabulate force, std and extrapolation slope on every point of ``surface``.

        Args:
            surface: N points; features ``surface.features``.
            depths: (K,) strictly increasing displacement grid, metres; start it below the
                earliest onset (negative depths are fine) so the table begins at zero force.

        Returns:
            ``BakedResponse`` with forces (N, K), std (N, K) and slopes (N,) = the law's
            derivative ``F p s^(p-1) / s_ref^p`` at ``depths[-1]`` (0 where not yet in contact).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: bad grid or surface.

        """
        self._require()
        if not isinstance(surface, Surface):
            raise InvalidInput(f'bake: expected a Surface, got {type(surface).__name__}')
        depths = check_depths(depths)
        theta, sd = self.predict_params(surface.features, return_std=True)
        th, sdt = theta.T[:, None, :], sd.T[:, None, :]                 # (3, 1, N)
        f_t, s_t, log_t = self._law(th[0], th[1], th[2], depths[:, None], dtype=np.float32)
        std_t = self._std(th[2], sdt[0], sdt[1], sdt[2], f_t, s_t, log_t)  # (K, N) float32
        forces = np.ascontiguousarray(f_t.T, dtype=np.float64)
        std = np.ascontiguousarray(std_t.T, dtype=np.float64)
        s_last = depths[-1] - theta[:, 0]
        f_last = forces[:, -1]
        slopes = np.where(s_last > 0, f_last * theta[:, 2] / np.where(s_last > 0, s_last, 1.0),
                          0.0)
        return BakedResponse(depths=depths, forces=forces, slopes=slopes, std=std,
                             version=self.version,
                             meta={'model': self.kind, 'n_pokes': len(self._ids),
                                   'poke_ids': list(self._ids), 'ref_depth': self.ref_depth})

    def reference_depth(self) -> float:
        """Return a depth (m) where every trained location is in contact: max onset + ref."""
        self._require()
        return float(self._theta[:, 0].max() + self.ref_depth)

    # ------------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        """JSON-serialisable state (config, per-poke parameters, GP hyperparameters)."""
        return {
            'kind': self.kind, 'format': FORMAT, 'version': int(self.version),
            'config': {'ref_depth': self.ref_depth, 'exponent_bounds': list(self.exponent_bounds),
                       'prior_scales': list(self.prior_scales),
                       'max_surface_distance': self.max_surface_distance,
                       'bases': list(self.bases), 'grid': _grid_to_dict(self.grid),
                       'decorrelate': self.decorrelate},
            'frame': None if self._frame is None else self._frame.to_dict(),
            'pokes': [{'poke_id': i, 'features': f.tolist(), 'params': th.tolist(),
                       'fit_rms': float(r), 'onset': float(o)}
                      for i, f, th, r, o in zip(self._ids, self._features, self._theta,
                                                self._fit_rms, self._onsets)],
            'processes': None if self._gps is None else [gp.state.to_dict() for gp in self._gps],
        }

    @classmethod
    def from_dict(cls, data: Mapping) -> 'ContactGpModel':
        """Rebuild a model saved by :meth:`to_dict` (no refit: hyperparameters are reused).

        Raises:
            InvalidInput: wrong kind or format, or missing fields.

        """
        if data.get('kind') != KIND or data.get('format') != FORMAT:
            raise InvalidInput(f'ContactGpModel.from_dict: not a {KIND} v{FORMAT} model '
                               f'(kind={data.get("kind")!r}, format={data.get("format")!r})')
        try:
            cfg = data['config']
            model = cls(ref_depth=cfg['ref_depth'], exponent_bounds=cfg['exponent_bounds'],
                        prior_scales=cfg['prior_scales'],
                        max_surface_distance=cfg['max_surface_distance'],
                        bases=cfg['bases'], grid=_grid_from_dict(cfg['grid']),
                        # saved before decorrelation existed: its processes are independent
                        decorrelate=cfg.get('decorrelate', False))
            pokes = data['pokes']
            model.version = int(data['version'])
            model._frame = None if data['frame'] is None \
                else FeatureFrame.from_dict(data['frame'])
            model._ids = [p['poke_id'] for p in pokes]
            model._features = np.array([p['features'] for p in pokes], dtype=float
                                       ).reshape(-1, 9)
            model._theta = np.array([p['params'] for p in pokes], dtype=float).reshape(-1, 3)
            model._fit_rms = np.array([p['fit_rms'] for p in pokes], dtype=float)
            # models saved before onsets were kept: the law's own onset stands in
            model._onsets = np.array([p.get('onset', p['params'][0]) for p in pokes],
                                     dtype=float)
            if data['processes'] is not None:
                states = [GpState.from_dict(s) for s in data['processes']]
                model._fit_processes(states)
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f'ContactGpModel.from_dict: malformed model data: {exc}') from exc
        return model


def _grid_to_dict(grid: GpGrid) -> dict:
    def enc(values):
        return [None if not np.isfinite(v) else float(v) for v in values]
    return {'position': enc(grid.position), 'colour': enc(grid.colour),
            'normal': enc(grid.normal), 'linear': enc(grid.linear),
            'nugget': enc(grid.nugget),
            'position_prior': list(grid.position_prior),
            'nugget_prior': list(grid.nugget_prior)}


def _grid_from_dict(data: Mapping) -> GpGrid:
    def dec(values):
        return tuple(np.inf if v is None else float(v) for v in values)
    return GpGrid(position=dec(data['position']), colour=dec(data['colour']),
                  normal=dec(data['normal']), linear=dec(data['linear']),
                  nugget=dec(data['nugget']),
                  position_prior=tuple(data['position_prior']),
                  nugget_prior=tuple(data['nugget_prior']))
