"""Use accepted effects: correct data before learning, and predict what the cell measures.

Accepted effects are the stored mapping ``{name: {param: value}}`` of
:mod:`pointforce_ros.effects.accepted` (:func:`~pointforce_ros.effects.accepted.effects_from_dict`
validates it; :func:`~pointforce_ros.effects.accepted.correct_surface` moves the camera surface
onto the true one).

* :func:`correct_records` turns measured pokes into what the clean, quasi-static, frictionless
  elastic contact would have produced: the learner applies it before extracting curves.
* :func:`correct_curve` does the same for an already extracted loading curve (the effects that a
  loading curve can show; friction needs the force vector and is left to the records).
* :func:`apply_series_compliance`, :func:`relaxed_fraction` and :func:`predict_measured` are the
  forward terms: the force a commanded depth really produces through a compliant arm, the
  long-hold force fraction, and what the cell's F/T would report for a depth series.
"""

from typing import Callable, Dict, List, Sequence

import numpy as np

from pointforce_ros.effects.accepted import Effects, effects_from_dict
from pointforce_ros.effects.library import (count_earlier, hysteresis_branch, hysteresis_factor,
                                            PLASTIC_RADIUS, plastic_depth, prony_terms)
from pointforce_ros.effects.relaxation import prony_filter, prony_inverse
from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.types import PokeRecord


