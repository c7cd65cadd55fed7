"""From a raw poke to a force-displacement curve: loading phase, contact onset, residual bias.

A poke (``PokeRecord``) streams TCP pose and wrench for the whole motion: the hold at the
stand-off (where the F/T sensor is tared), the push along ``-normal`` at constant speed, maybe a
hold at the force or depth limit, and the retraction. The force model is learned from the
*loading phase* only: the samples of the constant-speed push up to the deepest point.

Camera bias makes contact start anywhere from about -5 to +5 mm of nominal displacement (seed
000, section III.A), so the onset is not ``d = 0``. It is found by fitting, over the early
loading phase, ``f = b + a * (d - d0)_+ ** p`` (residual bias ``b``, onset ``d0``) with a
vectorised grid over ``(d0, p)`` and a closed-form solve for ``(b, a)``, refined by a robust
(soft-L1) least-squares step, so a single noisy sample cannot trigger the onset.

**Step data.** Another rig may measure a poke as a few quasi-static depth steps (5-20 settled
samples) instead of a stream. A poke with fewer than :data:`STEP_SAMPLES` samples is treated
as such: there is no constant-speed phase to find, so its loading phase is every sample that
reaches a new deepest depth up to the deepest one, at least :data:`MIN_STEP_SAMPLES` of them;
the onset fit and the contact test are the same (relative to the poke's own noise).
"""

from dataclasses import dataclass, field
from typing import Mapping, Optional, Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import savgol_filter

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array, PokeRecord, unit_rows

DEFAULT_EXPONENTS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0)
"""Contact exponents ``p`` tried by the grid stage of :func:`fit_power_onset`."""

STEP_SAMPLES = 25
"""A poke with fewer samples than this is quasi-static step data (module docstring)."""
MIN_STEP_SAMPLES = 5
"""Fewest loading samples of a step-data poke (the onset fit has four parameters)."""
MIN_STREAM_SAMPLES = 20
"""Fewest loading samples of a streamed poke."""


@dataclass(frozen=True)
class PokeCurve:
    """Loading-phase force-displacement curve of one poke.

    Attributes:
        poke_id: id of the poke it came from.
        point: (3,) poked surface point, metres, ``base``.
        normal: (3,) unit outward normal at ``point``, ``base``.
        d: (M,) displacement along ``-normal`` from ``point``, metres, non-decreasing in time
            (the nominal displacement of seed 000: positive = pushed in).
        f: (M,) normal force on the probe, newtons, with the residual bias removed (about zero
            before contact).
        onset_d: displacement at which contact starts, metres (often non-zero: camera bias).
        t: (M,) seconds since the first sample of the record (controller clock).
        meta: JSON-serialisable details (bias, noise, segment, fit), see :func:`extract_curve`.

    Raises:
        InvalidInput: arrays of different lengths, fewer than 2 samples, NaN, non-unit normal.

    """

    poke_id: str
    point: np.ndarray
    normal: np.ndarray
    d: np.ndarray
    f: np.ndarray
    onset_d: float
    t: np.ndarray
    meta: Mapping = field(default_factory=dict)

    def __post_init__(self):
        if not self.poke_id or not isinstance(self.poke_id, str):
            raise InvalidInput('PokeCurve.poke_id: must be a non-empty string')
        point = as_array(self.point, 'PokeCurve.point', (3,))
        normal = unit_rows(as_array(self.normal, 'PokeCurve.normal', (3,)), 'PokeCurve.normal')
        d = as_array(self.d, 'PokeCurve.d', (None,))
        if len(d) < 2:
            raise InvalidInput(f'PokeCurve.d: need at least 2 samples, got {len(d)}')
        f = as_array(self.f, 'PokeCurve.f', (len(d),))
        t = as_array(self.t, 'PokeCurve.t', (len(d),))
        onset = float(self.onset_d)
        if not np.isfinite(onset):
            raise InvalidInput(f'PokeCurve.onset_d: must be finite, got {onset}')
        for name, value in (('point', point), ('normal', normal), ('d', d), ('f', f), ('t', t)):
            object.__setattr__(self, name, value)
        object.__setattr__(self, 'onset_d', onset)
        object.__setattr__(self, 'meta', dict(self.meta))

    def __len__(self) -> int:
        """Return the number of samples ``M``."""
        return len(self.d)


