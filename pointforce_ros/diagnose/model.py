"""The structured base model of a point poke and its extension by library effects.

Base model (what residuals are measured against). For poke ``i`` and sample ``t``::

    F_hat(t) = phi(s(t)) * c_i                      s(t) = d(t)      (onset tied to the surface)
    phi(s)   = x ** p * exp(b x)                    x = max(s, 0) / s_ref, s_ref = 3 mm

``d`` is the displacement along ``-n_i`` past the *observed* surface point (so contact must start
at ``d = 0``), ``F`` the full measured force vector, ``c_i`` (3,) the force at ``s_ref`` along
the poke's contact direction: a per-poke nuisance (the local stiffness of a heterogeneous object
and the contact normal), solved in closed form for any poke, training or held-out, by linear
least squares (variable projection). Everything else is global and fitted on training pokes
only: the exponent ``p``, the curvature ``b`` and the parameters of the active effects, which
enter in the physical order

1. ``time_offset``: the pose is read ``offset`` earlier: ``d(t - offset)``.
2. ``surface_offset``, ``plastic_set``, ``series_compliance``: ``s = d + offset - set(n_i) -
   compliance * F_n`` (``F_n`` the model's own normal force, solved implicitly: the
   Oliver-Pharr frame-compliance correction without feeding measurement noise back).
3. ``viscoelastic`` (Prony filter of ``phi`` over time, no adhesion; history carried from a
   poke to the next one only at the same spot and when the times say the next one came
   later: tables whose per-poke time restarts at 0 give independent pokes) and then
   ``hysteresis`` (branch factor along the tip path) shape ``phi``.
4. ``friction``: ``F_hat = M (m_i - mu slip_dir)``, ``M`` the force magnitude, ``m_i = c_i /
   |c_i|`` the contact direction, the slip across it from the push motion.
5. ``ft_bias`` and ``ft_drift``: ``+ bias + rate (t - t_tare)``.

Because the per-poke amplitude and direction are profiled out, an effect only improves the fit
when it explains the *shape* of the curves (onset, loading vs unloading, hold, time, repetition,
lateral force), which is what makes each effect leave its own signature.
"""

import warnings
from dataclasses import dataclass
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
from scipy.optimize import least_squares

from pointforce_ros.diagnose.batch import PokeBatch, velocity
from pointforce_ros.effects.library import (BASE_PARAMS, derived_values, hysteresis_branch,
                                            hysteresis_factor, friction_direction, LIBRARY,
                                            ParamSpec, PLASTIC_RADIUS, plastic_depth,
                                            prony_terms, STICK_VELOCITY)
from pointforce_ros.effects.relaxation import hereditary
from pointforce_ros.errors import InvalidInput, NotConverged
from pointforce_ros.response.blas import single_threaded_blas

S_REF = 0.003
"""Reference depth of the per-poke amplitude, metres."""

BIG_RESIDUAL = 1e6
"""Residual, N, that replaces a non-finite model value inside a fit (the trust region then
backs away from the parameters that produced it)."""


class NumericalFailure(NotConverged):
    """A candidate's fit failed for numerical reasons (non-finite model at every start).

    Diagnose makes the verdict *inconclusive* for the effects the candidate competes with
    instead of letting another effect take its place.
    """


