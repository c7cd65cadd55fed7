"""Versioned, atomically saved contact models (surface + baked response + shape constant).

A *contact model* is everything the contact-wrench service needs, loadable without the learner:
the equilibrium surface, the baked force table, the shape-function constant ``c`` and the
accepted effects. Files are ``model-v000042.npz`` in one directory; a save writes a temporary file
and renames it, so a reader sees either the old or the new model, never half of one.

Versions are never reused for different content and never go down: each file's header carries
a SHA-256 of its content (everything but the version), a save whose version is taken by other
content, or is not above the highest version the directory has ever held, gets the next free
version instead, and that highest version is persisted (``versions.json``, written atomically)
beside the files and the quarantine. A file the loader cannot read (truncated, empty, not a zip,
altered, unknown format, a header of the wrong type, a header version that is not the one in
the file's name) is moved to ``quarantine/`` beside it with a ``.reason.txt``, logged, and
:func:`load_latest_model` falls back to the newest valid version.

A file that is intact but names an effect this build does not know (:class:`UnsupportedModel`,
written by a newer learner) is *skipped*, not quarantined: it is left where it is for a build
that can serve it (an old service must not move a newer learner's output away), logged once,
and not read again while it is unchanged; the newest older valid version is served meanwhile.
Its version still counts as taken, so a save never reuses it.

A shape-function update made at run time (``c``, decay length ``L``) is kept beside the models in
``shape.json`` (:func:`save_shape`, atomic), so that a restarted learner uses it again.
"""

import dataclasses
import hashlib
import json
import logging
import os
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Mapping, Optional, Tuple

import numpy as np

from pointforce_ros.contact.lcp import check_decay, check_near
from pointforce_ros.contact.simulator import check_decay_law, DECAY_LAW
from pointforce_ros.contact.uncertainty import SOURCE_KEYS, uncertainty_sources
from pointforce_ros.effects.forward import ForwardTerms
from pointforce_ros.effects.library import LIBRARY, PROBE_EFFECTS
from pointforce_ros.errors import check_npz_size, DataError, InvalidInput, read_json
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.types import Surface

FORMAT = 'pointforce-contact-model/1'
_NAME = re.compile(r'^model-v(\d{6,})\.npz$')
QUARANTINE = 'quarantine'
"""Folder, beside the model files, that unreadable files are moved to."""
VERSIONS = 'versions.json'
"""File, beside the model files, holding the highest version ever saved there."""
SHAPE = 'shape.json'
"""File, beside the model files, holding the shape function set at run time (c, L)."""
MAX_COUNTER = 10 ** 9
"""Largest ``versions.json`` counter believed; above it (or not a whole number) it is ignored."""
LOG = logging.getLogger(__name__)


class UnsupportedModel(DataError):
    """An intact model file this build cannot serve (an effect it does not know).

    :func:`load_latest_model` skips such a file (it stays for a build that knows the effect)
    instead of quarantining it.
    """


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
        shape_decay_law: how ``shape_decay`` applies
            (:data:`~pointforce_ros.contact.simulator.DECAY_LAWS`): ``'fixed'``, one length for
            every contact, or ``'penetration'``, each contact's length grows with its
            penetration. A file without it was written under ``'fixed'``, and is read so: a
            calibration keeps the law it was identified under.
        shape_near: the shape function's near field
            (:data:`~pointforce_ros.contact.lcp.NEARS`): ``'paper'``, ``c / (c + r)`` (a file
            without it), or ``'flat'``, ``(1 + r / c) exp(-r / c)``.

    Raises:
        InvalidInput: surface and table of different sizes, ``c <= 0``, ``shape_decay``
            neither a positive length nor ``inf``, an unknown ``shape_decay_law`` or
            ``shape_near``, or ``effects`` / ``meta`` not a mapping.

    """

    surface: Surface
    response: BakedResponse
    shape_constant: float
    version: int = 0
    shape_decay: float = float('inf')
    effects: Mapping = field(default_factory=dict)
    meta: Mapping = field(default_factory=dict)
    shape_decay_law: str = DECAY_LAW
    shape_near: str = 'paper'

    def __post_init__(self):
        for name in ('effects', 'meta'):
            if not isinstance(getattr(self, name), Mapping):
                raise InvalidInput(f'ContactModel.{name}: must be a mapping (JSON object), got '
                                   f'{type(getattr(self, name)).__name__}')
        if len(self.surface) != len(self.response):
            raise InvalidInput(f'ContactModel: surface has {len(self.surface)} points, baked '
                               f'table has {len(self.response)}')
        if not np.isfinite(self.shape_constant) or self.shape_constant <= 0:
            raise InvalidInput(f'ContactModel.shape_constant: must be > 0 m, got '
                               f'{self.shape_constant}')
        check_decay(self.shape_decay, 'ContactModel.shape_decay')
        check_decay_law(self.shape_decay_law, 'ContactModel.shape_decay_law')
        check_near(self.shape_near, 'ContactModel.shape_near')


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


def version_of_path(path) -> Optional[int]:
    """Version in a model file's name (``model-v000042.npz`` -> 42), or ``None``."""
    m = _NAME.match(Path(path).name)
    return int(m.group(1)) if m else None


