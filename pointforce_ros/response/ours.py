"""Ours: a monotone contact law per poke whose parameters a Gaussian process spreads over x.

How the laws are spread is ``spread``: the processes below (``gp``), Extra Trees over the same
features (``trees``, :mod:`.trees`), or both in equal parts (``mix``, :class:`Mixture`: the
moment-matched mixture of the two parameter Gaussians), which is the product's
(:data:`PRODUCT_SPREAD`, :func:`product_model`).

Public API (what other modules may rely on; shapes: ``features`` (M, 9) ``[p, rgb, n]``,
``d`` (M,) or scalar, metres, forces in newtons):

- :meth:`ContactGpModel.predict` -- with ``mean='mean'`` the predictive MEAN force
  ``E[f(theta, d)]`` at each query, the expectation over the predictive distribution of the
  point's law parameters ``theta`` (point 6 below); with ``mean='median'`` the force at the
  parameters' predictive mean ``f(E[theta], d)`` (about the median force: ``f`` is monotone
  in ``log F`` and ``p``). The default ``mean='auto'`` takes the one with the lower
  leave-one-poke-out error per object (:attr:`~ContactGpModel.mean` says which): held out,
  the mean is not always better (it is only as good as the spread; see point 6).
- :meth:`~ContactGpModel.predict_std` -- the standard deviation of ``f(theta, d)`` over the
  same distribution, ``sqrt(E[f^2] - E[f]^2)`` (the spread of the force *curve* at that
  point, including the scatter of a new poke about the smooth field; not F/T sample noise).
- :meth:`~ContactGpModel.predict_param_dist` -- mean (M, P) and covariance (M, P, P) of
  ``theta`` at each point (Gaussian; correlated within a point, marginal across points).
- :meth:`~ContactGpModel.sample_params` -- (S, M, P) draws of ``theta`` from that
  distribution, and :meth:`~ContactGpModel.force_from_params` -- ``f(theta, d)`` for given
  rows: together a Monte-Carlo spread of any derived quantity.
- :attr:`~ContactGpModel.law` (``power`` or ``stiffening``) and
  :attr:`~ContactGpModel.param_names` say what the P columns of ``theta`` are.

The seed's Extra-Trees regressor treats ``(x, d)`` as ten anonymous inputs. Facts it does
not use are built in here:

1. **Zero before contact, monotone in depth.** Each poke's loading curve is fitted with a law
   that is zero before the onset ``d0`` (where camera bias puts it) and increasing after it,
   and extrapolates beyond the poked depth like the material does. Two laws, ``s = d - d0``:

   - ``power``: ``f = F * (s / s_ref) ** p`` (``F`` = force at the reference contact depth
     ``s_ref``, ``p`` > 0; ``p = 1.5`` is Hertz for a sphere), parameters ``(d0, log F, p)``;
   - ``stiffening``: ``f = F * (s / s_ref) ** p * exp(q * (s / s_ref - 1))``, ``q >= 0``, a
     local exponent ``d log f / d log s = p + q s / s_ref`` that grows with depth (strain
     stiffening: on stiff parts a power law pushed ``p`` onto its cap and still fell short
     at the deepest samples), parameters ``(d0, log F, p, q)``.

   ``law='auto'`` chooses per object by held-out error inside the fit (point 7).
2. **Smooth over the surface.** The parameters vary smoothly over the object: each is a
   Gaussian process over ``x = [p, rgb, n]`` (:mod:`.gp`): position, colour and normal each
   have a length scale (``inf`` = irrelevant) chosen by the marginal likelihood, so an
   object where colour or normal means nothing does not use them.
3. **Uncertainty.** The processes give a mean and a standard deviation of ``theta`` anywhere.
4. **No extrapolation beyond the pokes.** Far from every poke (the object's sides, a corner
   the pokes never reached) a process's mean follows its basis and hyperparameters, not data.
   The predicted parameters are therefore kept within what the pokes showed: the onset within
   the pokes' detected onsets +- :data:`ONSET_MARGIN`, ``log F`` within the fitted values +-
   :data:`LOG_FORCE_MARGIN`, ``p`` and ``q`` within the fitted values. On lamb one stiffening
   curve fitted ``d0`` 2 mm before its detected onset, and the onset process spread -5 mm
   onsets over the sides: a line probe then touched them early and the predicted force tripled.
5. **The processes spread decorrelated parameters.** One curve's ``(d0, log F, p)`` trade
   against each other (an earlier onset with a softer, steeper law fits the same curve), and
   over an object they move together: on the simulated cell's lamb and dome their pairwise
   correlations are 0.94-1.00. So the processes spread ``y = L^-1 z``: ``z`` the parameters
   standardised over the training pokes, ``L`` the Cholesky factor of their covariance in
   the order of ``theta``, shrunk towards the identity by :data:`DECORRELATE_PRIOR_POKES`
   pseudo-pokes. A prediction maps back with ``L``, so the parameters' covariance at a point
   is ``S L diag(var y) L^T S``. With fewer than :data:`DECORRELATE_MIN_POKES` pokes the
   processes are independent.
6. **Mean force, not force at the mean parameters.** ``log f`` is linear in ``(log F, p, q)``
   for a fixed onset, so given ``d0`` the force is log-normal and its mean is
   ``exp(m + v / 2)`` (the log-space retransformation); the onset is integrated out with
   :data:`ONSET_NODES`-point Gauss-Hermite quadrature over its conditional Gaussian. The
   variance of ``log f`` is capped at :data:`LOG_VAR_CAP` (far from every poke, deep in
   contact, it would otherwise inflate the mean without bound). The mean is only as good as
   the spread: each process's predictive variance is scaled by its leave-one-out
   calibration (:meth:`ContactGpModel._calibration`: the mean squared standardised
   leave-one-out residual, shrunk towards 1). Uncalibrated, the prior-dominated spread of
   5-7 pokes inflated the mean force (the learner's predict-before-add RMSE on the clean
   cell went 0.54 -> 1.02 N).
7. **Law chosen by held-out error.** With ``law='auto'`` and at least
   :data:`LAW_SELECT_MIN_POKES` pokes, both laws are fitted and each is scored by
   leave-one-poke-out: the processes (hyperparameters of the full fit) are conditioned on the
   other pokes and predict the left-out poke's mean force over its contact samples; the law
   with the lower pooled RMSE wins (the power law unless the stiffening law is better by
   :data:`LAW_SELECT_MARGIN`). Fewer pokes: the power law.

8. **Optional: one extreme poke as a local departure, not the field** (``robust_z``, off by
   default). A poke the law fits only with
   extreme parameters (on the simulated lamb, one over the buried bone: exponent on its cap,
   onset 3 mm early) would otherwise pull the processes of pokes 17 mm away towards its set
   (their forces at 10 mm came out 60-80 % high). Each poke's robust z-score is its largest
   distance from the pokes' median in units of the interquartile range / 1.349 (floored by
   :data:`ROBUST_SCALE_FLOOR`); above :data:`ROBUST_Z`, for at most :data:`ROBUST_SHARE` of
   the pokes (the worst), the nugget is multiplied by ``(z / ROBUST_Z)^2`` and the poke weighs
   that much less in the decorrelation's mean and covariance, unless another poke lies within
   :data:`ROBUST_Z` of it (in the same units, every parameter): two pokes that agree are a
   material, not an outlier. The quartiles, the share and the confirmation
   keep a material that covers a third of the object (two foams told apart by colour) from
   being screened.

   Why it is off by default (simulated cell, the same draws; figure 1 = held-out point pokes,
   figure 2 = line and cylinder trials): with ``robust_z=ROBUST_Z`` lamb's figure 1 at 10 pokes
   goes 0.575 -> 0.408 N (ET 0.396), plush at 5 0.639 -> 0.592, dome at 5 0.324 -> 0.319, the
   rest unchanged; but lamb's figure 2 goes 0.850 -> 1.315 N (the paper's simulator 1.466 N):
   the wide contacts cross the bone, and a bone seen by one poke is exactly what the screen
   discounts. Which is right depends on where the planner will touch, so the learner keeps
   every poke's say unless a user turns the screen on. The screen is a function of the
   fitted parameters only, so a loaded model recomputes it.

A refit is: one bounded least-squares fit per law for the new poke (cached for the others),
then small GP fits on a fixed hyperparameter grid and the leave-one-out scores; baking 40 000
points is a handful of (N, K) numpy expressions per quadrature node.
"""

