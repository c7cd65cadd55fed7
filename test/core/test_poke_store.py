"""Poke store: MCAP round trip, frame conventions, atomicity and corrupt bags."""

import dataclasses
import json
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer

from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros import rotations as tf
from pointforce_ros.pokes import store as st
from pointforce_ros.pokes.recorder import StreamRecorder
from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.types import PokeRecord, Surface


def make_record(poke_id='poke-000001', n=300, seed=0, tilt=0.3):
    rng = np.random.default_rng(seed)
    t = 100.0 + np.arange(n) / 250.0
    normal = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    point = np.array([0.5, 0.01, 0.04])
    depth = np.linspace(-0.01, 0.008, n)
    pos = point - depth[:, None] * normal
    rotvec = np.tile([np.pi - tilt, 0.05, 0.0], (n, 1)) + rng.normal(0, 1e-3, (n, 3))
    wrench = rng.normal(0, 0.5, (n, 6))
    return PokeRecord(poke_id=poke_id, point=point, normal=normal, t=t,
                      t_controller=np.arange(n) * 0.004 + 7.0,
                      tcp_pose=np.hstack([pos, rotvec]), wrench=wrench, speed=0.002,
                      outcome='force_limit', meta={'object': 'lamb', 'scenario': 'clean'})


def test_rotation_helpers_are_consistent():
    rng = np.random.default_rng(1)
    rv = rng.normal(size=(50, 3))
    rv *= (rng.uniform(0.1, 3.0, 50) / np.linalg.norm(rv, axis=1))[:, None]
    rot = tf.rotvec_to_matrix(rv)
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2),
                               np.broadcast_to(np.eye(3), rot.shape), atol=1e-12)
    back = tf.quaternion_to_rotvec(tf.matrix_to_quaternion(rot))
    np.testing.assert_allclose(tf.rotvec_to_matrix(back), rot, atol=1e-9)


def test_bag_round_trip_keeps_series_and_uses_tool_frame_on_the_wire(tmp_path):
    rec = make_record()
    path = st.write_poke_bag(rec, tmp_path / rec.poke_id)
    back = st.read_poke_bag(path)
    np.testing.assert_allclose(back.t, rec.t, atol=1e-9)
    np.testing.assert_allclose(back.t_controller, rec.t_controller)
    np.testing.assert_allclose(back.tcp_pose[:, :3], rec.tcp_pose[:, :3])
    np.testing.assert_allclose(tf.rotvec_to_matrix(back.tcp_pose[:, 3:]),
                               tf.rotvec_to_matrix(rec.tcp_pose[:, 3:]), atol=1e-9)
    np.testing.assert_allclose(back.wrench, rec.wrench, atol=1e-9)
    np.testing.assert_allclose(back.displacement(), rec.displacement(), atol=1e-12)
    assert back.meta == rec.meta and back.outcome == 'force_limit'
    # on the wire the wrench is in tool0_controller: f_tool = R^T f_base
    with AnyReader([path], default_typestore=st.TYPESTORE) as reader:
        conn = [c for c in reader.connections if c.topic == st.WRENCH_TOPIC][0]
        _, _, raw = next(reader.messages(connections=[conn]))
        msg = reader.deserialize(raw, conn.msgtype)
    assert msg.header.frame_id == 'tool0_controller'
    expected = tf.rotvec_to_matrix(rec.tcp_pose[0, 3:]).T @ rec.wrench[0, :3]
    np.testing.assert_allclose([msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z],
                               expected, atol=1e-9)


def test_store_indexes_reopens_and_rebuilds_a_lost_index(tmp_path):
    store = st.PokeStore(tmp_path / 'store')
    ids = []
    for seed in range(3):
        rec = make_record(store.next_id(), n=50, seed=seed)
        store.add(rec)
        ids.append(rec.poke_id)
    assert ids == ['poke-000001', 'poke-000002', 'poke-000003']
    again = st.PokeStore(tmp_path / 'store')
    assert again.ids() == ids and again.next_id() == 'poke-000004'
    (tmp_path / 'store' / 'index.json').write_text('{not json')
    rebuilt = st.PokeStore(tmp_path / 'store')
    assert rebuilt.ids() == ids
    assert json.loads((tmp_path / 'store' / 'index.json').read_text())['pokes'][2]['samples'] == 50


