"""Switchable effects of the simulated cell: what lies between the clean physics and the sensors.

Each effect is a frozen dataclass of its parameters (SI units) with a registered ``name`` (the key
used in scenario YAML) and a ``stage`` that says where it acts:

``camera``   depth bias and noise, handed to :class:`~pointforce_ros.sim.camera.DepthCamera`.
``ft``       F/T noise, bias and drift, handed to :class:`~pointforce_ros.sim.ft_sensor.FtSensor`.
``geometry`` where the probe tip really is relative to the surface: series compliance (the tip
             lags the commanded pose by ``F / k``) and plastic set (the surface sinks after
             repeated pokes at one spot).
``material`` history-dependent force response: viscoelastic relaxation (Prony series) and
             rate-independent loading/unloading hysteresis.
``contact``  Coulomb friction on oblique contact.
``stream``   time offset between the pose and force streams.

Stateful effects are written as pure step functions ``step(state, ...) -> (output, new_state)``
so that the series-compliance solver can try a candidate tip position without committing the
history; :class:`~pointforce_ros.sim.scenario.CellForceModel` commits the state of the accepted
solution. Wrenches are (6,) ``[fx, fy, fz, tx, ty, tz]`` (N, N m), force = reaction of the object
on the probe, base-oriented, torque about the probe tip (the TCP).
"""

import collections
from dataclasses import asdict, dataclass, field, fields
from typing import Callable, ClassVar, Dict, Mapping, Optional, Tuple, Type

import numpy as np

from pointforce_ros.errors import InvalidInput, NotConverged

EFFECTS: Dict[str, Type['Effect']] = {}
"""Registry: effect name (as written in scenario YAML) -> effect class."""


def _register(cls):
    EFFECTS[cls.name] = cls
    return cls


def _finite(name: str, value, *, minimum: Optional[float] = None, strict: bool = False) -> float:
    """Return ``value`` as a float, raising InvalidInput if not finite or below ``minimum``."""
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f'{name}: must be a number, got {value!r}')
    if not np.isfinite(out):
        raise InvalidInput(f'{name}: must be finite, got {out}')
    if minimum is not None and (out < minimum or (strict and out == minimum)):
        raise InvalidInput(f'{name}: must be {">" if strict else ">="} {minimum}, got {out}')
    return out


def _vec(name: str, value, size: int) -> Tuple[float, ...]:
    """Return a scalar (broadcast) or length-``size`` sequence as a tuple of finite floats."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    if arr.shape != (size,) or not np.all(np.isfinite(arr)):
        raise InvalidInput(f'{name}: need a finite scalar or {size} values, got {value!r}')
    return tuple(float(x) for x in arr)


@dataclass(frozen=True)
class Effect:
    """Base class of the named, parameterised effects."""

    name: ClassVar[str] = ''
    stage: ClassVar[str] = ''

    @classmethod
    def from_params(cls, params: Mapping) -> 'Effect':
        """Build the effect from a parameter mapping (YAML), rejecting unknown keys.

        Raises:
            InvalidInput: unknown or missing parameters, or invalid values.

        """
        known = {f.name for f in fields(cls)}
        unknown = set(params) - known
        if unknown:
            raise InvalidInput(f'effect {cls.name}: unknown parameter(s) {sorted(unknown)}; '
                               f'expected some of {sorted(known)}')
        try:
            return cls(**dict(params))
        except TypeError as exc:
            raise InvalidInput(f'effect {cls.name}: {exc}')

    def params(self) -> dict:
        """Return the parameters as a plain mapping (YAML-ready)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


# --------------------------------------------------------------------------- camera


@_register
@dataclass(frozen=True)
class CameraDepthBias(Effect):
    """Constant depth offset of the depth camera, ``bias`` metres (positive reads too far)."""

    name: ClassVar[str] = 'camera_depth_bias'
    stage: ClassVar[str] = 'camera'
    bias: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, 'bias', _finite('camera_depth_bias.bias', self.bias))

    def camera_kwargs(self) -> dict:
        """Keyword arguments for :class:`DepthCamera`."""
        return {'depth_bias': self.bias}


