"""Exception hierarchy of pointforce_ros, and the readers that turn file faults into it.

:func:`reading` and :func:`read_json` turn every way of failing to read a file into a
:class:`DataError` naming the file.

Every error the package raises on purpose derives from :class:`PointforceError`, so a node can
catch one type, turn it into ``success=False`` with the message, and keep serving.
"""

import json
from contextlib import contextmanager
from pathlib import Path
from typing import Optional


class PointforceError(Exception):
    """Base class of every error raised on purpose by pointforce_ros."""


class InvalidInput(PointforceError, ValueError):
    """Input data is malformed: NaN, wrong shape, empty, degenerate, wrong message layout."""


class UnsafeCommand(PointforceError, ValueError):
    """A motion or poke request is outside the configured safety limits."""


class NotConverged(PointforceError, RuntimeError):
    """An iterative solver (FEM Newton, LCP, optimiser) did not reach its tolerance."""


class DataError(PointforceError, IOError):
    """Stored data (bag, poke store, model file) is missing, corrupt or of an unknown version."""


class DeviceFault(PointforceError, RuntimeError):
    """The robot or a sensor faulted: protective stop, lost connection, stalled F/T stream."""


class ModelNotReady(PointforceError, RuntimeError):
    """A query needs a fitted force-response model and none is available yet."""


TEXT_ENCODING = 'utf-8-sig'
"""Encoding of the text files the package reads: UTF-8, with the byte-order mark that
spreadsheet programs put in front of an exported CSV dropped."""


@contextmanager
def reading(path, what: str):
    """Turn every error raised inside the block into a :class:`DataError` about ``path``.

    A file a user or another process wrote can fail in more ways than any one ``except``
    clause lists: not UTF-8 (``UnicodeDecodeError``), JSON or YAML nested past the recursion
    limit (``RecursionError``), an empty or truncated ``.npz`` (``EOFError``, ``BadZipFile``),
    a top level of another type (``TypeError``, ``AttributeError``), a missing key. Wrap the
    read *and* the parse of one file in this block; a :class:`PointforceError` raised inside
    (a check of the content) passes through unchanged.

    Raises:
        DataError: ``'<path>: unreadable <what>: <error type>: <message>'``.

    """
    try:
        yield
    except PointforceError:
        raise
    except Exception as exc:  # noqa: BLE001 - codecs, json, yaml, zipfile, numpy: many types
        raise DataError(f'{path}: unreadable {what}: {type(exc).__name__}: {exc}') from exc


NPZ_BYTES = 512 << 20
"""Largest uncompressed content of an ``.npz`` the package reads, bytes (a surface of 7 M
points; the cell's models and surfaces are a few to tens of MB): a compressed file of a few MB
can hold gigabytes of zeros, and ``np.load`` inflates each array whole."""


def check_npz_size(archive, path, what: str, limit: Optional[int] = None) -> None:
    """Refuse an open ``np.load`` archive whose arrays inflate past ``limit`` bytes.

    ``limit`` None: :data:`NPZ_BYTES`.

    Reads only the zip directory, so a zip bomb is refused before any array is inflated.

    Raises:
        DataError: ``'<path>: <n> MiB of arrays uncompressed (limit ...)'``.

    """
    limit = NPZ_BYTES if limit is None else limit
    size = sum(info.file_size for info in archive.zip.infolist())
    if size > limit:
        raise DataError(f'{path}: {size / 2 ** 20:.0f} MiB of arrays uncompressed (limit '
                        f'{limit / 2 ** 20:.0f} MiB): not a {what} this node can hold')


def check_choice(value, choices, name: str) -> str:
    """Return ``value`` if it is one of the text ``choices``.

    Raises:
        InvalidInput: it is not (the message starts with ``name`` and lists ``choices``).

    """
    if not isinstance(value, str) or value not in tuple(choices):
        raise InvalidInput(f'{name}: must be one of {tuple(choices)}, got {value!r}')
    return str(value)


def read_json(path, what: str) -> dict:
    """Read a JSON file whose top level is an object; every fault is a :class:`DataError`.

    Raises:
        DataError: missing, unreadable, not UTF-8, not JSON, nested past the recursion limit,
            or a top level that is not an object.

    """
    with reading(path, what):
        body = json.loads(Path(path).read_text(encoding=TEXT_ENCODING))
    if not isinstance(body, dict):
        raise DataError(f'{path}: unreadable {what}: the top level is a {type(body).__name__}, '
                        'not a JSON object')
    return body