def test_interrupted_write_leaves_nothing_and_existing_id_is_refused(tmp_path):
    store = st.PokeStore(tmp_path)
    rec = make_record(n=20)
    store.add(rec)
    (tmp_path / '.tmp-poke-000002-abc').mkdir()  # what a crash mid-write leaves
    (tmp_path / '.tmp-poke-000003-def').mkdir()  # a write another process is doing now
    old = time.time() - st.PokeStore.LEFTOVER_AGE - 1
    os.utime(tmp_path / '.tmp-poke-000002-abc', (old, old))
    reopened = st.PokeStore(tmp_path)
    assert [p.name for p in tmp_path.glob('.tmp-*')] == ['.tmp-poke-000003-def']
    assert reopened.ids() == ['poke-000001']
    with pytest.raises(DataError, match='unique'):
        reopened.add(rec)


def test_corrupt_bag_is_a_clear_error_and_the_store_skips_it(tmp_path):
    store = st.PokeStore(tmp_path)
    for seed in range(2):
        store.add(make_record(store.next_id(), n=30, seed=seed))
    mcap = next((tmp_path / 'poke-000002').glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 3])
    with pytest.raises(DataError, match='poke-000002'):
        st.read_poke_bag(tmp_path / 'poke-000002')
    shutil.copytree(tmp_path / 'poke-000002', tmp_path / 'copy' / 'poke-000002')
    (tmp_path / 'copy' / 'poke-000001').mkdir()
    assert st.PokeStore(tmp_path / 'copy').ids() == []


def _store_of(root, count):
    store = st.PokeStore(root)
    for seed in range(count):
        store.add(make_record(store.next_id(), n=30, seed=seed))
    return store


def test_a_corrupt_newest_bag_is_quarantined_by_name_and_its_id_never_reused(tmp_path, caplog):
    """Issue 16: the next poke reused a corrupt bag's id and its storing failed after the poke."""
    _store_of(tmp_path, 3)
    mcap = next((tmp_path / 'poke-000003').glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:200])
    (tmp_path / 'index.json').unlink()
    with caplog.at_level('ERROR', logger='pointforce_ros.pokes.store'):
        reopened = st.PokeStore(tmp_path)
    assert reopened.ids() == ['poke-000001', 'poke-000002']
    moved = tmp_path / 'quarantine' / 'poke-000003'
    assert reopened.quarantined == [moved] and (moved / 'metadata.yaml').is_file()
    reason = (tmp_path / 'quarantine' / 'poke-000003.reason.txt').read_text()
    assert 'poke-000003' in reason and 'cannot read bag' in reason
    assert any('poke-000003' in r.getMessage() and 'quarantined' in r.getMessage()
               for r in caplog.records)
    new_id = reopened.next_id()
    assert new_id == 'poke-000004'
    reopened.add(make_record(new_id, n=30, seed=9))   # the arm's poke is stored
    assert reopened.ids()[-1] == 'poke-000004'


def _rot(path, data):
    """Write ``data`` over ``path`` keeping its size and times, as bits decaying on disk do."""
    before = path.stat()
    assert len(data) == before.st_size
    path.write_bytes(data)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))


