"""``pointforce diagnose``: attribute held-out residuals to candidate effects, or say it cannot.

Procedure (``diagnose``):

1. Load point pokes (store, bag, CSV table, records, or a ``pointforce cell generate``
   folder) and prepare a batch (:func:`~pointforce_ros.diagnose.batch.make_batch`).
2. Split the pokes, seeded and by poke, into ``folds`` groups. Each group is held out once: the
   global parameters (exponent and effect parameters) are fitted on the other groups, and the
   held-out pokes are scored with them (their per-poke amplitude and contact direction, the
   nuisance of :mod:`~pointforce_ros.diagnose.model`, are solved on the poke itself). Every poke
   thus has one held-out error from a model that never saw it.
3. Greedy forward selection. In each round every remaining library effect is added in turn to
   the accepted set, refitted on the training folds and scored on the held-out pokes. A
   candidate is *significant* when all three hold:

   * paired one-sided Wilcoxon signed-rank test on the per-poke held-out mean squared errors
     (per sample; current set vs current set + candidate): ``p < alpha``;
   * the held-out *model RMSE* drops by at least ``min_improvement`` (relative) and the
     held-out model RMSE by at least ``resolution`` times the median peak force (absolute:
     an effect that changes the force prediction by less than that is not worth a term,
     however clean the data);
   * the penalised held-out score ``n ln(MSE) + k ln(n)`` (``n`` pokes, ``k`` fitted effect
     parameters: a BIC counted per poke, the unit of independent data; MSE of the model
     RMSE) drops.

   The *model RMSE* (:class:`DiagnoseReport`) averages the held-out residual over blocks of
   0.25 s of one phase of one poke, which removes most of the F/T white noise and keeps every
   structural error: an effect must explain a share of the error a model *can* explain, not
   of the sensor noise (a small F/T drift would otherwise need a 3 % drop of an RMSE that is
   mostly noise). ``improvement_on='sample'`` states both rules on the per-sample RMSE as
   before. Every figure is held out, so noise alone cannot make a candidate pass.

   Two plausibility checks follow; a candidate failing one is not accepted, and the report
   says why (``CandidateResult.rejected``):

   * *on a bound*: in a training-fold fit, the candidate's own parameters or the base law's
     (exponent, curvature) sit on a bound of the search box where the current set's fit did
     not. The optimum is then not interior: the parameters are not estimates, and the gain
     comes from bending a law that does not fit the curves (e.g. on an object whose curves
     stiffen over a bone, an offset of 5 mm with the exponent driven to its bound 4 buys a
     better shape, while the true camera bias is 2 mm);
   * *onset*: a surface offset must agree with the one the per-poke contact onsets give
     (:class:`OnsetOffset`, an independent measure of the same quantity that does not assume
     a global law) within ``3 sem + onset_tolerance``.

   * *explanation*: the candidate must remove at least ``explain_step`` (30 %) of the
     systematic held-out model RMSE the current set leaves (the model RMSE less the sensor
     noise left in block means): an effect that only soaks up a little of a structure it does
     not explain is not its cause.

   The penalty counts a candidate's parameters that are fitted in effect (a non-negative
   Prony weight left at zero is not). A candidate whose fit fails numerically (a
   :class:`~pointforce_ros.diagnose.model.NumericalFailure`) makes the round *inconclusive*:
   no other effect is accepted in its place, and the report names the effects it competed
   with. Quasi-static step data (fewer than ``STEP_SAMPLES`` samples per poke) are scored
   with the effects that apply; the others are listed with the reason (``not_applicable``).

   The significant candidate with the lowest penalised score is accepted; the next round
   starts from it. After each acceptance a backward check drops any earlier effect that is no
   longer significant (same three tests, the model without it against the model with it):
   an effect that only stood in for one found later does not stay. Selection stops when no
   candidate is significant.
4. The accepted set must remove at least ``explain`` (50 %) of the base model's systematic
   held-out model RMSE; otherwise it is named as *not accepted* (``not_accepted``) and the
   residual is reported as unexplained. When nothing is accepted and a residual remains, the
   nearest candidate is named as not accepted. The accepted set is refitted on all pokes;
   parameter uncertainty is a bootstrap over pokes.
5. Probe trials, where the data have them (a ``cell generate`` folder's ``probes.npz`` with
   its ``surface.npz``, or ``probes=`` and ``surface=``), are scored by
   :func:`~pointforce_ros.diagnose.probes.score_probe_trials`: the point model the nodes learn
   (ours) from all point pokes without and with the accepted effects, answered through the
   contact service; force and torque RMSE before and after. The ``spatial_coupling`` effect
   (the shape constant of the contact simulator) is tested on them there: point pokes cannot
   identify it. So is a ``series_compliance`` the pokes did not name, on trials measured
   through the arm (a stiff arm only reparametrises a point poke's curve; a wide probe bends
   it by the total force). Effects accepted on the trials join ``accepted`` (and
   ``effects.json``); the point-poke RMSEs do not change with them.
6. The held-out residual after selection is compared with the sensor noise (estimated from
   sample-to-sample differences). When its systematic part exceeds ``tolerance`` times the
   median peak force, the report says "unexplained residual" and shows its structure (by depth,
   phase, time in the poke, poke order, poke, and the best-fitting periodic component) instead
   of inventing a cause.
"""

import json
import os
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from scipy.signal import lombscargle
from scipy.stats import wilcoxon

from pointforce_ros.diagnose.batch import make_batch, PokeBatch
from pointforce_ros.pokes.table import load_pokes
from pointforce_ros.effects.library import LIBRARY, NOT_TESTABLE_ON_POKES
from pointforce_ros.diagnose.probes import generated_files, ProbeScore, score_probe_trials
from pointforce_ros.pokes.trials import load_probe_trials
from pointforce_ros.diagnose.model import (block_sse, Fit, fit_global, fold_indices,
                                           heldout_residual, MODEL_BLOCK, model_blocks,
                                           NumericalFailure, residual_table)
from pointforce_ros.errors import InvalidInput, NotConverged, PointforceError
from pointforce_ros.diagnose.report import summary_dict, write_report
from pointforce_ros.effects.library import spec
from pointforce_ros.model.files import load_surface
from pointforce_ros.pokes.curves import extract_curve

UNDERPOWERED = 'too few pokes to test'

STEP_SAMPLES = 25
"""Pokes with fewer analysed samples than this (median) are quasi-static step data."""