import dataclasses
import time
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import least_squares

from pointforce_ros.errors import check_choice, InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import fit_power_onset, PokeCurve
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.response.blas import single_threaded_blas
from pointforce_ros.response.common import (check_curves, check_depths, check_query,
                                            curve_features, DEFAULT_MAX_SURFACE_DISTANCE,
                                            SCALE_FLOOR)
from pointforce_ros.response.gp import BASES, FeatureFrame, FeatureGp, GpGrid, GpState
from pointforce_ros.response.scoring import CONTACT_MARGIN
from pointforce_ros.response.trees import TreeSpread, TreeState
from pointforce_ros.types import Surface

KIND = 'pointforce.response.contact_gp'
FORMAT = 2
"""Saved-model format: 2 adds the law, the mean mode and per-law parameters (1 still loads)."""
LAWS = ('power', 'stiffening')
LAW_PARAMS = {'power': ('d0', 'log_force', 'exponent'),
              'stiffening': ('d0', 'log_force', 'exponent', 'stiffening')}
PARAMS = LAW_PARAMS['power']
MEANS = ('mean', 'median')
SPREADS = ('gp', 'trees', 'mix')
"""How the per-poke laws are spread over the surface (``ContactGpModel(spread=...)``)."""
PRODUCT_SPREAD = 'mix'
"""The spread of the product's point model: the learner node's ``point_spread`` default,
:class:`~pointforce_ros.model.learner.OnlineLearner`'s and the figures' ``ours``. Held out it
is better than the processes alone on every cell of figure 1 and under figure 2's probes on
every object (``data/figures/mix_spread.py``, record ``mix_spread.log``). ``ContactGpModel``'s
own default stays ``gp``: a fit in 0.1-0.4 s against about 4 s with the trees (which the unit
tests and studies that build many models use)."""
ONSET_MARGIN = 0.0005
"""How far (m) a predicted onset may lie outside the training pokes' detected onsets."""
LOG_FORCE_MARGIN = 0.3
"""How far a predicted ``log F`` may lie outside the training pokes' fitted values."""
STIFFENING_BOUNDS = (0.0, 6.0)
"""Allowed range of the stiffening rate ``q`` (per reference depth)."""
DECORRELATE_MIN_POKES = 3
"""Fewest pokes whose parameter covariance the processes are decorrelated with."""
DECORRELATE_RIDGE = 1e-3
"""Added to the diagonal of the standardised parameters' covariance (keeps it invertible)."""
DECORRELATE_PRIOR_POKES = 2.0
"""Pseudo-pokes of zero correlation the parameter covariance is shrunk with."""
ONSET_NODES = 3
"""Gauss-Hermite nodes over the onset in the mean force (module docstring, point 6)."""
LOG_VAR_CAP = 0.5
"""Largest variance of ``log f`` given the onset used in the mean force."""
LAW_SELECT_MIN_POKES = 4
"""Fewest pokes with which ``law='auto'`` compares the laws by leave-one-out."""
LAW_SELECT_MARGIN = 0.02
"""Relative held-out improvement the stiffening law needs to be chosen over the power law."""
CALIBRATION_PRIOR = 2.0
"""Pseudo-points of a calibrated spread (z^2 = 1) in the leave-one-out variance calibration."""
CALIBRATION_RANGE = (0.05, 4.0)
"""Smallest and largest factor the calibration puts on a process's predictive variance."""
FINE_COLOUR = (0.1, 0.05)
"""Colour length scales (RGB units) ``relevance='auto'`` adds to the grid when held out says."""
FINE_NORMAL = (0.2,)
"""Normal length scales ``relevance='auto'`` adds to the grid when held out says."""
STIFFENING_SAMPLES = 300
"""Most samples of one curve the stiffening law's least-squares fit uses (evenly thinned)."""
CV_SAMPLES = 40
"""Contact samples per poke kept for the leave-one-out law choice."""
ROBUST_Z = 2.5
"""The usual robust outlier cut-off (Leys et al., 2013) for ``robust_z``: distance from the
pokes' median in robust standard deviations, worst parameter; above it a poke's nugget grows as
``(z / ROBUST_Z)^2``. Not the default: module docstring, point 8."""
ROBUST_SHARE = 0.1
"""Largest share of the pokes the outlier screen may treat as local departures."""
ROBUST_MIN_POKES = 5
"""Fewest pokes whose parameters are screened for outliers (a median needs company)."""
ROBUST_SCALE_FLOOR = np.array([2e-4, 0.1, 0.1, 0.1])
"""Smallest robust spread of ``(d0 [m], log F, p, q)`` an outlier is measured against."""
MAX_PROCESS_POKES = 128
"""Most pokes the processes are conditioned on. A refit costs about ``n^3`` per grid point and
the leave-one-out law choice ``n^4``, its memory ``n^2`` per grid point (measured on this machine
kind: 100 pokes 4.6 s and 140 MB, 300 pokes 61 s and 1.3 GB, 1000 would need about 14 GB); past
this many, the processes are conditioned on the pokes spread furthest apart over the surface
(:meth:`ContactGpModel.process_rows`; every poke keeps its own law fit, and the parameters'
bounds are those of all pokes)."""

_GH_Z, _GH_W = np.polynomial.hermite_e.hermegauss(ONSET_NODES)
_GH_W = _GH_W / _GH_W.sum()


@dataclasses.dataclass(frozen=True)
class Mixture:
    """The processes' field and the trees' spread of one law, in equal parts (``spread='mix'``).

    Attributes:
        gp: the processes' field ``(gps, (mu, scale, chol), bounds, var_scale)``.
        trees: the trees' :class:`~pointforce_ros.response.trees.TreeSpread`.

    """

    gp: tuple
    trees: TreeSpread


def mixture(m1: np.ndarray, c1: np.ndarray, m2: np.ndarray, c2: np.ndarray
            ) -> Tuple[np.ndarray, np.ndarray]:
    """Mean (..., P) and covariance (..., P, P) of the equal mixture of two Gaussians.

    Moment matched: the mean of the means, and the mean covariance plus the covariance of the
    two means about it (their disagreement widens the spread).
    """
    half = (np.asarray(m1, dtype=float) - m2) / 2.0
    return (m1 + m2) / 2.0, (c1 + c2) / 2.0 + half[..., :, None] * half[..., None, :]


