"""Model files: every read error quarantined with a reason, versions never reused or lowered.

Issue 16: a truncated model file crashed ``contact_wrench`` (``zipfile.BadZipFile``; an empty one
``EOFError``) at every restart; a restarted service served nothing although older valid versions
were on disk; after a restart ``model-v000004.npz`` was overwritten by a different model.
"""

import json
import logging
import zipfile

import numpy as np
import pytest

from pointforce_ros import errors
from pointforce_ros.errors import DataError
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import (content_digest, ContactModel, highest_version,
                                        load_latest_model, load_model, load_surface,
                                        model_path, QUARANTINE, save_model, save_surface,
                                        UnsupportedModel)
from pointforce_ros.pokes.store import load_recovery
from pointforce_ros.model.serving import WrenchServer

MODEL = patch_contact_model(spacing=0.006)


def _other(version, c=0.005):
    """The same surface and table with another shape constant: different content."""
    return ContactModel(surface=MODEL.surface, response=MODEL.response, shape_constant=c,
                        version=version)


def _truncate(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _empty(path):
    path.write_bytes(b'')


def _garbage(path):
    path.write_bytes(np.random.default_rng(16).bytes(4096))


def _missing_array(path):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k != 'forces'}
    with open(path, 'wb') as fh:
        np.savez(fh, **arrays)


def _bad_header(path):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays['header'] = np.frombuffer(b'{"format": "pointforce-contact-model/1", "vers',
                                     dtype=np.uint8)
    with open(path, 'wb') as fh:
        np.savez(fh, **arrays)


def _altered(path):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays['forces'] = arrays['forces'] * 1.01   # same layout, header hash now wrong
    with open(path, 'wb') as fh:
        np.savez(fh, **arrays)


def _header_list(path):
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays['header'] = np.frombuffer(b'[1, 2]', dtype=np.uint8)
    with open(path, 'wb') as fh:
        np.savez(fh, **arrays)


BREAKAGES = [_truncate, _empty, _garbage, _missing_array, _bad_header, _altered, _header_list]


@pytest.mark.parametrize('breakage', BREAKAGES)
def test_every_read_error_is_a_data_error(tmp_path, breakage):
    path = save_model(MODEL, tmp_path)
    breakage(path)
    with pytest.raises(DataError, match=str(path.name)):
        load_model(path)


@pytest.mark.parametrize('breakage', BREAKAGES)
def test_a_corrupt_newest_file_is_quarantined_and_the_last_good_one_loaded(
        tmp_path, breakage, caplog):
    good = save_model(MODEL, tmp_path)
    bad = save_model(_other(2), tmp_path)
    breakage(bad)
    with caplog.at_level(logging.ERROR, logger='pointforce_ros.model.files'):
        model, path = load_latest_model(tmp_path)
    assert path == good and model.version == 1
    moved = tmp_path / QUARANTINE / bad.name
    assert not bad.exists() and moved.is_file()
    reason = (tmp_path / QUARANTINE / f'{bad.name}.reason.txt').read_text()
    assert bad.name in reason and 'DataError' not in reason and len(reason) > 40
    assert any(bad.name in r.getMessage() for r in caplog.records)
    # a server restarted on the folder serves the last good model
    server = WrenchServer()
    assert server.load_latest(tmp_path) and server.version == 1
    # a later save does not reuse the quarantined version
    assert save_model(_other(2, c=0.006), tmp_path) == model_path(tmp_path, 3)


def test_the_server_keeps_its_model_and_reports_a_corrupt_newer_file(tmp_path):
    save_model(MODEL, tmp_path)
    server = WrenchServer()
    assert server.load_latest(tmp_path) and server.version == 1
    bad = save_model(_other(2), tmp_path)
    _truncate(bad)
    notes = []
    assert not server.load_latest(tmp_path, log=notes.append)
    assert server.version == 1 and len(notes) == 1 and bad.name in notes[0]
    assert not server.load_latest(tmp_path, log=notes.append) and len(notes) == 1