NEEDS_STREAM = {
    'time_offset': 'a pose/force time offset needs continuous streams: quasi-static steps '
                   'are read at rest, where a lag changes nothing',
    'viscoelastic': 'relaxation needs the force in time during a push or hold: quasi-static '
                    'steps give one settled value per depth',
}
"""Library effects that do not apply to quasi-static step data, with the reason."""

EXPLAIN = 0.5
"""Least share of the systematic held-out model RMSE an accepted set must remove."""

EXPLAIN_STEP = 0.3
"""Least share of the systematic held-out model RMSE left by the current set that each
accepted effect must remove when it joins."""


@dataclass(frozen=True)
class CandidateResult:
    """One candidate effect scored in one selection round.

    Attributes:
        name: effect name.
        n_params: parameters it adds.
        rmse: pooled held-out RMSE of the force vector with it, N.
        improvement: relative RMSE drop against the round's current set (1 - new / old).
        p_value: one-sided Wilcoxon signed-rank p on per-poke held-out MSE.
        delta_score: change of the penalised score ``n ln(MSE) + k ln(n)``.
        improved: number of pokes whose held-out error dropped.
        significant: passed all three tests and neither plausibility check.
        values: fitted parameters on the first training fold (for the record).
        rejected: why a candidate that passed the three tests was still not accepted (its
            fit sits on a bound of the search box, or a surface offset contradicts the
            onset estimate); empty otherwise.
        model_rmse: held-out *model RMSE* with it (white sensor noise averaged out, see
            :class:`DiagnoseReport`), N.
        model_improvement: relative model-RMSE drop against the round's current set.

    """

    name: str
    n_params: int
    rmse: float
    improvement: float
    p_value: float
    delta_score: float
    improved: int
    significant: bool
    values: Dict[str, float] = field(default_factory=dict)
    rejected: str = ''
    model_rmse: float = float('nan')
    model_improvement: float = float('nan')


@dataclass(frozen=True)
class SelectionRound:
    """One round of greedy forward selection.

    Attributes:
        current: effects accepted before the round.
        rmse: held-out RMSE of the current set, N.
        candidates: every candidate tried, best penalised score first.
        chosen: the effect accepted in this round, or None (selection stops).
        removed: effects accepted earlier that the backward check dropped after ``chosen``
            joined (no longer significant given it).

    """

    current: Tuple[str, ...]
    rmse: float
    candidates: Tuple[CandidateResult, ...]
    chosen: Optional[str]
    removed: Tuple[str, ...] = ()


@dataclass(frozen=True)
class AcceptedEffect:
    """An accepted effect with its parameters fitted on all pokes.

    Attributes:
        name: library name.
        title: human name.
        params: value of each parameter (SI) and the fixed settings.
        std: bootstrap standard deviation of each fitted parameter.
        low, high: bootstrap 2.5 % and 97.5 % quantiles.

    """

    name: str
    title: str
    params: Dict[str, float]
    std: Dict[str, float]
    low: Dict[str, float]
    high: Dict[str, float]


@dataclass(frozen=True)
class Finding:
    """One view of the residual's structure.

    Attributes:
        factor: ``depth``, ``phase``, ``time_in_poke``, ``poke_order``, ``poke``, ``speed`` or
            ``periodic``.
        explained: fraction of the normal-residual variance the factor explains (0..1).
        detail: one line for the report.
        groups: ``(label, mean residual N, rms residual N, samples)`` per group.

    """

    factor: str
    explained: float
    detail: str
    groups: Tuple[Tuple[str, float, float, int], ...] = ()


@dataclass(frozen=True)
class OnsetOffset:
    """The surface offset the learner's per-poke contact onset absorbs (camera-bias estimate).

    The learner's contact law starts at a fitted onset ``d0`` per poke
    (:func:`~pointforce_ros.pokes.curves.extract_curve`), so a constant camera depth bias
    never reaches its predictions: it sits in ``d0``. Its mean is the bias estimate.

    Attributes:
        offset: ``-mean(d0)``, metres (> 0: the true surface lies outside the observed one,
            the sign of the library's ``surface_offset``).
        sem: standard error of the mean over pokes, metres.
        spread: standard deviation of ``d0`` over pokes, metres (camera noise + fit).
        count: pokes whose onset was found.

    """

    offset: float
    sem: float
    spread: float
    count: int

    def describe(self) -> str:
        """Return one line for the console and the report."""
        return (f'surface offset {self.offset * 1e3:.2f} +- {self.sem * 1e3:.2f} mm absorbed '
                f'by the onset (mean of {self.count} per-poke contact onsets d0, spread '
                f'{self.spread * 1e3:.2f} mm): the camera-bias estimate; the learner absorbs '
                'it without a correction')


def onset_offset(records) -> Optional[OnsetOffset]:
    """Return the surface offset absorbed by the per-poke onsets of point pokes (None: < 2).

    Pokes whose loading curve cannot be cut (no contact, too short) are left out.
    """
    onsets = []
    for rec in records:
        if rec.probe != 'point':
            continue
        try:
            curve = extract_curve(rec)
        except PointforceError:
            continue
        if curve.meta.get('onset_observed', True):
            onsets.append(float(curve.onset_d))
    if len(onsets) < 2:
        return None
    onsets = np.asarray(onsets)
    spread = float(np.std(onsets, ddof=1))
    return OnsetOffset(offset=-float(np.mean(onsets)), sem=spread / np.sqrt(len(onsets)),
                       spread=spread, count=len(onsets))