def product_model() -> 'ContactGpModel':
    """Return an empty point model as the product uses it (:data:`PRODUCT_SPREAD`)."""
    return ContactGpModel(spread=PRODUCT_SPREAD)


def check_spread(value, name: str = 'spread') -> str:
    """Return ``value`` as a spread, one of :data:`SPREADS`.

    Raises:
        InvalidInput: not one of them (the message starts with ``name`` and lists them).

    """
    return check_choice(value, SPREADS, name)


class ContactGpModel:
    """Per-poke monotone contact law + GP over the surface (see the module docstring).

    Args:
        ref_depth: reference contact depth ``s_ref`` at which ``F`` is defined, metres.
        exponent_bounds: allowed range of the contact exponent ``p``.
        prior_scales: prior standard deviations of ``(d0 [m], log F, p[, q])`` about their
            mean over the object (they matter only with very few pokes; ``q``: 1.0 if absent).
        max_surface_distance: farthest a poke may be from the surface, metres.
        bases: linear-term basis of the process of each parameter ``(d0, log F, p[, q])``:
            ``rigid`` (camera extrinsic error: the onset's natural structure), ``colour``,
            ``none`` (see :mod:`.gp`; ``q``: ``none`` if absent).
        grid: GP hyperparameter grid (:class:`~pointforce_ros.response.gp.GpGrid`).
        decorrelate: spread decorrelated parameters (module docstring, point 5); ``False``
            spreads each parameter by an independent process.
        law: ``auto`` (chosen by held-out error, point 7), ``power`` or ``stiffening``.
        mean: ``mean`` (predictive mean force, point 6), ``median`` (force at the
            parameters' predictive mean) or ``auto`` (the one with the lower
            leave-one-poke-out error, ``median`` unless ``mean`` wins by
            :data:`LAW_SELECT_MARGIN`; ``median`` below :data:`LAW_SELECT_MIN_POKES` pokes).
            :attr:`mean` is the mode in use.
        relevance: ``auto`` also offers the chosen law's processes finer colour and normal
            length scales (:data:`FINE_COLOUR`, :data:`FINE_NORMAL`) and keeps them where
            leave-one-poke-out says they help; ``fixed`` uses ``grid`` alone.
        robust_z: outlier screen (module docstring, point 8): a poke whose parameters lie more
            than this many robust z-scores from the others' median gets a larger nugget;
            ``None`` (the default) turns the screen off; :data:`ROBUST_Z` is the usual cut-off.
        spread: ``gp`` (the processes of points 2-5), ``trees`` (Extra Trees over the same
            features, :mod:`.trees`; ``bases``, ``grid``, ``decorrelate``, ``relevance`` and
            ``robust_z`` are then unused) or ``mix`` (both, in equal parts: a point's
            parameters are the moment-matched mixture of the two Gaussians, :func:`mixture`;
            ``relevance='auto'`` applies with ``gp`` alone). Not chosen per fit: with 5-10
            pokes the leave-one-poke-out errors chose the processes on thin_layer and lamb at
            10 pokes where the trees score 1.13 and 1.09 of ET held out and the processes 1.43
            and 1.45. :data:`PRODUCT_SPREAD` is the product's.

    Raises:
        InvalidInput: non-positive ``ref_depth`` or prior scales, bad exponent bounds, unknown
            law or mean.

    """

    kind = KIND
    monotone = True
    """The force never decreases with depth (the contact laws are increasing past the onset)."""

    def __init__(self, ref_depth: float = 0.003, exponent_bounds=(0.7, 3.5),
                 prior_scales=(0.003, 1.0, 0.4, 1.0),
                 max_surface_distance: float = DEFAULT_MAX_SURFACE_DISTANCE,
                 bases=('rigid', 'colour', 'none', 'none'), grid: Optional[GpGrid] = None,
                 decorrelate: bool = True, law: str = 'auto', mean: str = 'auto',
                 relevance: str = 'fixed', robust_z: Optional[float] = None,
                 spread: str = 'gp'):
        if not (np.isfinite(ref_depth) and ref_depth > 0):
            raise InvalidInput(f'ContactGpModel: ref_depth must be > 0 m, got {ref_depth}')
        lo, hi = (float(v) for v in exponent_bounds)
        if not (0 < lo < hi):
            raise InvalidInput(f'ContactGpModel: exponent_bounds must satisfy 0 < lo < hi, got '
                               f'{exponent_bounds}')
        scales = np.asarray(prior_scales, dtype=float)
        if scales.shape == (3,):
            scales = np.append(scales, 1.0)
        if scales.shape != (4,) or not np.all(scales > 0):
            raise InvalidInput('ContactGpModel: prior_scales must be three or four positive '
                               'numbers')
        bases = tuple(bases)
        if len(bases) == 3:
            bases = bases + ('none',)
        if len(bases) != 4 or any(b not in BASES for b in bases):
            raise InvalidInput(f'ContactGpModel: bases must be three or four of {BASES}, got '
                               f'{bases}')
        if law not in LAWS + ('auto',):
            raise InvalidInput(f'ContactGpModel: law must be auto or one of {LAWS}, got {law!r}')
        if relevance not in ('fixed', 'auto'):
            raise InvalidInput(f'ContactGpModel: relevance must be fixed or auto, got '
                               f'{relevance!r}')
        check_spread(spread, 'ContactGpModel: spread')
        if mean not in MEANS + ('auto',):
            raise InvalidInput(f'ContactGpModel: mean must be auto or one of {MEANS}, got '
                               f'{mean!r}')
        self.ref_depth = float(ref_depth)
        self.exponent_bounds = (lo, hi)
        self.prior_scales = tuple(float(s) for s in scales)
        self.max_surface_distance = float(max_surface_distance)
        self.bases = bases
        self.grid = grid or GpGrid()
        self.decorrelate = bool(decorrelate)
        self.law_setting = law
        self.mean_setting = mean
        self.mean = 'median' if mean == 'auto' else mean
        self._mode_scores: Dict[str, Dict[str, float]] = {}
        self.law = 'power' if law == 'auto' else law
        self.law_scores: Dict[str, float] = {}
        self.relevance = relevance
        self.robust_z = None if robust_z is None else float(robust_z)
        self.spread = spread
        self.fine_relevance = False
        self.version = 0
        self._ids: List[str] = []
        self._features = np.zeros((0, 9))
        self._thetas: Dict[str, np.ndarray] = {k: np.zeros((0, len(LAW_PARAMS[k])))
                                               for k in LAWS}
        self._rms: Dict[str, np.ndarray] = {k: np.zeros(0) for k in LAWS}
        self._samples: List[Optional[Tuple[np.ndarray, np.ndarray]]] = []
        self._onsets = np.zeros(0)
        self._frame: Optional[FeatureFrame] = None
        self._gps: Optional[List[FeatureGp]] = None
        self._mix: Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]] = None
        self._param_bounds = None
        self._var_scale: Optional[np.ndarray] = None
        self._surface: Optional[Surface] = None
        self.fit_seconds = 0.0

    # ----------------------------------------------------------------------------- fitting
    @property
    def param_names(self) -> Tuple[str, ...]:
        """Names of the P columns of ``theta`` under the current law."""
        return LAW_PARAMS[self.law]

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
        """(n, P) per-poke parameters of the current law (:attr:`param_names`)."""
        return self._thetas[self.law].copy()

    @property
    def _theta(self) -> np.ndarray:
        return self._thetas[self.law]

    @property
    def _fit_rms(self) -> np.ndarray:
        return self._rms[self.law]

    def _laws_to_fit(self) -> Tuple[str, ...]:
        return LAWS if self.law_setting == 'auto' else (self.law_setting,)

    def fit_curve(self, curve: PokeCurve, law: Optional[str] = None
                  ) -> Tuple[np.ndarray, float]:
        """Fit a contact law to one curve; return ``(theta, rms)``; stores nothing.

        ``law``: ``power`` (``theta = (d0, log F, p)``) or ``stiffening`` (``(d0, log F, p,
        q)``); default the model's current law.

        Raises:
            InvalidInput: the curve has no force above zero (nothing to fit).

        """
        law = law or self.law
        return self._fit_curve_laws(curve, (law,))[law]

    def _fit_curve_laws(self, curve: PokeCurve, laws: Sequence[str]
                        ) -> Dict[str, Tuple[np.ndarray, float]]:
        """``{law: (theta, rms)}`` for each of ``laws``, sharing one power-law fit."""
        if not np.any(curve.f > 0):
            raise InvalidInput(f'poke {curve.poke_id}: no positive force, cannot fit a contact '
                               'law')
        with single_threaded_blas():
            fit = fit_power_onset(curve.d, curve.f, with_bias=False,
                                  exponent_bounds=self.exponent_bounds, max_samples=600)
        force_ref = max(fit.a * self.ref_depth ** fit.p, 1e-9)
        power = np.array([fit.d0, np.log(force_ref), fit.p])
        out = {}
        for law in laws:
            out[law] = (power, float(fit.rms)) if law == 'power' \
                else self._fit_stiffening(curve, power, fit.noise)
        return out

    def _fit_stiffening(self, curve: PokeCurve, power: np.ndarray, noise: float
                        ) -> Tuple[np.ndarray, float]:
        """Fit the stiffening law by least squares; return ``(theta, rms)``.

        Started from the power fit (``q = 0``) and from a softer exponent with stiffening;
        the better of the two is kept.
        """
        d, f = curve.d, curve.f
        if len(d) > STIFFENING_SAMPLES:
            keep = np.round(np.linspace(0, len(d) - 1, STIFFENING_SAMPLES)).astype(int)
            d, f = d[keep], f[keep]
        sref = self.ref_depth
        x = d / sref
        span = float(d.max() - d.min()) / sref
        lo_p, hi_p = self.exponent_bounds
        lower = np.array([x.min() - 0.5 * span - 1.0, -30.0, lo_p, STIFFENING_BOUNDS[0]])
        upper = np.array([x.max(), 30.0, hi_p, STIFFENING_BOUNDS[1]])

        def model(z):
            s = x - z[0]
            pos = s > 0
            sp = np.where(pos, s, 1.0)
            lg = np.log(sp)
            out = np.exp(z[1] + z[2] * lg + z[3] * (sp - 1.0)) * pos
            return out, sp, lg, pos

        def residual(z):
            return model(z)[0] - f

        def jac(z):
            out, sp, lg, pos = model(z)
            return np.stack([-out * (z[2] / sp + z[3]) * pos, out, out * lg,
                             out * (sp - 1.0)], axis=1)

        f_scale = max(2.0 * noise, 1e-6 * max(1.0, float(np.abs(f).max())))
        best = None
        starts = [np.array([power[0] / sref, power[1], power[2], 0.0]),
                  np.array([power[0] / sref, power[1], max(lo_p, min(1.2, power[2])), 1.0])]
        for z0 in starts:
            z0 = np.clip(z0, lower + 1e-9, upper - 1e-9)
            try:
                sol = least_squares(residual, z0, jac=jac, bounds=(lower, upper),
                                    method='trf', loss='soft_l1', f_scale=f_scale,
                                    x_scale='jac', max_nfev=200)
            except ValueError:
                continue
            if best is None or sol.cost < best.cost:
                best = sol
        if best is None:
            theta = np.append(power, 0.0)
        else:
            theta = np.array([best.x[0] * sref, best.x[1], best.x[2], best.x[3]])
        res = self.force_from_params(np.repeat(theta[None], len(curve.d), 0), curve.d,
                                     law='stiffening') - curve.f
        return theta, float(np.sqrt(np.mean(res ** 2)))

    @staticmethod
    def _cv_samples(curve: PokeCurve) -> Tuple[np.ndarray, np.ndarray]:
        keep = np.flatnonzero(curve.d >= curve.onset_d - CONTACT_MARGIN)
        if len(keep) > CV_SAMPLES:
            keep = keep[np.round(np.linspace(0, len(keep) - 1, CV_SAMPLES)).astype(int)]
        return curve.d[keep].copy(), curve.f[keep].copy()

    def fit(self, curves: Sequence[PokeCurve], surface: Surface) -> 'ContactGpModel':
        """Fit from scratch on ``curves`` poked on ``surface``; returns ``self``.

        Raises:
            InvalidInput: no curves, duplicate ids, pokes off the surface, curves without force.

        """
        start = time.perf_counter()
        curves = check_curves(curves, surface)
        feats = curve_features(curves, surface, self.max_surface_distance)
        self._thetas = {k: np.zeros((0, len(LAW_PARAMS[k]))) for k in LAWS}
        self._rms = {k: np.zeros(0) for k in LAWS}
        fits = [self._fit_curve_laws(c, self._laws_to_fit()) for c in curves]
        for law in self._laws_to_fit():
            self._thetas[law] = np.stack([fit[law][0] for fit in fits])
            self._rms[law] = np.array([fit[law][1] for fit in fits])
        self._samples = [self._cv_samples(c) for c in curves]
        self._ids = [c.poke_id for c in curves]
        self._features = feats
        self._onsets = np.array([c.onset_d for c in curves], dtype=float)
        self._frame = FeatureFrame.of_surface(surface.points, surface.colors)
        self._surface = surface
        self._fit_processes()
        self.fit_seconds = time.perf_counter() - start
        return self

    def partial_fit(self, curve: PokeCurve, surface: Optional[Surface] = None, *,
                    refit: bool = True) -> 'ContactGpModel':
        """Add one poke (earlier per-poke fits are reused) and refit the processes.

        ``refit=False`` only adds the poke's own law fit: the model predicts as before until
        :meth:`refit_processes` (many pokes at once pay for one refit, not one each).

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
        laws = [k for k in self._laws_to_fit()
                if len(self._thetas[k]) == len(self._ids)]   # loaded without a law: stays out
        fits = self._fit_curve_laws(curve, laws)
        self._thetas = {k: (np.vstack([v, fits[k][0][None]]) if k in fits else v)
                        for k, v in self._thetas.items()}
        self._rms = {k: (np.append(v, fits[k][1]) if k in fits else v)
                     for k, v in self._rms.items()}
        self._ids = self._ids + [curve.poke_id]
        self._samples = self._samples + [self._cv_samples(curve)]
        self._features = np.vstack([self._features, feat])
        self._onsets = np.append(self._onsets, float(curve.onset_d))
        if self._frame is None or surface is not self._surface:
            self._frame = FeatureFrame.of_surface(surface.points, surface.colors)
        self._surface = surface
        if refit:
            self._fit_processes()
        self.fit_seconds = time.perf_counter() - start
        return self

    def refit_processes(self) -> 'ContactGpModel':
        """Refit the processes on every poke added so far (after ``partial_fit(refit=False)``).

        Raises:
            ModelNotReady: no poke yet.

        """
        if not self._ids:
            raise ModelNotReady('ContactGpModel: no pokes yet; fit the model first')
        start = time.perf_counter()
        self._fit_processes()
        self.fit_seconds = time.perf_counter() - start
        return self

    def process_rows(self) -> np.ndarray:
        """Return the indices of the pokes the processes are conditioned on (MAX_PROCESS_POKES).

        All of them up to :data:`MAX_PROCESS_POKES`; past it the newest poke and then, one at a
        time, the poke farthest in scaled position (object size 1, :class:`FeatureFrame`) from
        those already taken (deterministic: a reloaded model conditions on the same pokes).
        """
        n = len(self._ids)
        if n <= MAX_PROCESS_POKES:
            return np.arange(n)
        scale = self._frame.scale if self._frame is not None else 1.0
        pos = self._features[:, :3] / scale
        taken = [n - 1]
        gap = np.linalg.norm(pos - pos[n - 1], axis=1)
        gap[n - 1] = -np.inf
        for _ in range(MAX_PROCESS_POKES - 1):
            k = int(np.argmax(gap))
            taken.append(k)
            gap = np.minimum(gap, np.linalg.norm(pos - pos[k], axis=1))
            gap[taken] = -np.inf
        return np.sort(np.array(taken))

    def _fit_processes(self, states: Optional[Sequence[GpState]] = None) -> None:
        with single_threaded_blas():
            if states is not None:
                self._install(self.law, self._condition(self.law, states))
            else:
                self._choose_law()
            if states is None:
                self.version += 1

    def _choose_law(self) -> None:
        """Fit the processes of each candidate law; keep the one with the lower LOO error."""
        n = len(self._ids)
        usable = [k for k in self._laws_to_fit() if len(self._thetas[k]) == n]
        if self.law_setting == 'auto' and (n < LAW_SELECT_MIN_POKES
                                           or any(s is None for s in self._samples)):
            usable = ['power'] if 'power' in usable else usable[:1]
        fields = {k: self._condition(k, None) for k in usable}
        self.law_scores = {}
        self.fine_relevance = False
        self._mode_scores = {}
        scored = n >= LAW_SELECT_MIN_POKES and not any(s is None for s in self._samples)
        if len(usable) > 1:
            self.law_scores = {k: self._loo_rmse(k, fields[k][0]) for k in usable}
            best = 'stiffening' if self.law_scores['stiffening'] < \
                (1.0 - LAW_SELECT_MARGIN) * self.law_scores['power'] else 'power'
        else:
            best = usable[0]
        field = fields[best]
        if scored and self.relevance == 'auto' and self.spread == 'gp':
            # the same law with finer colour and normal length scales on offer (point 2)
            base = self.law_scores.get(best) or self._loo_rmse(best, field[0])
            fine = self._condition(best, None, grid=self._fine_grid())
            score = self._loo_rmse(best, fine[0])
            self.law_scores[best] = base
            self.law_scores[f'{best}+fine'] = score
            if score < (1.0 - LAW_SELECT_MARGIN) * base:
                field, self.fine_relevance = fine, True
        if self.mean_setting == 'auto':
            # median unless the mean force is better held out (module docstring, point 6)
            if scored and best not in self._mode_scores:
                self._loo_rmse(best, field[0])
            sc = self._mode_scores.get(best, {})
            self.mean = 'mean' if scored and sc['mean'] < (1.0 - LAW_SELECT_MARGIN) * \
                sc['median'] else 'median'
            self.law_scores.update({f'{best}/{k}': v for k, v in sc.items()})
        self.law = best
        self._install(best, field)

    def _fine_grid(self) -> GpGrid:
        """Return the configured grid with :data:`FINE_COLOUR` and :data:`FINE_NORMAL` added."""
        g = self.grid
        return dataclasses.replace(
            g, colour=tuple(sorted(set(g.colour) | set(FINE_COLOUR), reverse=True)),
            normal=tuple(sorted(set(g.normal) | set(FINE_NORMAL), reverse=True)))

    def _outlier_noise(self, theta: np.ndarray) -> np.ndarray:
        """(n,) nugget factors >= 1: large for a poke whose parameters lie far from the rest.

        Module docstring, point 8: the spread is the interquartile range (a two-material
        object keeps its minority material), at most :data:`ROBUST_SHARE` of the pokes are
        screened, and none that another poke's parameters confirm.
        """
        n, k = theta.shape
        out = np.ones(n)
        if self.robust_z is None or n < ROBUST_MIN_POKES:
            return out
        med = np.median(theta, axis=0)
        q25, q75 = np.percentile(theta, [25.0, 75.0], axis=0)
        spread = np.maximum((q75 - q25) / 1.349, ROBUST_SCALE_FLOOR[:k])
        score = np.max(np.abs(theta - med) / spread, axis=1)
        worst = np.argsort(-score)[:int(np.ceil(ROBUST_SHARE * n))]
        worst = worst[score[worst] > self.robust_z]
        # a poke that another poke's parameters confirm is a material, not an outlier
        apart = np.max(np.abs(theta[:, None, :] - theta[None, :, :]) / spread, axis=2)
        np.fill_diagonal(apart, np.inf)
        worst = worst[apart[worst].min(axis=1) > self.robust_z]
        out[worst] = (score[worst] / self.robust_z) ** 2
        return out

    def _decorrelation(self, theta: np.ndarray, weights: Optional[np.ndarray] = None
                       ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, Tuple[float, ...]]:
        """``(mu, scale, L, priors)``: ``theta = mu + scale * (L @ y)`` (module docstring, 5).

        ``priors``: the prior scale of each process of ``y``. A function of the training
        parameters only, so a loaded model recomputes it. Independent processes (``L = I``)
        keep ``theta`` itself as the targets (``mu = 0``, ``scale = 1``, the configured prior
        scales).
        """
        k = theta.shape[1]
        if not self.decorrelate or len(theta) < DECORRELATE_MIN_POKES:
            return np.zeros(k), np.ones(k), np.eye(k), self.prior_scales[:k]
        n = len(theta)
        w = np.ones(n) if weights is None else np.asarray(weights, dtype=float)
        w = w * (n / w.sum())                  # weights that sum to the number of pokes
        mu = w @ theta / n
        scale = np.maximum(np.sqrt(w @ (theta - mu) ** 2 / n), SCALE_FLOOR[:k])
        z = (theta - mu) / scale
        cov = ((z * w[:, None]).T @ z + DECORRELATE_PRIOR_POKES * np.eye(k)) \
            / (n + DECORRELATE_PRIOR_POKES)
        cov += DECORRELATE_RIDGE * np.eye(k)
        return mu, scale, np.linalg.cholesky(cov), (1.0,) * k

    def _bounds(self, theta: np.ndarray, onsets: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        lo, hi = theta.min(axis=0), theta.max(axis=0)
        lower = [onsets.min() - ONSET_MARGIN, lo[1] - LOG_FORCE_MARGIN,
                 max(lo[2], self.exponent_bounds[0])]
        upper = [onsets.max() + ONSET_MARGIN, hi[1] + LOG_FORCE_MARGIN,
                 min(hi[2], self.exponent_bounds[1])]
        if theta.shape[1] > 3:
            lower.append(lo[3])
            upper.append(hi[3])
        return np.array(lower), np.array(upper)

    def _condition(self, law: str, states: Optional[Sequence[GpState]],
                   rows: Optional[np.ndarray] = None, grid: Optional[GpGrid] = None):
        """``(gps, mix, bounds)`` of ``law``'s processes on the training pokes ``rows``.

        ``states``: hyperparameters to condition with (``None``: choose them on the grid).
        """
        every = rows is None
        rows = self.process_rows() if every else rows
        if self.spread == 'trees':
            return (self._tree_spread(law, states, rows), None,
                    self._field_bounds(law, rows, every), None)
        tree_state = None
        if self.spread == 'mix' and states is not None:
            states, tree_state = states
        field = self._condition_gp(law, states, rows, grid, every)
        if self.spread == 'mix':
            return Mixture(field, self._tree_spread(law, tree_state, rows)), None, field[2], None
        return field

    def _field_bounds(self, law: str, rows: np.ndarray, every: bool):
        """Parameter bounds of a field on the pokes ``rows`` (``every``: all pokes')."""
        if every:
            return self._bounds(self._thetas[law], self._onsets)
        return self._bounds(self._thetas[law][rows], self._onsets[rows])

    def _condition_gp(self, law: str, states: Optional[Sequence[GpState]], rows: np.ndarray,
                      grid: Optional[GpGrid] = None, every: bool = False):
        """Return the processes' field of ``law`` on the pokes ``rows`` (``every``: all)."""
        theta = self._thetas[law][rows]
        noise = self._outlier_noise(theta)
        mu, scale, chol, priors = self._decorrelation(theta, 1.0 / noise)
        y = np.linalg.solve(chol, ((theta - mu) / scale).T).T
        gps = []
        for j in range(theta.shape[1]):
            gp = FeatureGp(self._frame, priors[j], basis=self.bases[j], grid=grid or self.grid)
            if states is None:
                gp.fit(self._features[rows], y[:, j], noise=noise)
            else:
                gp.condition(self._features[rows], y[:, j], states[j], noise)
            gps.append(gp)
        return (gps, (mu, scale, chol), self._field_bounds(law, rows, every),
                self._calibration(gps))

    def _tree_spread(self, law: str, state: Optional[TreeState], rows: np.ndarray
                     ) -> TreeSpread:
        """:mod:`.trees` in the processes' place, on the training pokes ``rows``."""
        samples = [self._samples[i] for i in rows]

        def score(mean, cov):
            errs = [self.force_from_params(np.repeat(m[None], len(s[0]), 0), s[0], law=law)
                    - s[1] for m, s in zip(mean, samples)]
            return float(np.sqrt(np.mean(np.concatenate(errs) ** 2)))
        usable = not any(s is None for s in samples)
        return TreeSpread(self._features[rows], self._thetas[law][rows], state,
                          score if usable else None, self.prior_scales)

    @staticmethod
    def _calibration(gps: Sequence[FeatureGp]) -> np.ndarray:
        """Return (P,) factors on each process's predictive variance.

        From its leave-one-out residuals: ``(sum z^2 + CALIBRATION_PRIOR) / (n +
        CALIBRATION_PRIOR)`` within :data:`CALIBRATION_RANGE` (module docstring, point 6).
        """
        out = []
        for gp in gps:
            z2 = gp.loo_z2()
            out.append((float(np.sum(z2)) + CALIBRATION_PRIOR) / (len(z2) + CALIBRATION_PRIOR))
        return np.clip(np.array(out), *CALIBRATION_RANGE)

    def _install(self, law: str, field) -> None:
        self.law = law
        self._gps, self._mix, self._param_bounds, self._var_scale = field

    def _loo_rmse(self, law: str, gps: Sequence[FeatureGp]) -> float:
        """Pooled leave-one-poke-out RMSE (N) of ``law`` on the contact samples.

        Scores the configured mean mode; with ``mean='auto'`` the better of the two (the
        modes' own scores are kept in ``self._mode_scores[law]``).
        """
        every = self.process_rows()
        trees = isinstance(gps, TreeSpread)
        mixed = isinstance(gps, Mixture)
        if trees or mixed:
            held = (gps.trees if mixed else gps).held_out()
        if not trees:
            states = [gp.state for gp in (gps.gp[0] if mixed else gps)]
        errs = {'mean': [], 'median': []}
        for j, i in enumerate(every):
            if trees:
                mean, cov = held[0][j:j + 1], held[1][j:j + 1]
            else:
                field = self._condition_gp(law, states, np.delete(every, j))
                mean, cov = self._param_dist(field, self._features[i:i + 1])
                if mixed:
                    mean, cov = mixture(mean, cov, np.clip(held[0][j:j + 1], *field[2]),
                                        held[1][j:j + 1])
            d, f = self._samples[i]
            if self.mean_setting in ('median', 'auto'):
                errs['median'].append(self.force_from_params(np.repeat(mean, len(d), 0), d,
                                                             law=law) - f)
            if self.mean_setting in ('mean', 'auto'):
                errs['mean'].append(self._mean_force(law, mean[0], cov[0], d)[0] - f)
        scores = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) if v else np.inf
                  for k, v in errs.items()}
        self._mode_scores[law] = scores
        return min(scores.values())

    # ---------------------------------------------------------------------------- prediction
    def _require(self) -> None:
        if self._gps is None:
            raise ModelNotReady('ContactGpModel: no pokes yet; fit the model first')

    def _param_dist(self, field, features: np.ndarray, with_cov: bool = True):
        if isinstance(field[0], TreeSpread):
            mean, cov = field[0].dist(features)
            return np.clip(mean, *field[2]), (cov if with_cov else None)
        if isinstance(field[0], Mixture):
            m1, c1 = self._param_dist(field[0].gp, features)
            m2, c2 = self._param_dist((field[0].trees, None, field[2], None), features)
            mean, cov = mixture(m1, c1, m2, c2)
            return mean, (cov if with_cov else None)
        gps, (mu, scale, chol), bounds, var_scale = field
        sq = {}
        out = [gp.predict(features, return_std=with_cov, sq=sq) for gp in gps]
        y = np.stack([o[0] for o in out] if with_cov else out, axis=1)
        mean = np.clip(mu + scale * (y @ chol.T), *bounds)
        if not with_cov:
            return mean, None
        var_y = np.stack([o[1] for o in out], axis=1) ** 2                 # (M, P)
        var_y = var_y * var_scale
        a = scale[:, None] * chol                                          # (P, P)
        k = len(a)
        pairs = (a[:, None, :] * a[None, :, :]).reshape(k * k, k).T        # (P, P*P)
        cov = (var_y @ pairs).reshape(len(var_y), k, k)
        return mean, cov

    def _field(self):
        return self._gps, self._mix, self._param_bounds, self._var_scale

    def predict_param_dist(self, features: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Mean (M, P) and covariance (M, P, P) of the law parameters ``theta`` at ``features``.

        Gaussian (the processes' predictive distribution mapped back through the
        decorrelation); the mean is kept within the training pokes' range (module docstring,
        point 4). Columns: :attr:`param_names`.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: features not (M, 9) or not finite.

        """
        self._require()
        features, _ = check_query(features, 0.0)
        with single_threaded_blas():
            return self._param_dist(self._field(), features)

    def predict_params(self, features: np.ndarray, return_std: bool = False):
        """Mean (M, P) and optionally std (M, P) of ``theta`` (:attr:`param_names`).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: features not (M, 9) or not finite.

        """
        self._require()
        features, _ = check_query(features, 0.0)
        with single_threaded_blas():
            mean, cov = self._param_dist(self._field(), features,
                                         with_cov=return_std)
        if not return_std:
            return mean
        return mean, np.sqrt(np.diagonal(cov, axis1=1, axis2=2))

    def sample_params(self, features: np.ndarray, n_samples: int,
                      rng: np.random.Generator) -> np.ndarray:
        """(S, M, P) draws of ``theta`` at each point from :meth:`predict_param_dist`.

        Draws at different points are independent (marginal per point). Pass them with the
        depths to :meth:`force_from_params` for a Monte-Carlo spread.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: features malformed or ``n_samples < 1``.

        """
        if int(n_samples) < 1:
            raise InvalidInput(f'sample_params: n_samples must be >= 1, got {n_samples}')
        mean, cov = self.predict_param_dist(features)
        k = mean.shape[1]
        chol = np.linalg.cholesky(cov + 1e-15 * np.eye(k))
        z = rng.standard_normal((int(n_samples), len(mean), k))
        return mean[None] + np.einsum('mij,smj->smi', chol, z)

    def _mean_force(self, law: str, mean: np.ndarray, cov: np.ndarray, d,
                    second: bool = False, dtype=np.float64):
        """Predictive mean force (and optionally ``E[f^2]``) over Gaussian parameters.

        ``mean`` (..., P) and ``cov`` (..., P, P) broadcast against ``d``: queries (M,) each,
        or the bake's (1, N) parameters against (K, 1) depths (the leading axes of ``mean``
        are then (N,)). Module docstring, point 6.
        """
        mean = np.asarray(mean, dtype=float)
        cov = np.asarray(cov, dtype=float)
        stiff = law == 'stiffening'
        c00 = np.maximum(cov[..., 0, 0], 1e-18)
        sd0 = np.sqrt(c00)
        k = mean.shape[-1]
        gain = cov[..., 1:, 0] / sd0[..., None]                       # (..., P-1)
        cr = cov[..., 1:, 1:] - gain[..., :, None] * gain[..., None, :]
        c = [cr[..., i, j].astype(dtype) for i in range(k - 1) for j in range(k - 1)]
        d = np.asarray(d, dtype=dtype)
        inv_ref = dtype(1.0 / self.ref_depth)
        total = total2 = None
        for z, w in zip(_GH_Z, _GH_W):
            d0 = (mean[..., 0] + z * sd0).astype(dtype)
            m = (mean[..., 1:] + z * gain).astype(dtype)
            s = d - d0
            on = s > 0
            lr = np.maximum(s, dtype(1e-9))
            lr *= inv_ref
            np.log(lr, out=lr)
            if not stiff:
                var = lr * (2 * c[1] + lr * c[3])
                var += c[0]
                logm = lr * m[..., 1]
            else:
                t = s * inv_ref
                t -= dtype(1.0)
                # conditional covariance of (log F, p, q), row-major: 0 1 2 / 4 5 / 8
                var = lr * (2 * c[1] + lr * c[4])
                var += t * (2 * c[2] + 2 * lr * c[5] + t * c[8])
                var += c[0]
                logm = lr * m[..., 1]
                logm += m[..., 2] * t
            logm += m[..., 0]
            np.clip(var, 0.0, LOG_VAR_CAP, out=var)
            if second:
                term2 = logm + var
                term2 *= dtype(2.0)
                np.exp(term2, out=term2)
                term2 *= on
                term2 *= dtype(w)
                total2 = term2 if total2 is None else np.add(total2, term2, out=total2)
            var *= dtype(0.5)
            logm += var
            np.exp(logm, out=logm)
            logm *= on
            logm *= dtype(w)
            total = logm if total is None else np.add(total, logm, out=total)
        return total, total2

    def _median_force(self, law: str, mean: np.ndarray, d, dtype=np.float64):
        return self.force_from_params(mean, d, law=law, dtype=dtype, check=False)

    def predict(self, features: np.ndarray, d) -> np.ndarray:
        """Predictive mean force (M,), newtons, at ``features`` (M, 9) and depths ``d`` (M,) m.

        ``mean='median'``: the force at the parameters' predictive mean instead.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        self._require()
        features, d = check_query(features, d)
        if self.mean == 'median':
            return self._median_force(self.law, self.predict_params(features), d)
        mean, cov = self.predict_param_dist(features)
        return self._mean_force(self.law, mean, cov, d)[0]

    def force_from_params(self, params, d, law: Optional[str] = None, dtype=np.float64,
                          check: bool = True) -> np.ndarray:
        """Force (M,), newtons, of the contact law with per-row ``params`` (M, P) at ``d`` (M,).

        ``params`` are :attr:`param_names` as :attr:`poke_params`, :meth:`predict_params` and
        :meth:`sample_params` give them; ``law`` defaults to the model's. Leading axes of
        ``params`` (..., P) broadcast against ``d``.

        Raises:
            InvalidInput: shapes disagree or values are not finite.

        """
        law = law or self.law
        k = len(LAW_PARAMS[law])
        params = np.asarray(params, dtype=float)
        d = np.asarray(d, dtype=float)
        if check and (params.ndim < 2 or params.shape[-1] != k
                      or d.shape != params.shape[:-1]
                      or not (np.all(np.isfinite(params)) and np.all(np.isfinite(d)))):
            raise InvalidInput(f'force_from_params: need finite (..., {k}) params and matching '
                               f'depths for the {law} law, got {params.shape} and {d.shape}')
        s = d.astype(dtype) - params[..., 0].astype(dtype)
        lr = np.log(np.maximum(s, dtype(1e-9)) * dtype(1.0 / self.ref_depth))
        logf = params[..., 1].astype(dtype) + params[..., 2].astype(dtype) * lr
        if k > 3:
            logf = logf + params[..., 3].astype(dtype) * (s * dtype(1.0 / self.ref_depth)
                                                          - dtype(1.0))
        return np.exp(logf) * (s > 0)

    def predict_std(self, features: np.ndarray, d) -> np.ndarray:
        """Predictive standard deviation (M,) of the force curve, newtons.

        ``sqrt(E[f^2] - E[f]^2)`` over the parameters' predictive distribution (the same
        quadrature as :meth:`predict`).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        self._require()
        features, d = check_query(features, d)
        mean, cov = self.predict_param_dist(features)
        m1, m2 = self._mean_force(self.law, mean, cov, d, second=True)
        return np.sqrt(np.maximum(m2 - m1 * m1, 0.0))

    def bake(self, surface: Surface, depths) -> BakedResponse:
        """Tabulate force, std and extrapolation slope on every point of ``surface``.

        Args:
            surface: N points; features ``surface.features``.
            depths: (K,) strictly increasing displacement grid, metres; start it below the
                earliest onset (negative depths are fine) so the table begins at zero force.

        Returns:
            ``BakedResponse`` with forces (N, K) = :meth:`predict`, std (N, K) =
            :meth:`predict_std` and slopes (N,) = the derivative of :meth:`predict` at
            ``depths[-1]`` (a one-sided difference over 10 um; 0 where not yet in contact).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: bad grid or surface.

        """
        self._require()
        if not isinstance(surface, Surface):
            raise InvalidInput(f'bake: expected a Surface, got {type(surface).__name__}')
        depths = check_depths(depths)
        h = 1e-5
        grid = np.append(depths, depths[-1] + h)[:, None]                  # (K+1, 1)
        mean, cov = self.predict_param_dist(surface.features)
        # float32 (fast) unless a steep law overflows it deep in the grid (E[f^2] first)
        for dtype in (np.float32, np.float64):
            with single_threaded_blas(), np.errstate(over='ignore', invalid='ignore'):
                q1, q2 = self._mean_force(self.law, mean, cov, grid, second=True,
                                          dtype=dtype)                  # (K+1, N)
                m1 = q1 if self.mean == 'mean' else \
                    self._median_force(self.law, mean, grid, dtype=dtype)
                if np.isfinite(q2.sum()) and np.isfinite(m1.sum()) \
                        and np.isfinite(np.square(q1.max(), dtype=dtype)):
                    break
        var = q2[:-1]
        var -= q1[:-1] ** 2
        np.maximum(var, 0.0, out=var)
        np.sqrt(var, out=var)
        forces = np.ascontiguousarray(m1[:-1].T, dtype=np.float64)
        std = np.ascontiguousarray(var.T, dtype=np.float64)
        m1 = m1.astype(np.float64)
        slopes = np.maximum((m1[-1] - m1[-2]) / h, 0.0)
        return BakedResponse(depths=depths, forces=forces, slopes=slopes, std=std,
                             version=self.version,
                             meta={'model': self.kind, 'n_pokes': len(self._ids),
                                   'poke_ids': list(self._ids), 'ref_depth': self.ref_depth,
                                   'law': self.law, 'mean': self.mean, 'spread': self.spread})

    def reference_depth(self) -> float:
        """Return a depth (m) where every trained location is in contact: max onset + ref."""
        self._require()
        return float(self._theta[:, 0].max() + self.ref_depth)

    # ------------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        """JSON-serialisable state (config, per-poke parameters of each law, GP hyperparameters).

        Format 2: ``config`` adds ``law`` (the setting), ``mean``; the top level adds ``law``
        (the chosen law); each poke's ``params`` are the chosen law's and ``params_by_law``
        holds every fitted law's, ``samples`` the contact samples of the law choice.
        """
        n = len(self._ids)
        return {
            'kind': self.kind, 'format': FORMAT, 'version': int(self.version),
            'config': {'ref_depth': self.ref_depth, 'exponent_bounds': list(self.exponent_bounds),
                       'prior_scales': list(self.prior_scales),
                       'max_surface_distance': self.max_surface_distance,
                       'bases': list(self.bases), 'grid': _grid_to_dict(self.grid),
                       'decorrelate': self.decorrelate, 'law': self.law_setting,
                       'mean': self.mean_setting, 'relevance': self.relevance,
                       'robust_z': self.robust_z, 'spread': self.spread},
            'mean_used': self.mean,
            'fine_relevance': bool(self.fine_relevance),
            'law': self.law,
            'law_scores': {k: float(v) for k, v in self.law_scores.items()},
            'frame': None if self._frame is None else self._frame.to_dict(),
            'pokes': [{'poke_id': self._ids[i], 'features': self._features[i].tolist(),
                       'params': self._theta[i].tolist(),
                       'params_by_law': {k: self._thetas[k][i].tolist() for k in LAWS
                                         if len(self._thetas[k]) == n},
                       'fit_rms': float(self._fit_rms[i]),
                       'rms_by_law': {k: float(self._rms[k][i]) for k in LAWS
                                      if len(self._rms[k]) == n},
                       'onset': float(self._onsets[i]),
                       'samples': None if self._samples[i] is None
                       else [self._samples[i][0].tolist(), self._samples[i][1].tolist()]}
                      for i in range(n)],
            'processes': None if self._gps is None else self._states_dict(self._gps),
        }

    @staticmethod
    def _states_dict(spread):
        """Return the saved form of a fitted spread's states (``processes`` of :meth:`to_dict`)."""
        if isinstance(spread, TreeSpread):
            return {'trees': spread.state.to_dict()}
        if isinstance(spread, Mixture):
            return {'gp': [gp.state.to_dict() for gp in spread.gp[0]],
                    'trees': spread.trees.state.to_dict()}
        return [gp.state.to_dict() for gp in spread]

    @classmethod
    def from_dict(cls, data: Mapping) -> 'ContactGpModel':
        """Rebuild a model saved by :meth:`to_dict` (no refit: hyperparameters are reused).

        A format-1 model (before issue 17) loads as it was fitted: the power law, the force
        at the parameters' mean (``mean='median'``).

        Raises:
            InvalidInput: wrong kind or format, or missing fields.

        """
        fmt = data.get('format')
        if data.get('kind') != KIND or fmt not in (1, FORMAT):
            raise InvalidInput(f'ContactGpModel.from_dict: not a {KIND} v1/v{FORMAT} model '
                               f'(kind={data.get("kind")!r}, format={fmt!r})')
        try:
            cfg = data['config']
            model = cls(ref_depth=cfg['ref_depth'], exponent_bounds=cfg['exponent_bounds'],
                        prior_scales=cfg['prior_scales'],
                        max_surface_distance=cfg['max_surface_distance'],
                        bases=cfg['bases'], grid=_grid_from_dict(cfg['grid']),
                        # saved before decorrelation existed: its processes are independent
                        decorrelate=cfg.get('decorrelate', False),
                        law=cfg.get('law', 'power'), mean=cfg.get('mean', 'median'),
                        relevance=cfg.get('relevance', 'fixed'),
                        # saved before the outlier screen: conditioned without it
                        robust_z=cfg.get('robust_z'), spread=cfg.get('spread', 'gp'))
            model.fine_relevance = bool(data.get('fine_relevance', False))
            model.mean = data.get('mean_used', model.mean)
            pokes = data['pokes']
            law = data.get('law', 'power')
            model.law = law
            model.law_scores = dict(data.get('law_scores', {}))
            model.version = int(data['version'])
            model._frame = None if data['frame'] is None \
                else FeatureFrame.from_dict(data['frame'])
            model._ids = [p['poke_id'] for p in pokes]
            model._features = np.array([p['features'] for p in pokes], dtype=float
                                       ).reshape(-1, 9)
            for k in LAWS:
                size = len(LAW_PARAMS[k])
                rows = [p.get('params_by_law', {}).get(k) for p in pokes]
                if k == law:
                    rows = [p['params'] for p in pokes]
                if pokes and any(r is None for r in rows):
                    rows = []
                model._thetas[k] = np.array(rows, dtype=float).reshape(-1, size)
                rms = [p.get('rms_by_law', {}).get(k, p['fit_rms'] if k == law else None)
                       for p in pokes]
                model._rms[k] = np.array(rms, dtype=float) if len(rows) else np.zeros(0)
            model._samples = [None if p.get('samples') is None
                              else tuple(np.array(v, dtype=float) for v in p['samples'])
                              for p in pokes]
            # models saved before onsets were kept: the law's own onset stands in
            model._onsets = np.array([p.get('onset', p['params'][0]) for p in pokes],
                                     dtype=float)
            if data['processes'] is not None:
                saved = data['processes']
                if model.spread == 'trees':
                    model._fit_processes(TreeState.from_dict(saved['trees']))
                elif model.spread == 'mix':
                    model._fit_processes(([GpState.from_dict(s) for s in saved['gp']],
                                          TreeState.from_dict(saved['trees'])))
                else:
                    model._fit_processes([GpState.from_dict(s) for s in data['processes']])
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
