"""Probe trials: score the service's wrench answers against ground truth, before and after.

A probe trial (``pointforce cell generate --probes line,cylinder`` writes them to
``probes.npz``) presses a rigid body (a paddle or a cylinder) into the object along a fixed
direction and records the true force and torque at each depth. Point pokes never see how
contact points share a load; probe trials do, so they are the held-out test of what the point
model becomes once the contact simulator puts it to work.

:func:`score_probe_trials` learns the point model the way the nodes do
(:class:`~pointforce_ros.model.learner.OnlineLearner`: ours, :class:`ContactGpModel`, baked on the
equilibrium surface) once without and once with the accepted effects, answers every trial step
through :class:`~pointforce_ros.model.serving.WrenchServer` and
reports the force and torque RMSE of
both. The generated trials are the object's clean response (the cell applies a scenario's
effects to the pokes only), so the arm's series compliance is not added back for them
(``series_compliance=False``) and a viscoelastic effect answers the instantaneous force.

Spatial coupling beyond the shape function is tested here, not on pokes: a point probe has a
single contact point, so how strongly neighbouring contact points push each other's surface
down (``g(r) = c / (c + r)``, seed 000 eq. 2) leaves no trace in its curves. On probe trials a
wrong coupling shows as a force error that grows with the contact patch. The effect
``spatial_coupling`` has one parameter, the shape constant ``c`` (m), fitted on the trials
(:func:`fit_spatial_coupling`) with the tests diagnose uses on pokes: leave-one-trial-out
held-out error, one-sided Wilcoxon signed-rank on per-trial MSE, least relative improvement,
penalised score, and a fit that must not sit on the end of the searched range.

Series compliance is tested here too, on trials *measured through the arm*
(``ProbeTrial.compliant``: the arm or table gave way under the probe's total force). On point
pokes alone a series compliance only reparametrises each poke's curve (``d_meas = d + C f``
with the poke's own force ``f``): the learned curve absorbs it and nothing is left to identify
at a realistic stiffness (20 N/mm: p = 0.4-0.7 on pokes). A wide probe meets many contact
points at once and the arm gives way by ``C`` times their *total* force, far more than any
point's own share: a model that absorbed ``C`` into each point's curve is then too stiff.
:func:`fit_series_compliance` fits ``C`` on those trials with the same tests, the model for each
``C`` being the learned table corrected by ``C`` (``d -= C f`` per row, what the learner does to
the pokes) and served with the retreat on the total force.
"""

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.stats import wilcoxon

from pointforce_ros.effects.accepted import effects_from_dict
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.model.fit import fit_contact_model
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.pokes.trials import ProbeTrial
from pointforce_ros.types import ContactQuery, PokeRecord, Surface

COUPLING_RANGE = (5e-4, 0.05)
"""Searched range of the shape constant ``c``, metres."""

COUPLING_GRID = 17
"""Log-spaced values of ``c`` tried over :data:`COUPLING_RANGE`."""

COMPLIANCE_RANGE = (1e-6, 1e-3)
"""Searched range of the series compliance ``C``, m/N (1000 N/mm to 1 N/mm)."""

COMPLIANCE_GRID = 16
"""Log-spaced values of ``C`` tried over :data:`COMPLIANCE_RANGE`."""


def generated_files(data) -> Dict[str, Path]:
    """Files of a ``cell generate`` folder next to a pokes path (missing ones left out).

    ``data`` is the generate folder itself or its ``pokes`` store. Returns a mapping with
    ``probes`` (``probes.npz``) and ``surface`` (``surface.npz``) where they exist.
    """
    if isinstance(data, (list, tuple)):
        return {}
    path = Path(data)
    if not path.is_dir():
        return {}
    root = path if (path / 'pokes').is_dir() else path.parent
    found = {}
    for key, name in (('probes', 'probes.npz'), ('surface', 'surface.npz')):
        if (root / name).is_file():
            found[key] = root / name
    return found


# --------------------------------------------------------------------------- learning