@dataclass
class DiagnoseReport:
    """Result of :func:`diagnose` (see the module docstring for the procedure).

    RMSE figures are pooled over the held-out samples of all pokes (force vector, N);
    ``systematic_*`` remove the estimated sensor-noise variance.

    Two held-out RMSEs are reported. The *sample RMSE* (``rmse_*``) is taken over every
    analysed sample and includes the F/T white noise, which no model can predict: a small
    effect can never halve it. The *model RMSE* (``model_rmse_*``) is taken over the means of
    the held-out residual in blocks of :data:`~pointforce_ros.diagnose.model.MODEL_BLOCK`
    consecutive samples of one phase of one poke (:func:`~pointforce_ros.diagnose.model.
    model_blocks`; ``model_coverage`` is the share of samples in a block): averaging divides
    the white-noise variance by the block size and keeps every structural error slower than a
    block. "Held-out error at most half of before" (``halved``) is judged on the model RMSE,
    because only the model's error can be removed by an effect; the sample RMSE stays in the
    report as the error a single measured sample has.
    """

    source: str
    settings: Dict[str, float]
    ids: Tuple[str, ...]
    points: np.ndarray
    notes: List[str]
    rounds: List[SelectionRound]
    accepted: List[AcceptedEffect]
    exponent: float
    rmse_before: float
    rmse_after: float
    noise_rms: float
    systematic_before: float
    systematic_after: float
    poke_rmse_before: np.ndarray
    poke_rmse_after: np.ndarray
    unexplained: bool
    tolerance: float
    structure_before: List[Finding]
    structure_after: List[Finding]
    residual_before: Dict[str, np.ndarray]
    residual_after: Dict[str, np.ndarray]
    probe_trials: int
    not_testable: Dict[str, str]
    onset: Optional[OnsetOffset] = None
    probe: Optional[ProbeScore] = None
    model_rmse_before: float = float('nan')
    model_rmse_after: float = float('nan')
    model_coverage: float = float('nan')
    inconclusive: Tuple[str, ...] = ()
    inconclusive_reason: str = ''
    not_applicable: Dict[str, str] = field(default_factory=dict)
    not_accepted: Dict[str, str] = field(default_factory=dict)
    explained: float = float('nan')
    warnings_seen: Tuple[str, ...] = ()

    @property
    def halved(self) -> bool:
        """Whether the held-out model RMSE after is at most half of before (the criterion)."""
        return bool(self.model_rmse_after <= 0.5 * self.model_rmse_before)

    @property
    def accepted_names(self) -> List[str]:
        """Names of the accepted effects in the order they were accepted."""
        return [a.name for a in self.accepted]

    def effects(self) -> Dict[str, Dict[str, float]]:
        """Return the accepted effects as ``{name: {param: value}}`` (``ContactModel.effects``)."""
        return {a.name: dict(a.params) for a in self.accepted}

    def offset_disagreement(self) -> str:
        """Return a warning when an accepted surface offset disagrees with the onset estimate.

        They measure the same thing; a gap of more than 3 standard errors plus 0.5 mm means the
        base law's shape does not fit the curves and the offset fit soaked that up.
        """
        fitted = {a.name: a for a in self.accepted}.get('surface_offset')
        if fitted is None or self.onset is None:
            return ''
        gap = fitted.params['offset'] - self.onset.offset
        sigma = float(np.hypot(self.onset.sem, fitted.std.get('offset', 0.0)))
        if abs(gap) <= 3.0 * sigma + 5e-4:
            return ''
        return (f'caution: the fitted surface offset ({fitted.params["offset"] * 1e3:.2f} mm) '
                f'differs from the onset estimate ({self.onset.offset * 1e3:.2f} mm) by '
                f'{gap * 1e3:.2f} mm: the curves\' shape departs from the base law (see the '
                'unexplained residual), trust the onset estimate for the camera bias')

    def summary(self) -> str:
        """Return a few lines for the console."""
        lines = [f'{len(self.ids)} pokes; held-out RMSE {self.rmse_before:.4g} N -> '
                 f'{self.rmse_after:.4g} N per sample (sensor noise {self.noise_rms:.3g} N); '
                 f'model RMSE {self.model_rmse_before:.4g} N -> {self.model_rmse_after:.4g} N '
                 f'(noise averaged out; after/before '
                 f'{self.model_rmse_after / max(self.model_rmse_before, 1e-300):.2f})']
        for a in self.accepted:
            params = ', '.join(f'{k}={v:.4g}' + (f'+-{a.std[k]:.2g}' if k in a.std else '')
                               for k, v in a.params.items())
            lines.append(f'accepted {a.name}: {params}')
        if not self.accepted:
            lines.append('no effect accepted')
            if any(n.startswith(UNDERPOWERED) for n in self.notes) and self.rounds \
                    and self.rounds[0].candidates:
                best = min(self.rounds[0].candidates, key=lambda c: c.rmse)
                lines.append(f'{UNDERPOWERED}: the strongest candidate was {best.name} '
                             f'(held-out RMSE {self.rmse_before:.4g} -> {best.rmse:.4g} N), '
                             'not accepted: poke more before drawing a conclusion')
        refused = {}
        for rnd in self.rounds:
            for c in rnd.candidates:
                if c.rejected:
                    refused.setdefault(c.name, c.rejected)
        for name, why in refused.items():
            lines.append(f'not accepted: {name} passed the tests but {why}')
        for name, why in self.not_accepted.items():
            if name not in refused:
                lines.append(f'NOT accepted: {name}: {why}')
        if self.inconclusive:
            lines.append(f'inconclusive between {", ".join(self.inconclusive)}: '
                         f'{self.inconclusive_reason}')
        for name, why in self.not_applicable.items():
            lines.append(f'does not apply: {name}: {why}')
        if self.onset is not None:
            lines.append(self.onset.describe())
            note = self.offset_disagreement()
            if note:
                lines.append(note)
        if self.probe is not None:
            lines.append(self.probe.describe())
        if self.unexplained:
            top = self.structure_after[0] if self.structure_after else None
            lines.append('unexplained residual: systematic part '
                         f'{self.systematic_after:.3g} N > tolerance {self.tolerance:.3g} N'
                         + (f'; strongest structure: {top.detail}' if top else ''))
        return '\n'.join(lines)


# --------------------------------------------------------------------------- selection


def _cross_fit(batch: PokeBatch, folds: Sequence[np.ndarray], effects: Sequence[str],
               starts: Optional[Sequence[Dict]] = None) -> List[Tuple[np.ndarray, Fit]]:
    everything = np.arange(len(batch))
    out = []
    for k, held in enumerate(folds):
        train = np.setdiff1d(everything, held)
        start = starts[k] if starts is not None else None
        out.append((held, fit_global(batch, effects, pokes=train, start=start)))
    return out


