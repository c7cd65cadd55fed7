"""Probe trials: a rigid probe pushed into the object with its measured or true wrench per step.

The file format (``probes.npz`` arrays with trial-indexed keys beside ``probes.json``) is what
``pointforce cell generate`` writes and what the diagnosis and the lab figures read; SI units,
frame ``base``.
"""

from dataclasses import dataclass
import json
from pathlib import Path
from typing import Dict, List, Sequence, Tuple

import numpy as np

from pointforce_ros.errors import DataError, InvalidInput, read_json, reading
from pointforce_ros.types import Mesh, Pose


def save_probe_trials(trials: Sequence[Dict], out) -> None:
    """Write trials as ``probes.npz`` (arrays, trial-indexed keys) and ``probes.json``."""
    arrays, index = {}, []
    for i, trial in enumerate(trials):
        for key in ('vertices', 'triangles', 'start_position', 'orientation', 'direction',
                    'torque_centre', 'depths', 'force', 'torque'):
            arrays[f'{i:03d}_{key}'] = np.asarray(trial[key])
        index.append({'trial': i, 'kind': trial['kind'], 'steps': len(trial['depths']),
                      'seconds': round(float(trial.get('seconds', 0.0)), 2)})
    out = Path(out)
    np.savez(out / 'probes.npz', **arrays)
    (out / 'probes.json').write_text(json.dumps({'trials': index}, indent=1))


def load_trial_dicts(path) -> List[Dict]:
    """Read ``probes.npz`` written by :func:`save_probe_trials` (a directory or the file)."""
    path = Path(path)
    if path.is_dir():
        path = path / 'probes.npz'
    index = read_json(path.with_suffix('.json'), 'probe trial index')
    with reading(path, 'probe trials'), np.load(path, allow_pickle=False) as z:
        return [{'kind': e['kind'], **{key[4:]: z[key] for key in z.files
                                       if key.startswith(f'{e["trial"]:03d}_')}}
                for e in index['trials']]


@dataclass(frozen=True)
class ProbeTrial:
    """One probe trial with its ground truth (``base`` frame, SI units).

    Attributes:
        kind: probe name (``line``, ``cylinder``, ...).
        mesh: the rigid probe in its own frame.
        start: probe pose at travel 0 (just touching the true surface).
        direction: (3,) unit push direction.
        torque_centre: (3,) point the torques are taken about (fixed in ``base``), metres.
        depths: (K,) travel along ``direction`` past ``start``, metres.
        force: (K, 3) true force on the probe, N.
        torque: (K, 3) true torque on the probe about ``torque_centre``, N m.
        compliant: measured through the poking arm: the series compliance of the pokes acts
            on the trial (the generated trials of ``cell generate`` are the object's clean
            response: False).

    """

    kind: str
    mesh: Mesh
    start: Pose
    direction: np.ndarray
    torque_centre: np.ndarray
    depths: np.ndarray
    force: np.ndarray
    torque: np.ndarray
    compliant: bool = False

    def poses(self) -> Tuple[Pose, ...]:
        """Return the probe pose at every depth."""
        return tuple(Pose(self.start.position + d * self.direction, self.start.orientation,
                          self.start.frame) for d in self.depths)


def trials_from_dicts(entries: Sequence[Dict]) -> List[ProbeTrial]:
    """Build trials from the mappings :func:`load_trial_dicts` returns.

    Raises:
        DataError: a trial with missing keys or inconsistent shapes.

    """
    trials = []
    for i, e in enumerate(entries):
        try:
            depths = np.asarray(e['depths'], dtype=np.float64).reshape(-1)
            trial = ProbeTrial(
                kind=str(e['kind']),
                mesh=Mesh(np.asarray(e['vertices'], dtype=np.float64),
                          np.asarray(e['triangles'], dtype=np.int64)),
                start=Pose(np.asarray(e['start_position'], dtype=np.float64),
                           np.asarray(e['orientation'], dtype=np.float64)),
                direction=np.asarray(e['direction'], dtype=np.float64).reshape(3),
                torque_centre=np.asarray(e['torque_centre'], dtype=np.float64).reshape(3),
                depths=depths,
                force=np.asarray(e['force'], dtype=np.float64).reshape(len(depths), 3),
                torque=np.asarray(e['torque'], dtype=np.float64).reshape(len(depths), 3),
                compliant=bool(e.get('compliant', False)))
        except KeyError as exc:
            raise DataError(f'probe trial {i}: no {exc} in the file') from exc
        except (ValueError, InvalidInput) as exc:
            raise DataError(f'probe trial {i}: {exc}') from exc
        trials.append(trial)
    return trials


def load_probe_trials(path) -> List[ProbeTrial]:
    """Read ``probes.npz`` (+ ``probes.json``) of ``pointforce cell generate``.

    Raises:
        DataError: missing or unreadable files.

    """
    dicts = load_trial_dicts(path)
    try:
        return trials_from_dicts(dicts)
    except DataError as exc:      # a trial's content: say which file it is in
        raise DataError(f'{path}: {exc}') from exc
