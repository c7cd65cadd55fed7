"""Every file the package reads fails as a DataError, whatever is in it.

A node survives any file it reads only if each reader turns every way the file can be wrong
into the one error type the node catches. Each reader below gets the same damaged contents:
empty, random bytes, Latin-1 text, an archive cut in half, an archive of other arrays, JSON
and YAML whose top level is not a mapping, and JSON nested past Python's recursion limit.
"""

import io
import json
import shutil

import numpy as np
import pytest

from pointforce_ros.errors import DataError, PointforceError, read_json, reading
from pointforce_ros.lab.model_store import load_response_model
from pointforce_ros.model import files as model_files
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.pokes.table import read_poke_table, TABLE_COLUMNS
from pointforce_ros.pokes.trials import load_probe_trials
from pointforce_ros.replica.contour import read_camera_views
from pointforce_ros.replica.data import load_pokes as load_replica_pokes
from pointforce_ros.replica.mesh import read_vtk
from pointforce_ros.replica.replica import load_replica, read_description
from pointforce_ros.sim.objects import load_object
from pointforce_ros.sim.scenario import load_scenario
from pointforce_ros.deformation.store import load_model as load_deformation_model


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _contents():
    rng = np.random.default_rng(29)
    archive = _npz(a=np.arange(5.0))
    return {
        'empty': b'',
        'random bytes': rng.bytes(400),
        'latin-1 text': 'poke_id,t\nb\xe9,1\n'.encode('latin-1'),
        'half an archive': archive[:len(archive) // 2],
        'other arrays': archive,
        'json list': b'[1, 2, 3]',
        'json null': b'null',
        'yaml scalar': b'42\n',
        'nested past the recursion limit': b'[' * 100_000,
    }


CONTENTS = _contents()

# (reader, file name, whether the reader takes the folder rather than the file)
READERS = {
    'poke table': (read_poke_table, 'pokes.csv', False),
    'VTK mesh': (lambda p: read_vtk(p, 0.01), 'body.vtk', False),
    'object YAML': (load_object, 'object.yaml', False),
    'scenario YAML': (load_scenario, 'scenario.yaml', False),
    'shape constant': (model_files.load_shape, 'shape.json', True),
    'shape decay law': (model_files.load_shape_law, 'shape.json', True),
    'shape near field': (model_files.load_shape_near, 'shape.json', True),
    'shape uncertainty': (model_files.load_shape_uncertainty, 'shape.json', True),
    'response model JSON': (load_response_model, 'model.json', False),
    'probe trial index': (load_probe_trials, 'probes.json', True),
    'probe trial arrays': (load_probe_trials, 'probes.npz', True),
    'replica description': (read_description, 'replica.json', True),
    'replica': (load_replica, 'replica.json', True),
    'deformation model': (load_deformation_model, 'deformation-v000001.npz', False),
    'replica poke fixture': (load_replica_pokes, 'pokes.npz', False),
    'camera views': (read_camera_views, 'views.npz', False),
}


@pytest.mark.parametrize('reader', sorted(READERS))
def test_every_reader_turns_every_damaged_file_into_a_data_error(tmp_path, reader):
    fn, name, takes_folder = READERS[reader]
    wrong = {}
    for label, data in CONTENTS.items():
        folder = tmp_path / label.replace(' ', '_')
        folder.mkdir()
        (folder / name).write_bytes(data)
        if name == 'probes.json':      # the index beside a valid arrays file
            (folder / 'probes.npz').write_bytes(_npz(a=np.zeros(1)))
        if name == 'probes.npz':       # the arrays beside a valid index
            (folder / 'probes.json').write_text(json.dumps({'trials': [
                {'trial': 0, 'kind': 'line'}]}))
        try:
            fn(folder if takes_folder else folder / name)
        except DataError as exc:
            assert str(folder) in str(exc), f'{label}: the message does not name the file'
        except PointforceError:
            pass                      # a check of the content (InvalidInput) is fine too
        except Exception as exc:      # noqa: BLE001 - the test's point
            wrong[label] = f'{type(exc).__name__}: {exc}'[:120]
    assert not wrong, f'{reader}: errors a node would not catch: {wrong}'


def test_reading_passes_content_checks_through_and_wraps_everything_else(tmp_path):
    with pytest.raises(DataError, match=r'f\.bin: unreadable thing: RecursionError'):
        with reading(tmp_path / 'f.bin', 'thing'):
            raise RecursionError('deep')
    with pytest.raises(DataError, match='MemoryError'):
        with reading(tmp_path / 'f.bin', 'thing'):
            raise MemoryError()
    with pytest.raises(PointforceError, match='^content check$') as info:
        with reading(tmp_path / 'f.bin', 'thing'):
            raise PointforceError('content check')
    assert type(info.value) is PointforceError


def test_read_json_names_the_top_level_it_found(tmp_path):
    path = tmp_path / 'x.json'
    path.write_text('[1]')
    with pytest.raises(DataError, match='top level is a list, not a JSON object'):
        read_json(path, 'thing')
    path.write_text('{"a": 1}')
    assert read_json(path, 'thing') == {'a': 1}


def _table_text(normal=(0.0, 0.0, 1.0)) -> str:
    rows = [','.join(TABLE_COLUMNS)]
    for poke in ('a', 'b'):
        for i in range(6):
            rows.append(f'{poke},{0.1 * i},0.01,0.02,0.03,{normal[0]},{normal[1]},{normal[2]},'
                        f'{0.001 * i},{2.0 * i}')
    return '\n'.join(rows) + '\n'


def test_a_spreadsheet_csv_with_a_byte_order_mark_reads_like_the_plain_one(tmp_path):
    plain, marked = tmp_path / 'plain.csv', tmp_path / 'marked.csv'
    plain.write_text(_table_text(), encoding='utf-8')
    marked.write_text(_table_text(), encoding='utf-8-sig')
    assert marked.read_bytes().startswith(b'\xef\xbb\xbf')
    a, b = read_poke_table(plain), read_poke_table(marked)
    assert [r.poke_id for r in b] == ['a', 'b']
    for ra, rb in zip(a, b):
        np.testing.assert_array_equal(ra.wrench, rb.wrench)
        np.testing.assert_array_equal(ra.tcp_pose, rb.tcp_pose)


def test_a_table_normal_of_zero_length_is_named(tmp_path):
    path = tmp_path / 'zero.csv'
    path.write_text(_table_text(normal=(0.0, 0.0, 0.0)))
    with pytest.raises(DataError, match=r'poke a: the normal \(nx, ny, nz\) has zero length'):
        read_poke_table(path)


@pytest.mark.parametrize('column', ['force', 'depth', 'poke_id'])
def test_a_table_with_a_repeated_column_is_refused_naming_it(tmp_path, column):
    """Audit D7: a repeated header column was read silently from its last copy."""
    lines = _table_text().splitlines()
    i = lines[0].split(',').index(column)
    rng = np.random.default_rng(7)
    extra = [f'{rng.uniform(0.0, 0.01):.6f}' for _ in lines[1:]]
    path = tmp_path / 'repeated.csv'
    path.write_text('\n'.join([f'{lines[0]},{column}'] + [
        f'{line},{line.split(",")[i] if column == "poke_id" else value}'
        for line, value in zip(lines[1:], extra)]) + '\n')
    with pytest.raises(DataError, match=f"repeated.csv: column '{column}' appears 2 times"):
        read_poke_table(path)


@pytest.mark.parametrize('poke_id', ['../../etc/x', '/tmp/x', '..'])
def test_a_table_poke_id_that_is_a_path_is_refused(tmp_path, poke_id):
    """Audit, path traversal: a table id such as '../../etc/x' became a record."""
    path = tmp_path / 'ids.csv'
    path.write_text(_table_text().replace('\na,', f'\n{poke_id},'))
    with pytest.raises(DataError, match='not a plain name'):
        read_poke_table(path)


@pytest.mark.parametrize('label', ['nested past the recursion limit', 'latin-1 text',
                                   'json list'])
def test_a_poke_store_rebuilds_over_a_damaged_index_or_counter(tmp_path, label):
    for name in (PokeStore.INDEX, PokeStore.IDS):
        root = tmp_path / name
        root.mkdir()
        (root / name).write_bytes(CONTENTS[label])
        store = PokeStore(root)
        assert list(store) == []
        assert store.next_id() == 'poke-000001'
        shutil.rmtree(root)


def test_the_replica_names_a_table_as_the_wrong_kind_of_file(tmp_path):
    # before: numpy's "This file contains pickled (object) data" for a CSV table
    path = tmp_path / 'pokes.csv'
    path.write_text(_table_text())
    with pytest.raises(DataError, match='a CSV table carries no surface'):
        load_replica_pokes(path)


@pytest.mark.parametrize('column, message', [
    ('depth', r'depth = 5 m \(poke a\) is past 0.2 m.*millimetres\? divide by 1000'),
    ('px', r'px = 10 m \(poke a\) is past 5 m'),
    ('force', r'force = 10000 N \(poke a\) is past 1000 N.*millinewtons'),
])
def test_a_column_in_other_units_is_refused_with_the_likely_unit_named(
        tmp_path, column, message):
    plain = tmp_path / 'plain.csv'
    plain.write_text(_table_text())
    assert len(read_poke_table(plain)) == 2          # the same table in metres and newtons
    lines = _table_text().splitlines()
    i = lines[0].split(',').index(column)
    rows = [line.split(',') for line in lines[1:]]
    for row in rows:
        row[i] = repr(float(row[i]) * 1000.0)
    scaled = tmp_path / 'units.csv'
    scaled.write_text('\n'.join([lines[0]] + [','.join(r) for r in rows]) + '\n')
    with pytest.raises(DataError, match=message):
        read_poke_table(scaled)