def _heldout(batch: PokeBatch, fits, blocks: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Per-poke held-out sample SSE and model SSE (block means, :func:`model_blocks`), N^2."""
    resid = heldout_residual(batch, fits)
    sse = np.add.reduceat(np.einsum('ij,ij->i', resid, resid), batch.starts[:-1])
    return sse, block_sse(batch, resid, blocks)[0]


def _poke_mse(batch: PokeBatch, sse: np.ndarray) -> np.ndarray:
    return sse / np.diff(batch.starts)


def _pooled_rmse(batch: PokeBatch, sse: np.ndarray) -> float:
    return float(np.sqrt(np.sum(sse) / batch.n_samples))


def _score(batch: PokeBatch, sse: np.ndarray, k: int) -> float:
    n = len(batch)
    return n * np.log(max(np.sum(sse) / batch.n_samples, 1e-300)) + k * np.log(n)


def _on_bound(fit: Fit, effects: Sequence[str], rel: float = 1e-3) -> set:
    """``(effect, parameter)`` pairs of ``effects`` (``base`` for the law) on a search bound."""
    out = set()
    for (name, p), x in zip(fit.layout.entries, fit.x):
        if name not in effects:
            continue
        margin = rel * (p.upper - p.lower)
        if (x <= p.lower + margin and not (p.zero_ok or p.limit_ok)) or x >= p.upper - margin:
            out.add((name, p.name))
    return out


def _plausibility(name: str, cand_fits, cur_fits, onset: Optional[OnsetOffset],
                  onset_tolerance: float) -> str:
    """Return why a significant candidate cannot be accepted, or ''."""
    for (_, new), (_, old) in zip(cand_fits, cur_fits):
        flagged = _on_bound(new, ('base', name)) - _on_bound(old, ('base',))
        if flagged:
            text = ', '.join(f'{e}.{k} = {_value_text(new.values[e][k])}'
                             for e, k in sorted(flagged))
            return (f'fit on a bound of the search box ({text}): not an interior optimum, '
                    'the law does not fit the curves')
    if name == 'surface_offset' and onset is not None:
        fitted = float(np.mean([f.values[name]['offset'] for _, f in cand_fits]))
        allowed = 3.0 * onset.sem + float(onset_tolerance)
        if abs(fitted - onset.offset) > allowed:
            return (f'offset {fitted * 1e3:.2f} mm contradicts the onset estimate '
                    f'{onset.offset * 1e3:.2f} +- {onset.sem * 1e3:.2f} mm (allowed gap '
                    f'{allowed * 1e3:.2f} mm): the fit bends the law instead of moving the '
                    'surface')
    return ''


def _value_text(value: float) -> str:
    return f'{value:.4g}'


def _model_rmse(msse: np.ndarray, covered: float) -> float:
    return float(np.sqrt(np.sum(msse) / covered)) if covered > 0 else float('nan')


def _compare(batch, sse_old, sse_new, k_add, alpha, min_improvement, min_drop,
             msse_old=None, msse_new=None, covered=0.0, on_model=False):
    """Run the selection tests of a new set against an old one (module docstring, step 3).

    The Wilcoxon test uses the per-poke sample MSE; the relative improvement rule, the
    penalised score and the absolute resolution rule use the model RMSE when ``on_model`` (and
    model SSEs are given), else the sample RMSE.

    Returns:
        ``(rmse_new, improvement, p, delta, improved, significant, model_rmse_new,
        model_improvement)``.

    """
    mse_old, mse_new = _poke_mse(batch, sse_old), _poke_mse(batch, sse_new)
    diff = mse_old - mse_new
    if np.all(np.abs(diff) <= 1e-15 * np.maximum(mse_old, 1e-300)):
        p_value = 1.0
    else:
        p_value = float(wilcoxon(mse_old, mse_new, alternative='greater',
                                 zero_method='wilcox').pvalue)
    rmse_old, rmse_new = _pooled_rmse(batch, sse_old), _pooled_rmse(batch, sse_new)
    improvement = 1.0 - rmse_new / rmse_old if rmse_old > 0 else 0.0
    delta = _score(batch, sse_new, k_add) - _score(batch, sse_old, 0)
    model_new, model_imp = float('nan'), float('nan')
    relative = improvement
    drop = rmse_old - rmse_new
    if msse_old is not None and msse_new is not None:
        model_old, model_new = _model_rmse(msse_old, covered), _model_rmse(msse_new, covered)
        model_imp = 1.0 - model_new / model_old if model_old > 0 else 0.0
        if on_model and covered > 0:
            relative = model_imp
            n = len(batch)
            delta = n * np.log(max(model_new, 1e-150) ** 2 / max(model_old, 1e-150) ** 2) \
                + k_add * np.log(n)
            # the change of the prediction, white noise averaged out (issue 20: the sample
            # RMSE drop is compressed by the noise and hid a 63 % model-RMSE drop)
            drop = model_old - model_new
    significant = (p_value < alpha) and (relative >= min_improvement) and (delta < 0) \
        and (drop >= min_drop)
    return (rmse_new, improvement, p_value, delta, int(np.count_nonzero(diff > 0)),
            significant, model_new, model_imp)


# --------------------------------------------------------------------------- residual analysis


def noise_rms(batch: PokeBatch, resid: Dict[str, np.ndarray]) -> float:
    """Sensor-noise RMS of the force vector (N) from second differences of the residual.

    White noise of variance ``s^2`` gives second differences of variance ``6 s^2``; the smooth,
    systematic part of a residual (even a disturbance of a few hertz) hardly enters them.
    Robust (median absolute deviation), within pokes only.
    """
    same = (batch.seg[2:] == batch.seg[1:-1]) & (batch.seg[1:-1] == batch.seg[:-2])
    total = 0.0
    for key in ('rx', 'ry', 'rz'):
        second = np.diff(resid[key], n=2)[same]
        if len(second):
            mad = np.median(np.abs(second - np.median(second)))
            total += (1.4826 * mad) ** 2 / 6.0
    return float(np.sqrt(total))


def _phase_labels(resid: Dict[str, np.ndarray], batch: PokeBatch) -> np.ndarray:
    v = resid['v']
    slow = np.abs(v) < 0.1 * batch.per_sample(batch.speed)
    labels = np.where(resid['d'] < 0, 'd<0',
                      np.where(slow, 'hold', np.where(v > 0, 'loading', 'unloading')))
    return labels


def _grouped(values: np.ndarray, labels: np.ndarray, order=None):
    total = float(np.sum((values - values.mean()) ** 2))
    keys = order if order is not None else sorted(set(labels.tolist()))
    groups = []
    between = 0.0
    for key in keys:
        sel = labels == key
        if not np.any(sel):
            continue
        mean = float(values[sel].mean())
        groups.append((str(key), mean, float(np.sqrt(np.mean(values[sel] ** 2))),
                       int(np.count_nonzero(sel))))
        between += np.count_nonzero(sel) * (mean - values.mean()) ** 2
    return (between / total if total > 0 else 0.0), tuple(groups)


def analyse_structure(batch: PokeBatch, resid: Dict[str, np.ndarray]) -> List[Finding]:
    """Describe the residual's structure, strongest first (see :class:`Finding`)."""
    r = resid['normal']
    findings = []
    edges_mm = np.array([-np.inf, 0.0, 1.0, 2.0, 3.0, 4.0, 6.0, np.inf])
    depth_bin = np.digitize(resid['d'] * 1e3, edges_mm[1:-1])
    names = ['d<0', '0-1 mm', '1-2 mm', '2-3 mm', '3-4 mm', '4-6 mm', '>6 mm']
    frac, groups = _grouped(r, np.asarray(names)[depth_bin], order=names)
    findings.append(Finding('depth', frac, f'by depth: {frac:.0%} of the variance', groups))
    phase = _phase_labels(resid, batch)
    frac, groups = _grouped(r, phase, order=['d<0', 'loading', 'hold', 'unloading'])
    findings.append(Finding('phase', frac, f'by phase: {frac:.0%} of the variance', groups))
    span = max(float(resid['t'].max()), 1e-9)
    tbin = np.minimum((resid['t'] / span * 6).astype(int), 5)
    labels = np.array([f'{k * span / 6:.1f}-{(k + 1) * span / 6:.1f} s' for k in range(6)])
    frac, groups = _grouped(r, labels[tbin], order=list(labels))
    findings.append(Finding('time_in_poke', frac, f'by time in the poke: {frac:.0%} of the '
                            'variance', groups))
    n = len(batch)
    thirds = np.minimum((batch.order.argsort().argsort() * 3) // max(n, 1), 2)
    labels = np.array(['first third', 'middle third', 'last third'])[thirds][batch.seg]
    frac, groups = _grouped(r, labels, order=['first third', 'middle third', 'last third'])
    findings.append(Finding('poke_order', frac, f'by poke order: {frac:.0%} of the variance',
                            groups))
    frac, groups = _grouped(r, np.asarray(batch.ids)[batch.seg], order=list(batch.ids))
    findings.append(Finding('poke', frac, f'by poke (location): {frac:.0%} of the variance',
                            groups))
    t_abs = resid['t_abs']
    duration = float(t_abs.max() - t_abs.min())
    dt = float(np.median(batch.dt))
    if duration > 0 and len(r) > 20:
        f_lo = max(2.0 / duration, 0.05)
        f_hi = min(0.25 / dt, 20.0)
        if f_hi > f_lo:
            freqs = np.geomspace(f_lo, f_hi, 300)
            centred = r - r.mean()
            power = lombscargle(t_abs, centred, 2 * np.pi * freqs, normalize=True)
            k = int(np.argmax(power))
            frac = float(power[k])
            findings.append(Finding('periodic', frac, f'periodic component at {freqs[k]:.3g} Hz'
                                    f' (period {1 / freqs[k]:.3g} s): {frac:.0%} of the variance',
                                    ((f'{freqs[k]:.4g} Hz', 0.0, float(np.sqrt(2 * frac)
                                                                       * centred.std()),
                                      len(r)),)))
    findings.sort(key=lambda f: -f.explained)
    return findings


# --------------------------------------------------------------------------- main entry


def _bootstrap(batch: PokeBatch, effects: Sequence[str], start: Dict, n_boot: int,
               seed: int) -> List[Dict]:
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7919]))
    out = []
    for _ in range(int(n_boot)):
        idx = rng.integers(0, len(batch), len(batch))
        try:
            out.append(fit_global(batch, effects, pokes=idx, start=start,
                                  multistart=False).values)
        except NotConverged:
            continue
    return out


