"""Poke store: MCAP round trip, frame conventions, atomicity and corrupt bags."""

import json
import os
import shutil
import time

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from pointforce_ros.errors import DataError
from pointforce_ros import rotations as tf
from pointforce_ros.pokes import store as st
from pointforce_ros.types import PokeRecord


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


def test_a_bag_corrupted_after_indexing_is_quarantined_when_read(tmp_path):
    """Issue 16: a corrupt bag still listed in the index was never read again on reload."""
    store = _store_of(tmp_path, 3)
    mcap = next((tmp_path / 'poke-000002').glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:200])
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