def learned_depth(curves: Sequence[PokeCurve]) -> float:
    """Return the deepest nominal displacement (m) any of ``curves`` reached; 0 with none.

    A point model trained on them is measured to there; past it its force is extrapolated
    (:meth:`~pointforce_ros.response.baked.BakedResponse.with_extrapolation`).
    """
    return max((float(np.max(c.d)) for c in curves if len(c.d)), default=0.0)


@dataclass(frozen=True)
class PowerFit:
    """Result of :func:`fit_power_onset`: ``f = bias + a * (d - d0)_+ ** p``.

    Attributes:
        d0: onset displacement, metres.
        a: scale, N / m**p (>= 0).
        p: exponent (dimensionless).
        bias: constant offset, newtons (0 when fitted without bias).
        rms: root-mean-square residual of the fit, newtons.
        noise: robust (MAD) residual scale, newtons.

    """

    d0: float
    a: float
    p: float
    bias: float
    rms: float
    noise: float

    def __call__(self, d: np.ndarray) -> np.ndarray:
        """Evaluate the fitted curve at displacements ``d`` (metres) -> newtons."""
        s = np.maximum(np.asarray(d, dtype=float) - self.d0, 0.0)
        return self.bias + self.a * s ** self.p


def fit_power_onset(d: np.ndarray, f: np.ndarray, *, with_bias: bool = True,
                    exponents: Sequence[float] = DEFAULT_EXPONENTS,
                    exponent_bounds=(0.5, 4.0), grid_size: int = 160,
                    grid_samples: int = 400, max_samples: Optional[int] = None,
                    robust: bool = True) -> PowerFit:
    """Fit ``f = b + a * (d - d0)_+ ** p`` to one loading curve (vectorised grid + refinement).

    Args:
        d: (M,) displacement, metres, any order.
        f: (M,) force, newtons.
        with_bias: fit the offset ``b``; otherwise ``b = 0``.
        exponents: grid of ``p`` for the global stage; the refinement frees ``p`` within
            ``exponent_bounds``.
        grid_size: number of onset candidates spread over the range of ``d``.
        grid_samples: the grid stage uses at most this many samples (evenly thinned).
        max_samples: the refinement uses at most this many (``None``: all).
        robust: refine with a soft-L1 loss scaled to the noise (outlier-resistant).

    Returns:
        The fit; ``d0`` may lie below ``min(d)`` only if the data start in contact.

    Raises:
        InvalidInput: fewer than 5 samples, NaN, or no spread in ``d``.

    """
    d = as_array(d, 'd', (None,))
    f = as_array(f, 'f', (len(d),))
    if len(d) < 5:
        raise InvalidInput(f'fit_power_onset: need at least 5 samples, got {len(d)}')
    span = float(d.max() - d.min())
    if span <= 0.0:
        raise InvalidInput('fit_power_onset: displacement has no spread (probe did not move)')
    scale = span  # work in units of the span so that a is O(force)
    x_all = (d - d.min()) / scale
    f_all = f
    if max_samples is not None and len(x_all) > max_samples:
        keep = np.round(np.linspace(0, len(x_all) - 1, max_samples)).astype(int)
        x_all, f_all = x_all[keep], f_all[keep]
    thin = np.round(np.linspace(0, len(x_all) - 1, min(grid_samples, len(x_all)))).astype(int)
    x, f = x_all[thin], f_all[thin]
    grid = np.linspace(-0.05, 0.98, grid_size)
    p_grid = np.asarray(exponents, dtype=float)
    d0s = np.repeat(grid, len(p_grid))
    ps = np.tile(p_grid, len(grid))
    basis = np.maximum(x[None, :] - d0s[:, None], 0.0) ** ps[:, None]   # (G*P, M)
    m = float(len(x))
    if with_bias:
        mean_b = basis.mean(axis=1)
        var_b = (basis * basis).mean(axis=1) - mean_b ** 2
        cov_bf = basis @ f / m - mean_b * f.mean()
        a = np.where(var_b > 1e-15, cov_bf / np.maximum(var_b, 1e-15), 0.0)
        a = np.maximum(a, 0.0)
        b = f.mean() - a * mean_b
    else:
        bb = (basis * basis).sum(axis=1)
        a = np.maximum(np.where(bb > 1e-15, basis @ f / np.maximum(bb, 1e-15), 0.0), 0.0)
        b = np.zeros_like(a)
    sse = ((f[None, :] - b[:, None] - a[:, None] * basis) ** 2).sum(axis=1)
    best = int(np.argmin(sse))
    theta = np.array([b[best], a[best], d0s[best], ps[best]])
    resid = f - theta[0] - theta[1] * basis[best]
    noise = _mad(resid)
    theta = _refine(x_all, f_all, theta, with_bias, exponent_bounds, noise, robust)
    b_fit, a_fit, d0_fit, p_fit = theta
    model = b_fit + a_fit * np.maximum(x_all - d0_fit, 0.0) ** p_fit
    resid = f_all - model
    return PowerFit(d0=float(d.min() + d0_fit * scale), a=float(a_fit / scale ** p_fit),
                    p=float(p_fit), bias=float(b_fit),
                    rms=float(np.sqrt(np.mean(resid ** 2))), noise=float(_mad(resid)))