@_register
@dataclass(frozen=True)
class CameraDepthNoise(Effect):
    """Depth noise with standard deviation ``a + b z**2`` (``a`` metres, ``b`` 1/m)."""

    name: ClassVar[str] = 'camera_depth_noise'
    stage: ClassVar[str] = 'camera'
    a: float = 0.0
    b: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, 'a', _finite('camera_depth_noise.a', self.a, minimum=0.0))
        object.__setattr__(self, 'b', _finite('camera_depth_noise.b', self.b, minimum=0.0))

    def camera_kwargs(self) -> dict:
        """Keyword arguments for :class:`DepthCamera`."""
        return {'noise_a': self.a, 'noise_b': self.b}


# --------------------------------------------------------------------------- F/T sensor


@_register
@dataclass(frozen=True)
class FtNoise(Effect):
    """White F/T noise per controller sample: ``force_std`` N and ``torque_std`` N m."""

    name: ClassVar[str] = 'ft_noise'
    stage: ClassVar[str] = 'ft'
    force_std: float = 0.0
    torque_std: float = 0.0

    def __post_init__(self):
        for attr in ('force_std', 'torque_std'):
            object.__setattr__(self, attr, _finite(f'ft_noise.{attr}', getattr(self, attr),
                                                   minimum=0.0))

    def ft_kwargs(self) -> dict:
        """Keyword arguments for :class:`FtSensor`."""
        return {'noise_std': [self.force_std] * 3 + [self.torque_std] * 3}


@_register
@dataclass(frozen=True)
class FtBias(Effect):
    """Constant F/T offset, ``force`` (3,) N and ``torque`` (3,) N m, removed by a tare."""

    name: ClassVar[str] = 'ft_bias'
    stage: ClassVar[str] = 'ft'
    force: Tuple[float, ...] = (0.0, 0.0, 0.0)
    torque: Tuple[float, ...] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, 'force', _vec('ft_bias.force', self.force, 3))
        object.__setattr__(self, 'torque', _vec('ft_bias.torque', self.torque, 3))

    def ft_kwargs(self) -> dict:
        """Keyword arguments for :class:`FtSensor`."""
        return {'bias': list(self.force) + list(self.torque)}


@_register
@dataclass(frozen=True)
class FtDrift(Effect):
    """Linear temperature-like drift, ``force_rate`` (3,) N/s and ``torque_rate`` (3,) N m/s."""

    name: ClassVar[str] = 'ft_drift'
    stage: ClassVar[str] = 'ft'
    force_rate: Tuple[float, ...] = (0.0, 0.0, 0.0)
    torque_rate: Tuple[float, ...] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        object.__setattr__(self, 'force_rate', _vec('ft_drift.force_rate', self.force_rate, 3))
        object.__setattr__(self, 'torque_rate',
                           _vec('ft_drift.torque_rate', self.torque_rate, 3))

    def ft_kwargs(self) -> dict:
        """Keyword arguments for :class:`FtSensor`."""
        return {'drift_rate': list(self.force_rate) + list(self.torque_rate)}


# --------------------------------------------------------------------------- stream


@_register
@dataclass(frozen=True)
class TimeOffset(Effect):
    """The force stream lags the pose stream by ``offset`` seconds (>= 0).

    The wrench reported at time ``t`` is the contact wrench at ``t - offset``, linearly
    interpolated between computed samples (a negative offset would need the future wrench).
    """

    name: ClassVar[str] = 'time_offset'
    stage: ClassVar[str] = 'stream'
    offset: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, 'offset', _finite('time_offset.offset', self.offset,
                                                   minimum=0.0))

    def delay_line(self) -> 'DelayLine':
        """Return a fresh delay line for this offset."""
        return DelayLine(self.offset)