def test_a_bag_corrupted_after_indexing_is_quarantined_when_read(tmp_path):
    """Issue 16: a corrupt bag still listed in the index was never read again on reload.

    Bits that decay on disk keep the file's size and times, so the index still lists the
    bag on open (a truncated or rewritten one is read again then, the test below); reading
    it sets it aside.
    """
    store = _store_of(tmp_path, 3)
    mcap = next((tmp_path / 'poke-000002').glob('*.mcap'))
    data = mcap.read_bytes()
    _rot(mcap, data[:200] + bytes(len(data) - 200))
    reopened = st.PokeStore(tmp_path)   # the index lists it: not read on open
    assert reopened.ids() == ['poke-000001', 'poke-000002', 'poke-000003']
    with pytest.raises(DataError, match='poke-000002.*moved to .*quarantine'):
        reopened.get('poke-000002')
    assert reopened.ids() == ['poke-000001', 'poke-000003']
    assert (tmp_path / 'quarantine' / 'poke-000002' / 'metadata.yaml').is_file()
    assert 'poke-000002' in (tmp_path / 'quarantine' / 'poke-000002.reason.txt').read_text()
    assert st.PokeStore(tmp_path).ids() == ['poke-000001', 'poke-000003']   # index rewritten
    assert [r.poke_id for r in reopened] == ['poke-000001', 'poke-000003']
    assert store.next_id() == 'poke-000004'


def test_ids_survive_a_lost_counter_a_removed_bag_and_unused_ids(tmp_path):
    store = _store_of(tmp_path, 2)
    unused = store.next_id()          # handed out, never stored (a poke with no sample)
    assert unused == 'poke-000003' and store.next_id() == 'poke-000004'
    shutil.rmtree(tmp_path / 'poke-000002')
    (tmp_path / 'index.json').unlink()
    assert st.PokeStore(tmp_path).next_id() == 'poke-000005'   # the persisted counter
    assert json.loads((tmp_path / 'ids.json').read_text()) == {'last': 5}
    (tmp_path / 'ids.json').write_text('{broken')
    (tmp_path / 'quarantine').mkdir()
    (tmp_path / 'quarantine' / 'poke-000011').mkdir()
    assert st.PokeStore(tmp_path).next_id() == 'poke-000012'   # names on disk bound it


def test_a_failed_store_keeps_every_sample_in_a_recovery_file(tmp_path):
    store = _store_of(tmp_path, 1)
    record = make_record('poke-000001', n=40, seed=3)   # an id that exists: the write fails
    with pytest.raises(DataError, match='unique') as failed:
        store.add(record)
    path = store.save_recovery(record, failed.value)
    assert path == tmp_path / 'recovery' / 'poke-000001.npz'
    back = st.load_recovery(path)
    for name in ('t', 't_controller', 'tcp_pose', 'wrench', 'point', 'normal'):
        np.testing.assert_array_equal(getattr(back, name), getattr(record, name))
    assert back.meta == record.meta and back.outcome == record.outcome
    # a second failure of the same id does not overwrite the first file
    assert store.save_recovery(record, failed.value).name == 'poke-000001.1.npz'
    assert store.next_id() == 'poke-000002'
    with pytest.raises(DataError, match='recovery'):
        st.load_recovery(next((tmp_path / 'poke-000001').glob('*.mcap')))


# ------------------------------------------------------------------ hostile or damaged input

BAD_IDS = ['../../escaped', '../escaped', '/tmp/pointforce-abs-escaped', '.', '..',
           'sub/poke-1', '.tmp-poke-000009', ' poke 1', 'x' * 129, 'poke-1\n', 'a\\b']


@pytest.mark.parametrize('bad_id', BAD_IDS)
def test_a_poke_id_that_is_no_plain_name_is_refused_naming_it(tmp_path, bad_id):
    """Audit, path traversal: a poke_id from a topic was joined to the store root."""
    with pytest.raises(InvalidInput, match=r'PokeRecord\.poke_id: .*not a plain name'):
        make_record(bad_id, n=10)
    # a record built around the check: the store refuses it too, and writes nothing
    record = make_record('poke-000001', n=10)
    object.__setattr__(record, 'poke_id', bad_id)
    root = tmp_path / 'a' / 'b' / 'store'
    store = st.PokeStore(root)
    shown = bad_id if len(bad_id) <= 80 else bad_id[:77]
    with pytest.raises(InvalidInput, match=re.escape(repr(shown)[:-1])):
        store.add(record)
    with pytest.raises(InvalidInput, match='not a plain name'):
        store.get(bad_id)
    outside = {p for p in tmp_path.rglob('*') if root not in p.parents}
    assert store.ids() == [] and outside == {tmp_path / 'a', tmp_path / 'a' / 'b', root}
    assert not Path('/tmp/pointforce-abs-escaped').exists()
    # samples the server could not even make a record of stay inside the store
    kept = store.save_raw_recovery(bad_id, {'t': np.arange(3.0)}, {'poke_id': bad_id},
                                   InvalidInput('test'))
    assert kept.parent == root / 'recovery'
    assert json.loads(bytes(np.load(kept)['header']).decode())['poke_id'] == bad_id