def learn_contact_model(records: Sequence[PokeRecord], surface: Surface,
                        effects: Optional[Dict] = None, shape_constant: float = 0.004):
    """Learn the contact model the nodes would serve from ``records`` (probe scoring's name).

    Raises:
        DataError: no poke could be learned from.
        InvalidInput: malformed effects or shape constant.

    """
    try:
        return fit_contact_model(records, surface, effects=effects,
                                 shape_constant=shape_constant)
    except DataError as exc:
        raise DataError(f'probe scoring: {exc}') from exc


def _server(model, spacing: float, series_compliance: bool = False):
    server = WrenchServer(spacing, series_compliance=series_compliance, hold_time=0.0)
    server.swap(model)
    return server


def trial_errors(model, trials: Sequence[ProbeTrial], spacing: float = 0.003
                 ) -> Tuple[List[np.ndarray], List[np.ndarray]]:
    """Force and torque errors (K, 3) of every trial step answered by ``model`` (predicted - true).

    The answers come from :class:`~pointforce_ros.model.serving.WrenchServer` (batch query per
    trial,
    instantaneous viscoelastic force); a series compliance of the model is added back on
    ``compliant`` trials only.
    """
    servers = {flag: _server(model, spacing, flag)
               for flag in {bool(t.compliant) for t in trials}}
    force_err, torque_err = [], []
    for trial in trials:
        server = servers[bool(trial.compliant)]
        query = ContactQuery(mesh=trial.mesh, poses=trial.poses(), approach=trial.direction,
                             torque_centre=trial.torque_centre)
        batch, _ = server.answer_batch(query)
        force_err.append(batch.wrenches[:, :3] - trial.force)
        torque_err.append(batch.wrenches[:, 3:] - trial.torque)
    return force_err, torque_err


def _sse(errors: Sequence[np.ndarray]) -> np.ndarray:
    return np.array([float(np.sum(e ** 2)) for e in errors])


def _pooled(errors: Sequence[np.ndarray]) -> float:
    """RMSE of the error vectors over all steps (norm per step)."""
    total = sum(float(np.sum(e ** 2)) for e in errors)
    count = sum(len(e) for e in errors)
    return float(np.sqrt(total / max(count, 1)))


# --------------------------------------------------------------------------- coupling


@dataclass(frozen=True)
class CouplingResult:
    """An effect tested on probe trials: ``spatial_coupling`` or ``series_compliance``.

    Attributes:
        assumed: the model's value (shape constant ``c``, metres; compliance ``C``, m/N).
        fitted: the value that fits all trials best.
        std: jackknife standard deviation of the value over leave-one-trial-out fits.
        rmse_before: probe force RMSE with ``assumed``, N.
        rmse_after: held-out probe force RMSE, each trial with the value fitted on the
            others, N.
        improvement: ``1 - rmse_after / rmse_before``.
        p_value: one-sided Wilcoxon signed-rank p on the per-trial MSE.
        delta_score: change of ``n ln(MSE) + ln(n)`` (one added parameter, ``n`` trials).
        improved: trials whose held-out error dropped.
        accepted: passed every test and the bound check.
        rejected: why a candidate that passed the tests was refused ('' otherwise).
        trials: number of trials tested.
        alpha: significance level of the test.
        name: ``spatial_coupling`` (parameter ``shape_constant``) or ``series_compliance``
            (parameter ``compliance``).

    """

    assumed: float
    fitted: float
    std: float
    rmse_before: float
    rmse_after: float
    improvement: float
    p_value: float
    delta_score: float
    improved: int
    accepted: bool
    rejected: str = ''
    trials: int = 0
    alpha: float = 0.01
    name: str = 'spatial_coupling'

    @property
    def underpowered(self) -> bool:
        """Whether so few trials can never reach ``p < alpha`` (one-sided Wilcoxon)."""
        return 0.5 ** self.trials >= self.alpha

    @property
    def params(self) -> Dict[str, float]:
        """The effect's parameters as ``effects.json`` stores them."""
        key = 'shape_constant' if self.name == 'spatial_coupling' else 'compliance'
        return {key: float(self.fitted)}

    def describe(self) -> str:
        """Return one line for the console and the report."""
        verdict = 'accepted' if self.accepted else ('refused: ' + self.rejected
                                                    if self.rejected else 'not significant')
        if not self.accepted and self.underpowered:
            verdict += (f' (too few trials to test: {self.trials} cannot give p < '
                        f'{self.alpha:g}; at least '
                        f'{int(np.ceil(np.log(self.alpha) / np.log(0.5))) + 1} are needed)')
        if self.name == 'spatial_coupling':
            what = (f'shape constant c {self.fitted * 1e3:.2f} +- {self.std * 1e3:.2f} mm '
                    f'against the model\'s {self.assumed * 1e3:.2f} mm')
        else:
            stiffness = 1e-3 / self.fitted if self.fitted > 0 else float('inf')
            what = (f'compliance C {self.fitted * 1e3:.4g} +- {self.std * 1e3:.2g} mm/N '
                    f'(stiffness {stiffness:.3g} N/mm) against the model\'s '
                    f'{self.assumed * 1e3:.4g} mm/N, on trials measured through the arm')
        return (f'{self.name} (probe trials): {what}; held-out probe force RMSE '
                f'{self.rmse_before:.4g} -> {self.rmse_after:.4g} N '
                f'(p = {self.p_value:.2g}, {self.improved} trials better): {verdict}')