class DelayLine:
    """Delay a sampled (6,) signal by ``offset`` seconds with linear interpolation.

    Before the first ``offset`` seconds of history exist it returns the oldest sample.
    """

    def __init__(self, offset: float):
        self.offset = float(offset)
        self._buf = collections.deque()

    def __call__(self, t: float, value: np.ndarray) -> np.ndarray:
        """Push ``value`` at time ``t`` (non-decreasing) and return the value at ``t - offset``."""
        buf = self._buf
        buf.append((t, value))
        if self.offset == 0.0:
            buf.popleft()
            return value
        target = t - self.offset
        while len(buf) > 2 and buf[1][0] <= target:
            buf.popleft()
        t0, v0 = buf[0]
        if target <= t0 or len(buf) == 1:
            return v0
        t1, v1 = buf[1]
        if t1 <= t0:
            return v1
        w = min((target - t0) / (t1 - t0), 1.0)
        return v0 + w * (v1 - v0)

    def reset(self) -> None:
        """Forget the history."""
        self._buf.clear()


# --------------------------------------------------------------------------- material


@_register
@dataclass(frozen=True)
class ViscoelasticRelaxation(Effect):
    """Prony-series relaxation of the contact wrench.

    ``f(t) = g_inf f_e(t) + sum_i g_i int exp(-(t - s) / tau_i) df_e(s)`` with
    ``g_inf = 1 - sum g_i``: the clean (elastic) response ``f_e`` is the instantaneous one, and at
    constant depth the force relaxes to ``g_inf f_e``. The integral is updated recursively per
    sample, exactly for ``f_e`` piecewise linear in time. The result never pulls the probe
    (no adhesion): it is zero out of contact and clamped to zero if it points against ``f_e``.

    Attributes:
        g: (K,) relaxation fractions, each in (0, 1), sum < 1.
        tau: (K,) relaxation times, seconds, > 0.

    """

    name: ClassVar[str] = 'viscoelastic'
    stage: ClassVar[str] = 'material'
    g: Tuple[float, ...] = (0.2,)
    tau: Tuple[float, ...] = (1.0,)

    def __post_init__(self):
        g = np.atleast_1d(np.asarray(self.g, dtype=np.float64))
        tau = np.atleast_1d(np.asarray(self.tau, dtype=np.float64))
        if g.ndim != 1 or g.shape != tau.shape or len(g) == 0:
            raise InvalidInput(f'viscoelastic: g and tau must be equally long lists, got '
                               f'{self.g!r} and {self.tau!r}')
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(tau))):
            raise InvalidInput('viscoelastic: g and tau must be finite')
        if np.any(g <= 0) or g.sum() >= 1.0:
            raise InvalidInput(f'viscoelastic.g: each must be > 0 and their sum < 1 (sum = '
                               f'{g.sum():.4g}); g_inf = 1 - sum(g) is the relaxed fraction')
        if np.any(tau <= 0):
            raise InvalidInput('viscoelastic.tau: relaxation times must be > 0 seconds')
        object.__setattr__(self, 'g', tuple(float(x) for x in g))
        object.__setattr__(self, 'tau', tuple(float(x) for x in tau))
        object.__setattr__(self, '_g', g)
        object.__setattr__(self, '_tau', tau)

    @property
    def g_inf(self) -> float:
        """Long-term (fully relaxed) fraction of the elastic response."""
        return 1.0 - float(np.sum(self._g))

    def initial_state(self):
        """State of a material at rest and unloaded."""
        return None

    def step(self, state, f_e: np.ndarray, t: float):
        """Advance to time ``t`` with elastic wrench ``f_e`` (6,); return ``(f (6,), state)``."""
        if state is None:
            t_prev, f_prev, hist = t, np.zeros(6), np.zeros((len(self._g), 6))
        else:
            t_prev, f_prev, hist = state
        dt = t - t_prev
        if dt > 0:
            ratio = dt / self._tau
            decay = np.exp(-ratio)
            # average of exp(-(t - s) / tau) over the step: weight of a linear ramp of f_e
            ramp = np.where(ratio > 1e-8, -np.expm1(-ratio) / np.maximum(ratio, 1e-300),
                            1.0 - 0.5 * ratio)
        else:
            decay = ramp = np.ones_like(self._tau)
        hist = decay[:, None] * hist + ramp[:, None] * (f_e - f_prev)[None, :]
        out = self.g_inf * f_e + self._g @ hist
        force_e2 = float(f_e[:3] @ f_e[:3])
        if force_e2 == 0.0 or float(out[:3] @ f_e[:3]) < 0.0:
            out = np.zeros(6)
        return out, (t, f_e, hist)