def diagnose(data, **kwargs) -> DiagnoseReport:
    """Find which library effects explain the residual of held-out pokes (module docstring).

    Takes the arguments of :func:`_diagnose`. Numerical warnings (overflow, a degenerate test)
    never reach the user as warning text: they are handled where they arise (a fit that is not
    finite is a :class:`~pointforce_ros.diagnose.model.NumericalFailure`, which makes the
    verdict inconclusive) and any that remain are listed in ``report.warnings_seen`` and the
    notes.
    """
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        report = _diagnose(data, **kwargs)
    seen = sorted({f'{w.category.__name__}: {w.message}' for w in caught})
    if seen:
        report.warnings_seen = tuple(seen)
        report.notes.append(f'{len(seen)} numerical warning(s) handled during the analysis '
                            f'(first: {seen[0][:120]})')
    return report


def _diagnose(data, *, seed: int = 0, alpha: float = 0.01, folds: int = 2,
              min_improvement: float = 0.03, resolution: float = 0.001,
              tolerance: float = 0.005, bootstrap: int = 20,
              max_rate: float = 50.0, window: float = 0.002,
              candidates: Optional[Sequence[str]] = None, onset_tolerance: float = 0.001,
              probes=None, surface=None, shape_constant: float = 0.004,
              improvement_on: str = 'model', explain: float = EXPLAIN,
              explain_step: float = EXPLAIN_STEP, log=None) -> DiagnoseReport:
    """Run the diagnosis (see :func:`diagnose`).

    Args:
        data: a PokeStore directory, a bag directory, a CSV table or a sequence of
            :class:`~pointforce_ros.types.PokeRecord`.
        seed: seed of the train/held-out split and of the bootstrap.
        alpha: significance level of the one-sided Wilcoxon signed-rank test.
        folds: number of held-out groups (each poke is held out once).
        min_improvement: least relative drop of the held-out RMSE to accept an effect.
        resolution: least absolute drop of the held-out RMSE, as a fraction of the median
            peak force.
        tolerance: a systematic residual above ``tolerance`` times the median peak force (or
            above the noise, whichever is larger) is reported as unexplained.
        bootstrap: bootstrap resamples over pokes for the parameter uncertainty (0: none).
        max_rate: samples are block-averaged down to at most this rate, Hz.
        window: samples farther than this outside the surface are ignored, metres.
        candidates: restrict the library (names); all by default.
        onset_tolerance: largest gap, metres, beyond three standard errors, between an
            accepted surface offset and the onset estimate (the onset fit's own bias on a
            soft cap: 0.7 mm measured on ``lamb``).
        probes: probe trials (a ``probes.npz`` path or a sequence of
            :class:`~pointforce_ros.diagnose.probes.ProbeTrial`); by default those of the
            ``cell generate`` folder ``data`` is or lies in. None there: not scored.
        surface: the equilibrium surface the point model is baked on for the probe trials (a
            :class:`~pointforce_ros.types.Surface` or a ``surface.npz`` path); by default the
            generate folder's.
        shape_constant: ``c`` of the served model for the probe trials, metres (the
            learner's ``shape_constant`` parameter).
        improvement_on: ``'model'`` states the relative-improvement rule
            (``min_improvement``) on the held-out model RMSE, ``'sample'`` on the sample RMSE.
        explain: least share of the systematic held-out model RMSE (sensor noise removed)
            the accepted set must remove; a set that removes less is not accepted: the
            residual is reported as unexplained and the set named as not accepted.
        log: ``log(str)`` progress callback (e.g. ``print``), or None.

    Raises:
        DataError: unreadable data or fewer than 4 usable point pokes.
        InvalidInput: bad settings or unknown candidate names.

    """
    say = log if log is not None else (lambda message: None)
    if not 0 < alpha < 1:
        raise InvalidInput(f'diagnose: alpha must be in (0, 1), got {alpha}')
    if improvement_on not in ('model', 'sample'):
        raise InvalidInput(f"diagnose: improvement_on must be 'model' or 'sample', got "
                           f'{improvement_on!r}')
    if min(min_improvement, resolution, tolerance, bootstrap, onset_tolerance) < 0:
        raise InvalidInput('diagnose: min_improvement, resolution, tolerance, bootstrap and '
                           'onset_tolerance must be >= 0')
    names = list(LIBRARY) if candidates is None else list(candidates)
    unknown = [c for c in names if c not in LIBRARY]
    if unknown:
        raise InvalidInput(f'diagnose: unknown candidate(s) {unknown}; known: {list(LIBRARY)}')
    records = load_pokes(data)
    source = str(data) if not isinstance(data, (list, tuple)) else f'{len(records)} records'
    probes_in_records = sum(1 for r in records if r.probe != 'point')
    batch, notes = make_batch(records, window=window, max_rate=max_rate)
    lossy = stream_loss_note(records)
    if lossy:
        notes.append(lossy)
        say(lossy)
    not_applicable: Dict[str, str] = {}
    per_poke = float(np.median(np.diff(batch.starts)))
    if per_poke < STEP_SAMPLES:
        notes.append(f'quasi-static step data ({per_poke:.0f} samples per poke, median): '
                     'scored with the effects that apply to it')
        not_applicable = {k: v for k, v in NEEDS_STREAM.items() if k in names}
        names = [n for n in names if n not in not_applicable]
        for name, why in not_applicable.items():
            say(f'{name} does not apply: {why}')
    found = generated_files(data)
    trials = probes if probes is not None else found.get('probes')
    if isinstance(trials, (str, Path)):
        trials = load_probe_trials(trials)
    trials = list(trials or [])
    surface = surface if surface is not None else found.get('surface')
    if isinstance(surface, (str, Path)):
        surface = load_surface(surface)
    say(f'diagnose: {len(batch)} point pokes, {batch.n_samples} samples'
        + (f', {len(trials)} probe trial(s)' if trials else '')
        + (f', {probes_in_records} probe record(s) not scored (probe trials need ground '
           'truth)' if probes_in_records else ''))
    if trials and surface is None:
        notes.append(f'{len(trials)} probe trial(s) not scored: no equilibrium surface '
                     '(surface.npz next to the pokes, or surface=)')
        say(notes[-1])
    smallest_p = 0.5 ** len(batch)  # one-sided Wilcoxon, every poke better
    if smallest_p >= alpha:
        needed = int(np.ceil(np.log(alpha) / np.log(0.5))) + 1
        notes.append(f'{UNDERPOWERED}: {len(batch)} pokes cannot give p < {alpha:g} in the '
                     f'Wilcoxon test (best possible p = {smallest_p:.3g}); at least {needed} '
                     'pokes are needed before any effect can be accepted')
        say(notes[-1])
    onset = onset_offset(records)
    if onset is not None:
        say(onset.describe())
    groups = fold_indices(len(batch), int(folds), seed)
    min_drop = float(resolution) * float(np.median(batch.peak))
    blocks = model_blocks(batch)
    covered = float(np.count_nonzero(blocks >= 0))
    current: List[str] = []
    fits = _cross_fit(batch, groups, current)
    sse, msse = _heldout(batch, fits, blocks)
    first_fits, first_sse, first_msse = fits, sse, msse
    resid_before = residual_table(batch, first_fits)
    noise = noise_rms(batch, resid_before)
    model_noise = noise / np.sqrt(max(_block_size(batch), 1.0))
    say(f'base model: held-out RMSE {_pooled_rmse(batch, sse):.4g} N')
    rounds: List[SelectionRound] = []
    failed: Dict[str, str] = {}
    inconclusive: Tuple[str, ...] = ()
    inconclusive_reason = ''
    while True:
        results = []
        trial = {}
        failed.clear()
        for name in names:
            if name in current:
                continue
            try:
                cand_fits = _cross_fit(batch, groups, current + [name],
                                       starts=[f.values for _, f in fits])
                cand_sse, cand_msse = _heldout(batch, cand_fits, blocks)
                if not (np.all(np.isfinite(cand_sse)) and np.all(np.isfinite(cand_msse))):
                    raise NumericalFailure(f'held-out prediction of {name} is not finite')
            except NumericalFailure as exc:
                failed[name] = str(exc)
                notes.append(f'{name}: fit failed numerically ({exc})')
                say(notes[-1])
                continue
            except NotConverged as exc:
                notes.append(f'{name}: fit failed ({exc})')
                continue
            rmse, imp, p_value, delta, improved, sig, model_rmse, model_imp = _compare(
                batch, sse, cand_sse, _effective_params(name, cand_fits), alpha,
                min_improvement, min_drop, msse, cand_msse, covered,
                improvement_on == 'model')
            trial[name] = (cand_fits, cand_sse, cand_msse)
            why = _plausibility(name, cand_fits, fits, onset, onset_tolerance) if sig else ''
            if sig and not why:
                why = _explains(_systematic(_model_rmse(msse, covered), model_noise),
                                _systematic(model_rmse, model_noise), explain_step)
            if why:
                say(f'{name}: significant but not accepted: {why}')
            results.append(CandidateResult(name, LIBRARY[name].n_params, rmse, imp, p_value,
                                           delta, improved, sig and not why,
                                           dict(cand_fits[0][1].values.get(name, {})), why,
                                           model_rmse, model_imp))
        results.sort(key=lambda c: (not c.significant, c.delta_score))
        chosen = results[0].name if results and results[0].significant else None
        if failed and chosen is not None:
            # a candidate that could not be evaluated may be the better explanation: no
            # other effect takes its place
            rivals = [c.name for c in results if c.significant]
            inconclusive = tuple(sorted(failed)) + tuple(rivals)
            inconclusive_reason = (f'{", ".join(sorted(failed))} could not be evaluated '
                                   f'(numerical failure) while {", ".join(rivals)} passed the '
                                   'tests: which effect explains the residual is undecided')
            say(f'inconclusive: {inconclusive_reason}')
            rounds.append(SelectionRound(tuple(current), _pooled_rmse(batch, sse),
                                         tuple(results), None))
            break
        rounds.append(SelectionRound(tuple(current), _pooled_rmse(batch, sse), tuple(results),
                                     chosen))
        if chosen is None:
            say('no further effect reduces the held-out error significantly')
            break
        best = results[0]
        say(f'accepted {chosen}: held-out RMSE {_pooled_rmse(batch, sse):.4g} -> '
            f'{best.rmse:.4g} N (p = {best.p_value:.2g}, {best.improved}/{len(batch)} pokes '
            'better)')
        current.append(chosen)
        fits, sse, msse = trial[chosen]
        removed = []
        while len(current) > 1:
            weakest = None
            for name in current[:-1]:
                rest = [c for c in current if c != name]
                try:
                    rest_fits = _cross_fit(batch, groups, rest,
                                           starts=[f.values for _, f in fits])
                except NotConverged:
                    continue
                rest_sse, rest_msse = _heldout(batch, rest_fits, blocks)
                _, _, _, delta, _, sig, _, _ = _compare(
                    batch, rest_sse, sse, _effective_params(name, fits), alpha,
                    min_improvement, min_drop, rest_msse, msse, covered,
                    improvement_on == 'model')
                if not sig and (weakest is None or delta > weakest[1]):
                    weakest = (name, delta, rest_fits, rest_sse, rest_msse)
            if weakest is None:
                break
            name, _, fits, sse, msse = weakest
            current.remove(name)
            removed.append(name)
            say(f'dropped {name}: no longer significant once {chosen} is in the model')
        if removed:
            rounds[-1] = SelectionRound(rounds[-1].current, rounds[-1].rmse,
                                        rounds[-1].candidates, chosen, tuple(removed))
    model_before = _model_rmse(first_msse, covered)
    sys_model_before = _systematic(model_before, model_noise)
    not_accepted: Dict[str, str] = {}
    explained = float('nan')
    if current:
        sys_model_after = _systematic(_model_rmse(msse, covered), model_noise)
        explained = 1.0 - sys_model_after / sys_model_before if sys_model_before > 0 else 0.0
        if explained < explain:
            label = ' + '.join(current)
            why = (f'removes only {max(explained, 0.0):.0%} of the systematic held-out model '
                   f'RMSE ({sys_model_before:.3g} -> {sys_model_after:.3g} N, sensor noise '
                   f'{model_noise:.2g} N removed), less than the {explain:.0%} an explanation '
                   'must remove')
            not_accepted[label] = why
            say(f'not accepted: {label} {why}')
            current = []
            fits, sse, msse = first_fits, first_sse, first_msse
    ordered = [name for name in LIBRARY if name in current]
    start = {}
    for _, f in fits:
        for eff, params in f.values.items():
            start.setdefault(eff, {}).update(params)
    try:
        final = fit_global(batch, ordered, start=start, multistart=False)
    except NumericalFailure as exc:
        notes.append(f'final fit failed numerically ({exc}): the training-fold fits stand')
        final = fits[0][1]
    boots = _bootstrap(batch, ordered, final.values, bootstrap, seed) if current else []
    accepted = []
    for name in current:
        params = dict(final.values[name])
        fitted = [p.name for p in LIBRARY[name].params] + list(LIBRARY[name].derived)
        samples = {k: np.array([b[name][k] for b in boots]) for k in fitted} if boots else {}
        accepted.append(AcceptedEffect(
            name, LIBRARY[name].title, params,
            {k: float(np.std(v, ddof=1)) for k, v in samples.items() if len(v) > 1},
            {k: float(np.quantile(v, 0.025)) for k, v in samples.items() if len(v) > 1},
            {k: float(np.quantile(v, 0.975)) for k, v in samples.items() if len(v) > 1}))
    resid_after = residual_table(batch, fits)
    rmse_before, rmse_after = _pooled_rmse(batch, first_sse), _pooled_rmse(batch, sse)
    model_after = _model_rmse(msse, covered)
    sys_before = float(np.sqrt(max(rmse_before ** 2 - noise ** 2, 0.0)))
    sys_after = float(np.sqrt(max(rmse_after ** 2 - noise ** 2, 0.0)))
    tol = max(float(tolerance) * float(np.median(batch.peak)), noise)
    structure_after = analyse_structure(batch, resid_after)
    unexplained = sys_after > tol
    if unexplained:
        say(f'unexplained residual: {sys_after:.3g} N systematic (tolerance {tol:.3g} N); '
            f'strongest structure: {structure_after[0].detail}')
        if not current and not not_accepted:
            nearest = _nearest(rounds)
            if nearest is not None:
                not_accepted[nearest.name] = (
                    f'nearest candidate, not accepted: held-out model RMSE '
                    f'{model_before:.3g} -> {nearest.model_rmse:.3g} N'
                    + (f' ({nearest.rejected})' if nearest.rejected else ''))
    if failed and unexplained and not inconclusive:
        inconclusive = tuple(sorted(failed))
        inconclusive_reason = (f'{", ".join(inconclusive)} could not be evaluated (numerical '
                               'failure) and a residual remains that it may explain')
        say(f'inconclusive: {inconclusive_reason}')
    if inconclusive:
        for name in inconclusive:
            not_accepted.setdefault(name, 'inconclusive: ' + inconclusive_reason)
    probe = None
    if trials and surface is not None:
        say(f'probe trials: learning the point model without and with '
            f'{", ".join(current) or "no effect"}, answering {len(trials)} trial(s)')
        try:
            probe = score_probe_trials(records, trials, surface,
                                       {a.name: dict(a.params) for a in accepted},
                                       shape_constant=shape_constant, alpha=alpha,
                                       min_improvement=min_improvement)
        except InvalidInput as exc:
            notes.append(f'probe trials not scored: the point model cannot be learned from '
                         f'these pokes ({exc})')
            say(notes[-1])
        if probe is not None:
            for line in probe.describe().splitlines():
                say(line)
            accepted += _probe_accepted(probe)
    lengths = np.diff(batch.starts)
    return DiagnoseReport(
        source=source,
        settings={'seed': int(seed), 'alpha': float(alpha), 'folds': int(folds),
                  'min_improvement': float(min_improvement), 'resolution': float(resolution),
                  'tolerance': float(tolerance),
                  'onset_tolerance': float(onset_tolerance),
                  'bootstrap': int(bootstrap), 'max_rate': float(max_rate),
                  'window': float(window), 'shape_constant': float(shape_constant),
                  'improvement_on': str(improvement_on), 'model_block': MODEL_BLOCK,
                  'explain': float(explain), 'explain_step': float(explain_step)},
        ids=batch.ids, points=batch.point.copy(), notes=notes, rounds=rounds,
        accepted=accepted, exponent=float(final.values['base']['exponent']),
        rmse_before=rmse_before, rmse_after=rmse_after, noise_rms=noise,
        systematic_before=sys_before, systematic_after=sys_after,
        poke_rmse_before=np.sqrt(first_sse / lengths), poke_rmse_after=np.sqrt(sse / lengths),
        unexplained=bool(unexplained), tolerance=tol,
        structure_before=analyse_structure(batch, resid_before),
        structure_after=structure_after, residual_before=resid_before,
        residual_after=resid_after, probe_trials=len(trials) + probes_in_records,
        not_testable=dict(NOT_TESTABLE_ON_POKES), onset=onset, probe=probe,
        model_rmse_before=model_before, model_rmse_after=model_after,
        model_coverage=covered / batch.n_samples, inconclusive=inconclusive,
        inconclusive_reason=inconclusive_reason, not_applicable=not_applicable,
        not_accepted=not_accepted, explained=explained)


