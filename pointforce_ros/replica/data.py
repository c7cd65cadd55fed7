"""Measured pokes for the replica: loading curves plus the scanned surface they were poked on.

Two sources: a generated data set (``pointforce cell generate --out DIR``: ``DIR/pokes`` is the
poke store, ``DIR/surface.npz`` the equilibrium surface), or a poke fixture ``.npz`` of the
figures (``data/figures/pokes_<object>.npz``: curves and surface in one file). Either way the
result is a :class:`PokeSet`: per poke the x-y of the poked point, the depth past the contact
onset, the force and the time, in metres, newtons and seconds, frame ``base``.
"""

from dataclasses import dataclass
import glob
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

import numpy as np

from pointforce_ros.errors import DataError, InvalidInput, reading
from pointforce_ros.model.files import load_surface
from pointforce_ros.pokes.curves import extract_curve, PokeCurve
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.types import as_array


@dataclass(frozen=True)
class MeasuredPoke:
    """One measured loading curve, depth measured from the contact onset.

    Attributes:
        poke_id: id of the poke.
        xy: (2,) poked point x-y, metres, ``base``.
        depth: (M,) displacement past the contact onset, metres (``d - onset_d``).
        force: (M,) normal force, newtons.
        t: (M,) seconds since the first sample of the record.
        series: optional ramp-and-hold record ``(t, depth, force)``, each (S,), seconds from
            contact, metres past contact, newtons: the force against time while the pusher
            moves at :attr:`speed` and then holds (the relaxation the damping step needs).
            ``depth, force`` above are then the static (relaxed) curve.

    """

    poke_id: str
    xy: np.ndarray
    depth: np.ndarray
    force: np.ndarray
    t: np.ndarray
    series: Optional[Tuple[np.ndarray, np.ndarray, np.ndarray]] = None

    def __post_init__(self):
        xy = as_array(self.xy, 'MeasuredPoke.xy', (2,))
        depth = as_array(self.depth, 'MeasuredPoke.depth', (None,))
        force = as_array(self.force, 'MeasuredPoke.force', (len(depth),))
        t = as_array(self.t, 'MeasuredPoke.t', (len(depth),))
        for name, value in (('xy', xy), ('depth', depth), ('force', force), ('t', t)):
            object.__setattr__(self, name, value)
        if self.series is not None:
            st = as_array(self.series[0], 'MeasuredPoke.series t', (None,))
            object.__setattr__(self, 'series', (
                st, as_array(self.series[1], 'MeasuredPoke.series depth', (len(st),)),
                as_array(self.series[2], 'MeasuredPoke.series force', (len(st),))))

    @property
    def speed(self) -> float:
        """Median push speed over the curve, m/s."""
        v = np.diff(self.depth) / np.maximum(np.diff(self.t), 1e-9)
        return float(np.median(v[v > 0])) if np.any(v > 0) else 0.002

    def in_contact(self) -> 'MeasuredPoke':
        """Return the samples past the onset (depth > 0)."""
        keep = self.depth > 0
        return MeasuredPoke(self.poke_id, self.xy, self.depth[keep], self.force[keep],
                            self.t[keep], self.series)


@dataclass(frozen=True)
class PokeSet:
    """Measured pokes and the surface points they were poked on.

    Attributes:
        pokes: the pokes, in store order.
        surface_points: (P, 3) equilibrium-surface points, metres, ``base``.
        source: where it was read from.
        held_out_ids: poke ids the source marks as held out (then :meth:`split` uses them).
        surface_normals: (P, 3) unit normals of the surface points, or None.
        ball_radius: the object is a ball of this radius (m) on the table, compressed by a
            flat plate (seed 002's setup), or None (a scanned object poked by the probe).

    """

    pokes: Tuple[MeasuredPoke, ...]
    surface_points: np.ndarray
    source: str
    held_out_ids: Tuple[str, ...] = ()
    surface_normals: Optional[np.ndarray] = None
    ball_radius: Optional[float] = None

    def split(self, held_out: float = 0.5, seed: int = 0
              ) -> Tuple[List[MeasuredPoke], List[MeasuredPoke]]:
        """Seeded split into (training, held-out) pokes; each part gets at least one.

        Raises:
            InvalidInput: fewer than 2 pokes.

        """
        if len(self.pokes) < 2:
            raise InvalidInput(f'{self.source}: need at least 2 pokes to hold some out, got '
                               f'{len(self.pokes)}')
        if self.held_out_ids:
            return ([p for p in self.pokes if p.poke_id not in self.held_out_ids],
                    [p for p in self.pokes if p.poke_id in self.held_out_ids])
        order = np.random.default_rng(seed).permutation(len(self.pokes))
        n_out = int(np.clip(round(held_out * len(order)), 1, len(order) - 1))
        return ([self.pokes[i] for i in sorted(order[n_out:])],
                [self.pokes[i] for i in sorted(order[:n_out])])