@_register
@dataclass(frozen=True)
class Hysteresis(Effect):
    """Rate-independent loading/unloading hysteresis (a Bouc-Wen-like branch variable).

    A branch variable ``z`` in [-1, 1] follows the sign of the depth rate:
    ``dz = (sign(ds) - z) |ds| / transition`` (exact exponential update per sample), where ``s`` is
    the tip position along the probe axis. The wrench is ``f = f_e (1 - eta (1 - z) / 2)``: on
    the loading branch (``z = 1``) the clean response, on the unloading branch (``z = -1``) a
    fraction ``1 - eta`` of it, blended over a depth ``transition`` after each reversal. The loop
    area is proportional to ``eta``.

    Attributes:
        eta: unloading deficit, in [0, 1).
        transition: branch-switching depth, metres, > 0.

    """

    name: ClassVar[str] = 'hysteresis'
    stage: ClassVar[str] = 'material'
    eta: float = 0.15
    transition: float = 0.0005

    def __post_init__(self):
        eta = _finite('hysteresis.eta', self.eta, minimum=0.0)
        if eta >= 1.0:
            raise InvalidInput(f'hysteresis.eta: must be < 1 (unloading force fraction '
                               f'1 - eta), got {eta}')
        object.__setattr__(self, 'eta', eta)
        object.__setattr__(self, 'transition', _finite('hysteresis.transition',
                                                       self.transition, minimum=0.0,
                                                       strict=True))

    def initial_state(self):
        """State on the loading branch with no depth history."""
        return None

    def step(self, state, f_e: np.ndarray, s: float):
        """Move to axial tip position ``s`` (metres) with wrench ``f_e`` (6,).

        Returns:
            ``(f (6,), state)``.

        """
        if state is None:
            z = 1.0
        else:
            s_prev, z = state
            ds = s - s_prev
            if ds != 0.0:
                direction = 1.0 if ds > 0 else -1.0
                z = direction + (z - direction) * np.exp(-abs(ds) / self.transition)
        return f_e * (1.0 - self.eta * 0.5 * (1.0 - z)), (s, z)


# --------------------------------------------------------------------------- contact


@_register
@dataclass(frozen=True)
class Friction(Effect):
    """Coulomb friction on oblique contact.

    The tip's slip velocity ``v_t`` is its velocity minus the part along the contact normal (the
    direction of the incoming frictionless force). The tangential force ``-mu |F_n| v_t /
    max(|v_t|, stick_velocity)`` is added: ``mu |F_n|`` opposing the slip once it is faster than
    ``stick_velocity``, proportionally less below (a regularised stick). It acts at the tip, so it
    adds no torque about the TCP.

    Attributes:
        mu: friction coefficient, >= 0.
        stick_velocity: regularisation velocity, m/s, > 0.

    """

    name: ClassVar[str] = 'friction'
    stage: ClassVar[str] = 'contact'
    mu: float = 0.3
    stick_velocity: float = 1e-4

    def __post_init__(self):
        object.__setattr__(self, 'mu', _finite('friction.mu', self.mu, minimum=0.0))
        object.__setattr__(self, 'stick_velocity', _finite(
            'friction.stick_velocity', self.stick_velocity, minimum=0.0, strict=True))

    def initial_state(self):
        """State with no motion history."""
        return None

    def step(self, state, f_in: np.ndarray, tip: np.ndarray, t: float):
        """Add friction for tip position ``tip`` (3,) at time ``t``; return ``(f (6,), state)``."""
        if state is None:
            velocity = np.zeros(3)
        else:
            t_prev, tip_prev, v_prev = state
            dt = t - t_prev
            velocity = (tip - tip_prev) / dt if dt > 0 else v_prev
        new_state = (t, tip, velocity)
        force = f_in[:3]
        f_n = float(np.sqrt(force @ force))
        if f_n == 0.0 or self.mu == 0.0:
            return f_in, new_state
        normal = force / f_n
        slip = velocity - (velocity @ normal) * normal
        speed = float(np.sqrt(slip @ slip))
        if speed == 0.0:
            return f_in, new_state
        out = f_in.copy()
        out[:3] -= self.mu * f_n * slip / max(speed, self.stick_velocity)
        return out, new_state


