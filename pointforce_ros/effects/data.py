"""Measured poke data for the effect analysis: loading (store, bag, table) and the poke batch.

Sources :func:`load_pokes` accepts:

* a :class:`~pointforce_ros.pokes.store.PokeStore` directory (``index.json`` + ``poke-*`` bags),
  or a ``pointforce cell generate`` folder holding one as ``pokes/``,
* a single poke bag directory (rosbag2 MCAP with ``metadata.yaml``),
* an imported table (``.csv``, DESIGN.md section 4), one row per sample::

      poke_id,t,px,py,pz,nx,ny,nz,depth,force[,fx,fy,fz]

  ``t`` seconds (controller clock, strictly increasing within a poke), ``p`` the poked surface
  point (m, ``base``) and ``n`` its unit outward normal (repeated on every row of the poke),
  ``depth`` the probe displacement along ``-n`` past ``p`` (m), ``force`` the normal force on the
  probe (N, push-back > 0) and optionally the full force vector (N, ``base``). Parquet is not
  supported (no pyarrow in the pinned environment),
* a sequence of :class:`~pointforce_ros.types.PokeRecord`.

:class:`PokeBatch` concatenates the pokes' samples (time-ordered pokes, windowed near contact,
block-averaged to at most ``max_rate``) so that the model evaluates every poke in one pass of
numpy operations.
"""

import csv
import io
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np

from pointforce_ros.effects.library import count_earlier, PLASTIC_RADIUS
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.pokes.store import PokeStore, read_poke_bag
from pointforce_ros.transforms import rotvec_aligning_z
from pointforce_ros.types import PokeRecord

TABLE_COLUMNS = ('poke_id', 't', 'px', 'py', 'pz', 'nx', 'ny', 'nz', 'depth', 'force')
FORCE_COLUMNS = ('fx', 'fy', 'fz')


# --------------------------------------------------------------------------- tables


def write_poke_table(records: Sequence[PokeRecord], path) -> Path:
    """Write records as the plain import table (CSV, full double precision); return the path.

    ``t`` is the controller time; ``fx, fy, fz`` the base-oriented force vector.

    Raises:
        InvalidInput: no records.

    """
    records = list(records)
    if not records:
        raise InvalidInput('write_poke_table: no records to write')
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    buf.write(','.join(TABLE_COLUMNS + FORCE_COLUMNS) + '\n')
    for rec in records:
        if ',' in rec.poke_id or '\n' in rec.poke_id:
            raise InvalidInput(f'write_poke_table: poke id {rec.poke_id!r} contains a comma or '
                               'newline')
        n = len(rec)
        cols = np.column_stack([rec.t_controller, np.tile(rec.point, (n, 1)),
                                np.tile(rec.normal, (n, 1)), rec.displacement(),
                                rec.normal_force(), rec.wrench[:, :3]])
        body = io.StringIO()
        np.savetxt(body, cols, fmt='%.17g', delimiter=',')
        prefix = rec.poke_id + ','
        buf.write(''.join(prefix + line + '\n' for line in body.getvalue().splitlines()))
    path.write_text(buf.getvalue())
    return path


def _speed_of(t: np.ndarray, depth: np.ndarray) -> float:
    """Median inward speed of the samples moving in faster than a fifth of the fastest."""
    if len(t) < 2:
        return 0.002
    v = np.diff(depth) / np.diff(t)
    fast = v[v > 0.2 * v.max()] if v.max() > 0 else v[:0]
    return float(np.median(fast)) if len(fast) else 0.002