def _mad(r: np.ndarray) -> float:
    return float(1.4826 * np.median(np.abs(r - np.median(r))))


def _refine(x, f, theta, with_bias, bounds, noise, robust):
    """Polish ``(b, a, d0, p)`` (span units) with a bounded (robust) least-squares step."""
    free = [0, 1, 2, 3] if with_bias else [1, 2, 3]

    def unpack(z):
        full = theta.copy()
        full[free] = z
        return full

    def residual(z):
        b, a, d0, p = unpack(z)
        return b + a * np.maximum(x - d0, 0.0) ** p - f

    lo = {0: -np.inf, 1: 0.0, 2: -0.5, 3: bounds[0]}
    hi = {0: np.inf, 1: np.inf, 2: 1.0, 3: bounds[1]}
    z0 = np.array([np.clip(theta[i], lo[i], hi[i]) for i in free])
    lower = [lo[i] for i in free]
    upper = [hi[i] for i in free]
    z0 = np.clip(z0, np.array(lower) + 1e-12, np.array(upper) - 1e-12)
    f_scale = max(2.0 * noise, 1e-6 * max(1.0, float(np.abs(f).max())))
    try:
        sol = least_squares(residual, z0, bounds=(lower, upper), method='trf',
                            loss='soft_l1' if robust else 'linear', f_scale=f_scale,
                            x_scale='jac', max_nfev=200)
    except ValueError:
        return theta
    return unpack(sol.x)


def extract_curve(record: PokeRecord, *, min_samples: Optional[int] = None,
                  speed_band=(0.5, 1.5), smooth_time: float = 0.04, fit_fraction: float = 0.5,
                  min_snr: float = 5.0, step_samples: int = STEP_SAMPLES) -> PokeCurve:
    """Cut the loading phase out of ``record`` and find its contact onset and residual bias.

    Args:
        record: one poke; ``record.speed`` is the commanded push speed (m/s).
        min_samples: fewest loading-phase samples accepted; ``None``:
            :data:`MIN_STEP_SAMPLES` for step data, :data:`MIN_STREAM_SAMPLES` otherwise.
        speed_band: the loading phase is where the smoothed approach speed lies within this
            band times ``record.speed`` (excludes a faster approach, holds and retraction).
        smooth_time: window of the Savitzky-Golay speed estimate, seconds.
        fit_fraction: the onset fit uses the loading samples up to the first one whose force
            exceeds this fraction of the peak force (the onset is a local property; the deep
            part of the curve may change shape).
        min_snr: the peak force must exceed the residual bias by this many noise sigmas,
            otherwise there was no contact.
        step_samples: a record with fewer samples is quasi-static step data (module
            docstring); its loading phase is its new-deepest samples, ``speed_band`` and
            ``smooth_time`` do not apply.

    Returns:
        The curve, with ``f`` bias-corrected. ``meta`` holds ``bias`` (N), ``noise_std`` (N),
        ``onset_exponent``, ``segment`` ([first, last] sample indices in the record),
        ``peak_force`` (N), ``peak_d`` (m), ``speed`` (m/s), ``outcome``, ``onset_observed``
        (False when the push started already in contact), ``t0`` (controller time, s) and
        ``step_data`` (bool).

    Raises:
        InvalidInput: too few samples, no constant-speed loading phase, or no contact.

    """
    if not isinstance(record, PokeRecord):
        raise InvalidInput(f'extract_curve: expected a PokeRecord, got {type(record).__name__}')
    meta = dict(record.meta)
    meta.update(outcome=record.outcome, probe=record.probe)
    return curve_from_series(record.poke_id, record.point, record.normal, record.t_controller,
                             record.displacement(), record.normal_force(), speed=record.speed,
                             min_samples=min_samples, speed_band=speed_band,
                             smooth_time=smooth_time, fit_fraction=fit_fraction,
                             min_snr=min_snr, meta=meta, step_samples=step_samples)


