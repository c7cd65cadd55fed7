"""The candidate-effect library: named, parameterised terms the force model can add.

Each :class:`EffectSpec` says what the effect is, its parameters (with units, bounds and the
scale the optimiser works in), the residual signature it explains against the structured base
model of :mod:`pointforce_ros.diagnose.model`, and how a record is corrected for it
(:mod:`pointforce_ros.effects.correct`). The physics of the terms lives here as small
vectorised functions shared by the forward model and the corrections:

* :func:`prony_terms`: the weights and relaxation times of a viscoelastic effect's Prony
  series (the filters that apply it to a force series are in
  :mod:`pointforce_ros.effects.relaxation`).
* :func:`hysteresis_branch`: the loading/unloading branch variable ``z`` in [-1, 1].
* :func:`plastic_depth`: permanent set after ``n`` earlier pokes at a spot.
* :func:`friction_direction`: regularised friction direction of a tip sliding over a surface.

Units are SI at every interface. A parameter marked ``log`` is optimised as ``log10`` of its
value; the value itself (seconds, metres, ...) is what reports and model files carry.
"""

from dataclasses import dataclass
from typing import Dict, Mapping, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    Attributes:
        name: key in the effect's parameter mapping.
        unit: SI unit of the value.
        lower, upper: bounds of the optimised coordinate (``log10(value)`` when ``log``).
        start: starting points of the optimised coordinate (the best one is kept).
        scale: typical size of the optimised coordinate (the optimiser works in ``x / scale``).
        log: optimise ``log10(value)`` (positive values spanning decades).
        description: one line for reports.
        zero_ok: a fitted value on the lower bound is an estimate, not a failed fit (a
            non-negative weight that the data put at zero); the bound check of diagnose
            ignores that bound, and the parameter penalty does not count a weight left there.
        limit_ok: the lower bound is a physical limit, not the edge of a search box (e.g. a
            hysteresis switch sharper than one analysis sample): a fit there is a sharp
            effect, not a misfit; the bound check of diagnose ignores that bound.

    """

    name: str
    unit: str
    lower: float
    upper: float
    start: Tuple[float, ...]
    scale: float
    log: bool = False
    description: str = ''
    zero_ok: bool = False
    limit_ok: bool = False

    def to_value(self, x: float) -> float:
        """Return the parameter value for the optimised coordinate ``x``."""
        return float(10.0 ** x) if self.log else float(x)

    def to_coordinate(self, value: float) -> float:
        """Return the optimised coordinate of a parameter value (clipped into the bounds).

        Raises:
            InvalidInput: a non-positive value for a ``log`` parameter, or a non-finite one.

        """
        value = float(value)
        if not np.isfinite(value) or (self.log and value <= 0):
            raise InvalidInput(f'{self.name}: value {value} is not allowed (must be finite'
                               f'{" and > 0" if self.log else ""})')
        x = np.log10(value) if self.log else value
        return float(np.clip(x, self.lower, self.upper))


@dataclass(frozen=True)
class EffectSpec:
    """A candidate effect: name, parameters, the signature it explains, how data are corrected.

    Attributes:
        name: key used in reports and in ``ContactModel.effects``.
        title: human name.
        params: its parameters.
        signature: the residual structure (against the base model) the effect explains.
        correction: how :func:`pointforce_ros.effects.correct.correct_records` removes it.
        needs: what the data must contain for the effect to be identifiable.
        settings: fixed (not fitted) settings stored with the parameters.
        derived: values computed from the parameters and stored with them (not fitted, not
            counted by the penalty; reports give them an uncertainty), e.g. the total
            relaxing fraction ``g`` of the Prony series.

    """

    name: str
    title: str
    params: Tuple[ParamSpec, ...]
    signature: str
    correction: str
    needs: str = ''
    settings: Tuple[Tuple[str, float], ...] = ()
    derived: Tuple[str, ...] = ()

    @property
    def n_params(self) -> int:
        """Number of fitted parameters (the penalty counts these)."""
        return len(self.params)

    def defaults(self) -> Dict[str, float]:
        """Values of the fixed settings."""
        return dict(self.settings)


STICK_VELOCITY = 1e-4
"""Regularisation speed of the friction term, m/s (below it friction grows linearly)."""

PLASTIC_RADIUS = 0.004
"""Default lateral radius within which earlier pokes count towards a plastic set, metres."""

EXPONENT = ParamSpec('exponent', '1', 0.7, 4.0, (1.5,), 0.1,
                     description='contact-law exponent p of the base law')
CURVATURE = ParamSpec('curvature', '1', -1.0, 1.0, (0.0,), 0.05,
                      description='contact-law curvature b: f = A x^p exp(b x), x = s / s_ref')
BASE_PARAMS = (EXPONENT, CURVATURE)
"""Global parameters of the base model's contact law (always fitted)."""