@pytest.mark.parametrize('name', ['air-000001', 'site A 2', 'step-0001', 'Poke-000001'])
def test_a_plain_id_that_is_no_poke_number_is_refused_not_lost_on_reopening(tmp_path, name):
    """Session 40: the store took 'air-000001' and listed it, and the same store opened again
    (a restarted learner, ``refresh``) no longer did: the poke was gone from it."""
    store = st.PokeStore(tmp_path / 'store')
    store.add(make_record('poke-000001', n=10))
    with pytest.raises(InvalidInput, match=re.escape(repr(name)) + r".*'poke-<number>'"):
        store.add(make_record(name, n=10))
    assert store.ids() == ['poke-000001'] and not (tmp_path / 'store' / name).exists()
    store.add(make_record('poke-000007', n=10))
    store.refresh()
    listed = ['poke-000001', 'poke-000007']
    assert store.ids() == st.PokeStore(tmp_path / 'store').ids() == listed


def test_the_topic_recorder_refuses_a_path_as_poke_id_and_records_the_next_poke(tmp_path):
    """Audit, path traversal: the learner wrote bags outside its store."""
    record = make_record('poke-000001', n=20, seed=4)
    quats = tf.matrix_to_quaternion(tf.rotvec_to_matrix(np.array(record.tcp_pose[:, 3:])))
    recorder = StreamRecorder()
    store = st.PokeStore(tmp_path / 'store')
    for poke_id in ('../../escaped', str(tmp_path / 'abs'), 'poke-000001'):
        for i in range(len(record)):
            t = record.t[i]
            recorder.add_pose(t, record.tcp_pose[i, :3], quats[i])
            recorder.add_wrench(t, np.zeros(3), np.zeros(3))
        header = dict(st.record_header(record), poke_id=poke_id)
        if poke_id != 'poke-000001':
            with pytest.raises(DataError, match=re.escape(repr(poke_id)[:-1])):
                recorder.finish(header, timeout=1.0)
            continue
        store.add(recorder.finish(header, timeout=1.0))
    assert store.ids() == ['poke-000001']
    assert sorted(p.name for p in tmp_path.iterdir()) == ['store']


def _bag_with_header(monkeypatch, path, record, edit):
    """Write ``record`` as a bag at ``path`` whose poke_record header ``edit`` changed."""
    original = st.record_header

    def edited(rec):
        header = original(rec)
        edit(header)
        return header
    with monkeypatch.context() as m:
        m.setattr(st, 'record_header', edited)
        st.write_poke_bag(record, path)


HEADER_FAULTS = {
    'samples missing': (lambda h: h.pop('samples'), 'samples missing'),
    'speed a string': (lambda h: h.update(speed='0.002'), 'speed must be a number'),
    'meta a string': (lambda h: h.update(meta='lamb'), 'meta must be an object'),
    't_controller null': (lambda h: h.update(t_controller=None),
                          't_controller must be a list'),
    'outcome a list': (lambda h: h.update(outcome=['x']), 'outcome must be a string'),
    'probe a number': (lambda h: h.update(probe=3), 'probe must be a string'),
    'samples a float': (lambda h: h.update(samples=30.0), 'samples must be an integer'),
    'only format and a list id': (
        lambda h: (h.clear(), h.update(format=st.RECORD_FORMAT, poke_id=[1])), 'missing'),
}