def _header(model: ContactModel) -> dict:
    header = {
        'format': FORMAT, 'version': int(model.version),
        'shape_constant': float(model.shape_constant), 'frame': model.surface.frame,
        'shape_decay': float(model.shape_decay) if np.isfinite(model.shape_decay) else None,
        'effects': dict(model.effects), 'meta': dict(model.meta),
        'response_version': int(model.response.version), 'response_meta': model.response.meta,
    }
    if model.shape_decay_law != 'fixed':   # absent means 'fixed' (files from before the law)
        header['shape_decay_law'] = model.shape_decay_law
    if model.shape_near != 'paper':       # absent means 'paper' (files from before the field)
        header['shape_near'] = model.shape_near
    return header


def _arrays(model: ContactModel) -> dict:
    arrays = {
        'points': model.surface.points, 'normals': model.surface.normals,
        'colors': model.surface.colors, 'depths': model.response.depths,
        'forces': model.response.forces, 'slopes': model.response.slopes,
    }
    if model.response.std is not None:
        arrays['std'] = model.response.std
    return arrays


def content_digest(model: ContactModel) -> str:
    """SHA-256 (hex) of everything in ``model`` but its version: equal digests, same answers.

    Covers every array (dtype, shape and bytes) and the header (shape constant and decay,
    frame, effects, meta, the response's version and meta) in a canonical JSON form.
    """
    digest = hashlib.sha256()
    header = _header(model)
    del header['version']
    digest.update(json.dumps(header, sort_keys=True, default=str).encode())
    for name, array in sorted(_arrays(model).items()):
        array = np.ascontiguousarray(array)
        digest.update(f'{name}:{array.dtype.str}:{array.shape}'.encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def _versions_on_disk(directory: Path) -> List[int]:
    """Versions of model files in ``directory`` and in its quarantine."""
    found = []
    for folder in (directory, directory / QUARANTINE):
        if folder.is_dir():
            for p in folder.iterdir():
                m = _NAME.match(p.name.split('.npz')[0] + '.npz')
                if m:
                    found.append(int(m.group(1)))
    return found


def _stored_counter(path: Path) -> Optional[int]:
    """Return ``highest`` of ``versions.json``; ``None`` (and a warning) if implausible.

    Implausible: not a whole number (a string, ``NaN``, ``Infinity``, ``1e400``, ``2.5``),
    negative, or above :data:`MAX_COUNTER` (a hand edit; believing it would name the next
    file ``model-v1000...0.npz`` or fail to convert).
    """
    if not path.is_file():
        return None
    try:
        stored = read_json(path, 'version counter')['highest']
    except (DataError, KeyError) as exc:
        LOG.warning('%s: ignored (%s); the model files bound the version', path, exc)
        return None
    whole = (isinstance(stored, int) and not isinstance(stored, bool)) or (
        isinstance(stored, float) and np.isfinite(stored) and stored.is_integer())
    if not whole or not 0 <= stored <= MAX_COUNTER:
        LOG.warning('%s: ignored implausible counter %r (not a whole number in 0..%d); the '
                    'model files bound the version', path, stored, MAX_COUNTER)
        return None
    return int(stored)


def highest_version(directory) -> int:
    """Highest model version ``directory`` has ever held (files, quarantine, persisted), or -1.

    Reads ``versions.json`` when present, readable and plausible (:func:`_stored_counter`;
    otherwise it is ignored with a warning: the files still bound the answer from below).
    """
    directory = Path(directory)
    highest = max(_versions_on_disk(directory), default=-1)
    stored = _stored_counter(directory / VERSIONS)
    return highest if stored is None else max(highest, stored)


def _stored_digest(path: Path) -> Optional[str]:
    """Content digest of the model file at ``path``; ``None`` if it cannot be read."""
    try:
        return content_digest(load_model(path))
    except DataError:
        return None


def save_model(model: ContactModel, directory) -> Path:
    """Write ``model`` atomically into ``directory`` (created if needed); return its path.

    The version is kept when it is free and above every version the directory has held, or
    when the file of that version holds the same content (then nothing is written: a restarted
    learner reproducing a model gets the same file). The newest file holding the same content
    is returned as it is too (a restarted learner whose shape constant was restored reproduces
    the model last saved under a bumped version). Otherwise the model is saved under the
    next free version, so a version never names two different models and never goes down;
    the returned path (and the file's header) carry the version actually used.

    Raises:
        OSError: the directory or the file cannot be written.

    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    digest = content_digest(model)
    wanted = model_path(directory, model.version)
    if wanted.is_file() and _stored_digest(wanted) == digest:
        return wanted
    newest = latest_model_path(directory)
    if newest is not None and newest != wanted and _stored_digest(newest) == digest:
        return newest
    highest = highest_version(directory)
    if model.version <= highest:
        new = highest + 1
        LOG.warning('model v%d: that version is taken by other content or not above the '
                    'highest saved (v%d); saving as v%d', model.version, highest, new)
        model = dataclasses.replace(model, version=new)
    header = dict(_header(model), content_sha256=digest)
    arrays = dict(_arrays(model),
                  header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8))
    path = atomic_write(model_path(directory, model.version),
                        lambda fh: np.savez(fh, **arrays))
    atomic_write(directory / VERSIONS, lambda fh: json.dump(
        {'highest': max(int(model.version), highest)}, fh), binary=False)
    return path


def _header_version(header: dict, path: Path) -> int:
    """Return the header's version: a whole number >= 0, the one in the file's name if any.

    Raises:
        ValueError: anything else (a version "from the future" would pin every reader that
            only looks for newer files).

    """
    version = header['version']
    if isinstance(version, bool) or not isinstance(version, int) or version < 0:
        raise ValueError(f'header version {version!r} is not a whole number >= 0')
    named = version_of_path(path)
    if named is not None and version != named:
        raise ValueError(f'header version {version} is not the version in the file name '
                         f'({named})')
    return version


def _check_effects(effects: Mapping, path: Path) -> None:
    """Refuse effects the service could not apply, as :func:`WrenchServer.swap` would.

    Raises:
        UnsupportedModel: an effect name this build does not know (a newer learner's).
        InvalidInput: malformed parameters of a known effect.

    """
    known = set(LIBRARY) | set(PROBE_EFFECTS)
    unknown = sorted(str(name) for name in effects if name not in known)
    if unknown:
        raise UnsupportedModel(f'{path}: effect(s) {unknown} unknown to this build (a newer '
                               f'learner\'s model?); known: {", ".join(sorted(known))}')
    ForwardTerms.of(effects)


def _check_meta(meta: Mapping) -> None:
    """Refuse a ``surface_corrected`` entry the service could not read (a list of names).

    Raises:
        ValueError: ``meta['surface_corrected']`` present but not a list of effect names.

    """
    done = meta.get('surface_corrected', [])
    if not isinstance(done, list) or not all(isinstance(name, str) for name in done):
        raise ValueError(f'meta.surface_corrected: expected a list of effect names, got '
                         f'{done!r}')


def load_model(path) -> ContactModel:
    """Load a model file.

    Every read error (a truncated or empty file, not a zip archive, a missing array, a bad
    header or one of the wrong types, a header version that is not a whole number >= 0 or
    differs from the one in the file's name, content that does not match the header's
    SHA-256, malformed effects) becomes a :class:`DataError` naming the file.

    Raises:
        UnsupportedModel: an intact file naming an effect this build does not know.
        DataError: missing file, not a model file, unknown format, or corrupt content.

    """
    path = Path(path)
    if not path.is_file():
        raise DataError(f'model file not found: {path}')
    try:
        with np.load(path, allow_pickle=False) as z:
            check_npz_size(z, path, 'contact model')
            header = json.loads(bytes(z['header']).decode())
            if not isinstance(header, dict) or header.get('format') != FORMAT:
                found = header.get('format') if isinstance(header, dict) else header
                raise DataError(f'{path}: unknown model format {found!r}')
            surface = Surface(points=z['points'], normals=z['normals'], colors=z['colors'],
                              frame=header.get('frame', 'base'))
            response = BakedResponse(depths=z['depths'], forces=z['forces'], slopes=z['slopes'],
                                     std=z['std'] if 'std' in z.files else None,
                                     version=header.get('response_version', 0),
                                     meta=header.get('response_meta', {}))
        model = ContactModel(surface=surface, response=response,
                             shape_constant=float(header['shape_constant']),
                             version=_header_version(header, path),
                             shape_decay=float(header.get('shape_decay') or float('inf')),
                             effects=header.get('effects', {}), meta=header.get('meta', {}),
                             shape_decay_law=header.get('shape_decay_law', 'fixed'),
                             shape_near=header.get('shape_near', 'paper'))
        stored = header.get('content_sha256')
        if stored is not None and stored != content_digest(model):
            raise DataError(f'{path}: content does not match its SHA-256 (altered or corrupt)')
        _check_meta(model.meta)
        _check_effects(model.effects, path)
    except DataError:
        raise
    except Exception as exc:  # noqa: BLE001 - zipfile, zlib, numpy, json: many error types
        raise DataError(f'{path}: corrupt or unreadable model file: '
                        f'{type(exc).__name__}: {exc}') from exc
    return model


def quarantine_file(path, reason: str) -> Optional[Path]:
    """Move ``path`` into ``quarantine/`` beside it, with ``<name>.reason.txt``; log why.

    A name already in the quarantine gets a numbered suffix. Returns the new path, or ``None``
    when the file was gone already (another reader moved it).

    Raises:
        OSError: the quarantine folder cannot be created or written.

    """
    path = Path(path)
    folder = path.parent / QUARANTINE
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / path.name
    n = 0
    while target.exists():
        n += 1
        target = folder / f'{path.name}.{n}'
    try:
        os.replace(path, target)
    except FileNotFoundError:
        return None
    stamp = time.strftime('%Y-%m-%dT%H:%M:%S%z')
    atomic_write(folder / f'{target.name}.reason.txt',
                 lambda fh: fh.write(f'{stamp} {path}: {reason}\n'), binary=False)
    LOG.error('quarantined %s as %s: %s', path, target, reason)
    return target


_UNSUPPORTED: Dict[Path, Tuple[int, int, int]] = {}
"""Files skipped as :class:`UnsupportedModel` -> their (inode, mtime ns, size) when read."""


def _identity(path: Path) -> Optional[Tuple[int, int, int]]:
    """(inode, mtime ns, size) of ``path``: a rewritten or replaced file gets another."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def load_latest_model(directory, newer_than: int = -1,
                      log: Optional[Callable[[str], None]] = None
                      ) -> Optional[Tuple[ContactModel, Path]]:
    """Load the newest valid model in ``directory`` with a version above ``newer_than``.

    Files that cannot be read are quarantined (:func:`quarantine_file`) and the next older
    version is tried, down to ``newer_than``: a corrupt newest file never hides an older
    valid one. An intact file this build cannot serve (:class:`UnsupportedModel`) is skipped
    and left in place; it is reported once and not read again until it changes.

    Args:
        directory: the model directory.
        newer_than: the version already held (-1: none); older files are not read.
        log: called with one message per quarantined or newly skipped file (a node's logger).

    Returns:
        ``(model, path)``, or ``None`` when no valid file is newer than ``newer_than``.

    A bad file that cannot be moved (a read-only folder) is skipped and reported.

    """
    directory = Path(directory)
    if not directory.is_dir():
        return None
    candidates = []
    for p in directory.iterdir():
        m = _NAME.match(p.name)
        if m and int(m.group(1)) > newer_than:
            candidates.append((int(m.group(1)), p))
    for _, path in sorted(candidates, reverse=True):
        identity = _identity(path)
        if identity is not None and _UNSUPPORTED.get(path) == identity:
            continue
        try:
            return load_model(path), path
        except UnsupportedModel as exc:
            _UNSUPPORTED[path] = identity
            note = f'skipping {path.name}, left in place: {exc}'
            LOG.warning(note)
        except DataError as exc:
            try:
                moved = quarantine_file(path, str(exc))
                note = None if moved is None else f'quarantined {path.name} as {moved}: {exc}'
            except OSError as move_error:
                note = f'skipping {path.name} ({exc}); cannot quarantine it: {move_error}'
                LOG.error(note)
        if log is not None and note is not None:
            log(note)
    return None


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


def save_shape(directory, shape_constant: float, shape_decay: float = float('inf'),
               uncertainty: Optional[Mapping] = None, decay_law: str = DECAY_LAW,
               near: str = 'paper') -> Path:
    """Persist the shape function set at run time beside the models (``shape.json``, atomic).

    Args:
        directory: the model directory (created if needed).
        shape_constant: ``c``, metres (> 0).
        shape_decay: decay length ``L``, metres (``inf``: none, stored as ``null``).
        uncertainty: the wrench's uncertainty sources from the same calibration
            (:func:`~pointforce_ros.contact.uncertainty.uncertainty_sources`; ``None``: none).
        decay_law: the decay law ``(c, L)`` were identified under (:class:`ContactModel`).
        near: the near field ``(c, L)`` were identified with (:class:`ContactModel`).

    Raises:
        InvalidInput: ``c`` not finite and positive, ``L`` neither positive nor ``inf``,
            malformed uncertainty sources or an unknown decay law or near field.
        OSError: the file cannot be written.

    """
    if not (np.isfinite(shape_constant) and shape_constant > 0):
        raise InvalidInput(f'shape_constant: must be > 0 m, got {shape_constant}')
    decay = check_decay(shape_decay, 'shape_decay')
    check_decay_law(decay_law)
    check_near(near)
    body = {'shape_constant': float(shape_constant),
            'shape_decay': float(decay) if np.isfinite(decay) else None,
            'shape_decay_law': decay_law, 'shape_near': near,
            'uncertainty': uncertainty_sources(**dict(uncertainty or {}))}
    return atomic_write(Path(directory) / SHAPE, lambda fh: json.dump(body, fh), binary=False)


def load_shape(directory) -> Optional[Tuple[float, float]]:
    """Read ``shape.json`` of ``directory``: ``(c, L)`` in metres (``L`` inf: none), or ``None``.

    Raises:
        DataError: the file exists but cannot be read or holds invalid values.

    """
    path = Path(directory) / SHAPE
    if not path.is_file():
        return None
    body = read_json(path, 'shape file')
    try:
        c = float(body['shape_constant'])
        decay = body.get('shape_decay')
        decay = float('inf') if decay is None else float(decay)
        if not (np.isfinite(c) and c > 0):
            raise ValueError(f'shape_constant {c} is not > 0')
        check_decay(decay, 'shape_decay')
    except (OSError, ValueError, KeyError, TypeError, AttributeError, InvalidInput) as exc:
        raise DataError(f'{path}: unreadable shape file: {type(exc).__name__}: {exc}') from exc
    return c, decay


def _shape_entry(directory, key: str, absent: str, old: str, check: Callable, what: str) -> str:
    """Return ``key`` of ``shape.json``: ``absent`` without a file, ``old`` without the key.

    Raises:
        DataError: the file exists but cannot be read or ``check`` refuses the value.

    """
    path = Path(directory) / SHAPE
    if not path.is_file():
        return absent
    value = read_json(path, 'shape file').get(key, old)
    try:
        return check(value, key)
    except InvalidInput as exc:
        raise DataError(f'{path}: unknown {what}: {exc}') from exc


def load_shape_law(directory) -> str:
    """Return the decay law of ``shape.json`` (:func:`save_shape`).

    ``'fixed'`` for a file from before the law was stored,
    :data:`~pointforce_ros.contact.simulator.DECAY_LAW` when there is no file.

    Raises:
        DataError: the file exists but cannot be read or names an unknown law.

    """
    return _shape_entry(directory, 'shape_decay_law', DECAY_LAW, 'fixed', check_decay_law,
                        'decay law')


def load_shape_near(directory) -> str:
    """Return the near field of ``shape.json`` (:func:`save_shape`); ``'paper'`` without one.

    Raises:
        DataError: the file exists but cannot be read or names an unknown near field.

    """
    return _shape_entry(directory, 'shape_near', 'paper', 'paper', check_near, 'near field')


def load_shape_uncertainty(directory) -> dict:
    """Read the uncertainty sources of ``shape.json`` (:func:`save_shape`); ``{}`` if none.

    Raises:
        DataError: the file exists but its sources cannot be read or are invalid.

    """
    path = Path(directory) / SHAPE
    if not path.is_file():
        return {}
    body = read_json(path, 'shape file')
    try:
        sources = body.get('uncertainty') or {}
        unknown = set(sources) - set(SOURCE_KEYS)
        if unknown:
            raise ValueError(f'unknown uncertainty sources {sorted(unknown)}')
        return uncertainty_sources(**sources)
    except (OSError, ValueError, TypeError, AttributeError, InvalidInput) as exc:
        raise DataError(f'{path}: unreadable uncertainty sources: {type(exc).__name__}: '
                        f'{exc}') from exc


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
            check_npz_size(z, path, 'surface')
            return Surface(points=z['points'], normals=z['normals'], colors=z['colors'],
                           frame=bytes(z['frame']).decode() or 'base')
    except Exception as exc:  # noqa: BLE001 - zipfile, zlib, numpy: many error types
        raise DataError(f'{path}: corrupt or unreadable surface file: {exc}') from exc