def _explains(before: float, after: float, least: float) -> str:
    """Return why a candidate explains too little of the structure it joins, or ''."""
    share = 1.0 - after / before if before > 0 else 0.0
    if share >= least:
        return ''
    return (f'it removes only {max(share, 0.0):.0%} of the systematic held-out model RMSE '
            f'left ({before:.3g} -> {after:.3g} N; at least {least:.0%} for a cause): '
            'it soaks up part of a structure it does not explain')


def _block_size(batch: PokeBatch) -> float:
    """Return the samples per model-RMSE block (:func:`model_blocks`)."""
    return float(max(int(round(MODEL_BLOCK / float(np.median(batch.dt)))), 1))


def _systematic(model_rmse: float, model_noise: float) -> float:
    """Model RMSE less the sensor noise left in block means (quadrature), N."""
    return float(np.sqrt(max(model_rmse ** 2 - model_noise ** 2, 0.0)))


def _nearest(rounds: Sequence[SelectionRound]) -> Optional[CandidateResult]:
    """Return the first round's candidate of lowest held-out model RMSE (None: no candidate)."""
    if not rounds or not rounds[0].candidates:
        return None
    return min(rounds[0].candidates,
               key=lambda c: c.model_rmse if np.isfinite(c.model_rmse) else np.inf)


