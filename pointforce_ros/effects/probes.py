"""Probe trials: score the service's wrench answers against ground truth, before and after.

A probe trial (``pointforce cell generate --probes line,cylinder`` writes them to
``probes.npz``) presses a rigid body (a paddle or a cylinder) into the object along a fixed
direction and records the true force and torque at each depth. Point pokes never see how
contact points share a load; probe trials do, so they are the held-out test of what the point
model becomes once the contact simulator puts it to work.

:func:`score_probe_trials` learns the point model the way the nodes do
(:class:`~pointforce_ros.learner.OnlineLearner`: ours, :class:`ContactGpModel`, baked on the
equilibrium surface) once without and once with the accepted effects, answers every trial step
through :class:`~pointforce_ros.serving.WrenchServer` and reports the force and torque RMSE of
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
"""

import dataclasses
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.stats import wilcoxon

from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.types import Mesh, Pose, PokeRecord, Surface

COUPLING_RANGE = (5e-4, 0.05)
"""Searched range of the shape constant ``c``, metres."""

COUPLING_GRID = 17
"""Log-spaced values of ``c`` tried over :data:`COUPLING_RANGE`."""


@dataclass(frozen=True)
class ProbeTrial:
    """One probe trial with its ground truth (``base`` frame, SI units).

    Attributes:
        kind: probe name (``line``, ``cylinder``, ...).
        mesh: the rigid probe in its own frame.
        start: probe pose at travel 0 (just touching the true surface).
        direction: (3,) unit push direction.
        torque_centre: (3,) point the torques are taken about (fixed in ``base``), metres.
        depths: (K,) travel along ``direction`` past ``start``, metres.
        force: (K, 3) true force on the probe, N.
        torque: (K, 3) true torque on the probe about ``torque_centre``, N m.

    """

    kind: str
    mesh: Mesh
    start: Pose
    direction: np.ndarray
    torque_centre: np.ndarray
    depths: np.ndarray
    force: np.ndarray
    torque: np.ndarray

    def poses(self) -> Tuple[Pose, ...]:
        """Return the probe pose at every depth."""
        return tuple(Pose(self.start.position + d * self.direction, self.start.orientation,
                          self.start.frame) for d in self.depths)


def trials_from_dicts(entries: Sequence[Dict]) -> List[ProbeTrial]:
    """Build trials from the mappings ``cell.generate.load_probe_trials`` returns.

    Raises:
        DataError: a trial with missing keys or inconsistent shapes.

    """
    trials = []
    for i, e in enumerate(entries):
        try:
            depths = np.asarray(e['depths'], dtype=np.float64).reshape(-1)
            trial = ProbeTrial(
                kind=str(e['kind']),
                mesh=Mesh(np.asarray(e['vertices'], dtype=np.float64),
                          np.asarray(e['triangles'], dtype=np.int64)),
                start=Pose(np.asarray(e['start_position'], dtype=np.float64),
                           np.asarray(e['orientation'], dtype=np.float64)),
                direction=np.asarray(e['direction'], dtype=np.float64).reshape(3),
                torque_centre=np.asarray(e['torque_centre'], dtype=np.float64).reshape(3),
                depths=depths,
                force=np.asarray(e['force'], dtype=np.float64).reshape(len(depths), 3),
                torque=np.asarray(e['torque'], dtype=np.float64).reshape(len(depths), 3))
        except (KeyError, ValueError, InvalidInput) as exc:
            raise DataError(f'probe trial {i}: {exc}') from exc
        trials.append(trial)
    return trials


def load_probe_trials(path) -> List[ProbeTrial]:
    """Read ``probes.npz`` (+ ``probes.json``) of ``pointforce cell generate``.

    Raises:
        DataError: missing or unreadable files.

    """
    from pointforce_ros.cell.generate import load_probe_trials as load_dicts
    try:
        return trials_from_dicts(load_dicts(path))
    except (OSError, KeyError, ValueError, json.JSONDecodeError) as exc:
        raise DataError(f'cannot read probe trials at {path}: {exc}') from exc


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
    """Learn the contact model the nodes would serve from ``records``.

    The records go into a temporary poke store that an
    :class:`~pointforce_ros.learner.OnlineLearner` reads (ours, corrected by ``effects``,
    baked on ``surface``); its last saved model is returned.

    Raises:
        DataError: no poke could be learned from.
        InvalidInput: malformed effects or shape constant.

    """
    from pointforce_ros.learner import OnlineLearner
    from pointforce_ros.model_io import load_model
    from pointforce_ros.pokes.store import PokeStore
    with tempfile.TemporaryDirectory(prefix='pointforce-probes-') as tmp:
        store = PokeStore(Path(tmp) / 'pokes')
        for rec in sorted(records, key=lambda r: float(r.t[0]) if len(r) else 0.0):
            if rec.probe == 'point':
                store.add(rec)
        learner = OnlineLearner(Path(tmp) / 'pokes', Path(tmp) / 'models', surface,
                                shape_constant=shape_constant, effects=effects or {})
        status = learner.update()
        if status is None or status.model_path is None:
            raise DataError('probe scoring: no poke could be learned from ('
                            + '; '.join(f'{k}: {v}' for k, v in
                                        list(learner.skipped.items())[:3]) + ')')
        return load_model(status.model_path)


def _server(model, spacing: float):
    from pointforce_ros.serving import WrenchServer
    server = WrenchServer(spacing, series_compliance=False, hold_time=0.0)
    server.swap(model)
    return server