def _interp_columns(t_query: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    q = np.clip(t_query, t[0], t[-1])
    return np.column_stack([np.interp(q, t, values[:, k]) for k in range(values.shape[1])])


def _contact_direction(force: np.ndarray) -> np.ndarray:
    """Return the unit mean direction of the force over the samples above 5 % of the peak."""
    mag = np.linalg.norm(force, axis=1)
    strong = mag > 0.05 * mag.max() if mag.max() > 0 else np.zeros(len(mag), dtype=bool)
    total = force[strong].sum(axis=0) if np.any(strong) else force.sum(axis=0)
    norm = np.linalg.norm(total)
    return total / norm if norm > 0 else np.zeros(3)


def correct_records(records: Sequence[PokeRecord], effects: Effects) -> List[PokeRecord]:
    """Remove the accepted effects from measured pokes (inverse of the forward model).

    Per record, in this order: F/T bias and drift subtracted (drift since the tare, see
    :func:`~pointforce_ros.diagnose.batch.tare_reference`), force re-sampled at ``t + offset``
    (time offset), friction removed (force projected on the poke's contact direction),
    hysteresis branch divided out, relaxation deconvolved (inverse Prony filter; zero after the
    relaxed force has vanished during unloading, where the elastic force is not observable, and
    the material history of earlier pokes is not carried), TCP moved out
    by ``compliance * F_n`` along the normal (series compliance), and the poke point moved by
    ``+offset`` (surface offset) and ``-set(n)`` (plastic set after ``n`` earlier pokes within
    the radius, counted in time order over ``records``). Torques are left as measured.

    Args:
        records: pokes (any order; returned in the given order).
        effects: ``{name: {param: value}}`` (see :func:`effects_from_dict`).

    Returns:
        New records with ``meta['corrected']`` listing the effects removed.

    Raises:
        InvalidInput: bad effects mapping or non-records.

    """
    effects = effects_from_dict(effects)
    records = list(records)
    if any(not isinstance(r, PokeRecord) for r in records):
        raise InvalidInput('correct_records: expected PokeRecords')
    counts = np.zeros(len(records), dtype=int)
    if 'plastic_set' in effects and records:
        order = sorted(range(len(records)), key=lambda i: float(records[i].t[0]))
        pts = np.array([records[i].point for i in order])
        nrm = np.array([records[i].normal for i in order])
        peak = np.array([records[i].normal_force().max() for i in order])
        counted = count_earlier(pts, nrm, peak, effects['plastic_set'].get('radius',
                                                                           PLASTIC_RADIUS))
        counts[order] = counted
    return [_correct_one(rec, effects, int(k)) for rec, k in zip(records, counts)]


def correct_record(record: PokeRecord, effects: Effects, count_before: int = 0) -> PokeRecord:
    """Remove the accepted effects from one poke (see :func:`correct_records`).

    Args:
        record: the poke.
        effects: ``{name: {param: value}}``.
        count_before: earlier pokes at its spot (plastic set), counted by the caller.

    Raises:
        InvalidInput: bad effects, a non-record or a negative ``count_before``.

    """
    if not isinstance(record, PokeRecord):
        raise InvalidInput(f'correct_record: expected a PokeRecord, got {type(record).__name__}')
    if int(count_before) < 0:
        raise InvalidInput(f'correct_record: count_before must be >= 0, got {count_before}')
    return _correct_one(record, effects_from_dict(effects), int(count_before))


def _correct_one(rec: PokeRecord, effects: Dict[str, Dict[str, float]], count: int
                 ) -> PokeRecord:
    t = rec.t_controller
    force = np.array(rec.wrench[:, :3])
    n = rec.normal
    if 'ft_bias' in effects:
        b = effects['ft_bias']
        force -= np.array([b['fx'], b['fy'], b['fz']])
    if 'ft_drift' in effects:
        r = effects['ft_drift']
        force -= np.outer(t - tare_reference(rec), [r['rx'], r['ry'], r['rz']])
    if 'time_offset' in effects and len(t) > 1:
        force = _interp_columns(t + effects['time_offset']['offset'], t, force)
    sensor_corrected = force.copy()
    if 'friction' in effects:
        m = _contact_direction(force)
        force = np.outer(force @ m, m)
    d = rec.displacement()
    s = d + effects.get('surface_offset', {}).get('offset', 0.0)
    if 'hysteresis' in effects:
        h = effects['hysteresis']
        force = force / hysteresis_factor(hysteresis_branch(s, h['transition']), h['eta'])[:, None]
    if 'viscoelastic' in effects and len(t) > 1:
        force = _deconvolve(force, t, n, effects['viscoelastic'])
    pose = np.array(rec.tcp_pose)
    if 'series_compliance' in effects:
        f_n = np.maximum(sensor_corrected @ n, 0.0)
        pose[:, :3] += np.outer(effects['series_compliance']['compliance'] * f_n, n)
    point = np.array(rec.point)
    if 'surface_offset' in effects:
        point += effects['surface_offset']['offset'] * n
    if 'plastic_set' in effects and count:
        ps = effects['plastic_set']
        point -= float(plastic_depth(count, ps['max_set'], ps['n0'])) * n
    wrench = np.column_stack([force, rec.wrench[:, 3:]])
    meta = dict(rec.meta)
    meta['corrected'] = list(effects)
    return PokeRecord(poke_id=rec.poke_id, point=point, normal=n, t=rec.t, t_controller=t,
                      tcp_pose=pose, wrench=wrench, speed=rec.speed, probe=rec.probe,
                      outcome=rec.outcome, meta=meta)


def _deconvolve(force: np.ndarray, t: np.ndarray, normal: np.ndarray, visco) -> np.ndarray:
    """Elastic force (T, 3) of a relaxed force series: inverse Prony filter.

    Exact while the contact carries force. Once the relaxed force has dropped to zero during
    unloading (the material lags behind the retreating probe; no adhesion), the elastic force
    is no longer observable: from the first such sample after the peak the result is zero.
    """
    dt = float(np.median(np.diff(t)))
    elastic = prony_inverse(force, dt, *prony_terms(visco))
    f_n = force @ normal
    peak = int(np.argmax(f_n))
    scale = max(float(f_n[peak]), 0.0)
    gone = np.flatnonzero(f_n[peak:] <= 0.01 * scale)
    if scale > 0 and len(gone):
        elastic[peak + int(gone[0]):] = 0.0
    return elastic


def correct_curve(curve: PokeCurve, effects: Effects, *, count_before: int = 0) -> PokeCurve:
    """Remove the accepted effects from a loading curve (see :func:`correct_records`).

    On the loading phase: drift since the tare (``meta['tare_time']`` or the curve's first
    sample) along the normal, time offset, relaxation, series compliance (``d -= compliance
    f``), surface offset and plastic set (``count_before`` earlier pokes at the spot) shift
    ``d`` and ``onset_d``. Bias was already removed by curve extraction; hysteresis leaves the
    loading branch unchanged; friction needs the force vector (use :func:`correct_records`).

    Raises:
        InvalidInput: bad effects mapping or a negative ``count_before``.

    """
    effects = effects_from_dict(effects)
    if int(count_before) < 0:
        raise InvalidInput(f'correct_curve: count_before must be >= 0, got {count_before}')
    d = np.array(curve.d)
    f = np.array(curve.f)
    t = np.array(curve.t)
    onset = float(curve.onset_d)
    t0 = float(curve.meta.get('t0', 0.0))
    if 'ft_drift' in effects:
        r = effects['ft_drift']
        tare = curve.meta.get('tare_time')
        t_ref = float(tare) if tare is not None else t0 + float(t[0])
        rate_n = float(np.array([r['rx'], r['ry'], r['rz']]) @ curve.normal)
        f = f - rate_n * (t + t0 - t_ref)
    if 'time_offset' in effects and len(t) > 1:
        f = np.interp(np.clip(t + effects['time_offset']['offset'], t[0], t[-1]), t, f)
    if 'viscoelastic' in effects and len(t) > 1:
        f = prony_inverse(f, float(np.median(np.diff(t))), *prony_terms(effects['viscoelastic']))
    if 'series_compliance' in effects:
        d = d - effects['series_compliance']['compliance'] * np.maximum(f, 0.0)
    shift = effects.get('surface_offset', {}).get('offset', 0.0)
    if 'plastic_set' in effects and count_before:
        ps = effects['plastic_set']
        shift -= float(plastic_depth(int(count_before), ps['max_set'], ps['n0']))
    meta = dict(curve.meta)
    meta['corrected'] = [e for e in effects if e not in ('ft_bias', 'hysteresis', 'friction')]
    return PokeCurve(poke_id=curve.poke_id, point=curve.point, normal=curve.normal, d=d + shift,
                     f=f, onset_d=onset + shift, t=t, meta=meta)


def relaxed_fraction(effects: Effects) -> float:
    """Fraction of the instantaneous force left after a long hold (1 without relaxation)."""
    effects = effects_from_dict(effects)
    if 'viscoelastic' not in effects:
        return 1.0
    return 1.0 - float(np.sum(prony_terms(effects['viscoelastic'])[0]))


def apply_series_compliance(force_of_depth: Callable[[np.ndarray], np.ndarray], depth,
                            effects: Effects, iterations: int = 60) -> np.ndarray:
    """Force at commanded depths ``depth`` (M,) through the accepted series compliance.

    Solves ``F = force_of_depth(depth - compliance F)`` per entry by bisection on
    ``[0, force_of_depth(depth)]`` (valid for a force non-decreasing in depth); without the
    effect it returns ``force_of_depth(depth)``.

    Args:
        force_of_depth: vectorised elastic force (N) of true depth (m).
        depth: (M,) commanded depths, metres.
        effects: accepted effects.
        iterations: bisection steps (60 reach double precision).

    """
    effects = effects_from_dict(effects)
    depth = np.atleast_1d(np.asarray(depth, dtype=np.float64))
    upper = np.maximum(np.asarray(force_of_depth(depth), dtype=np.float64), 0.0)
    if 'series_compliance' not in effects:
        return upper
    c = effects['series_compliance']['compliance']
    lo, hi = np.zeros_like(upper), upper.copy()
    for _ in range(int(iterations)):
        mid = 0.5 * (lo + hi)
        too_big = mid > np.asarray(force_of_depth(depth - c * mid))
        hi = np.where(too_big, mid, hi)
        lo = np.where(too_big, lo, mid)
    return 0.5 * (lo + hi)


def predict_measured(force_of_depth: Callable[[np.ndarray], np.ndarray], t, d,
                     effects: Effects, *, first_poke: bool = True) -> np.ndarray:
    """Return the normal force (T,) the cell would report for a displacement series.

    The forward model of one poke with a known elastic law: time offset (the force at ``t`` is
    the one of ``d(t - offset)``), surface offset and series compliance (solved on the elastic
    force) on the depth, then relaxation and hysteresis on the force. F/T bias and drift are
    not added (they depend on the poke's direction and tare); friction and plastic set need the
    poke geometry and history and are not applied either.

    Args:
        force_of_depth: vectorised elastic force (N) of true depth (m).
        t: (T,) seconds, uniformly sampled.
        d: (T,) displacement past the observed surface, metres.
        effects: accepted effects.
        first_poke: the material starts on the loading branch (otherwise unloading).

    Raises:
        InvalidInput: mismatched or too short series.

    """
    effects = effects_from_dict(effects)
    t = np.asarray(t, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    if t.shape != d.shape or t.ndim != 1 or len(t) < 2:
        raise InvalidInput('predict_measured: t and d must be equal-length 1-D series (>= 2)')
    if 'time_offset' in effects:
        d = np.interp(np.clip(t - effects['time_offset']['offset'], t[0], t[-1]), t, d)
    s = d + effects.get('surface_offset', {}).get('offset', 0.0)
    force = apply_series_compliance(force_of_depth, s, effects)
    if 'viscoelastic' in effects:
        elastic = force
        force = prony_filter(force, float(np.median(np.diff(t))),
                             *prony_terms(effects['viscoelastic']))
        force = np.where(elastic > 0, np.maximum(force, 0.0), 0.0)
    if 'hysteresis' in effects:
        h = effects['hysteresis']
        z = hysteresis_branch(s, h['transition'], z0=1.0 if first_poke else -1.0)
        force = force * hysteresis_factor(z, h['eta'])
    return force


def tare_reference(record: PokeRecord) -> float:
    """Return the controller time the poke's F/T reading was zeroed at (drift reference), s.

    ``meta['tare_time']`` when present; 0 (the controller epoch) for a record marked
    ``tared: False``; otherwise the first sample (a tare right before the push).
    """
    tare_time = record.meta.get('tare_time')
    if tare_time is not None:
        return float(tare_time)
    if record.meta.get('tared') is False:
        return 0.0
    return float(record.t_controller[0])