def _refine(grid_log: np.ndarray, cost: np.ndarray) -> float:
    """Minimum of ``cost`` over ``grid_log`` refined by a parabola through its neighbours."""
    k = int(np.argmin(cost))
    if 0 < k < len(cost) - 1:
        y0, y1, y2 = cost[k - 1:k + 2]
        denom = y0 - 2 * y1 + y2
        if denom > 0:
            step = grid_log[1] - grid_log[0]
            return float(grid_log[k] + 0.5 * step * (y0 - y2) / denom)
    return float(grid_log[k])


def _scaled_sse(a: np.ndarray, b: np.ndarray, c: np.ndarray, fit: np.ndarray) -> np.ndarray:
    """SSE of ``s F_pred - F_true`` per trial, ``s`` fitted on the trials in ``fit``.

    ``a = sum F_pred . F_true``, ``b = sum |F_pred|^2``, ``c = sum |F_true|^2`` per trial along
    the last axis (any leading grid axes); ``fit`` (T,) bool.
    """
    s = np.sum(a * fit, axis=-1) / np.maximum(np.sum(b * fit, axis=-1), 1e-300)
    s = s[..., None]
    return s * s * b - 2.0 * s * a + c


def _cross_terms(model, trials, spacing) -> np.ndarray:
    """(3, T): ``sum F_pred . F_true``, ``sum |F_pred|^2``, ``sum |F_true|^2`` per trial."""
    errors = trial_errors(model, trials, spacing)[0]
    out = np.empty((3, len(trials)))
    for j, (err, trial) in enumerate(zip(errors, trials)):
        pred = err + trial.force
        out[:, j] = (np.sum(pred * trial.force), np.sum(pred * pred),
                     np.sum(trial.force * trial.force))
    return out