def trial_errors(model, trials: Sequence[ProbeTrial], spacing: float = 0.003
                 ) -> Tuple[List[np.ndarray], List[np.ndarray]]:
    """Force and torque errors (K, 3) of every trial step answered by ``model`` (predicted - true).

    The answers come from :class:`~pointforce_ros.serving.WrenchServer` (batch query per trial,
    no series compliance added back, instantaneous viscoelastic force).
    """
    from pointforce_ros.types import ContactQuery
    server = _server(model, spacing)
    force_err, torque_err = [], []
    for trial in trials:
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
    """The ``spatial_coupling`` effect tested on probe trials.

    Attributes:
        assumed: the model's shape constant ``c``, metres.
        fitted: ``c`` that fits all trials best, metres.
        std: jackknife standard deviation of ``c`` over leave-one-trial-out fits, metres.
        rmse_before: probe force RMSE with ``assumed``, N.
        rmse_after: held-out probe force RMSE, each trial with the ``c`` fitted on the
            others, N.
        improvement: ``1 - rmse_after / rmse_before``.
        p_value: one-sided Wilcoxon signed-rank p on the per-trial MSE.
        delta_score: change of ``n ln(MSE) + ln(n)`` (one added parameter, ``n`` trials).
        improved: trials whose held-out error dropped.
        accepted: passed every test and the bound check.
        rejected: why a candidate that passed the tests was refused ('' otherwise).
        trials: number of trials tested.
        alpha: significance level of the test.

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

    @property
    def underpowered(self) -> bool:
        """Whether so few trials can never reach ``p < alpha`` (one-sided Wilcoxon)."""
        return 0.5 ** self.trials >= self.alpha

    def describe(self) -> str:
        """Return one line for the console and the report."""
        verdict = 'accepted' if self.accepted else ('refused: ' + self.rejected
                                                    if self.rejected else 'not significant')
        if not self.accepted and self.underpowered:
            verdict += (f' (too few trials to test: {self.trials} cannot give p < '
                        f'{self.alpha:g}; at least '
                        f'{int(np.ceil(np.log(self.alpha) / np.log(0.5))) + 1} are needed)')
        return (f'spatial_coupling (probe trials): shape constant c {self.fitted * 1e3:.2f} +- '
                f'{self.std * 1e3:.2f} mm against the model\'s {self.assumed * 1e3:.2f} mm; '
                f'held-out probe force RMSE {self.rmse_before:.4g} -> {self.rmse_after:.4g} N '
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


def fit_spatial_coupling(model, trials: Sequence[ProbeTrial], *, spacing: float = 0.003,
                         alpha: float = 0.01, min_improvement: float = 0.03,
                         c_range: Tuple[float, float] = COUPLING_RANGE,
                         grid: int = COUPLING_GRID) -> CouplingResult:
    """Test the shape constant of ``model`` on probe trials (module docstring).

    Raises:
        InvalidInput: fewer than 2 trials or a bad range.

    """
    if len(trials) < 2:
        raise InvalidInput('fit_spatial_coupling: need at least 2 probe trials')
    lo, hi = float(c_range[0]), float(c_range[1])
    if not 0 < lo < hi:
        raise InvalidInput(f'fit_spatial_coupling: bad c range {c_range}')
    assumed = float(model.shape_constant)
    grid_log = np.linspace(np.log10(lo), np.log10(hi), int(grid))
    sse = np.array([_sse(trial_errors(dataclasses.replace(model, shape_constant=10 ** g),
                                      trials, spacing)[0]) for g in grid_log])   # (G, T)
    base_sse = _sse(trial_errors(model, trials, spacing)[0])
    steps = np.array([len(t.depths) for t in trials], dtype=np.float64)
    n = len(trials)
    held_sse = np.empty(n)
    c_loo = np.empty(n)
    for j in range(n):
        others = np.delete(sse, j, axis=1).sum(axis=1)
        k = int(np.argmin(others))
        c_loo[j] = _refine(grid_log, others)
        held_sse[j] = sse[k, j]
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
        rejected = (f'fit on the end of the searched range (c = {fitted * 1e3:.3g} mm, range '
                    f'{lo * 1e3:g}-{hi * 1e3:g} mm): not an interior optimum')
    return CouplingResult(assumed=assumed, fitted=float(fitted), std=std,
                          rmse_before=rmse_before, rmse_after=rmse_after,
                          improvement=float(improvement), p_value=p_value,
                          delta_score=float(delta), improved=int(np.sum(mse_new < mse_old)),
                          accepted=bool(significant and not rejected), rejected=rejected,
                          trials=n, alpha=float(alpha))


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

    def describe(self) -> str:
        """Return the console lines."""
        label = ', '.join(self.effects) or 'no effect'
        lines = [f'probe trials ({len(self.kinds)}: {", ".join(sorted(set(self.kinds)))}; '
                 f'peak {self.peak_force:.3g} N): force RMSE {self.force_rmse_before:.4g} -> '
                 f'{self.force_rmse_after:.4g} N, torque RMSE {self.torque_rmse_before:.4g} '
                 f'-> {self.torque_rmse_after:.4g} N m (model learned without -> with '
                 f'{label}, c = {self.shape_constant * 1e3:.2f} mm)']
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
        coupling: also test ``spatial_coupling`` on the "after" model (needs >= 2 trials).
        alpha, min_improvement: the coupling test's settings (as diagnose's).

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
        coupling=result)
