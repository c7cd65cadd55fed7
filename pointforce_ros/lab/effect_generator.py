"""An independent generator of poke tables with one known effect (or none) for diagnose.

Not the simulated cell (:mod:`pointforce_ros.sim`) and not the effect code diagnose tests
(:mod:`pointforce_ros.effects`): every law here is written from its own physics, with its own
parametrisation, and the tables reach diagnose through the documented CSV import
(``poke_id,t,px,py,pz,nx,ny,nz,depth,force,fx,fy,fz``).

Object: a heterogeneous elastic layer (thickness ``H``, Young's modulus varying smoothly by
about +-35 % over the surface, Poisson ratio 0.5) bonded to a rigid table, probed by a
spherical tip of radius ``R``; the force is Hertz's with the bonded thin-layer correction of
Dimitriadis et al. (2002)::

    F(delta) = 16/9 E sqrt(R) delta^1.5 (1 + 1.133 chi + 1.283 chi^2 + 0.769 chi^3
               + 0.0975 chi^4),   chi = sqrt(R delta) / H

Poke: from 2 mm outside the surface the tip moves in along ``-n`` at 2-5 mm/s until the force
reaches 4 N, holds 1 s, and moves out at the same speed; the laws are integrated on a 1 ms
grid and the F/T stream is read at 100 Hz with white noise (``NOISE`` N per component).

Effects (``EFFECTS``; the parameter each maps to in diagnose's library is in ``truth``):

* ``camera_bias``: the observed surface lies ``bias`` inside the true one.
* ``ft_bias``: a constant force vector, no tare.
* ``ft_drift``: a force vector growing linearly since the tare at each poke's start.
* ``time_offset``: the force stream lags the pose stream by ``lag`` (interpolated).
* ``viscoelastic``: generalised Maxwell solid, internal forces integrated by backward Euler;
  ``relaxed`` the fraction of the instantaneous force lost in an infinite hold, one or two
  relaxation times. Each spot is fresh material.
* ``hysteresis``: the unloading force is ``(1 - loss w)`` of the loading force, ``w`` the
  switch after a reversal: a step (``sharp``) or ``tanh(retraction / width)`` (``smooth``).
* ``series_compliance``: an arm of compliance ``C``: ``delta + C F(delta) = d``.
* ``plastic_set``: each poke at a spot sets it deeper by ``step * ratio^k`` (k-th repeat):
  ``ratio = 1`` equal steps, ``< 1`` saturating.
* ``friction``: Coulomb friction, the contact normal tilted 8-20 deg off the push axis, slip
  regularised by ``tanh(v_slip / 0.05 mm/s)``.

Out of the library (diagnose must not name a cause): ``saturation`` (each force component
clipped at a level below the peak), ``crosstalk`` (quadratic F/T crosstalk ``fx += a fz^2``),
``periodic`` (a 0.8 Hz vibration along z).
"""

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
from scipy.signal import lfilter

from pointforce_ros.pokes.table import read_poke_table

H = 0.015
"""Layer thickness, metres."""
R = 0.004
"""Tip radius, metres."""
E0 = 90e3
"""Mean Young's modulus, Pa."""
NOISE = 0.01
"""F/T white noise per component and 100 Hz sample, N."""
RATE = 100.0
"""Output sample rate, Hz."""
STEP = 1e-3
"""Integration step, seconds."""
FORCE_LIMIT = 4.0
"""Force at which the push stops, N."""
STANDOFF = 0.002
"""Start and end of a poke outside the true surface, metres."""
HOLD = 1.0
"""Hold at the turning point, seconds."""
GAP = 2.0
"""Pause between pokes, seconds."""


