"""The poke batch of the effect analysis: pokes as one concatenated, time-ordered sample array.

Loading (store, bag, CSV table) lives in :mod:`pointforce_ros.pokes.table`.
:class:`PokeBatch` concatenates the pokes' samples (time-ordered pokes, windowed near contact,
block-averaged to at most ``max_rate``) so that the model evaluates every poke in one pass of
numpy operations.
"""


from dataclasses import dataclass
from functools import cached_property
from typing import List, Optional, Sequence, Tuple

import numpy as np

from pointforce_ros.effects.library import count_earlier, PLASTIC_RADIUS
from pointforce_ros.effects.correct import tare_reference
from pointforce_ros.errors import DataError
from pointforce_ros.types import PokeRecord

# --------------------------------------------------------------------------- batch


@dataclass(frozen=True)
class PokeBatch:
    """Point pokes as one concatenated sample array (pokes in time order).

    Attributes:
        ids: (P,) poke ids.
        starts: (P + 1,) sample offsets of each poke.
        seg: (N,) poke index of each sample.
        t: (N,) controller time, seconds.
        tv: (N,) virtual time: ``t`` minus the poke's first time plus ``1e4 * k`` (monotone over
            the batch, so one interpolation serves every poke without crossing between them).
        d: (N,) nominal displacement along ``-normal`` past the observed point, metres.
        force: (N, 3) measured force on the probe, ``base``, N.
        motion: (N,) mean sign of the inward motion over the raw samples of each sample
            (+1 pushing, -1 retracting, 0 still; fractions where a block holds a reversal).
        moving_speed: (N,) mean inward speed of the raw samples that moved, m/s.
        t_ref: (P,) tare time of each poke (drift reference), seconds.
        dt: (P,) sample spacing, seconds.
        point: (P, 3) observed surface points, metres.
        normal: (P, 3) unit outward normals.
        count: (P,) earlier pokes within the plastic radius.
        speed: (P,) push speed, m/s.
        peak: (P,) peak measured normal force, N.
        order: (P,) position of each poke in the time order of the whole data set.

    """

    ids: Tuple[str, ...]
    starts: np.ndarray
    seg: np.ndarray
    t: np.ndarray
    tv: np.ndarray
    d: np.ndarray
    force: np.ndarray
    motion: np.ndarray
    moving_speed: np.ndarray
    t_ref: np.ndarray
    dt: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    count: np.ndarray
    speed: np.ndarray
    peak: np.ndarray
    order: np.ndarray

    def __len__(self) -> int:
        """Return the number of pokes ``P``."""
        return len(self.ids)

    @property
    def n_samples(self) -> int:
        """Total number of samples ``N``."""
        return len(self.t)

    def sums(self, values: np.ndarray) -> np.ndarray:
        """Sum per-sample ``values`` (N, ...) over each poke: (P, ...)."""
        return np.add.reduceat(values, self.starts[:-1], axis=0)

    @cached_property
    def normal_s(self) -> np.ndarray:
        """(N, 3) normal of each sample's poke (cached)."""
        return self.normal[self.seg]

    def per_sample(self, values: np.ndarray) -> np.ndarray:
        """Expand per-poke ``values`` (P, ...) to samples (N, ...)."""
        return np.asarray(values)[self.seg]

    def subset(self, indices) -> 'PokeBatch':
        """Return the batch of pokes ``indices`` (repeats allowed: bootstrap)."""
        indices = np.asarray(indices, dtype=np.int64)
        parts = [np.arange(self.starts[i], self.starts[i + 1]) for i in indices]
        take = np.concatenate(parts)
        lengths = np.array([len(p) for p in parts])
        starts = np.concatenate([[0], np.cumsum(lengths)])
        seg = np.repeat(np.arange(len(indices)), lengths)
        t = self.t[take]
        first = np.repeat(self.t[self.starts[indices]], lengths)
        return PokeBatch(
            ids=tuple(self.ids[i] for i in indices), starts=starts, seg=seg, t=t,
            tv=t - first + 1e4 * seg, d=self.d[take], force=self.force[take],
            motion=self.motion[take], moving_speed=self.moving_speed[take],
            t_ref=self.t_ref[indices], dt=self.dt[indices], point=self.point[indices],
            normal=self.normal[indices], count=self.count[indices],
            speed=self.speed[indices], peak=self.peak[indices], order=self.order[indices])