def _grid_test(name: str, assumed: float, grid_log: np.ndarray, sse: np.ndarray,
               base_sse: np.ndarray, steps: np.ndarray, alpha: float,
               min_improvement: float, unit: str, scale: float,
               terms: Optional[np.ndarray] = None,
               base_terms: Optional[np.ndarray] = None) -> CouplingResult:
    """Leave-one-trial-out test of a one-parameter effect searched on a log grid.

    Args:
        sse: (G, T) per-trial force SSE at every grid value.
        base_sse: (T,) per-trial SSE of the model as it is.
        steps: (T,) steps per trial.
        unit, scale: for the bound message (value * scale in unit).
        terms, base_terms: (G, 3, T) and (3, T) cross terms (:func:`_cross_terms`): when
            given, every model (the base one included) also gets a force scale fitted on
            the training trials, a nuisance that absorbs a uniform stiffness error of the
            learned model, so that only the effect's own structure can pass the test.

    """
    n = sse.shape[1]
    everything = np.ones(n, dtype=bool)
    if terms is not None:
        a, b, c = terms[:, 0], terms[:, 1], terms[:, 2]
        ba, bb, bc = base_terms
        sse = _scaled_sse(a, b, c, everything)
        base_sse = np.array([_scaled_sse(ba, bb, bc, np.arange(n) != j)[j] for j in range(n)])
    held_sse = np.empty(n)
    c_loo = np.empty(n)
    for j in range(n):
        train = np.arange(n) != j
        per = sse if terms is None else _scaled_sse(a, b, c, train)       # (G, T)
        others = per[:, train].sum(axis=1)
        k = int(np.argmin(others))
        c_loo[j] = _refine(grid_log, others)
        held_sse[j] = per[k, j]
    total = sse.sum(axis=1)
    fitted = 10 ** _refine(grid_log, total)
    std = float(np.sqrt((n - 1) / n * np.sum((10 ** c_loo - np.mean(10 ** c_loo)) ** 2)))
    mse_old, mse_new = base_sse / steps, held_sse / steps
    if np.allclose(mse_old, mse_new, rtol=1e-12, atol=0.0):
        p_value = 1.0
    else:
        p_value = float(wilcoxon(mse_old, mse_new, alternative='greater',
                                 zero_method='wilcox').pvalue)
    rmse_before = float(np.sqrt(base_sse.sum() / steps.sum()))
    rmse_after = float(np.sqrt(held_sse.sum() / steps.sum()))
    improvement = 1.0 - rmse_after / rmse_before if rmse_before > 0 else 0.0
    delta = (n * np.log(max(held_sse.sum() / steps.sum(), 1e-300)) + np.log(n)
             - n * np.log(max(base_sse.sum() / steps.sum(), 1e-300)))
    significant = p_value < alpha and improvement >= min_improvement and delta < 0
    rejected = ''
    k_all = int(np.argmin(total))
    if significant and k_all in (0, len(grid_log) - 1):
        rejected = (f'fit on the end of the searched range ({fitted * scale:.3g} {unit}, range '
                    f'{10 ** grid_log[0] * scale:g}-{10 ** grid_log[-1] * scale:g} {unit}): '
                    'not an interior optimum')
    return CouplingResult(assumed=float(assumed), fitted=float(fitted), std=std,
                          rmse_before=rmse_before, rmse_after=rmse_after,
                          improvement=float(improvement), p_value=p_value,
                          delta_score=float(delta), improved=int(np.sum(mse_new < mse_old)),
                          accepted=bool(significant and not rejected), rejected=rejected,
                          trials=n, alpha=float(alpha), name=name)


def _check_range(what: str, trials, value_range) -> Tuple[float, float]:
    if len(trials) < 2:
        raise InvalidInput(f'{what}: need at least 2 probe trials')
    lo, hi = float(value_range[0]), float(value_range[1])
    if not 0 < lo < hi:
        raise InvalidInput(f'{what}: bad range {value_range}')
    return lo, hi


def fit_spatial_coupling(model, trials: Sequence[ProbeTrial], *, spacing: float = 0.003,
                         alpha: float = 0.01, min_improvement: float = 0.03,
                         c_range: Tuple[float, float] = COUPLING_RANGE,
                         grid: int = COUPLING_GRID) -> CouplingResult:
    """Test the shape constant of ``model`` on probe trials (module docstring).

    Raises:
        InvalidInput: fewer than 2 trials or a bad range.

    """
    lo, hi = _check_range('fit_spatial_coupling', trials, c_range)
    grid_log = np.linspace(np.log10(lo), np.log10(hi), int(grid))
    sse = np.array([_sse(trial_errors(dataclasses.replace(model, shape_constant=10 ** g),
                                      trials, spacing)[0]) for g in grid_log])   # (G, T)
    base_sse = _sse(trial_errors(model, trials, spacing)[0])
    steps = np.array([len(t.depths) for t in trials], dtype=np.float64)
    return _grid_test('spatial_coupling', float(model.shape_constant), grid_log, sse, base_sse,
                      steps, alpha, min_improvement, 'mm', 1e3)