def modulus(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Return the layer's Young's modulus, Pa, at the surface point (x, y), metres."""
    field_ = (0.6 * np.sin(2 * np.pi * x / 0.045 + 0.3) * np.cos(2 * np.pi * y / 0.06)
              + 0.4 * np.exp(-((x - 0.015) ** 2 + (y + 0.01) ** 2) / (2 * 0.008 ** 2)))
    return E0 * np.exp(0.35 * field_)


def layer_force(delta: np.ndarray, e: float) -> np.ndarray:
    """Hertz force of the tip on the bonded layer (N) at indentation ``delta`` (m)."""
    dpos = np.maximum(np.asarray(delta, dtype=np.float64), 0.0)
    chi = np.sqrt(R * dpos) / H
    corr = 1 + 1.133 * chi + 1.283 * chi ** 2 + 0.769 * chi ** 3 + 0.0975 * chi ** 4
    return 16.0 / 9.0 * e * np.sqrt(R) * dpos ** 1.5 * corr


@dataclass(frozen=True)
class Case:
    """One table: an effect (or none), its strength and shape, a seed.

    Attributes:
        effect: a key of ``EFFECTS`` or ``'clean'``.
        level: strength multiplier of the effect's base size (1, 3, 10 sweep a decade).
        shape: effect shape (``sharp``/``smooth``, ``one``/``two`` time constants, ...).
        seed: seed of locations, speeds and noise.
        pokes: number of pokes.
        restart: every poke's ``t`` starts at 0 (the import format allows it).

    """

    effect: str
    level: float = 1.0
    shape: str = ''
    seed: int = 0
    pokes: int = 24
    restart: bool = False

    @property
    def label(self) -> str:
        """Return a short name of the case."""
        shape = f'/{self.shape}' if self.shape else ''
        return f'{self.effect}{shape} x{self.level:g} s{self.seed}'


@dataclass
class Poke:
    """One generated poke (internal)."""

    point: np.ndarray
    normal: np.ndarray
    t: np.ndarray
    depth: np.ndarray
    force: np.ndarray
    reference: np.ndarray


# ------------------------------------------------------------------ effect sizes and truth

BASE = {
    'camera_bias': 0.0003,            # m
    'ft_bias': 0.02,                  # N, norm of the vector
    'ft_drift': 0.008,                # N/s, norm of the rate
    'time_offset': 0.008,             # s
    'viscoelastic': 0.02,             # relaxed fraction
    'hysteresis': 0.04,               # unloading loss
    'series_compliance': 1e-4,        # m/N
    'plastic_set': 0.00006,           # m, first step
    'friction': 0.03,                 # mu
    'saturation': 1.0,                # (fixed) clip level 0.85 x force limit
    'crosstalk': 0.004,               # 1/N
    'periodic': 0.02,                 # N amplitude
}
"""Base size of each effect (level 1); the sweep multiplies it by 1, 3 and 10."""

SHAPES = {
    'viscoelastic': ('one', 'two'),
    'hysteresis': ('sharp', 'smooth'),
    'plastic_set': ('equal', 'saturating'),
}
"""Shapes swept per effect (one shape when absent)."""

IN_LIBRARY = ('camera_bias', 'ft_bias', 'ft_drift', 'time_offset', 'viscoelastic',
              'hysteresis', 'series_compliance', 'plastic_set', 'friction')
OUT_OF_LIBRARY = ('saturation', 'crosstalk', 'periodic')
LIBRARY_NAME = {'camera_bias': 'surface_offset'}
"""Generator effect -> the library effect that names it (same name when absent)."""

BIAS_DIR = np.array([0.6, -0.4, 0.7]) / np.linalg.norm([0.6, -0.4, 0.7])
DRIFT_DIR = np.array([0.5, -0.4, 0.77]) / np.linalg.norm([0.5, -0.4, 0.77])
TWO_TAUS = ((0.6, 0.25), (0.4, 3.0))
"""Two-time-constant relaxation: (share of the relaxed fraction, tau s)."""
ONE_TAU = 1.0
HYST_WIDTH = 0.0004
"""Smooth hysteresis switch width (tanh), metres."""
PLASTIC_RATIO = 0.5
"""Ratio of successive plastic steps of the ``saturating`` shape."""
REPEATS = 4
"""Pokes per spot of the plastic-set tables."""


def library_name(effect: str) -> Optional[str]:
    """Return the library effect that is the right verdict for ``effect`` (None: none is)."""
    if effect in IN_LIBRARY:
        return LIBRARY_NAME.get(effect, effect)
    return None


def size(case: Case) -> float:
    """Return the effect's size for ``case`` (base times level)."""
    return BASE.get(case.effect, 0.0) * float(case.level)


def truth(case: Case) -> Dict[str, float]:
    """Return the parameters diagnose should find, in the library's names and units.

    ``plastic_set`` is compared by the set after three earlier pokes (``set3``, metres),
    ``viscoelastic`` by the total relaxing fraction ``g``; others by their parameters.
    """
    s = size(case)
    if case.effect == 'camera_bias':
        return {'offset': s}
    if case.effect == 'ft_bias':
        return dict(zip(('fx', 'fy', 'fz'), (s * BIAS_DIR).tolist()))
    if case.effect == 'ft_drift':
        return dict(zip(('rx', 'ry', 'rz'), (s * DRIFT_DIR).tolist()))
    if case.effect == 'time_offset':
        return {'offset': s}
    if case.effect == 'viscoelastic':
        return {'g': s}
    if case.effect == 'hysteresis':
        return {'eta': s}
    if case.effect == 'series_compliance':
        return {'compliance': s}
    if case.effect == 'plastic_set':
        ratio = 1.0 if case.shape == 'equal' else PLASTIC_RATIO
        return {'set3': s * (1 + ratio + ratio ** 2)}
    if case.effect == 'friction':
        return {'mu': s}
    return {}


# ------------------------------------------------------------------ one poke


def _trajectory(speed: float, e: float, compliance: float, offset_in: float):
    """Commanded tip depth on the 1 ms grid (past the true surface) until the force limit."""
    # loading: move in until the (true) force reaches the limit
    d_max = STANDOFF + 0.02
    n_in = int(np.ceil(d_max / speed / STEP)) + 1
    d_in = -STANDOFF + speed * STEP * np.arange(n_in) + offset_in
    delta = _indentation(d_in, e, compliance)
    f = layer_force(delta, e)
    stop = int(np.argmax(f >= FORCE_LIMIT)) if np.any(f >= FORCE_LIMIT) else n_in - 1
    d_in = d_in[:stop + 1]
    n_hold = int(round(HOLD / STEP))
    d_hold = np.full(n_hold, d_in[-1])
    n_out = int(np.ceil((d_in[-1] - d_in[0]) / speed / STEP))
    d_out = d_in[-1] - speed * STEP * np.arange(1, n_out + 1)
    return np.concatenate([d_in, d_hold, d_out])


def _indentation(d: np.ndarray, e: float, compliance: float) -> np.ndarray:
    """Return the true indentation at tip depth ``d`` with an arm ``compliance`` (bisection)."""
    d = np.asarray(d, dtype=np.float64)
    if compliance <= 0:
        return d
    lo = np.minimum(d, 0.0)
    hi = d.copy()
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        g = mid + compliance * layer_force(mid, e) - d
        hi = np.where(g > 0, mid, hi)
        lo = np.where(g > 0, lo, mid)
    return 0.5 * (lo + hi)


def _maxwell(f_e: np.ndarray, relaxed: float, taus) -> np.ndarray:
    """Generalised Maxwell response to the instantaneous force ``f_e`` (backward Euler).

    Branch ``i`` carries ``q_i`` with ``dq_i/dt = w_i df_e/dt - q_i / tau_i``; the force is
    ``(1 - relaxed) f_e + sum q_i`` (``sum w_i = relaxed``), clamped at 0 (no adhesion).
    """
    out = (1.0 - relaxed) * f_e.copy()
    df = np.diff(f_e, prepend=0.0)
    for share, tau in taus:
        w = relaxed * share
        k = 1.0 / (1.0 + STEP / tau)
        out += lfilter([k * w], [1.0, -k], df)        # q_n = k (q_{n-1} + w df_n)
    return np.maximum(out, 0.0)


def _poke(case: Case, rng, point, normal, tilt, e, speed, repeat, t0):
    """Simulate one poke; return a :class:`Poke` (force vectors, ``base``)."""
    eff, s = case.effect, size(case)
    compliance = s if eff == 'series_compliance' else 0.0
    plastic = 0.0
    if eff == 'plastic_set':
        ratio = 1.0 if case.shape == 'equal' else PLASTIC_RATIO
        plastic = s * sum(ratio ** k for k in range(repeat))
    bias = s if eff == 'camera_bias' else 0.0
    d_true = _trajectory(speed, e, compliance, 0.0)         # tip depth past the true surface
    delta = _indentation(d_true, e, compliance) - plastic
    f_e = layer_force(delta, e)
    if eff == 'hysteresis':
        turn = int(np.argmax(d_true))
        back = np.maximum(d_true[turn] - d_true, 0.0)
        back[:turn] = 0.0
        if case.shape == 'sharp':
            w = (np.arange(len(d_true)) > turn) & (back > 0)
        else:
            w = np.tanh(back / HYST_WIDTH)
        f_e = f_e * (1.0 - s * w)
    if eff == 'viscoelastic':
        taus = TWO_TAUS if case.shape == 'two' else ((1.0, ONE_TAU),)
        f_e = _maxwell(f_e, s, taus)
    t = t0 + STEP * np.arange(len(d_true))
    m = tilt                                               # contact normal (unit)
    forces = f_e[:, None] * m[None, :]
    if eff == 'friction':
        push = -normal
        across = push - (push @ m) * m
        v = np.gradient(d_true, STEP)
        slip = np.tanh(v * np.linalg.norm(across) / 5e-5)
        unit = across / max(np.linalg.norm(across), 1e-12)
        forces = forces - s * f_e[:, None] * slip[:, None] * unit[None, :]
    # the F/T stream at 100 Hz
    every = int(round(1.0 / RATE / STEP))
    take = np.arange(0, len(t), every)
    t_out = t[take]
    if eff == 'time_offset':
        f_out = np.stack([np.interp(t_out - s, t, forces[:, k]) for k in range(3)], axis=1)
    else:
        f_out = forces[take]
    if eff == 'ft_bias':
        f_out = f_out + s * BIAS_DIR
    if eff == 'ft_drift':
        f_out = f_out + np.outer(t_out - t_out[0], s * DRIFT_DIR)
    if eff == 'crosstalk':
        f_out = f_out + np.outer(f_out[:, 2] ** 2, [s, -0.7 * s, 0.0])
    if eff == 'periodic':
        f_out = f_out + np.outer(s * np.sin(2 * np.pi * 0.8 * t_out), [0.0, 0.0, 1.0])
    if rng is not None:
        f_out = f_out + rng.normal(0.0, NOISE, f_out.shape)
    if eff == 'saturation' and s > 0:
        level = 0.85 * FORCE_LIMIT
        f_out = np.clip(f_out, -level, level)
    depth = d_true[take] - bias                              # past the observed surface point
    observed = point - bias * normal
    reference = layer_force(depth, e)[:, None] * m[None, :]   # no effect, same reported depth
    return Poke(point=observed, normal=normal, t=t_out, depth=depth, force=f_out,
                reference=reference)


def _locations(case: Case, rng) -> List[Tuple[np.ndarray, int]]:
    """(point, repeat index) of every poke in time order."""
    if case.effect == 'plastic_set':
        spots = max(case.pokes // REPEATS, 2)
        xy = _spread(rng, spots)
        return [(xy[i], k) for k in range(REPEATS) for i in range(spots)]
    return [(p, 0) for p in _spread(rng, case.pokes)]


def _spread(rng, n: int) -> np.ndarray:
    """``n`` points over the 60 x 40 mm patch at least 6 mm apart (seeded rejection)."""
    out = []
    while len(out) < n:
        p = rng.uniform([-0.03, -0.02], [0.03, 0.02])
        if all(np.hypot(*(p - q)) >= 0.006 for q in out) or len(out) > 200:
            out.append(p)
    return np.asarray(out)


def generate(case: Case, noise: bool = True) -> List[Poke]:
    """Simulate every poke of ``case`` (deterministic for its seed; ``noise`` False: none)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(case.seed), 20]))
    noise_rng = np.random.default_rng(np.random.SeedSequence([int(case.seed), 21]))
    normal = np.array([0.0, 0.0, 1.0])
    pokes = []
    t0 = 0.0
    for xy, repeat in _locations(case, rng):
        point = np.array([xy[0], xy[1], 0.03])
        speed = float(rng.uniform(0.002, 0.005))
        m = normal
        if case.effect == 'friction':
            angle = np.radians(rng.uniform(8.0, 20.0))
            azimuth = rng.uniform(0, 2 * np.pi)
            m = np.array([np.sin(angle) * np.cos(azimuth), np.sin(angle) * np.sin(azimuth),
                          np.cos(angle)])
        e = float(modulus(xy[0], xy[1]))
        poke = _poke(case, noise_rng if noise else None, point, normal, m, e, speed, repeat,
                     0.0 if case.restart else t0)
        pokes.append(poke)
        t0 = float(poke.t[-1]) + GAP if not case.restart else t0
    return pokes


def table_text(pokes: List[Poke]) -> str:
    """Return the CSV import table of ``pokes`` (DESIGN.md section 4)."""
    buf = io.StringIO()
    buf.write('poke_id,t,px,py,pz,nx,ny,nz,depth,force,fx,fy,fz\n')
    for k, p in enumerate(pokes):
        f_n = p.force @ p.normal
        for i in range(len(p.t)):
            buf.write(f'p{k:03d},{p.t[i]:.6f},{p.point[0]:.9g},{p.point[1]:.9g},'
                      f'{p.point[2]:.9g},{p.normal[0]:.9g},{p.normal[1]:.9g},'
                      f'{p.normal[2]:.9g},{p.depth[i]:.9g},{f_n[i]:.6g},{p.force[i, 0]:.6g},'
                      f'{p.force[i, 1]:.6g},{p.force[i, 2]:.6g}\n')
    return buf.getvalue()


def write_table(case: Case, path) -> Path:
    """Write ``case`` as a CSV import table at ``path``; return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(table_text(generate(case)))
    return path


def records(case: Case, folder) -> list:
    """Return ``case``'s pokes as records read back through the CSV import (``folder``)."""
    name = case.label.replace(' ', '_').replace('/', '-')
    return read_poke_table(write_table(case, Path(folder) / f'{name}.csv'))


def signal_to_noise(case: Case) -> float:
    """RMS force change (N, per component) the effect makes, in units of ``NOISE``.

    Noise-free pokes of the case against the force the bare layer gives at the same reported
    depth: the residual a model without the effect would be left with. The ratio says how far
    above the sensor's noise floor the case lies.
    """
    if case.effect == 'clean':
        return 0.0
    total, count = 0.0, 0
    for poke in generate(case, noise=False):
        diff = poke.force - poke.reference
        total += float(np.sum(diff ** 2))
        count += diff.size
    return float(np.sqrt(total / max(count, 1))) / NOISE


def sweep(seeds=(0, 1), levels=(1.0, 3.0, 10.0), pokes: int = 24) -> List[Case]:
    """Every case of the confusion sweep: clean, each effect x level x shape, out-of-library.

    Seed 1 writes tables whose per-poke time restarts at 0.
    """
    cases = []
    for seed in seeds:
        cases.append(Case('clean', seed=seed, pokes=pokes, restart=bool(seed % 2)))
        for eff in IN_LIBRARY:
            for shape in SHAPES.get(eff, ('',)):
                for level in levels:
                    cases.append(Case(eff, level, shape, seed, pokes, bool(seed % 2)))
        for eff in OUT_OF_LIBRARY:
            cases.append(Case(eff, 3.0 if eff != 'saturation' else 1.0, '', seed, pokes,
                              bool(seed % 2)))
    return cases