LIBRARY: Dict[str, EffectSpec] = {}
"""All candidate effects by name, in the order they are tried."""


def _add(spec: EffectSpec) -> None:
    LIBRARY[spec.name] = spec


_add(EffectSpec(
    'surface_offset', 'displacement offset (camera depth bias)',
    (ParamSpec('offset', 'm', -0.03, 0.03, (0.0,), 1e-3,
               description='true surface lies this far outside the observed one along n'),),
    signature='force starts before (offset > 0) or after d = 0 by the same amount on every '
              'poke: low-depth residual of one sign',
    correction='move the poke point by +offset along the normal',
    needs='onset tied to the observed surface (pokes start in free space)'))

_add(EffectSpec(
    'ft_bias', 'F/T bias (not tared)',
    (ParamSpec('fx', 'N', -50.0, 50.0, (0.0,), 0.1),
     ParamSpec('fy', 'N', -50.0, 50.0, (0.0,), 0.1),
     ParamSpec('fz', 'N', -50.0, 50.0, (0.0,), 0.1)),
    signature='constant force vector in free space and in contact (base orientation)',
    correction='subtract the bias from the force',
    needs='free-space samples (a tare right before each push removes it)'))

_add(EffectSpec(
    'ft_drift', 'F/T drift since the tare',
    (ParamSpec('rx', 'N/s', -2.0, 2.0, (0.0,), 0.01),
     ParamSpec('ry', 'N/s', -2.0, 2.0, (0.0,), 0.01),
     ParamSpec('rz', 'N/s', -2.0, 2.0, (0.0,), 0.01)),
    signature='force offset growing linearly with time since the tare (free space after the '
              'poke differs from before it)',
    correction='subtract rate * (t - t_tare) from the force'))

_add(EffectSpec(
    'time_offset', 'pose/force time offset',
    (ParamSpec('offset', 's', -0.2, 0.2, (0.0,), 0.01,
               description='force stream lags the pose stream by this (negative: leads)'),),
    signature='loading force low and unloading force high (lag) in proportion to speed times '
              'slope; transients at the turning point',
    correction='re-sample the force at t + offset'))

