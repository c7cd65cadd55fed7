"""Save and load force-response models (the learner's state, not the baked contact model).

A model file is the JSON of the model's ``to_dict()`` with a ``format`` header. Writes go to a
temporary file in the same directory and are renamed into place, so a reader sees the old or
the new model, never half of one. The contact service loads the *baked* table instead
(:mod:`pointforce_ros.model.files`); this file lets the learner restart without refitting.
"""

import json
from pathlib import Path
from typing import Mapping

from pointforce_ros.errors import DataError, InvalidInput, read_json
from pointforce_ros.model.files import atomic_write
from pointforce_ros.lab.baseline import AutoEtBaseline, EtBaseline
from pointforce_ros.response.ours import ContactGpModel

FILE_FORMAT = 'pointforce-response-model/1'
KINDS = {cls.kind: cls for cls in (ContactGpModel, EtBaseline, AutoEtBaseline)}


def model_from_dict(data: Mapping):
    """Rebuild any known model from its ``to_dict()``.

    Raises:
        InvalidInput: unknown ``kind`` or malformed data.

    """
    kind = data.get('kind') if isinstance(data, Mapping) else None
    if kind not in KINDS:
        raise InvalidInput(f'unknown force-response model kind {kind!r}; known: {sorted(KINDS)}')
    return KINDS[kind].from_dict(data)


def save_response_model(model, path) -> Path:
    """Write ``model`` to ``path`` (JSON) atomically; return the path.

    Raises:
        InvalidInput: the model has no ``to_dict``.

    """
    if not hasattr(model, 'to_dict'):
        raise InvalidInput(f'cannot save {type(model).__name__}: no to_dict()')
    payload = json.dumps({'format': FILE_FORMAT, 'model': model.to_dict()})
    return atomic_write(path, lambda fh: fh.write(payload), binary=False)


def load_response_model(path):
    """Load a model written by :func:`save_response_model`.

    Raises:
        DataError: missing or unreadable file, wrong format, or a model that does not parse.

    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f'response model file not found: {path}')
    data = read_json(path, 'JSON response model file')
    if data.get('format') != FILE_FORMAT:
        raise DataError(f'{path}: unknown response model format {data.get("format")!r}')
    try:
        return model_from_dict(data['model'])
    except (InvalidInput, KeyError) as exc:
        raise DataError(f'{path}: corrupt response model: {exc}') from exc