def _effective_params(name: str, fits) -> int:
    """Parameters of ``name`` the penalty counts: those not left at a ``zero_ok`` bound.

    A non-negative weight the data leave at zero is not fitted in effect (the count of a
    non-negative least-squares fit's active coefficients); the largest count over the folds,
    at least one.
    """
    specs = LIBRARY[name].params
    counts = []
    for _, fit in fits:
        k = 0
        for (eff, p), x in zip(fit.layout.entries, fit.x):
            if eff != name:
                continue
            at_zero = p.zero_ok and x <= p.lower + 1e-6 * (p.upper - p.lower)
            k += 0 if at_zero else 1
        counts.append(k)
    return max(max(counts) if counts else len(specs), 1)


def _probe_accepted(probe: ProbeScore) -> List[AcceptedEffect]:
    """Effects accepted on probe trials, as accepted effects (jackknife std, +- 2 std range)."""
    out = []
    for result in (probe.compliance, probe.coupling):
        if result is None or not result.accepted:
            continue
        ((key, value),) = result.params.items()
        out.append(AcceptedEffect(result.name, spec(result.name).title + ' (probe trials)',
                                  {key: value}, {key: result.std},
                                  {key: value - 2.0 * result.std},
                                  {key: value + 2.0 * result.std}))
    return out