def _from_curve(curve: PokeCurve) -> MeasuredPoke:
    return MeasuredPoke(curve.poke_id, curve.point[:2], curve.d - curve.onset_d, curve.f,
                        curve.t).in_contact()


def _fixture(path: Path) -> PokeSet:
    with reading(path, 'poke file'), np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    if 'static_offsets' in data:
        return _ball_plate(path, data)
    if 'surface_points' not in data or len(data['surface_points']) == 0:
        raise DataError(f'{path}: the pokes come without a surface (no surface_points): the '
                        'replica needs the scanned object')
    if 'curve_offsets' not in data or len(data.get('curve_ids', [])) == 0:
        raise InvalidInput(f'{path}: no pokes in the file')
    off = data['curve_offsets']
    pokes = []
    for k, poke_id in enumerate(data['curve_ids']):
        s = slice(int(off[k]), int(off[k + 1]))
        d = np.asarray(data['curve_d'][s], dtype=float) - float(data['curve_onsets'][k])
        pokes.append(MeasuredPoke(str(poke_id), np.asarray(data['curve_points'][k][:2], float),
                                  d, np.asarray(data['curve_f'][s], float),
                                  np.asarray(data['curve_t'][s], float)).in_contact())
    normals = data.get('surface_normals')
    return PokeSet(tuple(pokes), np.asarray(data['surface_points'], float), str(path),
                   surface_normals=None if normals is None else np.asarray(normals, float))


def _dataset(root: Path) -> PokeSet:
    store_dir = root / 'pokes' if (root / 'pokes').is_dir() else root
    surface_file = next((p for p in (root / 'surface.npz', root.parent / 'surface.npz')
                         if p.is_file()), None)
    if not (store_dir / PokeStore.INDEX).exists() and not any(store_dir.glob('poke-*')):
        raise DataError(f'{root}: not a poke store or a generated data set (no index.json '
                        'or poke-* bags)')
    store = PokeStore(store_dir)
    if len(store) == 0:
        raise InvalidInput(f'{store_dir}: the poke store holds no pokes')
    if surface_file is None:
        raise DataError(f'{root}: the pokes come without a surface (no surface.npz beside '
                        'the store): the replica needs the scanned object')
    surface = load_surface(surface_file)
    pokes = []
    for record in store:
        try:
            pokes.append(_from_curve(extract_curve(record)))
        except InvalidInput:
            continue  # a poke without contact or loading phase adds nothing to calibrate
    if not pokes:
        raise InvalidInput(f'{store_dir}: no poke with a usable loading curve')
    return PokeSet(tuple(pokes), np.asarray(surface.points), str(root),
                   surface_normals=np.asarray(surface.normals))