PRONY_TAUS = (0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
"""Fixed relaxation times of the library's Prony series, seconds (half-decade spacing, from
about one analysis sample to tens of seconds; a relaxation faster than one analysis sample is
part of the instantaneous response, one slower than 30 s a slow drift of the hold). Weights
the data leave at zero are not counted by the parameter penalty."""

_add(EffectSpec(
    'viscoelastic', 'rate dependence and relaxation (Prony series, fixed relaxation times)',
    tuple(ParamSpec(f'e{i + 1}', '1', 0.0, 10.0, (0.05,), 0.05, zero_ok=True,
                    description=f'modulus of the term with tau = {tau:g} s relative to the '
                                'long-term modulus (>= 0)')
          for i, tau in enumerate(PRONY_TAUS)),
    signature='force decays during a hold, unloading below loading, stiffer at higher speed',
    correction='deconvolve the force with the inverse Prony filter (elastic response)',
    needs='holds or different speeds',
    settings=tuple((f'tau{i + 1}', tau) for i, tau in enumerate(PRONY_TAUS))
    + (('memory', 0.0),),
    derived=('g',)))
"""``memory``: 0 when the relaxation memory stays with the material under the tip (it carries
only to the next poke at the same spot), 1 when one material state carries from every poke
to the next (as the simulated cell keeps it); diagnose picks the one that fits."""

_add(EffectSpec(
    'hysteresis', 'rate-independent loading/unloading hysteresis',
    (ParamSpec('eta', '1', 0.0, 0.95, (0.05,), 0.05, description='unloading force deficit'),
     ParamSpec('transition', 'm', -5.3, -2.0, (-3.3, -4.5), 0.3, log=True, limit_ok=True,
               description='depth over which the branch switches (the lower bound, 5 um, '
                           'is a sharp switch: below one analysis sample of depth)')),
    signature='unloading force a constant fraction below loading at any speed; no change '
              'during a hold',
    correction='divide the force by the branch factor 1 - eta (1 - z) / 2'))

_add(EffectSpec(
    'series_compliance', 'series compliance (table or arm)',
    (ParamSpec('compliance', 'm/N', 0.0, 2e-3, (1e-5,), 1e-4,
               description='tip retreats compliance * F along the normal'),),
    signature='curve softens with force independently of the local stiffness: stiff spots '
              'bend more than soft ones (Oliver-Pharr frame compliance)',
    correction='subtract compliance * F_n from the displacement',
    needs='on point pokes alone only where the arm is soft against the object (0.5 mm/N on '
          'a 2 mm/N spot): a stiff arm (20 N/mm) only reparametrises each poke\'s curve '
          '(d_meas = d + C f) and the learned curve absorbs it; probe trials measured through '
          'the arm name it (a wide probe deflects it by the total force of all its contacts)'))

_add(EffectSpec(
    'plastic_set', 'plastic set with repeated pokes',
    (ParamSpec('max_set', 'm', 0.0, 2e-2, (5e-4,), 2e-4, description='saturation set'),
     ParamSpec('n0', 'pokes', -1.0, 3.0, (0.3, 1.5), 0.3, log=True, limit_ok=True,
               description='pokes to reach 63 % of the saturation (small: all set by the '
                           'first poke; large: the set grows in equal steps per repeat)')),
    signature='onset moves deeper at a spot each time it is poked again',
    correction='move the poke point by -set(n) along the normal (n earlier pokes within '
               'radius)',
    needs='repeated pokes at the same spots',
    settings=(('radius', PLASTIC_RADIUS),)))

_add(EffectSpec(
    'friction', 'Coulomb friction on oblique contact',
    (ParamSpec('mu', '1', 0.0, 5.0, (0.1,), 0.05, description='friction coefficient'),),
    signature='lateral force flips with the direction of motion (loading vs unloading) when '
              'the push is not along the contact normal',
    correction='keep only the force along the per-poke contact normal',
    needs='oblique pokes (push axis off the contact normal) and the full force vector',
    settings=(('stick_velocity', STICK_VELOCITY),)))

PROBE_EFFECTS: Dict[str, EffectSpec] = {
    'spatial_coupling': EffectSpec(
        'spatial_coupling', 'spatial coupling beyond the shape function (shape constant c)',
        (ParamSpec('shape_constant', 'm', 5e-4, 0.05, (0.004,), 1e-3,
                   description='c of g(r) = c / (c + r) that fits the probe trials'),),
        signature='probe-trial force error growing with the contact patch',
        correction='none on the pokes: the learner serves the model with this shape constant',
        needs='probe trials with ground truth'),
}
"""Effects tested on probe trials only (``effects.probes``), stored in ``effects.json`` like the
library's."""

NOT_TESTABLE_ON_POKES = {
    'spatial_coupling': 'spatial coupling beyond the shape function acts between contact '
                        'points, and a point probe has one: it is tested on probe trials '
                        '(rigid probes pressed into the object, effects.probes: the shape '
                        'constant c refitted on them, held out by trial)',
}
"""Library members that point pokes cannot identify, with the reason (shown in reports)."""


def spec(name: str) -> EffectSpec:
    """Return the library entry ``name`` (a point-poke effect or one of :data:`PROBE_EFFECTS`).

    Raises:
        InvalidInput: an unknown effect (the message lists the known ones).

    """
    if name in PROBE_EFFECTS:
        return PROBE_EFFECTS[name]
    if name not in LIBRARY:
        raise InvalidInput(f'unknown effect {name!r}; known: '
                           f'{", ".join(list(LIBRARY) + list(PROBE_EFFECTS))}')
    return LIBRARY[name]


def prony_terms(visco: Mapping) -> Tuple[np.ndarray, np.ndarray]:
    """Return the Prony weights ``g`` (K,) and relaxation times ``tau`` (K,), seconds.

    ``visco`` is a viscoelastic effect's parameter mapping. Two forms are read: the library's
    (``e1..eK`` moduli relative to the long-term modulus, ``tau1..tauK`` seconds;
    ``g_i = e_i / (1 + sum e)``) and a single term ``{'g', 'tau'}`` (older files, hand-written
    effects).
    """
    if 'tau' in visco:
        return (np.atleast_1d(np.asarray(visco['g'], dtype=np.float64)),
                np.atleast_1d(np.asarray(visco['tau'], dtype=np.float64)))
    count = sum(1 for key in visco if key.startswith('tau'))
    e = np.array([float(visco[f'e{i + 1}']) for i in range(count)])
    tau = np.array([float(visco[f'tau{i + 1}']) for i in range(count)])
    return e / (1.0 + float(np.sum(e))), tau


def derived_values(name: str, params: Mapping) -> Dict[str, float]:
    """Return the derived values of effect ``name`` (viscoelastic: the total fraction ``g``)."""
    if name == 'viscoelastic' and 'tau' not in params:
        return {'g': float(np.sum(prony_terms(params)[0]))}
    return {}


def check_params(name: str, params: Mapping) -> Dict[str, float]:
    """Validate a parameter mapping of effect ``name``; return it as floats with settings.

    Derived values (``EffectSpec.derived``) are recomputed from the parameters. A viscoelastic
    effect may also be given as one term ``{'g': fraction in [0, 1), 'tau': seconds > 0}``, or
    as a series on other relaxation times when every ``e<i>`` comes with its ``tau<i>``.

    Raises:
        InvalidInput: unknown effect, missing/unknown parameters, non-finite values, a
            negative Prony modulus or a one-term fraction outside [0, 1).

    """
    entry = spec(name)
    if not isinstance(params, Mapping):
        raise InvalidInput(f'effect {name}: parameters must be a mapping, got '
                           f'{type(params).__name__}')
    wanted = {p.name for p in entry.params}
    settings = entry.defaults()
    derived = set(entry.derived)
    if name == 'viscoelastic' and 'tau' in params:
        wanted, settings, derived = {'g', 'tau'}, {}, set()
    elif name == 'viscoelastic' and isinstance(params, Mapping):
        moduli = {k for k in params if k.startswith('e') and k[1:].isdigit()}
        if moduli and moduli != wanted and all('tau' + k[1:] in params for k in moduli):
            # a series on other relaxation times (e.g. a model file written with the
            # earlier five-term grid 0.1-10 s): its own times, given with it
            wanted, settings = moduli | {'tau' + k[1:] for k in moduli}, {}
    unknown = set(params) - wanted - set(settings) - derived
    if unknown:
        raise InvalidInput(f'effect {name}: unknown parameter(s) {sorted(unknown)}; expected '
                           f'{sorted(wanted | set(settings))}')
    missing = wanted - set(params)
    if missing:
        raise InvalidInput(f'effect {name}: missing parameter(s) {sorted(missing)}')
    out = dict(settings)
    for key, value in params.items():
        if key in derived:
            continue
        try:
            out[key] = float(value)
        except (TypeError, ValueError):
            raise InvalidInput(f'effect {name}.{key}: must be a number, got {value!r}')
        if not np.isfinite(out[key]):
            raise InvalidInput(f'effect {name}.{key}: must be finite, got {value!r}')
    for p in entry.params:
        if p.name in out and p.log and out[p.name] <= 0:
            raise InvalidInput(f'effect {name}.{p.name}: must be > 0, got {out[p.name]}')
        if p.name in out and p.zero_ok and out[p.name] < 0:
            raise InvalidInput(f'effect {name}.{p.name}: must be >= 0, got {out[p.name]}')
    if name == 'viscoelastic':
        g, tau = prony_terms(out)
        if np.any(tau <= 0):
            raise InvalidInput(f'effect {name}: relaxation times must be > 0, got {tau}')
        if np.any(g < 0) or float(np.sum(g)) >= 1.0:
            raise InvalidInput(f'effect {name}: relaxing fraction must be in [0, 1), got '
                               f'{float(np.sum(g))}')
    out.update(derived_values(name, out))
    return out


# --------------------------------------------------------------------------- physics


def hysteresis_branch(s: np.ndarray, transition: float, z0=1.0, starts=None,
                      deadband: float = 2e-7) -> np.ndarray:
    """Branch variable ``z`` (T,) in [-1, 1] along the axial tip path ``s`` (T,), metres.

    ``dz = (sign(ds) - z) |ds| / transition`` integrated exactly per sample; steps smaller than
    ``deadband`` (encoder noise) leave ``z`` unchanged. ``z = 1`` on the loading branch, -1 on
    the unloading one.

    Args:
        s: (T,) tip positions along the push axis, metres (several pokes concatenated when
            ``starts`` is given).
        transition: branch-switching depth, metres, > 0.
        z0: ``z`` before the first sample, scalar or one per poke.
        starts: (P + 1,) sample offsets of the pokes (each restarts from its ``z0``); one poke
            when None.
        deadband: smallest step that counts as motion, metres.

    """
    s = np.asarray(s, dtype=np.float64)
    n = len(s)
    starts = np.array([0, n]) if starts is None else np.asarray(starts)
    z0 = np.broadcast_to(np.asarray(z0, dtype=np.float64), (len(starts) - 1,))
    ds = np.diff(s, prepend=s[:1])
    ds[starts[:-1][starts[:-1] < n]] = 0.0
    ds = np.where(np.abs(ds) > deadband, ds, 0.0)
    poke = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
    moving = np.flatnonzero(ds)
    z = z0[poke].copy()
    if len(moving) == 0:
        return z
    direction = np.sign(ds[moving])
    mpoke = poke[moving]
    cum = np.cumsum(np.abs(ds[moving]) / float(transition))
    new_run = np.ones(len(moving), dtype=bool)
    new_run[1:] = (direction[1:] != direction[:-1]) | (mpoke[1:] != mpoke[:-1])
    first = np.flatnonzero(new_run)
    last = np.concatenate([first[1:], [len(moving)]]) - 1
    base = np.where(first > 0, cum[first - 1], 0.0)
    decay_run = np.exp(-(cum[last] - base))
    z_start = np.empty(len(first))
    prev_poke, z_end = -1, 0.0
    for k, (i, d_run, decay) in enumerate(zip(first, direction[first], decay_run)):
        start = z0[mpoke[i]] if mpoke[i] != prev_poke else z_end
        z_start[k] = start
        z_end = d_run + (start - d_run) * decay
        prev_poke = mpoke[i]
    run = np.cumsum(new_run) - 1
    z_moving = direction + (z_start[run] - direction) * np.exp(-(cum - base[run]))
    # samples that do not move keep the last moving sample's value within their poke
    index = np.full(n, -1)
    index[moving] = np.arange(len(moving))
    index = np.maximum.accumulate(index)
    valid = index >= 0
    same_poke = np.zeros(n, dtype=bool)
    same_poke[valid] = mpoke[index[valid]] == poke[valid]
    z[same_poke] = z_moving[index[same_poke]]
    return z


def hysteresis_factor(z: np.ndarray, eta: float) -> np.ndarray:
    """Force factor ``1 - eta (1 - z) / 2`` of the branch variable ``z``."""
    return 1.0 - float(eta) * 0.5 * (1.0 - np.asarray(z))


def plastic_depth(count, max_set: float, n0: float) -> np.ndarray:
    """Permanent set (metres) after ``count`` earlier pokes: ``max_set (1 - exp(-n / n0))``."""
    return float(max_set) * -np.expm1(-np.asarray(count, dtype=np.float64) / float(n0))


def friction_direction(inward: np.ndarray, contact_normal: np.ndarray, motion: np.ndarray,
                       speed: np.ndarray, stick_velocity: float = STICK_VELOCITY) -> np.ndarray:
    """Return the regularised slip direction (T, 3) of a tip moving along a fixed axis.

    Friction on the probe is ``-mu F_n`` times it. The tip moves along ``inward`` ((T, 3) unit
    push direction) with signed ``motion`` in [-1, 1] (+1 pushing in, -1 retracting, fractions
    for a sample interval that holds both: the mean sign over the raw samples it averages) at
    ``speed`` m/s while moving. The slip is the part of the motion across ``contact_normal``
    ((T, 3) unit); its length is ``|slip| / max(|slip|, stick_velocity)`` (sticking below
    ``stick_velocity``).
    """
    along = np.einsum('ij,ij->i', inward, contact_normal)
    across = inward - along[:, None] * contact_normal
    sin = np.sqrt(np.einsum('ij,ij->i', across, across))
    unit = across / np.where(sin > 0, sin, 1.0)[:, None]
    factor = np.asarray(motion) * np.minimum(1.0, np.asarray(speed) * sin / float(stick_velocity))
    return factor[:, None] * unit


def count_earlier(points: np.ndarray, normals: np.ndarray, peak_force: np.ndarray,
                  radius: float = PLASTIC_RADIUS, min_force: float = 0.5,
                  start: int = 0) -> np.ndarray:
    """Earlier pokes within ``radius`` across each poke's axis (pokes in time order).

    Args:
        points: (P, 3) poke points, metres, in time order.
        normals: (P, 3) unit normals.
        peak_force: (P,) peak normal force, N; pokes below ``min_force`` leave no set.
        radius: lateral radius, metres.
        min_force: least peak force of a poke that counts, N.
        start: count for the pokes from this index on only (a learner counting its newest).

    Returns:
        (P - start,) int counts.

    """
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    strong = np.asarray(peak_force) >= float(min_force)
    counts = np.zeros(len(points), dtype=np.int64)
    start = min(max(int(start), 0), len(points))
    # rows in blocks: (rows, earlier pokes, 3) of at most ~1e6 elements (a full (P, P, 3)
    # was 216 MB at 3000 pokes)
    block = max(1, 1_000_000 // max(3 * len(points), 1))
    for lo in range(start, len(points), block):
        hi = min(lo + block, len(points))
        rel = points[None, :hi, :] - points[lo:hi, None, :]          # (i, j, 3) p_j - p_i
        along = np.einsum('ijk,ik->ij', rel, normals[lo:hi])
        across = rel - along[:, :, None] * normals[lo:hi, None, :]
        near = np.einsum('ijk,ijk->ij', across, across) <= float(radius) ** 2
        earlier = np.arange(hi)[None, :] < np.arange(lo, hi)[:, None]
        counts[lo:hi] = np.count_nonzero(near & earlier & strong[None, :hi], axis=1)
    return counts[start:]