def read_poke_table(path) -> List[PokeRecord]:
    """Read the plain import table (see the module docstring) into point-poke records.

    The TCP is placed at ``p - depth * n`` with its z axis along ``-n``; the wrench is the force
    vector when ``fx, fy, fz`` are present, else ``force * n``; torques are zero. The push speed
    is estimated from the depth series.

    Raises:
        DataError: unreadable file, missing columns, non-numeric values, a poke whose time is
            not strictly increasing, or a poke whose point/normal changes between rows.

    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise DataError(f'cannot read poke table {path}: {exc}')
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise DataError(f'{path}: empty table')
    header = [h.strip() for h in rows[0]]
    missing = [c for c in TABLE_COLUMNS if c not in header]
    if missing:
        raise DataError(f'{path}: missing column(s) {missing}; need {", ".join(TABLE_COLUMNS)}'
                        f'[, {", ".join(FORCE_COLUMNS)}]')
    has_vector = all(c in header for c in FORCE_COLUMNS)
    body = [r for r in rows[1:] if r and any(cell.strip() for cell in r)]
    if not body:
        raise DataError(f'{path}: no data rows')
    if any(len(r) != len(header) for r in body):
        raise DataError(f'{path}: rows with a different number of fields than the header')
    col = {name: i for i, name in enumerate(header)}
    ids = [r[col['poke_id']].strip() for r in body]
    numeric = [c for c in header if c != 'poke_id']
    try:
        values = np.array([[float(r[col[c]]) for c in numeric] for r in body], dtype=np.float64)
    except ValueError as exc:
        raise DataError(f'{path}: non-numeric value: {exc}')
    if not np.all(np.isfinite(values)):
        raise DataError(f'{path}: NaN or infinite values')
    num = {c: values[:, i] for i, c in enumerate(numeric)}
    id_arr = np.asarray(ids)
    order, first = np.unique(id_arr, return_index=True)
    records = []
    for poke_id in order[np.argsort(first)]:
        sel = id_arr == poke_id
        t = num['t'][sel]
        point = np.column_stack([num['px'][sel], num['py'][sel], num['pz'][sel]])
        normal = np.column_stack([num['nx'][sel], num['ny'][sel], num['nz'][sel]])
        if np.ptp(point, axis=0).max() > 0 or np.ptp(normal, axis=0).max() > 0:
            raise DataError(f'{path}: poke {poke_id}: point or normal changes between rows')
        depth = num['depth'][sel]
        n = normal[0] / np.linalg.norm(normal[0])
        if has_vector:
            force = np.column_stack([num['fx'][sel], num['fy'][sel], num['fz'][sel]])
        else:
            force = num['force'][sel][:, None] * n
        tcp = np.column_stack([point[0] - depth[:, None] * n,
                               np.tile(rotvec_aligning_z(-n), (len(t), 1))])
        try:
            records.append(PokeRecord(
                poke_id=str(poke_id), point=point[0], normal=n, t=t, t_controller=t,
                tcp_pose=tcp, wrench=np.column_stack([force, np.zeros((len(t), 3))]),
                speed=max(_speed_of(t, depth), 1e-6), meta={'source': str(path)}))
        except InvalidInput as exc:
            raise DataError(f'{path}: poke {poke_id}: {exc}') from exc
    return records


def load_pokes(data) -> List[PokeRecord]:
    """Load poke records from a store directory, one bag, a CSV table or a record sequence.

    Raises:
        DataError: a path that is none of these, or unreadable content.
        InvalidInput: a sequence holding something other than PokeRecords.

    """
    if isinstance(data, (list, tuple)):
        bad = [type(r).__name__ for r in data if not isinstance(r, PokeRecord)]
        if bad:
            raise InvalidInput(f'load_pokes: expected PokeRecords, got {bad[0]}')
        return list(data)
    path = Path(data)
    if not path.exists():
        raise DataError(f'no poke data at {path}')
    if path.is_file():
        if path.suffix.lower() == '.csv':
            return read_poke_table(path)
        if path.suffix.lower() in ('.parquet', '.pq'):
            raise DataError(f'{path}: Parquet needs pyarrow, which is not installed; export '
                            'the table as CSV')
        raise DataError(f'{path}: unknown data file type (expected a .csv table, a poke store '
                        'directory or a bag directory)')
    if (path / 'metadata.yaml').is_file():
        return [read_poke_bag(path)]
    if (path / PokeStore.INDEX).is_file() or any(path.glob('poke-*/metadata.yaml')):
        return list(PokeStore(path))
    pokes = path / 'pokes'
    if (pokes / PokeStore.INDEX).is_file() or any(pokes.glob('poke-*/metadata.yaml')):
        return list(PokeStore(pokes))  # a ``pointforce cell generate`` folder
    raise DataError(f'{path}: neither a poke store (index.json, poke-* bags) nor a bag')


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


def make_batch(records: Sequence[PokeRecord], *, window: float = 0.002,
               max_rate: float = 100.0, radius: float = PLASTIC_RADIUS,
               min_samples: int = 20) -> Tuple[PokeBatch, List[str]]:
    """Prepare point pokes for the analysis; return the batch and notes on skipped records.

    Pokes are ordered by their first ROS time. Each keeps the contiguous samples from the first
    to the last one with displacement ``d >= -window``, or ``window`` before the depth where the
    force first exceeds 10 % of its peak when contact starts earlier (a large camera bias); the
    approach from far away carries no information. Samples are block-averaged to at most
    ``max_rate`` Hz (time and force averaged alike, so no lag is introduced). Probe trials
    (``probe != 'point'``) and pokes with fewer than ``min_samples`` samples are skipped with
    a note.

    Raises:
        DataError: fewer than 4 usable point pokes.

    """
    notes = []
    usable = []
    for rec in sorted(records, key=lambda r: (float(r.t[0]) if len(r) else 0.0, r.poke_id)):
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