def _static_pushes(pattern: str) -> PokeSet:
    """Read the static pushes of the deformation fixtures (``push_<object>_*.npz``, ``rest_*``).

    Each file holds the force vector at a few depths of one vertical push from the surface;
    the rest scan beside them is the surface. Roles ``heldout`` become the held-out pokes.
    """
    files = sorted(glob.glob(pattern))
    if not files:
        raise InvalidInput(f'{pattern}: no push files match')
    pokes, held = [], []
    for f in files:
        with reading(f, 'push file'):
            with np.load(f, allow_pickle=False) as z:
                depth = np.asarray(z['depths'], float)
                force = np.asarray(z['force'], float) @ np.asarray(z['direction'], float)
                poke = MeasuredPoke(Path(f).stem, np.asarray(z['xy'], float), depth, force,
                                    depth / 0.002)
                if str(z['role']) == 'heldout':
                    held.append(poke.poke_id)
        pokes.append(poke)
    name = Path(files[0]).stem.split('_', 1)[1].rsplit('_', 1)[0]
    rest = Path(files[0]).parent / f'rest_{name}.npz'
    if not rest.is_file():
        raise DataError(f'{pattern}: the pushes come without a surface (no {rest.name})')
    with reading(rest, 'rest surface'), np.load(rest, allow_pickle=False) as z:
        points = np.asarray(z['points'], float)
        normals = np.asarray(z['normals'], float) if 'normals' in z.files else None
    return PokeSet(tuple(pokes), points, pattern, tuple(held), surface_normals=normals)


def _ball_plate(path: Path, data: dict) -> PokeSet:
    """Read plate-on-ball trials (``test/data/replica/make_ball_plate.py``).

    Each trial becomes a poke at the ball's centre x-y whose curve is the static (relaxed)
    force against compression and whose ``series`` is the ramp-and-hold record.
    """
    with reading(path, 'plate-on-ball trials'):
        off, soff = data['offsets'], data['static_offsets']
        radius = float(data['radius'])
        pokes, held = [], []
        for k, (speed, role) in enumerate(zip(data['speeds'], data['role'])):
            s, q = slice(int(off[k]), int(off[k + 1])), slice(int(soff[k]), int(soff[k + 1]))
            depth = np.asarray(data['static_depth'][q], float)
            poke_id = f'trial-{k}-{1e3 * float(speed):g}mm_s'
            pokes.append(MeasuredPoke(
                poke_id, np.zeros(2), depth, np.asarray(data['static_force'][q], float),
                depth / float(speed),
                (data['t'][s], data['depth'][s], data['force'][s])))
            if str(role) == 'heldout':
                held.append(poke_id)
    if not pokes:
        raise InvalidInput(f'{path}: no pokes in the file')
    theta = np.linspace(0, np.pi, 12)[:, None]
    phi = np.linspace(0, 2 * np.pi, 24, endpoint=False)[None, :]
    normals = np.stack(np.broadcast_arrays(np.sin(theta) * np.cos(phi),
                                           np.sin(theta) * np.sin(phi), np.cos(theta)),
                       -1).reshape(-1, 3)
    return PokeSet(tuple(pokes), normals * radius + [0.0, 0.0, radius], str(path), tuple(held),
                   surface_normals=normals, ball_radius=radius)


def load_pokes(path) -> PokeSet:
    """Read measured pokes from a generated data set, a poke store or a poke fixture ``.npz``.

    A glob pattern (``.../push_foam_block_*.npz``) reads the deformation wing's static pushes.

    Raises:
        DataError: missing path, unreadable store or file, no surface beside the pokes.
        InvalidInput: no pokes, or none with a usable loading curve.

    """
    if '*' in str(path):
        return _static_pushes(str(path))
    path = Path(path)
    if not path.exists():
        raise DataError(f'{path}: no such poke store or file')
    if path.is_file():
        if path.suffix.lower() != '.npz':
            raise DataError(f'{path}: a replica is built from a poke store, a generated data set '
                            '(pointforce cell generate) or a poke fixture .npz, not a '
                            f'{path.suffix or "suffix-less"} file (a CSV table carries no '
                            'surface to build the body from)')
        return _fixture(path)
    return _dataset(path)


def subset(pokes: Sequence[MeasuredPoke], every: int) -> List[MeasuredPoke]:
    """Return every ``every``-th sample of each poke (pokes of <= 20 samples are kept whole)."""
    return [p if len(p.depth) <= 20 else
            MeasuredPoke(p.poke_id, p.xy, p.depth[::every], p.force[::every], p.t[::every],
                         p.series)
            for p in pokes]