def _block_average(x: np.ndarray, factor: int) -> np.ndarray:
    if factor <= 1:
        return x
    n = (len(x) // factor) * factor
    shaped = x[:n].reshape((n // factor, factor) + x.shape[1:])
    return shaped.mean(axis=1)


def _threshold(rec: PokeRecord, d: np.ndarray, window: float) -> float:
    """Lowest displacement kept: ``-window``, or ``window`` before an earlier contact."""
    f_n = rec.normal_force()
    if len(f_n) < 2:
        return -window
    rise = f_n - np.median(f_n[:max(1, min(10, len(f_n)))])
    peak = float(rise.max())
    if peak <= 0:
        return -window
    touch = int(np.argmax(rise > 0.1 * peak))
    return min(-window, float(d[touch]) - window)


def time_order(records: Sequence[PokeRecord]) -> Tuple[List[PokeRecord], bool]:
    """Order pokes in time; return them and whether their times are one increasing clock.

    Pokes are sorted by their first time (ties keep the given order) when every poke starts
    after the one before it ended. When times overlap or restart (an imported table whose
    ``t`` starts at 0 on every poke, as the import format allows) the given (file) order is
    the poke order and each poke's time is its own clock: nothing (relaxation memory) may
    run from one poke into the next.
    """
    records = list(records)
    ranked = sorted(range(len(records)),
                    key=lambda i: (float(records[i].t[0]) if len(records[i]) else 0.0, i))
    ordered = [records[i] for i in ranked]
    for a, b in zip(ordered[:-1], ordered[1:]):
        if len(a) and len(b) and float(b.t[0]) < float(a.t[-1]):
            return records, False
    return ordered, True


def make_batch(records: Sequence[PokeRecord], *, window: float = 0.002,
               max_rate: float = 100.0, radius: float = PLASTIC_RADIUS,
               min_samples: int = 5) -> Tuple[PokeBatch, List[str]]:
    """Prepare point pokes for the analysis; return the batch and notes on skipped records.

    Pokes are ordered by their first ROS time (:func:`time_order`: the given order when the
    times overlap or restart per poke; a note says so). Each keeps the contiguous samples from
    the first to the last one with displacement ``d >= -window``, or ``window`` before the
    depth where the force first exceeds 10 % of its peak when contact starts earlier (a large
    camera bias); the approach from far away carries no information. Samples are
    block-averaged to at most ``max_rate`` Hz (time and force averaged alike, so no lag is
    introduced). Probe trials
    (``probe != 'point'``) and pokes with fewer than ``min_samples`` samples are skipped with
    a note. Quasi-static step data (5-20 samples per poke) are kept as they are.

    Raises:
        DataError: fewer than 4 usable point pokes.

    """
    notes = []
    usable = []
    ordered, one_clock = time_order(records)
    if not one_clock:
        notes.append('poke times overlap or restart (e.g. t starts at 0 on every poke): pokes '
                     'are taken in table order and each poke\'s history is independent (no '
                     'relaxation memory runs from one poke into the next)')
    for rec in ordered:
        if rec.probe != 'point':
            notes.append(f'{rec.poke_id}: probe trial ({rec.probe}) not scored by point-poke '
                         'effects')
            continue
        d = rec.displacement()
        near = np.flatnonzero(d >= _threshold(rec, d, window))
        if len(near) < min_samples:
            notes.append(f'{rec.poke_id}: only {len(near)} samples near the surface, skipped')
            continue
        usable.append((rec, slice(int(near[0]), int(near[-1]) + 1)))
    if len(usable) < 4:
        raise DataError(f'need at least 4 usable point pokes for a diagnosis, got {len(usable)}'
                        + (f' ({"; ".join(notes[:3])})' if notes else ''))
    parts = []
    for rec, sl in usable:
        t = rec.t_controller[sl]
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0 / max_rate
        factor = max(1, int(np.floor((1.0 / max_rate) / dt + 1e-9)))
        d = rec.displacement()[sl]
        v = np.zeros_like(d)
        v[1:] = np.diff(d) / np.diff(t)
        sign = np.sign(np.where(np.abs(v) > 1e-5 * max(rec.speed, 1e-9), v, 0.0))
        moving = _block_average(np.abs(sign), factor)
        speed = np.where(moving > 0, _block_average(np.abs(v), factor)
                         / np.maximum(moving, 1e-12), 0.0)
        parts.append((rec, _block_average(t, factor), _block_average(d, factor),
                      _block_average(rec.wrench[sl, :3], factor), dt * factor,
                      _block_average(sign, factor), speed))
    lengths = np.array([len(p[1]) for p in parts])
    starts = np.concatenate([[0], np.cumsum(lengths)])
    seg = np.repeat(np.arange(len(parts)), lengths)
    t = np.concatenate([p[1] for p in parts])
    first = np.repeat([p[1][0] for p in parts], lengths)
    point = np.array([p[0].point for p in parts])
    normal = np.array([p[0].normal for p in parts])
    force = np.concatenate([p[3] for p in parts])
    peak = np.maximum.reduceat(np.einsum('ij,ij->i', force, normal[seg]), starts[:-1])
    batch = PokeBatch(
        ids=tuple(p[0].poke_id for p in parts), starts=starts, seg=seg, t=t,
        tv=t - first + 1e4 * seg, d=np.concatenate([p[2] for p in parts]), force=force,
        motion=np.concatenate([p[5] for p in parts]),
        moving_speed=np.concatenate([p[6] for p in parts]),
        t_ref=np.array([tare_reference(p[0]) for p in parts]),
        dt=np.array([p[4] for p in parts]), point=point, normal=normal,
        count=count_earlier(point, normal, peak, radius=radius),
        speed=np.array([p[0].speed for p in parts]), peak=peak,
        order=np.arange(len(parts)))
    return batch, notes


def velocity(batch: PokeBatch, d: Optional[np.ndarray] = None, backward: bool = False
             ) -> np.ndarray:
    """(N,) inward speed ``dd/dt`` of each sample within its poke, m/s.

    Central differences by default; ``backward`` uses the motion over the last sample interval
    (zero on a poke's first sample), which is what a friction force at that sample sees.
    """
    d = batch.d if d is None else d
    if not backward:
        return np.gradient(d, batch.tv)
    v = np.zeros_like(d)
    v[1:] = np.diff(d) / np.diff(batch.tv)
    v[batch.starts[:-1]] = 0.0
    return v