@pytest.mark.parametrize('fault', sorted(HEADER_FAULTS))
def test_a_bag_with_a_mistyped_header_field_is_quarantined_and_the_others_kept(
        tmp_path, monkeypatch, fault):
    """Audit D3: one such bag made the whole store unopenable with a bare KeyError/TypeError."""
    edit, message = HEADER_FAULTS[fault]
    _store_of(tmp_path, 2)
    bad = tmp_path / 'poke-000003'
    _bag_with_header(monkeypatch, bad, make_record('poke-000003', n=30, seed=3), edit)
    with pytest.raises(DataError, match=f'poke-000003: invalid poke record: .*{message}'):
        st.read_poke_bag(bad)
    (tmp_path / 'index.json').unlink()
    reopened = st.PokeStore(tmp_path)
    assert reopened.ids() == ['poke-000001', 'poke-000002']
    assert reopened.quarantined == [tmp_path / 'quarantine' / 'poke-000003']
    assert message in (tmp_path / 'quarantine' / 'poke-000003.reason.txt').read_text()
    assert reopened.next_id() == 'poke-000004'


@pytest.mark.parametrize('field, value', [('speed', '0.002'), ('speed', True),
                                          ('meta', 'lamb'), ('outcome', ['x']),
                                          ('probe', None)])
def test_a_record_field_of_the_wrong_type_is_invalid_input_naming_it(field, value):
    """Audit D3: PokeRecord took outcome=['x'] and raised a bare TypeError for speed='0.002'."""
    good = make_record(n=10)
    fields = {name: getattr(good, name) for name in good.__dataclass_fields__}
    with pytest.raises(InvalidInput, match=f'PokeRecord.{field}: must be'):
        PokeRecord(**dict(fields, **{field: value}))


def test_a_bag_with_a_zero_quaternion_is_quarantined_and_the_others_kept(tmp_path, monkeypatch):
    """Audit D4: scipy's ValueError for a zero-norm quaternion escaped read_poke_bag."""
    _store_of(tmp_path, 2)
    original = st.matrix_to_quaternion
    rng = np.random.default_rng(12)
    broken = int(rng.integers(0, 30))

    def one_zero(rot):
        quats = np.array(original(rot))
        quats[broken] = 0.0
        return quats
    with monkeypatch.context() as m:
        m.setattr(st, 'matrix_to_quaternion', one_zero)
        st.write_poke_bag(make_record('poke-000003', n=30, seed=3), tmp_path / 'poke-000003')
    with pytest.raises(DataError, match=f'poke-000003: .*quaternion of length 0 '
                                        rf'\(first: sample {broken}\)'):
        st.read_poke_bag(tmp_path / 'poke-000003')
    (tmp_path / 'index.json').unlink()
    reopened = st.PokeStore(tmp_path)
    assert reopened.ids() == ['poke-000001', 'poke-000002']
    assert reopened.quarantined == [tmp_path / 'quarantine' / 'poke-000003']


def test_a_bag_whose_record_names_another_poke_is_quarantined(tmp_path):
    """Audit D8: folder poke-000003 holding poke-000001's record gave duplicate ids."""
    _store_of(tmp_path, 2)
    st.write_poke_bag(make_record('poke-000001', n=30, seed=7), tmp_path / 'poke-000003')
    (tmp_path / 'index.json').unlink()
    reopened = st.PokeStore(tmp_path)
    assert reopened.ids() == ['poke-000001', 'poke-000002']
    assert [e['poke_id'] for e in reopened.entries()] == ['poke-000001', 'poke-000002']
    reason = (tmp_path / 'quarantine' / 'poke-000003.reason.txt').read_text()
    assert 'bag folder poke-000003 holds the record of poke poke-000001' in reason
    # a bag swapped after it was indexed: refused when read, and moved aside
    shutil.rmtree(tmp_path / 'poke-000002')
    st.write_poke_bag(make_record('poke-000001', n=30, seed=8), tmp_path / 'poke-000002')
    with pytest.raises(DataError, match='poke-000002 holds the record of poke poke-000001'):
        reopened.get('poke-000002')
    assert reopened.ids() == ['poke-000001'] and reopened.next_id() == 'poke-000004'