def compliance_corrected(response, compliance: float):
    """Return a baked table learned through a series compliance, with the compliance removed.

    Each row's curve is moved by ``d -= compliance * f`` (what the learner does to the pokes)
    and resampled on the same depth grid; beyond the moved last depth it is extrapolated with
    the row's slope ``s / (1 - compliance s)`` (the denominator kept >= 0.05). A row whose
    moved depths fold back (``compliance * s >= 1``: the compliance exceeds the point's own)
    keeps its running maximum of depth.

    Args:
        response: :class:`~pointforce_ros.response.baked.BakedResponse` (N rows, K depths).
        compliance: m/N, >= 0.

    Raises:
        InvalidInput: a negative or non-finite compliance.

    """
    compliance = float(compliance)
    if not np.isfinite(compliance) or compliance < 0:
        raise InvalidInput(f'compliance_corrected: compliance must be >= 0, got {compliance}')
    if compliance == 0:
        return response
    depths, forces = response.depths, np.maximum(response.forces, 0.0)
    n, k = forces.shape
    moved = np.maximum.accumulate(depths[None, :] - compliance * forces, axis=1)
    moved = moved + np.arange(k)[None, :] * 1e-12            # strictly increasing per row
    span = float(depths[-1] - depths[0]) + float(np.max(depths[None, :] - moved)) + 1.0
    offset = np.arange(n)[:, None] * 2.0 * span
    flat_x = (moved + offset).ravel()
    query = (depths[None, :] + offset).ravel()
    j = np.clip(np.searchsorted(flat_x, query, side='right') - 1, 0, n * k - 2)
    row = np.repeat(np.arange(n), k)
    j = np.clip(j, row * k, row * k + k - 2)                 # stay inside each row
    x0, x1 = flat_x[j], flat_x[j + 1]
    f_flat = forces.ravel()
    w = np.clip((query - x0) / np.maximum(x1 - x0, 1e-300), 0.0, 1.0)
    resampled = (f_flat[j] + w * (f_flat[j + 1] - f_flat[j])).reshape(n, k)
    slope = response.slopes / np.maximum(1.0 - compliance * response.slopes, 0.05)
    last = moved[:, -1]
    beyond = depths[None, :] > last[:, None]
    resampled = np.where(beyond, forces[:, -1:] + slope[:, None] * (depths[None, :]
                                                                    - last[:, None]),
                         resampled)
    return dataclasses.replace(response, forces=resampled, slopes=slope)