@dataclass(frozen=True)
class Layout:
    """Order of the global parameters for a set of active effects.

    Attributes:
        effects: active effect names (library order).
        entries: ``(effect, ParamSpec)`` per coordinate; the first is the base exponent.

    """

    effects: Tuple[str, ...]
    entries: Tuple[Tuple[str, ParamSpec], ...]

    @classmethod
    def of(cls, effects: Sequence[str]) -> 'Layout':
        """Layout of the base model plus ``effects`` (unknown names raise InvalidInput)."""
        for name in effects:
            if name not in LIBRARY:
                raise InvalidInput(f'unknown effect {name!r}; known: {", ".join(LIBRARY)}')
        ordered = tuple(name for name in LIBRARY if name in set(effects))
        entries = [('base', p) for p in BASE_PARAMS]
        for name in ordered:
            entries += [(name, p) for p in LIBRARY[name].params]
        return cls(ordered, tuple(entries))

    def __len__(self) -> int:
        """Return the number of fitted coordinates."""
        return len(self.entries)

    @property
    def n_effect_params(self) -> int:
        """Parameters added by the effects (the base exponent excluded)."""
        return len(self.entries) - len(BASE_PARAMS)

    def values(self, x: np.ndarray) -> Dict[str, Dict[str, float]]:
        """Map optimised coordinates ``x`` to ``{effect: {param: value}}`` (with settings)."""
        out: Dict[str, Dict[str, float]] = {'base': {}}
        for name in self.effects:
            out[name] = LIBRARY[name].defaults()
        for (name, p), xi in zip(self.entries, x):
            out[name][p.name] = p.to_value(xi)
        for name in self.effects:
            out[name].update(derived_values(name, out[name]))
        return out

    def coordinates(self, values: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        """Optimised coordinates of ``values``; missing entries take their first start."""
        x = []
        for name, p in self.entries:
            given = values.get(name, {})
            x.append(p.to_coordinate(given[p.name]) if p.name in given else p.start[0])
        return np.asarray(x, dtype=np.float64)


def _padded(batch: PokeBatch):
    """Row and column of every sample in a (P, T_max) padded layout."""
    return batch.seg, np.arange(batch.n_samples) - batch.starts[batch.seg]


_HEREDITARY_CACHE: Dict[Tuple, np.ndarray] = {}


def _hereditary(batch: PokeBatch, phi: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Return the unit hereditary integrals ``h_k`` (N, K) of ``phi`` for times ``tau`` (K,).

    They do not depend on the Prony weights, so the last result is kept: a fit that changes
    only the weights (most of a finite-difference Jacobian) filters nothing again.
    """
    key = (batch.n_samples, hash(batch.starts.tobytes()), hash(batch.dt.tobytes()),
           tuple(np.round(tau, 12)), hash(phi.tobytes()))
    cached = _HEREDITARY_CACHE.get(key)
    if cached is not None:
        return cached
    rows, cols = _padded(batch)
    h = np.empty((len(phi), len(tau)))
    dts = np.round(batch.dt, 9)
    for dt in np.unique(dts):
        take = dts[rows] == dt
        grid = np.zeros((len(batch), int(cols.max()) + 1))
        grid[rows[take], cols[take]] = phi[take]
        for k, tk in enumerate(tau):
            h[take, k] = hereditary(grid.T, float(dt), float(tk)).T[rows[take], cols[take]]
    _HEREDITARY_CACHE.clear()
    _HEREDITARY_CACHE[key] = h
    return h


def _relax(batch: PokeBatch, phi: np.ndarray, target_n: np.ndarray, active: np.ndarray,
           g: np.ndarray, tau: np.ndarray, scale: Optional[np.ndarray] = None,
           across: bool = False) -> Tuple[np.ndarray, np.ndarray]:
    """Prony-relaxed shape of every poke and the history carried in from earlier pokes.

    ``g`` (K,) and ``tau`` (K,) are the Prony weights and relaxation times.

    Returns:
        ``(own, carry)``: ``own`` (N,) is the relaxed response to the poke's own shape
        (unit amplitude, unclamped: ``g_inf phi + sum_k g_k h_k``); ``carry`` (N,) newtons is
        what the material remembers of the earlier pokes (``sum_k g_k H_k exp(-(t - t_0) /
        tau_k)``), non-zero only for a complete, time-ordered batch (in a subset each poke
        starts at rest). Both are multiplied by ``scale`` (the hysteresis branch factor,
        applied after the relaxation as in the cell); the carried amplitudes are fitted
        accordingly.

    """
    g = np.atleast_1d(np.asarray(g, dtype=np.float64))
    tau = np.atleast_1d(np.asarray(tau, dtype=np.float64))
    h = _hereditary(batch, phi, tau)
    g_inf = 1.0 - float(np.sum(g))
    own = g_inf * phi + h @ g
    carry = np.zeros_like(phi)
    if not np.array_equal(batch.order, np.arange(len(batch))) or not np.any(g > 0):
        return (own if scale is None else own * scale), carry
    first = batch.starts[:-1]
    last = batch.starts[1:] - 1
    linked = carried_links(batch, across=across)
    if not np.any(linked):
        return (own if scale is None else own * scale), carry
    since = np.maximum(batch.t - batch.per_sample(batch.t[first]), 0.0)
    decay = np.exp(-since[:, None] / tau)                                         # (N, K)
    factor = np.ones_like(phi) if scale is None else scale
    act_own = np.where(active, own * factor, 0.0)
    s_oy = batch.sums(act_own * target_n)
    s_od = batch.sums(act_own[:, None] * decay * (g * factor[:, None]))          # (P, K)
    s_oo = batch.sums(act_own * act_own)
    h_last = h[last]                                                              # (P, K)
    decay_last = decay[last]
    pause = np.maximum(batch.t[first[1:]] - batch.t[last[:-1]], 0.0)
    gap = np.where(linked[:, None], np.exp(-pause[:, None] / tau), 0.0)          # (P-1, K)
    carried = np.zeros((len(batch), len(g)))
    h_in = np.zeros(len(g))
    for k in range(len(batch)):
        carried[k] = h_in
        amp = max((s_oy[k] - float(s_od[k] @ h_in)) / s_oo[k], 0.0) if s_oo[k] > 0 else 0.0
        if k + 1 < len(batch):
            h_in = (amp * h_last[k] + h_in * decay_last[k]) * gap[k]
    if scale is not None:
        own = own * scale
    return own, np.einsum('ik,ik->i', batch.per_sample(carried) * decay, g[None, :]) * factor


def carried_links(batch: PokeBatch, radius: float = PLASTIC_RADIUS,
                  across: bool = False) -> np.ndarray:
    """(P - 1,) whether poke ``k``'s relaxation memory reaches poke ``k + 1``.

    Memory is the material's under the tip: it carries only to the next poke at the same spot
    (within ``radius`` across the axis), or to any next poke when ``across`` (one material
    state for the whole object, as the simulated cell keeps it: the viscoelastic effect's
    ``memory`` setting, chosen by the fit), and only when that poke starts after this one
    ended. Times that overlap or restart (an imported table whose ``t`` starts at 0 on every
    poke) leave each poke's history independent.
    """
    if len(batch) < 2:
        return np.zeros(0, dtype=bool)
    first = batch.starts[:-1]
    last = batch.starts[1:] - 1
    later = batch.t[first[1:]] >= batch.t[last[:-1]]
    if across:
        return later
    rel = batch.point[1:] - batch.point[:-1]
    along = np.einsum('ij,ij->i', rel, batch.normal[:-1])
    across = rel - along[:, None] * batch.normal[:-1]
    near = np.einsum('ij,ij->i', across, across) <= float(radius) ** 2
    return later & near


def _solve_amplitudes(batch: PokeBatch, phi: np.ndarray, carry: Optional[np.ndarray],
                      active: np.ndarray, target: np.ndarray, mu: float, stick: float,
                      motion) -> Tuple[np.ndarray, np.ndarray]:
    """Per-poke amplitude ``c`` (P, 3) and the predicted force (N, 3) without sensor terms.

    Model: ``F = M (m - mu friction_direction(-n, m, motion))`` with
    ``M = max(|c| phi + carry, 0)`` in contact (``active``) and ``m = c / |c|``; ``c`` by
    linear least squares on ``phi``, iterated when the carry or friction terms are present (they
    are moved to the data side with the last ``c``).
    """
    reg = np.where(active, phi, 0.0)
    sw = batch.sums(reg * reg)
    safe = np.where(sw > 0, sw, 1.0)

    def amplitudes(y):
        return np.where(sw[:, None] > 0, batch.sums(reg[:, None] * y) / safe[:, None], 0.0)

    def direction(c):
        norm = np.linalg.norm(c, axis=1)
        unit = np.where(norm[:, None] > 0, c / np.where(norm > 0, norm, 1.0)[:, None],
                        batch.normal)
        return norm, unit

    has_carry = carry is not None and np.any(carry != 0.0)
    friction = motion is not None and mu != 0.0
    inward = -batch.normal_s

    def slip(unit_s):
        return friction_direction(inward, unit_s, motion[0], motion[1], stick)

    c = amplitudes(target)
    for _ in range(3 if (has_carry or friction) else 0):
        norm, unit = direction(c)
        unit_s = batch.per_sample(unit)
        y = target
        if has_carry:
            y = y - carry[:, None] * unit_s
        if friction:
            y = y + mu * (batch.per_sample(norm) * reg)[:, None] * slip(unit_s)
        c = amplitudes(y)
    norm, unit = direction(c)
    unit_s = batch.per_sample(unit)
    magnitude = batch.per_sample(norm) * phi
    if has_carry:
        magnitude = magnitude + carry
    magnitude = np.where(active, np.maximum(magnitude, 0.0), 0.0)
    if friction:
        return magnitude[:, None] * (unit_s - mu * slip(unit_s)), c
    return magnitude[:, None] * unit_s, c


def forward(batch: PokeBatch, values: Mapping[str, Mapping[str, float]]
            ) -> Tuple[np.ndarray, np.ndarray]:
    """Predicted force (N, 3) of every sample and the per-poke amplitudes ``c`` (P, 3).

    Args:
        batch: the pokes. When it is complete (every poke of the data set, in time order), the
            viscoelastic history is carried from poke to poke (decaying over the gaps);
            in a subset each poke starts from a material at rest.
        values: ``{effect: {param: value}}``; ``values['base']['exponent']`` is ``p``; an effect
            that is absent is off.

    """
    p = float(values['base']['exponent'])
    curvature = float(values['base'].get('curvature', 0.0))
    n_seg = batch.normal_s
    sensor = np.zeros_like(batch.force)
    if 'ft_bias' in values:
        b = values['ft_bias']
        sensor += np.array([b['fx'], b['fy'], b['fz']])
    if 'ft_drift' in values:
        r = values['ft_drift']
        sensor += np.outer(batch.t - batch.per_sample(batch.t_ref), [r['rx'], r['ry'], r['rz']])
    target = batch.force - sensor
    d = batch.d
    if 'time_offset' in values:
        tau = float(values['time_offset']['offset'])
        lo = batch.tv[batch.starts[:-1]]
        hi = batch.tv[batch.starts[1:] - 1]
        query = np.clip(batch.tv - tau, batch.per_sample(lo), batch.per_sample(hi))
        d = np.interp(query, batch.tv, batch.d)
    s_kin = d
    if 'surface_offset' in values:
        s_kin = s_kin + float(values['surface_offset']['offset'])
    if 'plastic_set' in values:
        ps = values['plastic_set']
        s_kin = s_kin - batch.per_sample(plastic_depth(batch.count, ps['max_set'], ps['n0']))
    branch = None
    if 'hysteresis' in values:
        h = values['hysteresis']
        z = hysteresis_branch(s_kin, h['transition'], z0=np.where(batch.order > 0, -1.0, 1.0),
                              starts=batch.starts)
        branch = hysteresis_factor(z, h['eta'])
    visco = values.get('viscoelastic')
    fric = values.get('friction')
    mu = float(fric['mu']) if fric else 0.0
    stick = float(fric.get('stick_velocity', STICK_VELOCITY)) if fric else STICK_VELOCITY
    motion = None
    if fric:
        motion = (batch.motion, batch.moving_speed)
        if 'time_offset' in values:
            motion = (np.interp(query, batch.tv, batch.motion),
                      np.interp(query, batch.tv, batch.moving_speed))
    target_n = np.einsum('ij,ij->i', target, n_seg)

    def evaluate(s):
        x = np.maximum(s, 0.0) / S_REF
        phi_e = x ** p * np.exp(curvature * x)
        active = phi_e > 0
        carry = None
        if visco is not None:
            # relaxation acts on the elastic response, the hysteresis branch on the result
            g, tau = prony_terms(visco)
            phi, carry = _relax(batch, phi_e, target_n, active, g, tau, scale=branch,
                                across=float(visco.get('memory', 0.0)) > 0.5)
        else:
            phi = phi_e * branch if branch is not None else phi_e
        return _solve_amplitudes(batch, phi, carry, active, target, mu, stick, motion)

    if 'series_compliance' in values:
        # Frame compliance: the tip retreats compliance * F_n, where F_n solves
        # F = a h phi(s - compliance F) per sample (Newton) for the per-poke normal amplitude
        # a (h: hysteresis branch factor). The amplitude is the fixed point of "solve F with a,
        # refit a by least squares", found by Aitken extrapolation of two refits. The measured
        # force enters only through a (one number per poke): building the displacement from the
        # measured force itself would leak the data's own time structure (noise, disturbances)
        # into the prediction.
        compliance = float(values['series_compliance']['compliance'])

        def refit(a):
            a_s = batch.per_sample(a) * (branch if branch is not None else 1.0)
            f_n = _compliant_force(s_kin, a_s, compliance, p, curvature)
            pred, c = evaluate(s_kin - compliance * f_n)
            return np.maximum(np.einsum('ij,ij->i', c, batch.normal), 0.0), pred, c

        _, c = evaluate(s_kin)
        a0 = np.maximum(np.einsum('ij,ij->i', c, batch.normal), 0.0)
        a1, _, _ = refit(a0)
        a2, pred, c = refit(a1)
        denom = a2 - 2.0 * a1 + a0
        safe = np.abs(denom) > 1e-12 * np.maximum(np.abs(a2), 1e-300)
        a_star = np.where(safe, a0 - (a1 - a0) ** 2 / np.where(safe, denom, 1.0), a2)
        a_star = np.where(np.isfinite(a_star) & (a_star >= 0), a_star, a2)
        _, pred, c = refit(a_star)
    else:
        pred, c = evaluate(s_kin)
    return pred + sensor, c


def _compliant_force(s: np.ndarray, amplitude: np.ndarray, compliance: float, p: float,
                     curvature: float, steps: int = 6) -> np.ndarray:
    """Solve ``F = amplitude phi((s - compliance F) / s_ref)`` per sample (Newton, F >= 0).

    ``phi(x) = x^p exp(curvature x)``; ``F`` is bracketed by 0 and the compliance-free force
    and each step is clipped into that bracket.
    """
    def law(depth):
        x = np.maximum(depth, 0.0) / S_REF
        value = x ** p * np.exp(curvature * x)
        slope = np.where(x > 0, value * (p / np.where(x > 0, x, 1.0) + curvature), 0.0) / S_REF
        return value, slope

    upper = amplitude * law(s)[0]
    force = upper.copy()
    for _ in range(steps):
        value, slope = law(s - compliance * force)
        g = force - amplitude * value
        dg = 1.0 + amplitude * compliance * slope
        force = np.clip(force - g / dg, 0.0, upper)
    return force


def _coupled(batch: PokeBatch, effects) -> bool:
    """Tell whether pokes interact (material history), so the whole batch must be evaluated."""
    return 'viscoelastic' in effects and np.array_equal(batch.order, np.arange(len(batch)))


def _sample_index(batch: PokeBatch, pokes: np.ndarray) -> np.ndarray:
    return np.concatenate([np.arange(batch.starts[i], batch.starts[i + 1]) for i in pokes])


def predict(batch: PokeBatch, values, pokes=None) -> Tuple[np.ndarray, np.ndarray]:
    """Predicted force (M, 3) of the samples of ``pokes`` (all when None) and their indices.

    When the pokes interact (viscoelastic history over a complete batch) the whole batch is
    evaluated and the requested samples are taken from it; otherwise only ``pokes`` are.
    """
    if pokes is None:
        pred, _ = forward(batch, values)
        return pred, np.arange(batch.n_samples)
    pokes = np.asarray(pokes, dtype=np.int64)
    take = _sample_index(batch, pokes)
    if _coupled(batch, values):
        pred, _ = forward(batch, values)
        return pred[take], take
    pred, _ = forward(batch.subset(pokes), values)
    return pred, take


def poke_sse(batch: PokeBatch, values, pokes=None) -> np.ndarray:
    """Sum of squared force residuals (N^2) of each poke in ``pokes`` (all when None)."""
    pokes = np.arange(len(batch)) if pokes is None else np.asarray(pokes, dtype=np.int64)
    pred, take = predict(batch, values, pokes)
    r = batch.force[take] - pred
    lengths = np.diff(batch.starts)[pokes]
    offsets = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    return np.add.reduceat(np.einsum('ij,ij->i', r, r), offsets)


@dataclass(frozen=True)
class Fit:
    """Global parameters fitted on some pokes.

    Attributes:
        layout: parameter order.
        x: (k,) optimised coordinates.
        values: ``{effect: {param: value}}``.
        cost: mean squared force residual per sample on the fitted pokes, N^2.
        nfev: model evaluations used.

    """

    layout: Layout
    x: np.ndarray
    values: Dict[str, Dict[str, float]]
    cost: float
    nfev: int


def _data_starts(batch: PokeBatch, effect: str, spec: ParamSpec) -> Tuple[float, ...]:
    """Extra starting points read off the data (where the library's starts may see no slope).

    ``surface_offset``: minus the median displacement at which the force first exceeds 5 % of
    each poke's peak. Contact that starts far outside the observed surface leaves the base
    model with no force at all, hence no gradient from an offset of zero.
    """
    if effect != 'surface_offset' or spec.name != 'offset':
        return ()
    f_n = np.einsum('ij,ij->i', batch.force, batch.normal_s)
    first = batch.starts[:-1]
    rise = f_n - f_n[first][batch.seg]
    peak = np.maximum.reduceat(rise, first)
    above = rise > 0.05 * batch.per_sample(np.maximum(peak, 1e-12))
    index = np.where(above, np.arange(batch.n_samples), batch.n_samples)
    touch = np.minimum.reduceat(index, first)
    valid = touch < batch.starts[1:]
    if not np.any(valid):
        return ()
    guess = -float(np.median(batch.d[touch[valid]]))
    return (float(np.clip(guess, spec.lower, spec.upper)),) if abs(guess) > 1e-4 else ()


def unresolved(batch: PokeBatch, layout: Layout, reach: float = 1.0) -> np.ndarray:
    """(k,) coordinates of ``layout`` the data cannot resolve; they stay at their lower bound.

    A Prony term whose relaxation time exceeds ``reach`` times the stretch of time the data
    follow the material (the median poke, or the longest chain of pokes at one spot whose
    memory carries, :func:`carried_links`) only shows its initial slope ``g / tau``: its
    weight, hence the relaxed fraction, would be a guess. Such weights are pinned at 0 (the
    relaxation the data show is fitted by the resolved terms), so holds of tens of seconds
    bring the tens-of-seconds terms in.
    """
    pinned = np.zeros(len(layout), dtype=bool)
    if 'viscoelastic' not in layout.effects:
        return pinned
    first = batch.starts[:-1]
    last = batch.starts[1:] - 1
    span = batch.t[last] - batch.t[first]
    horizon = float(np.median(span)) if len(span) else 0.0
    links = carried_links(batch)
    run = float(span[0]) if len(span) else 0.0
    for k, linked in enumerate(links):
        if linked:
            run += float(batch.t[last[k + 1]] - batch.t[last[k]])
            horizon = max(horizon, run)
        else:
            run = float(span[k + 1])
    settings = LIBRARY['viscoelastic'].defaults()
    for i, (name, p) in enumerate(layout.entries):
        if name == 'viscoelastic' and p.zero_ok:
            tau = settings.get('tau' + p.name[1:])
            pinned[i] = tau is not None and tau > reach * horizon
    return pinned


def fit_global(batch: PokeBatch, effects: Sequence[str], *, pokes=None,
               start: Optional[Mapping[str, Mapping[str, float]]] = None,
               max_nfev: int = 60, multistart: bool = True) -> Fit:
    """Fit the exponent and the parameters of ``effects`` on ``pokes`` (bounded least squares).

    Args:
        batch: the whole data set (pokes in time order).
        effects: active effect names.
        pokes: indices of the training pokes, repeats allowed (bootstrap); all when None.
        start: values to start from (e.g. the previous round's fit); parameters not in it start
            from each of their library starts (``multistart``) and the best is kept.
        max_nfev: most model evaluations per start.
        multistart: try every combination of library starts of the new parameters.

    Non-finite model values (an overflow on extreme parameters) are replaced by a large
    residual inside the fit, so the optimiser backs away from them; no warning is printed.

    Raises:
        NumericalFailure: the model is not finite at any start, or the optimiser failed on
            every start (a :class:`NotConverged`).

    """
    layout = Layout.of(effects)
    scale = np.array([p.scale for _, p in layout.entries])
    lower = np.array([p.lower for _, p in layout.entries]) / scale
    upper = np.array([p.upper for _, p in layout.entries]) / scale
    start = start or {}
    base = layout.coordinates(start)
    pinned = unresolved(batch, layout)
    base = np.where(pinned, lower * scale, base)
    free = np.flatnonzero(~pinned)
    fresh = [i for i, (name, p) in enumerate(layout.entries)
             if p.name not in start.get(name, {})]
    pokes = np.arange(len(batch)) if pokes is None else np.asarray(pokes, dtype=np.int64)
    starts = [base]
    if multistart:
        for i in fresh:
            name, spec = layout.entries[i]
            options = tuple(spec.start) + _data_starts(batch.subset(pokes), name, spec)
            if len(options) > 1:
                starts = [np.where(np.arange(len(base)) == i, opt, s)
                          for s in starts for opt in options]
    if _coupled(batch, layout.effects):
        counts = np.bincount(pokes, minlength=len(batch)).astype(np.float64)
        keep = np.flatnonzero(counts[batch.seg] > 0)
        weight = np.sqrt(counts[batch.seg][keep])[:, None]
        data, force = batch, batch.force[keep]
    else:
        data = batch.subset(pokes)
        keep, weight, force = None, None, data.force
    n_samples = max(len(force), 1)

    bad = {'count': 0}

    def full(u):
        x = lower.copy()
        x[free] = u
        return x

    memory = {'value': None}

    def values_of(x):
        values = layout.values(x)
        if memory['value'] is not None:
            values['viscoelastic']['memory'] = memory['value']
        return values

    def residual(u):
        with np.errstate(all='ignore'):
            pred, _ = forward(data, values_of(full(u) * scale))
            if keep is None:
                r = (force - pred).ravel()
            else:
                r = ((force - pred[keep]) * weight).ravel()
        finite = np.isfinite(r)
        if not np.all(finite):
            # a guarded condition, not a warning: the trust region backs away from here
            bad['count'] += 1
            r = np.where(finite, r, BIG_RESIDUAL)
        return r

    best = None
    last_error = None
    scopes = [None]
    if _coupled(batch, layout.effects) and not np.array_equal(
            carried_links(batch), carried_links(batch, across=True)):
        given = start.get('viscoelastic', {}).get('memory')
        scopes = [float(given)] if given is not None else [0.0, 1.0]
    chosen = scopes[0]
    for scope in scopes:
        memory['value'] = scope
        with single_threaded_blas(), warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)
            found, error = _solve_starts([(x0 / scale)[free] for x0 in starts], residual,
                                         lower[free], upper[free], max_nfev, n_samples)
        last_error = error if found is None else last_error
        if found is not None and (best is None or found[1] < best[1]):
            best, chosen = found, scope
    memory['value'] = chosen
    if best is None:
        raise NumericalFailure(f'effect fit {list(effects)} failed on every start: '
                               f'{last_error}')
    if not np.isfinite(best[1]) or best[1] >= BIG_RESIDUAL ** 2 * 1e-3:
        raise NumericalFailure(f'effect fit {list(effects)}: the model is not finite at the '
                               f'best of {len(starts)} start(s) ({bad["count"]} non-finite '
                               'evaluations)')
    sol, cost = best
    x = full(sol.x) * scale
    return Fit(layout=layout, x=x, values=values_of(x), cost=cost, nfev=int(sol.nfev))


def _solve_starts(starts, residual, lower, upper, max_nfev, n_samples):
    """Bounded least squares from every start (scaled coordinates).

    Returns ``((solution, cost) or None, last error)``.

    Run with BLAS on one thread: the Jacobians are tall and thin (samples x a few
    parameters), where a multi-threaded BLAS gains nothing and, on a loaded machine, made the
    SVDs of the trust-region solver 4x slower.
    """
    best = None
    last_error = None
    for x0 in starts:
        u0 = np.clip(x0, lower + 1e-9 * (upper - lower), upper - 1e-9 * (upper - lower))
        try:
            sol = least_squares(residual, u0, bounds=(lower, upper), x_scale=1.0,
                                diff_step=1e-3, max_nfev=max_nfev, method='trf', ftol=1e-6,
                                xtol=1e-6, gtol=1e-8)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            last_error = exc
            continue
        cost = 2.0 * float(sol.cost) / n_samples
        if best is None or cost < best[1]:
            best = (sol, cost)
    return best, last_error


def heldout_sse(batch: PokeBatch, fits: Sequence[Tuple[np.ndarray, Fit]]) -> np.ndarray:
    """(P,) per-poke SSE where each poke is scored by the fit of the fold that held it out.

    Args:
        batch: every poke.
        fits: ``(heldout_indices, fit)`` per fold.

    """
    out = np.full(len(batch), np.nan)
    for idx, fit in fits:
        out[idx] = poke_sse(batch, fit.values, idx)
    return out


def residual_table(batch: PokeBatch, fits: Sequence[Tuple[np.ndarray, Fit]]
                   ) -> Dict[str, np.ndarray]:
    """Held-out residuals of every sample, for plots and structure analysis.

    Returns:
        Mapping of (N,) arrays in the batch's sample order: ``poke`` index, ``t`` (s since the
        poke's first sample), ``t_abs`` (controller s), ``d`` (m), ``v`` (m/s), ``measured`` and
        ``predicted`` normal force (N), ``normal`` (normal residual, N), ``lateral`` (norm of the
        lateral residual, N), ``norm`` (norm of the residual vector, N), and ``rx, ry, rz`` (N).

    """
    resid = heldout_residual(batch, fits)
    pred = batch.force - resid
    n_seg = batch.normal_s
    normal = np.einsum('ij,ij->i', resid, n_seg)
    lateral = resid - normal[:, None] * n_seg
    first = batch.per_sample(batch.t[batch.starts[:-1]])
    return {
        'poke': batch.seg.copy(), 't': batch.t - first, 't_abs': batch.t.copy(),
        'd': batch.d.copy(), 'v': velocity(batch),
        'measured': np.einsum('ij,ij->i', batch.force, n_seg),
        'predicted': np.einsum('ij,ij->i', pred, n_seg), 'normal': normal,
        'lateral': np.linalg.norm(lateral, axis=1), 'norm': np.linalg.norm(resid, axis=1),
        'rx': resid[:, 0], 'ry': resid[:, 1], 'rz': resid[:, 2],
    }


def fold_indices(n: int, folds: int, seed: int) -> List[np.ndarray]:
    """Seeded split of ``n`` pokes into ``folds`` held-out groups (sizes differ by at most 1).

    Raises:
        InvalidInput: fewer than 2 folds or more folds than pokes.

    """
    if folds < 2 or folds > n:
        raise InvalidInput(f'folds must be in 2..{n} (number of pokes), got {folds}')
    perm = np.random.default_rng(seed).permutation(n)
    return [np.sort(perm[k::folds]) for k in range(folds)]


MODEL_BLOCK = 0.25
"""Duration of the blocks the model RMSE averages the residual over, seconds."""


def model_blocks(batch: PokeBatch, seconds: float = MODEL_BLOCK) -> np.ndarray:
    """Block of every sample for the *model RMSE* (N,) int; -1: in no block.

    A block is ``size = round(seconds / dt)`` consecutive samples (``dt`` the median analysis
    interval; 12 samples, 0.24 s, at the default 50 Hz) of one phase (free space ``d < 0``,
    loading, hold, unloading) of one poke; the last block of a phase run takes its leftover
    samples (up to ``2 size - 1``); runs shorter than ``size`` samples are left out. Averaging
    a residual over a block divides the variance of white sensor noise by the block size and
    keeps every structure slower than the block (at 5 mm/s a block spans 1.2 mm of depth).
    Blocks never mix loading and unloading, so a hysteresis or lag residual of opposite sign
    on the two branches does not cancel.

    Raises:
        InvalidInput: ``seconds`` not > 0.

    """
    if not (np.isfinite(seconds) and seconds > 0):
        raise InvalidInput(f'model_blocks: seconds must be > 0, got {seconds}')
    size = max(int(round(float(seconds) / float(np.median(batch.dt)))), 1)
    v = velocity(batch)
    slow = np.abs(v) < 0.1 * batch.per_sample(batch.speed)
    phase = np.where(batch.d < 0, 0, np.where(slow, 2, np.where(v > 0, 1, 3)))
    n = batch.n_samples
    new_run = np.ones(n, dtype=bool)
    new_run[1:] = (phase[1:] != phase[:-1]) | (batch.seg[1:] != batch.seg[:-1])
    run = np.cumsum(new_run) - 1
    run_start = np.flatnonzero(new_run)
    run_len = np.diff(np.append(run_start, n))
    pos = np.arange(n) - run_start[run]
    per_run = run_len // size                                   # blocks in each run
    first_block = np.concatenate([[0], np.cumsum(per_run)[:-1]])
    local = np.minimum(pos // size, np.maximum(per_run[run] - 1, 0))
    return np.where(per_run[run] > 0, first_block[run] + local, -1)


def block_sse(batch: PokeBatch, resid: np.ndarray, blocks: np.ndarray
              ) -> Tuple[np.ndarray, np.ndarray]:
    """Per-poke model SSE from block means of a residual and the samples it covers.

    Args:
        batch: the pokes.
        resid: (N, 3) residual force vectors, N.
        blocks: (N,) block ids of :func:`model_blocks` (-1: left out).

    Returns:
        ``(sse, count)``, both (P,): ``sum_b n_b |mean_b|^2`` over the blocks of each poke
        (N^2) and the number of samples in them.

    """
    keep = blocks >= 0
    b = blocks[keep]
    n_blocks = int(b.max()) + 1 if len(b) else 0
    n_b = np.bincount(b, minlength=n_blocks).astype(np.float64)
    sums = np.stack([np.bincount(b, weights=resid[keep, k], minlength=n_blocks)
                     for k in range(3)], axis=1)
    energy = np.sum(sums ** 2, axis=1) / np.maximum(n_b, 1.0)          # n_b |mean_b|^2
    poke = np.zeros(n_blocks, dtype=np.int64)
    poke[b] = batch.seg[keep]
    sse = np.bincount(poke, weights=energy, minlength=len(batch))
    count = np.bincount(batch.seg[keep], minlength=len(batch)).astype(np.float64)
    return sse, count


def heldout_residual(batch: PokeBatch, fits: Sequence[Tuple[np.ndarray, Fit]]) -> np.ndarray:
    """(N, 3) held-out force residual (measured - predicted) of every sample, N.

    Each poke is predicted by the fit of the fold that held it out.
    """
    pred = np.zeros_like(batch.force)
    for idx, fit in fits:
        p, take = predict(batch, fit.values, idx)
        pred[take] = p
    return batch.force - pred