# --------------------------------------------------------------------------- geometry


@_register
@dataclass(frozen=True)
class SeriesCompliance(Effect):
    """Table or arm compliance in series with the contact, ``stiffness`` N/m along the probe axis.

    The encoders report the commanded TCP; the tip really sits ``u = F_n / stiffness`` back along
    the axis, where ``F_n`` is the push-back force there. Solved per sample by
    :func:`solve_series_compliance`. On a linear contact spring ``k`` the apparent stiffness is
    ``stiffness k / (stiffness + k)``.
    """

    name: ClassVar[str] = 'series_compliance'
    stage: ClassVar[str] = 'geometry'
    stiffness: float = 2.0e4

    def __post_init__(self):
        object.__setattr__(self, 'stiffness', _finite('series_compliance.stiffness',
                                                      self.stiffness, minimum=0.0, strict=True))


def solve_series_compliance(normal_force: Callable[[float], float], stiffness: float, *,
                            guess: float = 0.0, contact_stiffness: float = 0.0,
                            tol: float = 1e-9, max_iter: int = 30) -> Tuple[float, float, int]:
    """Solve ``u = max(F_n(u), 0) / stiffness`` for the retraction ``u >= 0`` of the tip.

    ``g(u) = u - F_n(u) / stiffness`` rises with slope ``1 + k_c / stiffness >= 1`` when the
    push-back ``F_n`` falls as the tip retracts, so a safeguarded secant (Newton with the last
    contact stiffness ``k_c`` as first slope) converges in a few evaluations.

    Args:
        normal_force: ``F_n(u)`` in N for a retraction of ``u`` metres.
        stiffness: series stiffness, N/m.
        guess: first retraction to try (the previous sample's solution).
        contact_stiffness: estimate of ``-dF_n/du``, N/m, for the first slope.
        tol: tolerance on ``|g(u)|``, metres.
        max_iter: most evaluations of ``normal_force``.

    Returns:
        ``(u, k_c, evaluations)``: retraction (m), updated contact stiffness estimate (N/m) and
        the number of force evaluations.

    Raises:
        NotConverged: ``|g(u)| > tol`` after ``max_iter`` evaluations.

    """
    lo, hi = 0.0, np.inf
    u = max(float(guess), 0.0)
    u_old = g_old = None
    slope = 1.0 + max(contact_stiffness, 0.0) / stiffness
    for evaluation in range(1, max_iter + 1):
        g = u - max(float(normal_force(u)), 0.0) / stiffness
        if abs(g) <= tol:
            k_c = (slope - 1.0) * stiffness
            return u, k_c, evaluation
        if g < 0:
            lo = max(lo, u)
        else:
            hi = min(hi, u)
        if u_old is not None and u != u_old:
            secant = (g - g_old) / (u - u_old)
            if np.isfinite(secant) and secant >= 1.0:
                slope = secant
        u_old, g_old = u, g
        u_new = u - g / slope
        if not lo <= u_new <= hi or u_new == u:
            u_new = 0.5 * (lo + hi) if np.isfinite(hi) else max(u_new, lo)
        u = u_new
    raise NotConverged(f'series compliance: |u - F/k| = {abs(g):.3g} m after {max_iter} '
                       f'evaluations (stiffness {stiffness} N/m); the contact force may not be '
                       f'monotone in depth')