def fit_series_compliance(model, trials: Sequence[ProbeTrial], *, spacing: float = 0.003,
                          alpha: float = 0.01, min_improvement: float = 0.03,
                          c_range: Tuple[float, float] = COMPLIANCE_RANGE,
                          grid: int = COMPLIANCE_GRID) -> CouplingResult:
    """Test a series compliance on probe trials measured through the arm (module docstring).

    ``model`` was learned without a compliance correction; for each ``C`` of the grid its table
    is corrected by ``C`` (:func:`compliance_corrected`) and served with the retreat on the total
    force. Only ``compliant`` trials are used.

    The test (held-out RMSE, p, penalised score) is the one of :func:`fit_spatial_coupling` on
    the models as the service would answer. The *value* is fitted with a nuisance: every
    model, the uncorrected one included, gets a force scale fitted on the training trials. A
    point model learned from noisy pokes can be uniformly too stiff by several per cent, which
    a compliance soaks up (0.03 N pokes: 12.6 N/mm fitted for a 20 N/mm arm without the
    nuisance, 23.6 N/mm with it; no arm at all: 33 N/mm at p = 0.05). A significant compliance
    is refused when, with the scale fitted too, it no longer lowers the held-out error or sits
    on the end of the range: a uniform stiffness error then explains the trials as well.

    Raises:
        InvalidInput: fewer than 2 compliant trials, a bad range, or a model that already
            holds a series compliance.

    """
    trials = [t for t in trials if t.compliant]
    lo, hi = _check_range('fit_series_compliance (trials marked compliant)', trials, c_range)
    effects = effects_from_dict(model.effects)
    if 'series_compliance' in effects:
        raise InvalidInput('fit_series_compliance: the model already holds a series compliance')
    grid_log = np.linspace(np.log10(lo), np.log10(hi), int(grid))
    terms = []
    for g in grid_log:
        candidate = dataclasses.replace(
            model, response=compliance_corrected(model.response, 10 ** g),
            effects={**effects, 'series_compliance': {'compliance': float(10 ** g)}})
        terms.append(_cross_terms(candidate, trials, spacing))
    terms = np.array(terms)                                            # (G, 3, T)
    base_terms = _cross_terms(model, trials, spacing)
    base_sse = base_terms[2] - 2 * base_terms[0] + base_terms[1]
    sse = terms[:, 2] - 2 * terms[:, 0] + terms[:, 1]
    steps = np.array([len(t.depths) for t in trials], dtype=np.float64)
    plain = _grid_test('series_compliance', 0.0, grid_log, sse, base_sse, steps,
                       alpha, min_improvement, 'mm/N', 1e3)
    scaled = _grid_test('series_compliance', 0.0, grid_log, sse, base_sse, steps,
                        alpha, min_improvement, 'mm/N', 1e3, terms=terms,
                        base_terms=base_terms)
    rejected = plain.rejected
    ends = 10 ** grid_log[[0, -1]]
    if plain.accepted and (scaled.improvement <= 0 or scaled.fitted <= ends[0] * 1.001
                           or scaled.fitted >= ends[1] / 1.001):
        rejected = (f'with a fitted force scale (a uniform stiffness error of the point model) '
                    f'the compliance no longer helps (held-out RMSE {scaled.rmse_before:.3g} -> '
                    f'{scaled.rmse_after:.3g} N, C {scaled.fitted * 1e3:.3g} mm/N)')
    return dataclasses.replace(plain, fitted=scaled.fitted, std=scaled.std,
                               accepted=bool(plain.accepted and not rejected),
                               rejected=rejected)


# --------------------------------------------------------------------------- scoring


@dataclass(frozen=True)
class ProbeScore:
    """Probe-trial errors of the served model before and after the accepted effects.

    Attributes:
        kinds: (T,) probe kind of each trial.
        steps: (T,) steps per trial.
        effects: the accepted effects the "after" model was learned with.
        shape_constant: ``c`` of both models, metres.
        force_before, force_after: (T,) per-trial force RMSE, N.
        torque_before, torque_after: (T,) per-trial torque RMSE, N m.
        force_rmse_before, force_rmse_after: pooled over all steps, N.
        torque_rmse_before, torque_rmse_after: pooled over all steps, N m.
        peak_force: largest true force magnitude over the trials, N.
        coupling: the spatial-coupling test on the "after" model (None: not run).
        compliance: the series-compliance test on the trials measured through the arm (None:
            not run: no such trials, or the pokes' selection already accepted one). When it
            is accepted, ``effects`` holds it and the "after" model was learned with it.

    """

    kinds: Tuple[str, ...]
    steps: np.ndarray
    effects: Dict[str, Dict[str, float]]
    shape_constant: float
    force_before: np.ndarray
    force_after: np.ndarray
    torque_before: np.ndarray
    torque_after: np.ndarray
    force_rmse_before: float
    force_rmse_after: float
    torque_rmse_before: float
    torque_rmse_after: float
    peak_force: float
    coupling: Optional[CouplingResult] = None
    compliance: Optional[CouplingResult] = None

    def describe(self) -> str:
        """Return the console lines."""
        label = ', '.join(self.effects) or 'no effect'
        lines = [f'probe trials ({len(self.kinds)}: {", ".join(sorted(set(self.kinds)))}; '
                 f'peak {self.peak_force:.3g} N): force RMSE {self.force_rmse_before:.4g} -> '
                 f'{self.force_rmse_after:.4g} N, torque RMSE {self.torque_rmse_before:.4g} '
                 f'-> {self.torque_rmse_after:.4g} N m (model learned without -> with '
                 f'{label}, c = {self.shape_constant * 1e3:.2f} mm)']
        if self.compliance is not None:
            lines.append(self.compliance.describe())
        if self.coupling is not None:
            lines.append(self.coupling.describe())
        return '\n'.join(lines)


