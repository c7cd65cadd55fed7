"""Versioned, atomically saved contact models (surface + baked response + shape constant).

A *contact model* is everything the contact-wrench service needs, loadable without the learner:
the equilibrium surface, the baked force table, the shape-function constant ``c`` and the
accepted effects. Files are ``model-v000042.npz`` in one directory; a save writes a temporary file
and renames it, so a reader sees either the old or the new model, never half of one.
"""

import json
import os
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping, Optional, Tuple

import numpy as np

from pointforce_ros.contact.lcp import check_decay
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Surface

FORMAT = 'pointforce-contact-model/1'
_NAME = re.compile(r'^model-v(\d{6,})\.npz$')


@dataclass(frozen=True)
class ContactModel:
    """What the contact service answers from.

    Attributes:
        surface: equilibrium surface (``base``), N points.
        response: baked force table for the same N points.
        shape_constant: ``c`` of the shape function ``g(r) = c / (c + r)``, metres.
        shape_decay: decay length of the shape function's tail, metres (``inf``: the paper's
            ``g``; see :func:`~pointforce_ros.contact.lcp.shape_function`).
        version: model version (monotone over refits).
        effects: accepted model effects from ``pointforce diagnose`` (name -> parameters).
        meta: free-form JSON description (training pokes, errors, model kind).

    Raises:
        InvalidInput: surface and table of different sizes, ``c <= 0`` or ``shape_decay``
            neither a positive length nor ``inf``.

    """

    surface: Surface
    response: BakedResponse
    shape_constant: float
    version: int = 0
    shape_decay: float = float('inf')
    effects: Mapping = field(default_factory=dict)
    meta: Mapping = field(default_factory=dict)

    def __post_init__(self):
        if len(self.surface) != len(self.response):
            raise InvalidInput(f'ContactModel: surface has {len(self.surface)} points, baked '
                               f'table has {len(self.response)}')
        if not np.isfinite(self.shape_constant) or self.shape_constant <= 0:
            raise InvalidInput(f'ContactModel.shape_constant: must be > 0 m, got '
                               f'{self.shape_constant}')
        check_decay(self.shape_decay, 'ContactModel.shape_decay')


def atomic_write(path, write: Callable, binary: bool = True) -> Path:
    """Write ``path`` atomically: ``write(fh)`` fills a temporary sibling, then it is renamed.

    A reader sees the old file or the new one, never a part; on an error the temporary file is
    removed and the error propagates.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix='.tmp-', suffix=path.suffix)
    try:
        with os.fdopen(fd, 'wb' if binary else 'w') as fh:
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def model_path(directory, version: int) -> Path:
    """Path of model ``version`` in ``directory``."""
    return Path(directory) / f'model-v{int(version):06d}.npz'


def save_model(model: ContactModel, directory) -> Path:
    """Write ``model`` atomically into ``directory`` (created if needed); return its path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    header = {
        'format': FORMAT, 'version': int(model.version),
        'shape_constant': float(model.shape_constant), 'frame': model.surface.frame,
        'shape_decay': float(model.shape_decay) if np.isfinite(model.shape_decay) else None,
        'effects': dict(model.effects), 'meta': dict(model.meta),
        'response_version': int(model.response.version), 'response_meta': model.response.meta,
    }
    arrays = {
        'points': model.surface.points, 'normals': model.surface.normals,
        'colors': model.surface.colors, 'depths': model.response.depths,
        'forces': model.response.forces, 'slopes': model.response.slopes,
        'header': np.frombuffer(json.dumps(header).encode(), dtype=np.uint8),
    }
    if model.response.std is not None:
        arrays['std'] = model.response.std
    return atomic_write(model_path(directory, model.version),
                        lambda fh: np.savez(fh, **arrays))


def load_model(path) -> ContactModel:
    """Load a model file.

    Raises:
        DataError: missing file, not a model file, unknown format, or corrupt arrays.

    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f'model file not found: {path}')
    try:
        with np.load(path, allow_pickle=False) as z:
            header = json.loads(bytes(z['header']).decode())
            if header.get('format') != FORMAT:
                raise DataError(f'{path}: unknown model format {header.get("format")!r}')
            surface = Surface(points=z['points'], normals=z['normals'], colors=z['colors'],
                              frame=header.get('frame', 'base'))
            response = BakedResponse(depths=z['depths'], forces=z['forces'], slopes=z['slopes'],
                                     std=z['std'] if 'std' in z.files else None,
                                     version=header.get('response_version', 0),
                                     meta=header.get('response_meta', {}))
    except DataError:
        raise
    except (OSError, ValueError, KeyError, InvalidInput) as exc:
        raise DataError(f'{path}: corrupt or unreadable model file: {exc}') from exc
    return ContactModel(surface=surface, response=response,
                        shape_constant=header['shape_constant'], version=header['version'],
                        shape_decay=float(header.get('shape_decay') or float('inf')),
                        effects=header.get('effects', {}), meta=header.get('meta', {}))


def latest_model_path(directory) -> Optional[Path]:
    """Newest model file in ``directory`` by version, or ``None``."""
    found: Tuple[int, Optional[Path]] = (-1, None)
    directory = Path(directory)
    if not directory.is_dir():
        return None
    for p in directory.iterdir():
        m = _NAME.match(p.name)
        if m and int(m.group(1)) > found[0]:
            found = (int(m.group(1)), p)
    return found[1]


def save_surface(surface: Surface, path) -> Path:
    """Write an equilibrium surface atomically to ``path`` (``.npz``); returns the path."""
    return atomic_write(path, lambda fh: np.savez(
        fh, points=surface.points, normals=surface.normals, colors=surface.colors,
        frame=np.frombuffer(surface.frame.encode(), dtype=np.uint8)))


def load_surface(path) -> Surface:
    """Read a surface written by :func:`save_surface`; DataError if missing or corrupt."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f'surface file not found: {path}')
    try:
        with np.load(path, allow_pickle=False) as z:
            return Surface(points=z['points'], normals=z['normals'], colors=z['colors'],
                           frame=bytes(z['frame']).decode() or 'base')
    except (OSError, ValueError, KeyError, InvalidInput) as exc:
        raise DataError(f'{path}: corrupt or unreadable surface file: {exc}') from exc
