"""Make ``lamb_realistic.npz``: the lamb pokes on which diagnose once accepted a wrong offset.

Scenario: ``pointforce cell generate --object lamb --scenario realistic --pokes 8 --probes point
--seed 1`` (FEM live contact path of the ``lamb`` object: a fat cap over muscle with a bone
inclusion; 2 mm camera depth bias, camera range noise, F/T noise, bias and drift, tared before
each push). The curves stiffen sharply over the bone, so they are not power laws; diagnose used
to accept ``surface_offset`` = 5.13 mm with the exponent on its bound 4 (the truth is the
camera bias, 1.90 mm on average over the poked points). Regenerate (about 30 s)::

    nice -n 10 pointforce cell generate --object lamb --scenario realistic --pokes 8
        --probes point --seed 1 --out /tmp/lamb_realistic     (one line)
    python test/data/diagnose/make_lamb_fixture.py /tmp/lamb_realistic

To stay small the file keeps, per poke, the samples from 8 mm outside the observed surface on
(diagnose looks at most a few millimetres outside it), block-averaged from 250 Hz to 50 Hz
(diagnose's own analysis rate), positions and forces as float32. ``true_offset`` holds, per
poke, how far the true top lies outside the observed point along the normal, metres.
"""

import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FIXTURE = HERE / 'lamb_realistic.npz'
FACTOR = 5


def _blocks(x: np.ndarray) -> np.ndarray:
    n = (len(x) // FACTOR) * FACTOR
    return x[:n].reshape((n // FACTOR, FACTOR) + x.shape[1:]).mean(axis=1)


def make(folder) -> Path:
    """Write the fixture from a ``cell generate`` output folder; return its path."""
    from pointforce_ros.sim.objects import load_object
    from pointforce_ros.pokes.store import PokeStore
    folder = Path(folder)
    manifest = json.loads((folder / 'manifest.json').read_text())
    spec = load_object(manifest['object'])
    arrays, index = {}, []
    for k, rec in enumerate(PokeStore(folder / 'pokes')):
        keep = np.flatnonzero(rec.displacement() >= -0.008)
        sl = slice(int(keep[0]), int(keep[-1]) + 1)
        top = np.asarray(spec.top_point(rec.point[0], rec.point[1]))
        arrays[f'{k:02d}_t'] = _blocks(rec.t[sl])
        arrays[f'{k:02d}_t_controller'] = _blocks(rec.t_controller[sl])
        arrays[f'{k:02d}_tcp_pose'] = _blocks(rec.tcp_pose[sl]).astype(np.float32)
        arrays[f'{k:02d}_wrench'] = _blocks(rec.wrench[sl]).astype(np.float32)
        arrays[f'{k:02d}_point'] = rec.point
        arrays[f'{k:02d}_normal'] = rec.normal
        index.append({'poke_id': rec.poke_id, 'speed': rec.speed, 'outcome': rec.outcome,
                      'meta': rec.meta, 'true_offset': float((top - rec.point) @ rec.normal)})
    arrays['index'] = np.array(json.dumps({'manifest': manifest, 'pokes': index}))
    np.savez_compressed(FIXTURE, **arrays)
    return FIXTURE


def load(path=FIXTURE):
    """Return ``(records, true_offset (P,))`` of the fixture."""
    from pointforce_ros.types import PokeRecord
    with np.load(path, allow_pickle=False) as z:
        index = json.loads(str(z['index']))['pokes']
        records = []
        for k, entry in enumerate(index):
            def get(key):
                return np.asarray(z[f'{k:02d}_{key}'], dtype=np.float64)
            records.append(PokeRecord(
                poke_id=entry['poke_id'], point=get('point'), normal=get('normal'),
                t=get('t'), t_controller=get('t_controller'), tcp_pose=get('tcp_pose'),
                wrench=get('wrench'), speed=entry['speed'], outcome=entry['outcome'],
                meta=entry['meta']))
    return records, np.array([e['true_offset'] for e in index])


if __name__ == '__main__':
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    print(make(sys.argv[1]))