def _per_trial(errors: Sequence[np.ndarray]) -> np.ndarray:
    return np.array([np.sqrt(np.mean(np.sum(e ** 2, axis=1))) for e in errors])


def score_probe_trials(records: Sequence[PokeRecord], trials: Sequence[ProbeTrial],
                       surface: Surface, effects: Optional[Dict] = None, *,
                       shape_constant: float = 0.004, spacing: float = 0.003,
                       coupling: bool = True, alpha: float = 0.01,
                       min_improvement: float = 0.03) -> ProbeScore:
    """Score probe trials with the point model learned without and with ``effects``.

    Args:
        records: the point pokes (all of them train the model: the trials are the held-out
            data).
        trials: probe trials with ground truth.
        surface: the equilibrium surface the model is baked on (``base``).
        effects: accepted effects ``{name: {param: value}}``.
        shape_constant: ``c`` of the served model, metres (the learner's parameter).
        spacing: rigid-mesh sampling of the simulator, metres.
        coupling: also test ``spatial_coupling`` on the "after" model (needs >= 2 trials)
            and, when ``effects`` has no series compliance and >= 2 trials are ``compliant``,
            ``series_compliance`` first (:func:`fit_series_compliance`); an accepted one joins
            the effects and the "after" model is learned again with it.
        alpha, min_improvement: the probe tests' settings (as diagnose's).

    Raises:
        InvalidInput: no trials, bad effects or settings.
        DataError: no poke could be learned from.

    """
    trials = list(trials)
    if not trials:
        raise InvalidInput('score_probe_trials: no probe trials')
    effects = dict(effects or {})
    before = learn_contact_model(records, surface, {}, shape_constant)
    after = learn_contact_model(records, surface, effects, shape_constant) if effects \
        else before
    fb, tb = trial_errors(before, trials, spacing)
    compliance = None
    if coupling and 'series_compliance' not in effects \
            and sum(1 for t in trials if t.compliant) >= 2:
        compliance = fit_series_compliance(after, trials, spacing=spacing, alpha=alpha,
                                           min_improvement=min_improvement)
        if compliance.accepted:
            effects['series_compliance'] = compliance.params
            after = learn_contact_model(records, surface, effects, shape_constant)
    fa, ta = trial_errors(after, trials, spacing) if effects else (fb, tb)
    result = fit_spatial_coupling(after, trials, spacing=spacing, alpha=alpha,
                                  min_improvement=min_improvement) \
        if coupling and len(trials) >= 2 else None
    return ProbeScore(
        kinds=tuple(t.kind for t in trials), steps=np.array([len(t.depths) for t in trials]),
        effects=effects, shape_constant=float(shape_constant),
        force_before=_per_trial(fb), force_after=_per_trial(fa),
        torque_before=_per_trial(tb), torque_after=_per_trial(ta),
        force_rmse_before=_pooled(fb), force_rmse_after=_pooled(fa),
        torque_rmse_before=_pooled(tb), torque_rmse_after=_pooled(ta),
        peak_force=float(max(np.linalg.norm(t.force, axis=1).max() for t in trials)),
        coupling=result, compliance=compliance)