@pytest.mark.parametrize('counter', ['Infinity', '1e400', '1e300', '-5', '2.5', 'true',
                                     '1000000001', '"1e300"'])
def test_an_implausible_id_counter_is_ignored_with_a_warning(tmp_path, caplog, counter):
    """Audit D5: Infinity raised OverflowError; 1e300 gave a 306-character id (poke lost)."""
    _store_of(tmp_path, 2)
    (tmp_path / 'ids.json').write_text(f'{{"last": {counter}}}')
    with caplog.at_level('WARNING', logger='pointforce_ros.pokes.store'):
        store = st.PokeStore(tmp_path)
        poke_id = store.next_id()
    assert poke_id == 'poke-000003'               # the names on disk bound the ids
    assert any('ids.json' in r.getMessage() and 'implausible' in r.getMessage()
               for r in caplog.records)
    store.add(make_record(poke_id, n=20))         # the poke is stored
    assert st.PokeStore(tmp_path).next_id() == 'poke-000004'


def test_a_plausible_counter_still_bounds_the_ids(tmp_path, caplog):
    _store_of(tmp_path, 2)
    (tmp_path / 'ids.json').write_text('{"last": 41}')
    with caplog.at_level('WARNING', logger='pointforce_ros.pokes.store'):
        assert st.PokeStore(tmp_path).next_id() == 'poke-000042'
    assert not caplog.records


CONTACT = HalfSpaceContact(z0=0.04, k0=1.4e4, exponent=1.5, ripple=0.4, wavelength=0.06)


def test_the_learner_learns_the_good_pokes_around_a_malformed_bag(tmp_path, monkeypatch):
    """Audit D3: one bag with a bad header made every later refit raise (learning stopped)."""
    obj = halfspace_object(CONTACT, region=((0.47, 0.53), (-0.03, 0.03)))
    records = simulate_campaign(obj, load_scenario('clean'), count=5, seed=3,
                                force_limit=4.0, depth_limit=0.01, speed=0.004, gap=0.5)
    store = st.PokeStore(tmp_path / 'pokes')
    for record in records[:3]:
        store.add(record)
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 24), np.linspace(-0.035, 0.035, 24))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    surface = Surface(points=points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface,
                            shape_constant=0.004)
    assert learner.update().num_pokes == 3
    # a malformed bag arrives (another writer, a copied-in folder), then a good poke
    _bag_with_header(monkeypatch, tmp_path / 'pokes' / records[3].poke_id, records[3],
                     lambda h: h.update(outcome=['x']))
    store.add(records[4])
    status = learner.update()
    assert status is not None and status.num_pokes == 4
    assert [c.poke_id for c in learner.curves][-1] == records[4].poke_id
    assert (tmp_path / 'pokes' / 'quarantine' / records[3].poke_id).is_dir()


def test_a_sample_changed_on_disk_is_caught_by_the_bags_checksum(tmp_path):
    """A byte changed inside a sample used to read back as a valid poke (session 38 audit).

    rosbags writes MCAP chunks without a CRC, so only the SHA-256 the writer stores in the
    record can tell: one pose coordinate moved by 1 mm is refused, and the store quarantines
    the bag and keeps the others.
    """
    store = st.PokeStore(tmp_path / 'store')
    for k in (1, 2):
        store.add(make_record(f'poke-00000{k}', n=40))
    bag = next((tmp_path / 'store' / 'poke-000002').glob('*.mcap'))
    record = st.read_poke_bag(bag.parent)
    data = bag.read_bytes()
    original = np.float64(record.tcp_pose[7, 0]).tobytes()
    assert data.count(original) == 1
    _rot(bag, data.replace(original, np.float64(record.tcp_pose[7, 0] + 1e-3).tobytes()))
    with pytest.raises(DataError, match='does not match the SHA-256'):
        st.read_poke_bag(bag.parent)
    reopened = st.PokeStore(tmp_path / 'store')   # the index lists it until it is read
    with pytest.raises(DataError, match='SHA-256'):
        reopened.get('poke-000002')
    assert reopened.ids() == ['poke-000001'] and reopened.get('poke-000001').poke_id
    assert any((tmp_path / 'store' / 'quarantine').iterdir())