def curve_from_series(poke_id: str, point, normal, t, d, f, *, speed: Optional[float] = None,
                      min_samples: Optional[int] = None, speed_band=(0.5, 1.5),
                      smooth_time: float = 0.04, fit_fraction: float = 0.5,
                      min_snr: float = 5.0, meta: Optional[Mapping] = None,
                      step_samples: int = STEP_SAMPLES) -> PokeCurve:
    """Build a :class:`PokeCurve` from plain time series (imported tables use this directly).

    Args:
        poke_id, point, normal: as in :class:`PokeCurve`.
        t: (T,) seconds, strictly increasing.
        d: (T,) displacement along ``-normal``, metres.
        f: (T,) normal force, newtons.
        speed: commanded push speed, m/s; ``None`` estimates it as the median speed of the
            samples moving inwards faster than a fifth of the fastest one.
        others: see :func:`extract_curve`.

    Raises:
        InvalidInput: see :func:`extract_curve`; also NaN or mismatched lengths.

    """
    t = as_array(t, 'curve t', (None,))
    n = len(t)
    d = as_array(d, 'curve d', (n,))
    f = as_array(f, 'curve f', (n,))
    step = n < step_samples
    if min_samples is None:
        min_samples = MIN_STEP_SAMPLES if step else MIN_STREAM_SAMPLES
    if n < min_samples:
        raise InvalidInput(f'poke {poke_id}: {n} samples, need at least {min_samples}')
    dt_all = np.diff(t)
    if np.any(dt_all <= 0):
        raise InvalidInput(f'poke {poke_id}: time must be strictly increasing')
    if step:
        seg, first, deepest, speed = _step_loading(poke_id, t, d, min_samples)
    else:
        seg, first, deepest, speed = _stream_loading(poke_id, t, d, speed, min_samples,
                                                     speed_band, smooth_time)
    d_l, f_l, t_l = d[seg], f[seg], t[seg]
    # Onset fit on the early part of the loading phase.
    baseline = float(np.median(f_l[:max(5, len(f_l) // 10)]))
    peak = float(f_l.max())
    cut = np.flatnonzero(f_l >= baseline + fit_fraction * (peak - baseline))
    stop = max(int(cut[0]) + 1 if len(cut) else len(f_l), min(len(f_l), 10))
    fit = fit_power_onset(d_l[:stop], f_l[:stop], with_bias=True)
    noise = max(fit.noise, 1e-9)
    if not step:
        # the onset fit's residual over a short early stretch can fit the noise itself: a
        # stream's sample-to-sample scatter bounds it from below (the signal changes little
        # between two samples; for steps it changes a lot, and this would overstate it)
        noise = max(noise, _mad(np.diff(f_l)) / np.sqrt(2.0))
    if peak - fit.bias < min_snr * noise:
        raise InvalidInput(f'poke {poke_id}: no contact detected (peak force {peak:.3g} N is '
                           f'within {min_snr:g} sigma = {min_snr * noise:.3g} N of the baseline)')
    info = dict(meta or {})
    info.update(bias=fit.bias, noise_std=noise, onset_exponent=fit.p,
                segment=[first, deepest], peak_force=peak - fit.bias, peak_d=float(d_l[-1]),
                speed=float(speed), onset_observed=bool(fit.d0 > d_l[0]), t0=float(t[0]),
                step_data=bool(step))
    return PokeCurve(poke_id=poke_id, point=point, normal=normal, d=d_l, f=f_l - fit.bias,
                     onset_d=fit.d0, t=t_l - t[0], meta=info)


def _step_loading(poke_id, t, d, min_samples):
    """Select the loading samples of step data: each sample that reaches a new deepest depth."""
    deepest = int(np.argmax(d))
    before = np.maximum.accumulate(np.concatenate([[-np.inf], d[:deepest]]))
    seg = np.flatnonzero(d[:deepest + 1] > before)
    if len(seg) < min_samples:
        raise InvalidInput(f'poke {poke_id}: {len(seg)} steps reach a new depth, need at least '
                           f'{min_samples}')
    span = float(d[deepest] - d[seg[0]])
    if span <= 0:
        raise InvalidInput(f'poke {poke_id}: no loading phase (the probe never moves in)')
    speed = span / max(float(t[deepest] - t[seg[0]]), 1e-9)
    return seg, int(seg[0]), deepest, speed


def _stream_loading(poke_id, t, d, speed, min_samples, speed_band, smooth_time):
    """Select loading samples of a stream: the constant-speed push to the deepest point."""
    n = len(t)
    dt = float(np.median(np.diff(t)))
    window = max(5, int(round(smooth_time / dt)) | 1)
    window = min(window, n if n % 2 else n - 1)
    polyorder = 2 if window > 3 else 1
    velocity = savgol_filter(d, window, polyorder, deriv=1, delta=dt, mode='interp')
    if speed is None:
        vmax = float(velocity.max())
        if vmax <= 0:
            raise InvalidInput(f'poke {poke_id}: no loading phase (the probe never moves in)')
        speed = float(np.median(velocity[velocity > 0.2 * vmax]))
    if not np.isfinite(speed) or speed <= 0:
        raise InvalidInput(f'poke {poke_id}: speed must be positive, got {speed}')
    inband = (velocity >= speed_band[0] * speed) & (velocity <= speed_band[1] * speed)
    inband = _close_gaps(inband, max_gap=max(2, window // 2))
    if not np.any(inband):
        raise InvalidInput(f'poke {poke_id}: no loading phase: the probe never moves inwards at '
                           f'about {speed * 1e3:.3g} mm/s')
    # The loading phase: the longest in-band run, extended to the deepest point after it, and
    # back over the earlier runs of the same push. A push that slowed on its way in (a loaded
    # controller, a speed hiccup) leaves several runs; the longest alone started mid-contact,
    # and its in-contact "baseline" was subtracted as bias (a re-poke learned at 0.45 of its
    # force). Runs join while the probe never backs out between them; the slow samples
    # between runs are left out (a pause lets a viscoelastic object relax).
    starts, stops = _runs(inband)
    lengths = stops - starts
    k = int(np.argmax(lengths))
    first, last_inband = int(starts[k]), int(stops[k]) - 1
    tail_end = last_inband + 1
    while tail_end < n and d[tail_end] >= d[tail_end - 1]:
        tail_end += 1
    deepest = first + int(np.argmax(d[first:tail_end]))
    tolerance = max(1e-5, 2.0 * speed * dt)     # m a probe may seem to back out (noise)
    gaps = []
    while k > 0:
        between = d[stops[k - 1] - 1:starts[k] + 1]
        if np.max(np.maximum.accumulate(between) - between) > tolerance:
            break                               # it backed out: an earlier push
        gaps.append((int(stops[k - 1]), int(starts[k])))
        k -= 1
        first = int(starts[k])
    keep = np.ones(deepest + 1 - first, dtype=bool)
    # A run's edge beside a pause is decided by a smoothed speed near the band's limit, so a
    # rounding difference between machines can keep one sample of the pause itself: within a
    # window of each join, a kept sample must reach beyond the depth already reached.
    seg_d = d[first:deepest + 1]
    new_depth = np.r_[True, seg_d[1:] > np.maximum.accumulate(seg_d)[:-1]]
    for gap_start, gap_stop in gaps:
        keep[gap_start - first:gap_stop - first] = False
        edges = slice(max(1, gap_start - window - first + 1), gap_stop + window - first)
        keep[edges] &= new_depth[edges]
    seg = first + np.flatnonzero(keep)
    if len(seg) < min_samples:
        raise InvalidInput(f'poke {poke_id}: loading phase has {len(seg)} samples, '
                           f'need at least {min_samples}')
    return seg, first, deepest, speed


def _runs(mask: np.ndarray):
    """Start and stop indices of the True runs of a boolean array."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.diff(padded)
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _close_gaps(mask: np.ndarray, max_gap: int) -> np.ndarray:
    """Fill False gaps of at most ``max_gap`` samples between True runs (noise dropouts)."""
    starts, stops = _runs(mask)
    out = mask.copy()
    for s, e in zip(stops[:-1], starts[1:]):
        if e - s <= max_gap:
            out[s:e] = True
    return out