def test_a_version_never_names_two_models_and_never_goes_down(tmp_path):
    v4 = save_model(_other(4), tmp_path)
    original = v4.read_bytes()
    # the same content again (a restarted learner): the same file, nothing written
    assert save_model(_other(4), tmp_path) == v4 and v4.read_bytes() == original
    # different content under a taken version: the next free version, v4 untouched
    v5 = save_model(_other(4, c=0.006), tmp_path)
    assert v5 == model_path(tmp_path, 5) and v4.read_bytes() == original
    assert load_model(v5).version == 5 and load_model(v5).shape_constant == 0.006
    # a lower version than the highest (a restart that lost a shape-constant update)
    v6 = save_model(_other(3, c=0.007), tmp_path)
    assert v6 == model_path(tmp_path, 6)
    # persisted: files removed, the highest version survives in versions.json
    v5.unlink()
    v6.unlink()
    assert json.loads((tmp_path / 'versions.json').read_text()) == {'highest': 6}
    assert highest_version(tmp_path) == 6
    assert save_model(_other(5, c=0.008), tmp_path) == model_path(tmp_path, 7)
    # and every file's header carries its content hash
    with np.load(v4) as z:
        header = json.loads(bytes(z['header']).decode())
    assert header['content_sha256'] == content_digest(_other(4))
    assert content_digest(_other(4)) != content_digest(_other(4, c=0.006))
    assert content_digest(_other(4)) == content_digest(_other(9))


def test_files_without_a_hash_still_load_and_compare_by_content(tmp_path):
    """Files written before the hash existed load, and an identical save reuses them."""
    path = save_model(MODEL, tmp_path)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(bytes(arrays['header']).decode())
    del header['content_sha256']
    arrays['header'] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    with open(path, 'wb') as fh:
        np.savez(fh, **arrays)
    (tmp_path / 'versions.json').unlink()
    before = path.read_bytes()
    np.testing.assert_array_equal(load_model(path).response.forces, MODEL.response.forces)
    assert save_model(MODEL, tmp_path) == path and path.read_bytes() == before
    assert zipfile.is_zipfile(path)