def test_a_bag_changed_after_it_was_indexed_is_quarantined_when_the_store_reopens(tmp_path):
    """The index trusted its bags: a truncated one stayed listed after a restart (session 38).

    ``pointforce bench faults`` cuts the newest bag to a third and reopened the store with it
    still listed (``quarantined_on_reload: false``); the index now keeps each bag's file sizes
    and times, and a bag whose files changed is read again and set aside if it no longer reads.
    """
    store = st.PokeStore(tmp_path / 'store')
    for k in (1, 2, 3):
        store.add(make_record(f'poke-00000{k}', n=40, seed=k))
    bag = next((tmp_path / 'store' / 'poke-000002').glob('*.mcap'))
    bag.write_bytes(bag.read_bytes()[: bag.stat().st_size // 3])
    reopened = st.PokeStore(tmp_path / 'store')
    assert reopened.ids() == ['poke-000001', 'poke-000003']
    moved = (tmp_path / 'store' / 'quarantine').iterdir()
    assert any(p.name.startswith('poke-000002') for p in moved)
    assert 'cannot read bag' in reopened.quarantine_reasons['poke-000002']
    assert reopened.next_id() == 'poke-000004'
    # an unchanged store reopens on its index alone, listing the same bags
    assert st.PokeStore(tmp_path / 'store').ids() == ['poke-000001', 'poke-000003']


def test_a_poke_whose_wall_clock_steps_back_reads_back_in_the_order_written(tmp_path):
    """Stamps may step back (NTP) while the controller's clock rises (session 38).

    The bag used those stamps as log times, a reader returned the samples sorted by them, so
    the poke came back reordered, and with the bag's checksum it was quarantined and lost.
    """
    record = make_record('poke-000001', n=40)
    t = record.t.copy()
    t[20:] -= 0.5                      # the wall clock steps back half a second
    stepped = dataclasses.replace(record, t=t)
    store = st.PokeStore(tmp_path)
    store.add(stepped)
    back = st.PokeStore(tmp_path).get('poke-000001')
    np.testing.assert_allclose(back.t, stepped.t, rtol=0, atol=1e-9)
    np.testing.assert_allclose(back.tcp_pose[:, :3], stepped.tcp_pose[:, :3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.wrench, stepped.wrench, rtol=0, atol=1e-9)


def test_a_bag_without_poke_topics_is_named_as_such(tmp_path):
    """A generated scans bag read as a poke bag said 'TypeError: the JSON object must be str'.

    rosbags' ``messages(connections=[])`` reads every topic; the reader now says the bag has
    no poke topics.
    """
    bag = tmp_path / 'scans'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection('/camera/points', 'std_msgs/msg/String',
                                     typestore=st.TYPESTORE)
        text = st.TYPESTORE.types['std_msgs/msg/String'](data='not a poke')
        writer.write(conn, 1, st.TYPESTORE.serialize_cdr(text, 'std_msgs/msg/String'))
    with pytest.raises(DataError, match='no poke topics'):
        st.read_poke_bag(bag)


def test_opening_a_store_writes_nothing_when_nothing_changed(tmp_path):
    """An index from before the file records stays byte for byte (a committed fixture did not)."""
    store = _store_of(tmp_path, 2)
    index = tmp_path / 'index.json'
    old = json.loads(index.read_text())
    old.pop('files')
    index.write_text(json.dumps(old))
    before = index.read_bytes()
    assert st.PokeStore(tmp_path).ids() == store.ids()
    assert index.read_bytes() == before