@_register
@dataclass(frozen=True)
class PlasticSet(Effect):
    """Permanent surface set that grows with the number of pokes near a spot.

    After ``n`` completed pokes whose axis passes within ``radius`` of the tip (distance measured
    across the probe axis), the surface there sits ``delta(n) = max_set (1 - exp(-n / n0))``
    deeper along the probe axis. A poke counts when the push-back force rose above
    ``min_force``; it starts when the force exceeds ``contact_force`` and ends when it falls
    back below half of that (or at ``reset_poke``).

    Attributes:
        max_set: saturation depth of the set, metres, >= 0.
        n0: number of pokes for ``1 - 1/e`` of the saturation, > 0.
        radius: lateral radius of the affected spot, metres, > 0.
        min_force: least peak force of a poke that leaves a set, N.
        contact_force: force that marks contact, N, > 0.

    """

    name: ClassVar[str] = 'plastic_set'
    stage: ClassVar[str] = 'geometry'
    max_set: float = 0.0005
    n0: float = 3.0
    radius: float = 0.005
    min_force: float = 1.0
    contact_force: float = 0.05

    def __post_init__(self):
        object.__setattr__(self, 'max_set', _finite('plastic_set.max_set', self.max_set,
                                                    minimum=0.0))
        for attr in ('n0', 'radius', 'contact_force'):
            object.__setattr__(self, attr, _finite(f'plastic_set.{attr}', getattr(self, attr),
                                                   minimum=0.0, strict=True))
        object.__setattr__(self, 'min_force', _finite('plastic_set.min_force', self.min_force,
                                                      minimum=0.0))

    def set_depth(self, n) -> np.ndarray:
        """Return the set depth (metres) after ``n`` pokes at a spot."""
        return self.max_set * -np.expm1(-np.asarray(n, dtype=np.float64) / self.n0)

    def memory(self) -> 'PlasticMemory':
        """Return a fresh memory of poked spots for this effect."""
        return PlasticMemory(self)


@dataclass
class PlasticMemory:
    """Where pokes happened (mutable; owned by one force model)."""

    effect: PlasticSet
    spots: list = field(default_factory=list)
    _in_contact: bool = False
    _onset: Optional[np.ndarray] = None
    _peak: float = 0.0

    def count_near(self, tip: np.ndarray, axis: np.ndarray) -> int:
        """Count the registered pokes within ``radius`` of ``tip`` across ``axis``."""
        if not self.spots:
            return 0
        rel = np.asarray(self.spots) - tip
        across = rel - np.outer(rel @ axis, axis)
        return int(np.count_nonzero(np.einsum('ij,ij->i', across, across)
                                    <= self.effect.radius ** 2))

    def depth_offset(self, tip: np.ndarray, axis: np.ndarray) -> float:
        """Return the set depth (metres) of the surface under ``tip`` along ``axis``."""
        n = self.count_near(tip, axis)
        return float(self.effect.set_depth(n)) if n else 0.0

    def observe(self, normal_force: float, tip: np.ndarray) -> None:
        """Track contact episodes from the push-back force (N) at tip position ``tip``."""
        eff = self.effect
        if not self._in_contact:
            if normal_force > eff.contact_force:
                self._in_contact, self._onset, self._peak = True, np.array(tip), normal_force
            return
        self._peak = max(self._peak, normal_force)
        if normal_force < 0.5 * eff.contact_force:
            self.end_poke()

    def end_poke(self) -> None:
        """Close the current contact episode, registering it if its peak was high enough."""
        if self._in_contact and self._peak >= self.effect.min_force:
            self.spots.append(self._onset)
        self._in_contact, self._onset, self._peak = False, None, 0.0

    def reset(self) -> None:
        """Forget every poke (a fresh object)."""
        self.spots.clear()
        self._in_contact, self._onset, self._peak = False, None, 0.0


def build_effect(spec: Mapping) -> Effect:
    """Build an effect from a YAML mapping ``{effect: <name>, <param>: <value>, ...}``.

    Raises:
        InvalidInput: not a mapping, no or unknown ``effect`` name, or bad parameters.

    """
    if not isinstance(spec, Mapping) or 'effect' not in spec:
        raise InvalidInput(f'effect entry must be a mapping with an "effect" key, got {spec!r}')
    params = dict(spec)
    name = params.pop('effect')
    if name not in EFFECTS:
        raise InvalidInput(f'unknown effect {name!r}; known: {sorted(EFFECTS)}')
    return EFFECTS[name].from_params(params)
