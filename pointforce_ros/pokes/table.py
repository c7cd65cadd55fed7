"""Loading measured pokes: a poke store, one bag, or the documented import table.

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

"""

import csv
import io
from pathlib import Path
from typing import List, Sequence

import numpy as np

from pointforce_ros.errors import DataError, InvalidInput, reading, TEXT_ENCODING
from pointforce_ros.pokes.store import PokeStore, read_poke_bag
from pointforce_ros.rotations import rotvec_aligning_z
from pointforce_ros.types import PokeRecord, Surface

TABLE_COLUMNS = ('poke_id', 't', 'px', 'py', 'pz', 'nx', 'ny', 'nz', 'depth', 'force')
FORCE_COLUMNS = ('fx', 'fy', 'fz')

UNIT_LIMITS = {'position': 5.0, 'depth': 0.2, 'force': 1000.0}
"""Largest plausible magnitudes in a table of a robot cell, in its units (m, m, N): a poked point
5 m from the base, a probe 200 mm past the surface, 1 kN on a soft object. A value past one is
almost always a column in other units (millimetres, millinewtons), and the table is refused
with that said, instead of learning a stiffness a thousand times off."""


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
    with np.errstate(divide='ignore', invalid='ignore'):   # repeated times: refused later
        v = np.diff(depth) / np.diff(t)
    v = v[np.isfinite(v)]
    if not len(v):
        return 0.002
    fast = v[v > 0.2 * v.max()] if v.max() > 0 else v[:0]
    return float(np.median(fast)) if len(fast) else 0.002


def _check_units(path, num: dict, ids: List[str]) -> None:
    """Refuse a column whose largest magnitude is past :data:`UNIT_LIMITS` (another unit)."""
    groups = {'position': (('px', 'py', 'pz'), 'm', 'millimetres? divide by 1000'),
              'depth': (('depth',), 'm', 'millimetres? divide by 1000'),
              'force': (('force',) + tuple(c for c in FORCE_COLUMNS if c in num), 'N',
                        'millinewtons? divide by 1000; grams-force? multiply by 0.00981')}
    for kind, (columns, unit, hint) in groups.items():
        stack = np.abs(np.column_stack([num[c] for c in columns]))
        row, col = np.unravel_index(np.argmax(stack), stack.shape)
        if stack[row, col] > UNIT_LIMITS[kind]:
            raise DataError(
                f'{path}: {columns[col]} = {num[columns[col]][row]:g} {unit} (poke '
                f'{ids[row]}) is past {UNIT_LIMITS[kind]:g} {unit}, the largest plausible '
                f'{kind} of a robot cell: the table is in metres and newtons ({hint})')


def read_poke_table(path) -> List[PokeRecord]:
    """Read the plain import table (see the module docstring) into point-poke records.

    The TCP is placed at ``p - depth * n`` with its z axis along ``-n``; the wrench is the force
    vector when ``fx, fy, fz`` are present, else ``force * n``; torques are zero. The push speed
    is estimated from the depth series.

    Raises:
        DataError: unreadable file (not UTF-8 text; a byte-order mark is fine), missing
            or repeated columns, non-numeric values, a poke id that is no plain file name, a
            poke whose time is not strictly increasing, a poke whose point/normal changes
            between rows, a normal of zero length, or a position, depth or force past
            :data:`UNIT_LIMITS` (a column in other units).

    """
    path = Path(path)
    with reading(path, 'poke table'):
        rows = list(csv.reader(io.StringIO(path.read_text(encoding=TEXT_ENCODING))))
    if not rows:
        raise DataError(f'{path}: empty table')
    header = [h.strip() for h in rows[0]]
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise DataError(f'{path}: column {repeated[0]!r} appears {header.count(repeated[0])} '
                        'times in the header; which copy holds the data is ambiguous: keep one')
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
    _check_units(path, num, ids)
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
        length = float(np.linalg.norm(normal[0]))
        if length < 1e-9:
            raise DataError(f'{path}: poke {poke_id}: the normal (nx, ny, nz) has zero length')
        n = normal[0] / length
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


def surface_from_records(records: Sequence[PokeRecord]) -> Surface:
    """Return the surface a table without a cloud implies: its poked points and normals.

    Data from another rig often comes without a depth-camera cloud; the learner then bakes
    its model on the poked points themselves (one surface point per distinct poke point, in
    first-seen order, no colour), enough to learn, score and serve point pokes there.

    Raises:
        InvalidInput: no records, or records that are not PokeRecords.

    """
    records = list(records)
    if not records or not all(isinstance(r, PokeRecord) for r in records):
        raise InvalidInput('surface_from_records: need a non-empty sequence of PokeRecords')
    points = np.array([r.point for r in records])
    normals = np.array([r.normal for r in records])
    _, first = np.unique(points, axis=0, return_index=True)
    keep = np.sort(first)
    return Surface(points=points[keep], normals=normals[keep])


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