def check_report_dir(out_dir) -> Path:
    """Return ``out_dir`` as a path a report can be written to (it need not exist yet).

    Checked before the analysis, so a mistyped ``--out`` is refused at once, not after it.

    Raises:
        InvalidInput: ``out_dir``, or the nearest of its parents that exists, is not a folder
            or is not writable (the message names both).

    """
    out = Path(out_dir)
    existing = out
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise InvalidInput(f'--out {out}: {existing} is a file, not a folder')
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InvalidInput(f'--out {out}: folder {existing} is not writable')
    return out


def stream_loss_note(records) -> str:
    """Return a note on the pokes whose F/T stream missed slots (``''`` when none did).

    The poke server stores the runs of 250 Hz slots with no sample in a poke's
    ``meta['stream_losses']`` (``[[t_controller, slots, held_s], ...]``,
    :class:`~pointforce_ros.drivers.ur_arm.StreamLoss`); their samples are analysed as
    recorded, and the report says which pokes have such holes. Malformed entries (a bag from
    elsewhere) are not counted.
    """
    lossy = {}
    for record in records:
        losses = (record.meta or {}).get('stream_losses')
        if not isinstance(losses, list):
            continue
        slots = [int(x[1]) for x in losses if isinstance(x, (list, tuple)) and len(x) >= 2
                 and isinstance(x[1], (int, float)) and np.isfinite(x[1]) and x[1] > 0]
        if slots:
            lossy[record.poke_id] = (sum(slots), len(slots))
    if not lossy:
        return ''
    worst = sorted(lossy, key=lambda k: -lossy[k][0])[:3]
    return (f'{len(lossy)} poke(s) have F/T stream slots with no sample ('
            f'{sum(v[0] for v in lossy.values())} slots in {sum(v[1] for v in lossy.values())} '
            'runs; most: ' + ', '.join(f'{k} {lossy[k][0]}' for k in worst)
            + '): analysed as recorded (meta stream_losses)')


def run_diagnose(data, out_dir, seed: int = 0, json_out: bool = False, **kwargs) -> int:
    """CLI entry: diagnose ``data``, write the report into ``out_dir``, print progress.

    With ``json_out`` stdout carries only the JSON summary (:func:`~pointforce_ros.diagnose.
    report.summary_dict`, one object); progress goes to stderr.

    Returns:
        0 on success (whatever was found), 2 when the data cannot be diagnosed (the reason is
        printed to stderr).

    """
    def to_stderr(message):
        print(message, file=sys.stderr)

    try:
        check_report_dir(out_dir)
        report = diagnose(data, seed=seed, log=to_stderr if json_out else print, **kwargs)
        path = write_report(report, out_dir)
    except PointforceError as exc:
        print(f'pointforce diagnose: {exc}', file=sys.stderr)
        return 2
    if json_out:
        print(json.dumps(summary_dict(report), indent=1))
        to_stderr(f'report: {Path(path)}')
        return 0
    print(report.summary())
    print(f'report: {Path(path)}')
    return 0