def _edit_header(path, edit, drop_hash=False):
    """Rewrite the header of the file at ``path`` with ``edit(header)``; the hash as written."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(bytes(arrays['header']).decode())
    edit(header)
    if drop_hash:
        del header['content_sha256']
    arrays['header'] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    with open(path, 'wb') as fh:
        np.savez(fh, **arrays)


@pytest.mark.parametrize('key, value, drop_hash', [
    ('meta', 'xy', False), ('effects', 5, False), ('meta', [1, 2], False),
    ('effects', 5, True), ('meta', {'surface_corrected': 5}, True)])
def test_a_header_entry_of_the_wrong_type_is_quarantined_and_the_older_model_served(
        tmp_path, key, value, drop_hash):
    """Audit D1: ``"meta": "xy"`` in the newest file raised a bare ValueError naming no file.

    Without a hash (a file from before it) nothing else catches the type.
    """
    good = save_model(MODEL, tmp_path)
    bad = save_model(_other(2), tmp_path)
    _edit_header(bad, lambda h: h.__setitem__(key, value), drop_hash=drop_hash)
    with pytest.raises(DataError, match=bad.name):
        load_model(bad)
    server = WrenchServer()
    notes = []
    assert server.load_latest(tmp_path, log=notes.append)
    assert server.version == 1 and server.loaded_path == good
    assert (tmp_path / QUARANTINE / bad.name).is_file() and not bad.exists()
    assert len(notes) == 1 and bad.name in notes[0]


@pytest.mark.parametrize('version', [10 ** 12, -7, 2.5, 1.0, '1', True])
def test_a_header_version_other_than_the_file_name_is_refused_and_pins_nothing(
        tmp_path, version):
    """Audit D2: a v1 file whose header said 10**12 pinned the server: v2, v3 never served."""
    first = save_model(MODEL, tmp_path)
    _edit_header(first, lambda h: h.__setitem__('version', version))
    with pytest.raises(DataError, match=first.name):
        load_model(first)
    server = WrenchServer()
    assert not server.load_latest(tmp_path) and server.version == -1
    assert (tmp_path / QUARANTINE / first.name).is_file()
    newer = save_model(_other(2, c=0.006), tmp_path)
    assert server.load_latest(tmp_path) and server.version == 2
    assert server.loaded_path == newer and load_model(newer).shape_constant == 0.006


def test_a_model_with_an_effect_unknown_to_this_build_is_skipped_not_quarantined(tmp_path):
    """Audit D1b: the file loaded, then the server refused it on every poll and served nothing.

    A newer learner may write an effect this build does not know: the file stays where it is
    (for a build that knows it), is reported once, and the older valid model is served.
    """
    good = save_model(MODEL, tmp_path)
    newer = save_model(_other(2), tmp_path)
    _edit_header(newer, lambda h: h.__setitem__('effects', {'bogus_effect': {'k': 1.0}}),
                 drop_hash=True)
    with pytest.raises(UnsupportedModel, match=f'{newer.name}.*bogus_effect'):
        load_model(newer)
    server = WrenchServer()
    notes = []
    assert server.load_latest(tmp_path, log=notes.append)
    assert server.version == 1 and server.loaded_path == good
    assert newer.is_file() and not (tmp_path / QUARANTINE).exists()
    assert len(notes) == 1 and newer.name in notes[0] and 'bogus_effect' in notes[0]
    assert not server.load_latest(tmp_path, log=notes.append) and len(notes) == 1
    # its version stays taken: the next save does not overwrite it
    assert save_model(_other(2, c=0.006), tmp_path) == model_path(tmp_path, 3)


@pytest.mark.parametrize('counter', ['Infinity', '-Infinity', 'NaN', '1e400', '1e300',
                                     '2.5', '"12"', '-3', 'true'])
def test_an_implausible_version_counter_is_ignored_and_the_names_on_disk_bound_it(
        tmp_path, counter, caplog):
    """Audit D5: ``{"highest": Infinity}`` raised a bare OverflowError in save_model."""
    save_model(MODEL, tmp_path)
    (tmp_path / 'versions.json').write_text(f'{{"highest": {counter}}}')
    with caplog.at_level(logging.WARNING, logger='pointforce_ros.model.files'):
        assert highest_version(tmp_path) == 1
    assert any('versions.json' in r.getMessage() for r in caplog.records)
    assert save_model(_other(2), tmp_path) == model_path(tmp_path, 2)
    assert highest_version(tmp_path) == 2


def _inflating(path, name, megabytes):
    """Add ``name``: an array of ``megabytes`` MiB of zeros (a few kB compressed) to ``path``."""
    with zipfile.ZipFile(path, 'a', compression=zipfile.ZIP_DEFLATED) as z:
        with z.open(f'{name}.npy', 'w') as fh:
            np.lib.format.write_array_header_1_0(
                fh, dict(descr='<f8', fortran_order=False, shape=(megabytes << 17,)))
            for _ in range(megabytes):
                fh.write(bytes(1 << 20))


def test_files_that_inflate_past_the_limit_are_refused_before_an_array_is_read(
        tmp_path, monkeypatch):
    """Audit 39: a contact model, a surface or a recovery file of a few MB could hold
    gigabytes of zeros, and each was inflated whole at start-up."""
    monkeypatch.setattr(errors, 'NPZ_BYTES', 4 << 20)
    model = save_model(MODEL, tmp_path / 'models')
    surface = tmp_path / 'surface.npz'
    save_surface(MODEL.surface, surface)
    recovery = tmp_path / 'poke-000001.npz'
    np.savez(recovery, header=np.frombuffer(b'{}', dtype=np.uint8))
    assert load_model(model).version == MODEL.version   # within the limit: read as before
    np.testing.assert_array_equal(load_surface(surface).points, MODEL.surface.points)
    for path, load in ((model, load_model), (surface, load_surface),
                       (recovery, load_recovery)):
        _inflating(path, 'zeros', 6)
        assert path.stat().st_size < (1 << 20)
        with pytest.raises(DataError, match='MiB of arrays uncompressed'):
            load(path)
