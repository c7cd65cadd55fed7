"""Poke store: one rosbag2 MCAP bag per poke, written atomically, plus a JSON index.

Layout of a store directory::

    <store>/index.json                 one entry per poke (id, point, normal, samples, outcome)
    <store>/poke-000017/               a rosbag2 bag (metadata.yaml + poke-000017_0.mcap)
    <store>/ids.json                   the last poke id handed out (written atomically)
    <store>/quarantine/poke-000016/    a bag that could not be read, with a .reason.txt
    <store>/recovery/poke-000018.npz   the samples of a poke the store failed to write

Each bag holds the topics the poke server publishes, so Foxglove and ``ros2 bag`` read it:

* ``/poke_server/tcp_pose`` geometry_msgs/PoseStamped, frame ``base``, 250 Hz
* ``/poke_server/wrench`` geometry_msgs/WrenchStamped, frame ``tool0_controller`` (the UR
  driver's convention: ur_rtde's base-oriented ``actual_TCP_force`` rotated into the tool frame)
* ``/poke_server/poke_record`` std_msgs/String, one JSON message: request, probe, outcome,
  controller timestamps and metadata

A bag is written into a hidden temporary directory and renamed into place, so a poke is either
wholly on disk or absent; a crash mid-write leaves only a ``.tmp-*`` directory that the next
open removes. Pure Python (``rosbags``), no rclpy.

Ids are never reused: :meth:`PokeStore.next_id` hands out one more than the highest of the
persisted counter (ignored, with a warning, when damaged or implausible), the index, every
``poke-*`` folder, the quarantine and the recovery folder, and persists it before returning.
A poke id is a plain file name (:func:`~pointforce_ros.types.check_poke_id`): the store never
writes or reads outside its folder. A bag that cannot be read when the store is opened (or
whose record names another poke than its folder) is moved to ``quarantine/`` with a logged
reason that names it. A poke whose bag cannot be written (after the arm moved) is kept whole
by :meth:`PokeStore.save_recovery` and read back by :func:`load_recovery`.
"""

import hashlib
import json
import logging
import math
import numbers
import os
import re
import shutil
import tempfile
import threading
import time
from pathlib import Path
from typing import Dict, Iterator, List, Optional

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from pointforce_ros.errors import check_npz_size, DataError, InvalidInput, read_json
from pointforce_ros.rotations import (matrix_to_quaternion, quaternion_to_rotvec,
                                      rotvec_to_matrix)
from pointforce_ros.types import check_poke_id, PokeRecord

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
POSE_TOPIC = '/poke_server/tcp_pose'
WRENCH_TOPIC = '/poke_server/wrench'
RECORD_TOPIC = '/poke_server/poke_record'
RECORD_FORMAT = 'pointforce-poke/1'
RECOVERY_FORMAT = 'pointforce-poke-recovery/1'
LOG = logging.getLogger(__name__)
_ID = re.compile(r'^poke-(\d+)')
_COUNTER_TEXT = re.compile(r'[0-9]{1,10}')
MAX_ID_NUMBER = 10 ** 9
"""Largest id counter :meth:`PokeStore.next_id` believes: a store of a billion pokes is not a
robot cell's; a larger persisted counter is damage, and the names on disk bound the ids."""
HEADER_FIELDS = (('poke_id', str, 'a string'), ('point', list, 'a list of 3 numbers'),
                 ('normal', list, 'a list of 3 numbers'), ('speed', numbers.Real, 'a number'),
                 ('probe', str, 'a string'), ('outcome', str, 'a string'),
                 ('samples', int, 'an integer'), ('t_controller', list, 'a list of numbers'))
"""Required fields of a ``poke_record`` header: (name, JSON type, what it must be)."""
DIGEST_KEY = 'sha256'
"""Header field of a bag written by :func:`write_poke_bag`: SHA-256 of the rest of the header
and of every pose and wrench message as serialised (:func:`_bag_digest`). MCAP chunks carry no
CRC as rosbags writes them, and a flipped byte in a sample read back as a valid poke in a third
of the mutations tried (session 38); a bag without the field (recorded by other tools, or
before it) is read as before."""
QUATERNION_MIN_NORM = 1e-6
"""Shortest pose quaternion read as a rotation; a shorter (zero) one is a damaged sample."""

_T = TYPESTORE.types
_Time = _T['builtin_interfaces/msg/Time']
_Header = _T['std_msgs/msg/Header']
_Point = _T['geometry_msgs/msg/Point']
_Quaternion = _T['geometry_msgs/msg/Quaternion']
_Vector3 = _T['geometry_msgs/msg/Vector3']


def _stamp(t: float):
    sec = int(np.floor(t))
    return _Time(sec=sec, nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


def record_header(record: PokeRecord) -> dict:
    """JSON-able description of ``record`` without its pose/wrench series (``poke_record``).

    Carries the controller timestamps and the ROS-time span ``t_start``..``t_end`` of the
    samples, so a recorder listening to the pose and wrench topics can cut the poke out.
    """
    return {
        'format': RECORD_FORMAT, 'poke_id': record.poke_id,
        'point': record.point.tolist(), 'normal': record.normal.tolist(),
        'speed': record.speed, 'probe': record.probe, 'outcome': record.outcome,
        'samples': len(record), 't_controller': record.t_controller.tolist(),
        't_start': float(record.t[0]) if len(record) else 0.0,
        't_end': float(record.t[-1]) if len(record) else 0.0,
        'meta': dict(record.meta),
    }


def check_header(header) -> dict:
    """Return ``header`` if it has every field of :data:`HEADER_FIELDS` with its JSON type.

    ``meta``, when present, must be an object; ``poke_id`` a plain file name
    (:func:`~pointforce_ros.types.check_poke_id`). Values are checked further by
    :class:`~pointforce_ros.types.PokeRecord`.

    Raises:
        InvalidInput: not a JSON object, a missing field, a field of another type (the
            message names the field, what it holds and what it must be), or a poke id that
            is no plain file name.

    """
    if not isinstance(header, dict):
        raise InvalidInput(f'{RECORD_TOPIC}: expected a JSON object, got '
                           f'{type(header).__name__}')
    who = header.get('poke_id', 'poke_record')
    who = who if isinstance(who, str) else repr(who)
    missing = [name for name, _, _ in HEADER_FIELDS if name not in header]
    if missing:
        raise InvalidInput(f'{who}: header field(s) {", ".join(missing)} missing')
    fields = HEADER_FIELDS + (('meta', dict, 'an object'),) * ('meta' in header)
    for name, kind, what in fields:
        value = header[name]
        if isinstance(value, bool) or not isinstance(value, kind):
            raise InvalidInput(f'{who}: header field {name} must be {what}, got '
                               f'{type(value).__name__} {value!r:.80}')
    if header['samples'] < 0:
        raise InvalidInput(f'{who}: header field samples must be >= 0, got {header["samples"]}')
    check_poke_id(header['poke_id'], 'header field poke_id')
    return header


def record_from_samples(header: dict, pose_rows: np.ndarray, wrench_tool: np.ndarray
                        ) -> PokeRecord:
    """Rebuild a record from its header and the samples as they travel on the topics.

    Args:
        header: :func:`record_header` output.
        pose_rows: (T, 8) ``[t, x, y, z, qx, qy, qz, qw]`` of ``tcp_pose`` (``base``).
        wrench_tool: (T, 6) wrench in ``tool0_controller``; rotated back to base orientation.

    Raises:
        InvalidInput: a header :func:`check_header` refuses, counts that disagree with the
            header, a pose quaternion of zero length, or an invalid record.

    """
    check_header(header)
    pose_rows = np.asarray(pose_rows, dtype=np.float64).reshape(-1, 8)
    wrench_tool = np.asarray(wrench_tool, dtype=np.float64).reshape(-1, 6)
    if not (len(pose_rows) == len(wrench_tool) == header['samples']
            == len(header['t_controller'])):
        raise InvalidInput(f'{header.get("poke_id")}: sample counts disagree (pose '
                           f'{len(pose_rows)}, wrench {len(wrench_tool)}, record '
                           f'{header["samples"]})')
    norms = np.linalg.norm(pose_rows[:, 4:8], axis=1)
    bad = np.flatnonzero(~(np.isfinite(norms) & (norms >= QUATERNION_MIN_NORM)))
    if len(bad):
        raise InvalidInput(f'{header["poke_id"]}: {len(bad)} pose sample(s) with a quaternion '
                           f'of length {norms[bad[0]]:g} (first: sample {bad[0]}): not a '
                           'rotation')
    rotvec = quaternion_to_rotvec(pose_rows[:, 4:8])
    rot = rotvec_to_matrix(rotvec)
    wrench = np.hstack([np.einsum('nij,nj->ni', rot, wrench_tool[:, :3]),
                        np.einsum('nij,nj->ni', rot, wrench_tool[:, 3:])])
    return PokeRecord(poke_id=header['poke_id'], point=header['point'], normal=header['normal'],
                      t=pose_rows[:, 0], t_controller=header['t_controller'],
                      tcp_pose=np.hstack([pose_rows[:, 1:4], rotvec]), wrench=wrench,
                      speed=header['speed'], probe=header['probe'], outcome=header['outcome'],
                      meta=header.get('meta', {}))


def write_poke_bag(record: PokeRecord, path) -> Path:
    """Write ``record`` as a rosbag2 MCAP bag at ``path`` (a directory that must not exist).

    The write is atomic: the bag is assembled in a temporary sibling directory and renamed.

    Raises:
        DataError: ``path`` exists already.

    """
    path = Path(path)
    if path.exists():
        raise DataError(f'{path} exists: poke ids must be unique')
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_root = Path(tempfile.mkdtemp(dir=path.parent, prefix=f'.tmp-{path.name}-'))
    tmp_bag = tmp_root / path.name
    try:
        rot = rotvec_to_matrix(np.array(record.tcp_pose[:, 3:]))  # a writable copy for scipy
        quats = matrix_to_quaternion(rot)
        # ur_rtde's actual_TCP_force is base-oriented; the UR driver publishes it in the tool
        # frame: f_tool = R^T f_base, same for the torque
        f_tool = np.einsum('nji,nj->ni', rot, record.wrench[:, :3])
        m_tool = np.einsum('nji,nj->ni', rot, record.wrench[:, 3:])
        pose_raw, wrench_raw = [], []
        with Writer(tmp_bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            pose_conn = writer.add_connection(POSE_TOPIC, 'geometry_msgs/msg/PoseStamped',
                                              typestore=TYPESTORE)
            wrench_conn = writer.add_connection(WRENCH_TOPIC, 'geometry_msgs/msg/WrenchStamped',
                                                typestore=TYPESTORE)
            rec_conn = writer.add_connection(RECORD_TOPIC, 'std_msgs/msg/String',
                                             typestore=TYPESTORE)
            pose_t = _T['geometry_msgs/msg/PoseStamped']
            pose_in = _T['geometry_msgs/msg/Pose']
            wrench_t = _T['geometry_msgs/msg/WrenchStamped']
            wrench_in = _T['geometry_msgs/msg/Wrench']
            # log times strictly increasing, whatever the stamps do (a wall clock stepped back
            # mid-poke): a reader returns each topic in log-time order, so the samples come
            # back in the order written and the digest below holds
            log_ns = [int(round(t * 1e9)) for t in record.t]
            for i in range(1, len(log_ns)):
                log_ns[i] = max(log_ns[i], log_ns[i - 1] + 1)
            for i in range(len(record)):
                stamp = _stamp(record.t[i])
                t_ns = log_ns[i]
                p = record.tcp_pose[i]
                q = quats[i]
                msg = pose_t(header=_Header(stamp=stamp, frame_id='base'), pose=pose_in(
                    position=_Point(x=p[0], y=p[1], z=p[2]),
                    orientation=_Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])))
                pose_raw.append(TYPESTORE.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped'))
                writer.write(pose_conn, t_ns, pose_raw[-1])
                f, m = f_tool[i], m_tool[i]
                msg = wrench_t(header=_Header(stamp=stamp, frame_id='tool0_controller'),
                               wrench=wrench_in(force=_Vector3(x=f[0], y=f[1], z=f[2]),
                                                torque=_Vector3(x=m[0], y=m[1], z=m[2])))
                wrench_raw.append(TYPESTORE.serialize_cdr(msg,
                                                          'geometry_msgs/msg/WrenchStamped'))
                writer.write(wrench_conn, t_ns, wrench_raw[-1])
            end_ns = (log_ns[-1] if log_ns else 0) + 1
            header = record_header(record)
            header[DIGEST_KEY] = _bag_digest(header, pose_raw, wrench_raw)
            text = _T['std_msgs/msg/String'](data=json.dumps(header))
            writer.write(rec_conn, end_ns, TYPESTORE.serialize_cdr(text, 'std_msgs/msg/String'))
        for f in tmp_bag.iterdir():
            with open(f, 'rb') as fh:
                os.fsync(fh.fileno())
        os.replace(tmp_bag, path)
    finally:
        shutil.rmtree(tmp_root, ignore_errors=True)
    return path


def _bag_digest(header: dict, pose_raw, wrench_raw) -> str:
    """Return the SHA-256 of ``header`` (less :data:`DIGEST_KEY`) and the serialised samples.

    The header as sorted-key JSON (floats print and parse back exactly), then every pose
    message's bytes and every wrench message's, each topic in its order in the bag.
    """
    digest = hashlib.sha256(json.dumps({k: v for k, v in header.items() if k != DIGEST_KEY},
                                       sort_keys=True).encode())
    for chunk in pose_raw:
        digest.update(bytes(chunk))
    digest.update(b'\0wrench\0')
    for chunk in wrench_raw:
        digest.update(bytes(chunk))
    return digest.hexdigest()


def read_poke_bag(path) -> PokeRecord:
    """Read a poke bag written by :func:`write_poke_bag` (or recorded live) into a record.

    Raises:
        DataError: not a bag, corrupt MCAP, content that does not match the SHA-256 the
            writer stored (:data:`DIGEST_KEY`), missing topics, a ``poke_record`` header with a
            missing or mistyped field, sample counts that disagree, a zero pose quaternion,
            or any other invalid record (the message names the bag).

    """
    path = Path(path)
    if not path.exists():
        raise DataError(f'poke bag not found: {path}')
    poses, wrenches, header = [], [], None
    pose_raw, wrench_raw = [], []
    try:
        with AnyReader([path], default_typestore=TYPESTORE) as reader:
            conns = [c for c in reader.connections
                     if c.topic in (POSE_TOPIC, WRENCH_TOPIC, RECORD_TOPIC)]
            if not conns:   # messages(connections=[]) would read every topic
                raise DataError(f'{path}: no poke topics ({POSE_TOPIC}, {WRENCH_TOPIC}, '
                                f'{RECORD_TOPIC}): not a poke bag')
            for conn, _, raw in reader.messages(connections=conns):
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == POSE_TOPIC:
                    pose_raw.append(raw)
                    p, q = msg.pose.position, msg.pose.orientation
                    poses.append((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec,
                                  p.x, p.y, p.z, q.x, q.y, q.z, q.w))
                elif conn.topic == WRENCH_TOPIC:
                    wrench_raw.append(raw)
                    f, m = msg.wrench.force, msg.wrench.torque
                    wrenches.append((f.x, f.y, f.z, m.x, m.y, m.z))
                else:
                    header = json.loads(msg.data)
    except DataError:
        raise
    except Exception as exc:  # rosbags raises many types for a corrupt file
        raise DataError(f'{path}: cannot read bag: {type(exc).__name__}: {exc}') from exc
    if not isinstance(header, dict) or header.get('format') != RECORD_FORMAT:
        raise DataError(f'{path}: no {RECORD_TOPIC} record of format {RECORD_FORMAT}')
    stored = header.get(DIGEST_KEY)
    if stored is not None and stored != _bag_digest(header, pose_raw, wrench_raw):
        raise DataError(f'{path}: content does not match the SHA-256 its writer stored '
                        '(a sample or the record was altered or damaged on disk)')
    try:
        return record_from_samples(header, np.array(poses), np.array(wrenches))
    except InvalidInput as exc:
        raise DataError(f'{path}: invalid poke record: {exc}') from exc
    except Exception as exc:  # noqa: BLE001 - a record no check above foresaw: still the bag's
        raise DataError(f'{path}: invalid poke record: {type(exc).__name__}: {exc}') from exc


def load_recovery(path) -> PokeRecord:
    """Read a recovery file written by :meth:`PokeStore.save_recovery` back into a record.

    Raises:
        DataError: not a recovery file, or unreadable.

    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            check_npz_size(z, path, 'poke recovery file')
            header = json.loads(bytes(z['header']).decode())
            if header.get('recovery_format') != RECOVERY_FORMAT:
                raise DataError(f'{path}: not a poke recovery file')
            return PokeRecord(poke_id=header['poke_id'], point=header['point'],
                              normal=header['normal'], t=z['t'],
                              t_controller=z['t_controller'], tcp_pose=z['tcp_pose'],
                              wrench=z['wrench'], speed=header['speed'], probe=header['probe'],
                              outcome=header['outcome'], meta=header.get('meta', {}))
    except DataError:
        raise
    except Exception as exc:  # noqa: BLE001 - zipfile, numpy, json: many error types
        raise DataError(f'{path}: unreadable recovery file: {type(exc).__name__}: '
                        f'{exc}') from exc


class PokeStore:
    """A directory of poke bags with an index; safe for one writer and many readers.

    Raises:
        DataError: the directory exists but is not a store (a file, or unreadable index).

    """

    INDEX = 'index.json'
    IDS = 'ids.json'
    QUARANTINE = 'quarantine'
    RECOVERY = 'recovery'
    RESERVED = (INDEX, IDS, QUARANTINE, RECOVERY)
    """Names of the store's own entries, never poke ids."""
    LEFTOVER_AGE = 300.0
    """Seconds after which a ``.tmp-*`` entry is an interrupted write, not one in progress."""

    def __init__(self, root):
        """Open (and create) the store at ``root``; removes leftovers of interrupted writes.

        A ``.tmp-*`` entry younger than ``LEFTOVER_AGE`` is kept: another process (the poke
        server, while the learner opens the store) may be writing it. Bags that cannot be
        read are moved to ``quarantine/`` (logged with the reason).
        """
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise DataError(f'poke store {self.root} is a file, not a directory')
        self.root.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        now = time.time()
        for leftover in self.root.glob('.tmp-*'):
            try:
                if now - leftover.stat().st_mtime < self.LEFTOVER_AGE:
                    continue  # another process may be writing it right now
            except OSError:
                continue
            if leftover.is_dir():
                shutil.rmtree(leftover, ignore_errors=True)
            else:
                leftover.unlink(missing_ok=True)
        self.quarantined: List[Path] = []
        self.quarantine_reasons: Dict[str, str] = {}   # name -> why, for a learner's report
        self._index = self._load_index()

    def _quarantine(self, path: Path, reason: str) -> Optional[Path]:
        """Move a bad bag (folder or file) to ``quarantine/`` with ``<name>.reason.txt``."""
        folder = self.root / self.QUARANTINE
        folder.mkdir(exist_ok=True)
        target = folder / path.name
        n = 0
        while target.exists():
            n += 1
            target = folder / f'{path.name}.{n}'
        try:
            os.replace(path, target)
        except FileNotFoundError:
            return None  # another reader moved it
        except OSError as exc:
            LOG.error('poke store %s: cannot quarantine %s (%s): %s', self.root, path.name,
                      exc, reason)
            return None
        note = f'{time.strftime("%Y-%m-%dT%H:%M:%S%z")} {path.name}: {reason}\n'
        (folder / f'{target.name}.reason.txt').write_text(note)
        LOG.error('poke store %s: quarantined %s as %s: %s', self.root, path.name, target,
                  reason)
        self.quarantined.append(target)
        self.quarantine_reasons[path.name] = reason
        return target

    def _load_index(self) -> Dict[str, dict]:
        """Return the index of the bags on disk, reading each new or changed bag.

        The index keeps each bag's file sizes and modification times (``files``): a bag
        whose files changed since it was indexed (truncated, rewritten, replaced) is read
        again on open and quarantined if it no longer reads, so a restarted server or
        learner never lists it (an index from before that record trusts its bags once).
        Sets ``self._stats``.
        """
        bags = set()
        for p in self.root.iterdir():
            if not (p.name.startswith('poke-') and _ID.match(p.name)):
                continue
            if p.is_dir() and (p / 'metadata.yaml').exists():
                bags.add(p.name)
            else:  # a poke-* entry that is no bag would block its id and hide a problem
                self._quarantine(p, 'not a rosbag2 bag (no metadata.yaml)')
        index: Dict[str, dict] = {}
        stored: dict = {}
        path = self.root / self.INDEX
        if path.exists():
            try:
                data = read_json(path, 'poke index')
                index = {e['poke_id']: e for e in data['pokes']}
                stored = data.get('files', {})
                stored = stored if isinstance(stored, dict) else {}
            except (DataError, KeyError, TypeError):
                index = {}  # rebuilt below from the bags, which are the truth
        changed = set(index) != bags
        index = {k: v for k, v in index.items() if k in bags}
        stats = {}
        for name in sorted(bags):
            stats[name] = self._bag_stat(name)
            if name in index and stored.get(name, stats[name]) == stats[name]:
                continue
            changed = True
            try:
                index[name] = self._entry(self._read(name))
            except DataError as exc:  # never fatal to the store; moved aside, logged
                self._quarantine(self.root / name, str(exc))
                index.pop(name, None)
                stats.pop(name)
        self._stats = stats
        if changed:   # not to record stats alone: an index from before them stays as it is
            self._write_index(index)
        return index

    def _bag_stat(self, name: str) -> dict:
        """Return ``{file: [size, mtime ns]}`` of the bag folder ``name`` (empty if gone)."""
        try:
            return {p.name: [st.st_size, st.st_mtime_ns]
                    for p in sorted((self.root / name).iterdir()) if p.is_file()
                    for st in (p.stat(),)}
        except OSError:
            return {}

    def _read(self, name: str) -> PokeRecord:
        """Read the bag folder ``name``; the record in it must carry that same id.

        Raises:
            DataError: an unreadable bag, or one whose record names another poke (a copied or
                renamed bag: its id would be a duplicate).

        """
        path = self.root / name
        record = read_poke_bag(path)
        if record.poke_id != name:
            raise DataError(f'{path}: the bag folder {name} holds the record of poke '
                            f'{record.poke_id} (a copied or renamed bag; ids must be unique)')
        return record

    @staticmethod
    def _entry(record: PokeRecord) -> dict:
        return {'poke_id': record.poke_id, 'point': record.point.tolist(),
                'normal': record.normal.tolist(), 'samples': len(record),
                'outcome': record.outcome, 'probe': record.probe,
                'meta': dict(record.meta)}

    def _write_index(self, index: Dict[str, dict]) -> None:
        self._write_json(self.INDEX, {'pokes': [index[k] for k in sorted(index)],
                                      'files': {k: self._stats[k] for k in sorted(index)
                                                if k in self._stats}})

    def _highest_number(self) -> int:
        """Highest poke number ever used here: counter, index, folders, quarantine, recovery."""
        names = list(self._index)
        for folder in (self.root, self.root / self.QUARANTINE, self.root / self.RECOVERY):
            if folder.is_dir():
                names.extend(p.name for p in folder.iterdir())
        used = [int(m.group(1)) for m in map(_ID.match, names) if m]
        counter = self._counter()
        if counter is not None:
            used.append(counter)
        return max(used, default=0)

    def _counter(self) -> Optional[int]:
        """Return the persisted counter, or ``None`` when it is lost, damaged or implausible.

        A damaged counter is logged and ignored: the names on disk still bound the ids. An
        implausible one (not an integer, negative, non-finite, or past
        :data:`MAX_ID_NUMBER`) would hand out ids no file system can name.
        """
        path = self.root / self.IDS
        if not path.exists():
            return None
        try:
            value = read_json(path, 'poke id counter')['last']
        except (DataError, KeyError) as exc:
            LOG.warning('poke store %s: ignoring the damaged id counter %s (%s); ids continue '
                        'from the names on disk', self.root, path, exc)
            return None
        number = None
        if isinstance(value, str) and _COUNTER_TEXT.fullmatch(value.strip()):
            number = int(value.strip())
        elif isinstance(value, float) and math.isfinite(value) and value.is_integer():
            number = int(value)
        elif isinstance(value, int) and not isinstance(value, bool):
            number = value
        if number is None or not 0 <= number <= MAX_ID_NUMBER:
            LOG.warning('poke store %s: ignoring the implausible id counter %s: last = %.40r '
                        '(not an integer in 0..%d); ids continue from the names on disk',
                        self.root, path, value, MAX_ID_NUMBER)
            return None
        return number

    def next_id(self) -> str:
        """Return a fresh poke id (``poke-000001``, ...); an id is never handed out twice.

        The new id is one more than the highest ever used in this store (the persisted
        counter unless it is damaged or implausible, see :data:`MAX_ID_NUMBER`; the index,
        every ``poke-*`` folder, the quarantine and the recovery folder) and is persisted
        atomically before it is returned, so a corrupt or removed bag, a failed write or a
        restart cannot bring an id back.

        Raises:
            OSError: the counter cannot be written.

        """
        with self._lock:
            number = self._highest_number() + 1
            self._write_json(self.IDS, {'last': number})
            return f'poke-{number:06d}'

    def _write_json(self, name: str, content) -> None:
        fd, tmp = tempfile.mkstemp(dir=self.root, prefix=f'.tmp-{name}-')
        try:
            with os.fdopen(fd, 'w') as fh:
                json.dump(content, fh)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.root / name)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise

    def save_recovery(self, record: PokeRecord, error: BaseException) -> Path:
        """Keep every sample of ``record`` when its bag could not be stored; return the path.

        Writes ``<store>/recovery/<poke_id>.npz`` (or, if the store cannot be written, the
        same name under the system temporary folder's ``pointforce-recovery/``) atomically,
        with the record header and ``error``. :func:`load_recovery` reads it back.

        Raises:
            OSError: neither place can be written.

        """
        header = dict(record_header(record), recovery_format=RECOVERY_FORMAT)
        arrays = dict(t=record.t, t_controller=record.t_controller, tcp_pose=record.tcp_pose,
                      wrench=record.wrench)
        return self.save_raw_recovery(record.poke_id, arrays, header, error)

    def save_raw_recovery(self, poke_id: str, arrays: dict, header: dict,
                          error: BaseException) -> Path:
        """Keep ``arrays`` (name -> array) of a poke that is not even a valid record.

        As :meth:`save_recovery`, for samples a :class:`PokeRecord` refused (the header says
        why); ``np.load`` reads the file, :func:`load_recovery` only when it was a record.

        Raises:
            OSError: neither the store nor the temporary folder can be written.

        """
        header = dict(header, error=f'{type(error).__name__}: {error}')
        try:
            check_poke_id(poke_id)
        except InvalidInput:  # the samples must survive; the header keeps the id as it was
            poke_id = 'unnamed-poke'
        arrays = {name: np.asarray(value) for name, value in arrays.items()}
        arrays['header'] = np.frombuffer(json.dumps(header, default=str).encode(),
                                         dtype=np.uint8)
        samples = max((len(a) for a in arrays.values() if a.ndim), default=0)
        places = [self.root / self.RECOVERY,
                  Path(tempfile.gettempdir()) / 'pointforce-recovery']
        for i, folder in enumerate(places):
            try:
                folder.mkdir(parents=True, exist_ok=True)
                fd, tmp = tempfile.mkstemp(dir=folder, prefix='.tmp-', suffix='.npz')
                try:
                    with os.fdopen(fd, 'wb') as fh:
                        np.savez(fh, **arrays)
                        fh.flush()
                        os.fsync(fh.fileno())
                    path = folder / f'{poke_id}.npz'
                    n = 0
                    while path.exists():
                        n += 1
                        path = folder / f'{poke_id}.{n}.npz'
                    os.replace(tmp, path)
                finally:
                    if os.path.exists(tmp):
                        os.unlink(tmp)
            except OSError:
                if i == len(places) - 1:
                    raise
                continue
            LOG.error('poke store %s: %s not stored (%s); its samples (%d) are kept in %s',
                      self.root, poke_id, header['error'], samples, path)
            return path
        raise OSError('unreachable')  # pragma: no cover

    def add(self, record: PokeRecord) -> Path:
        """Persist ``record`` (atomically) and index it; returns the bag path.

        Raises:
            InvalidInput: a poke id that is no plain file name, a name the store uses, or
                not ``poke-<number>`` (the only bags a store lists when it is opened again).
            DataError: the id is stored already.

        """
        check_poke_id(record.poke_id, 'PokeStore.add: poke_id')
        if record.poke_id in self.RESERVED:
            raise InvalidInput(f'PokeStore.add: poke_id {record.poke_id!r} is a name the store '
                               'uses for its own files')
        if not _ID.match(record.poke_id):
            raise InvalidInput(f"PokeStore.add: poke_id {record.poke_id!r} is not "
                               "'poke-<number>': a store lists only such bags when it is opened "
                               'again, so this poke would vanish from it (name it with '
                               'next_id())')
        with self._lock:
            path = write_poke_bag(record, self.root / record.poke_id)
            self._index[record.poke_id] = self._entry(record)
            self._stats[record.poke_id] = self._bag_stat(record.poke_id)
            self._write_index(self._index)
            return path

    def ids(self) -> List[str]:
        """Return the poke ids in store order."""
        return sorted(self._index)

    def entries(self) -> List[dict]:
        """Return the index entry of every poke, without time series, in store order."""
        return [self._index[k] for k in self.ids()]

    def __len__(self) -> int:
        """Return the number of stored pokes."""
        return len(self._index)

    def get(self, poke_id: str) -> PokeRecord:
        """Load one poke.

        An indexed bag that cannot be read (corrupted after it was indexed: bags are written
        atomically) is moved to ``quarantine/`` with the reason and leaves the index; its id
        is never reused.

        Raises:
            InvalidInput: a poke id that is no plain file name.
            DataError: an unknown id, or a corrupt bag (the message says where it went).

        """
        check_poke_id(poke_id, 'PokeStore.get: poke_id')
        if poke_id not in self._index:
            raise DataError(f'no poke {poke_id!r} in {self.root}')
        try:
            return self._read(poke_id)
        except DataError as exc:
            with self._lock:
                target = self._quarantine(self.root / poke_id, str(exc))
                self._stats.pop(poke_id, None)
                if self._index.pop(poke_id, None) is not None:
                    self._write_index(self._index)
            where = f'; moved to {target}' if target is not None else ''
            raise DataError(f'{exc}{where}') from exc

    def __iter__(self) -> Iterator[PokeRecord]:
        """Load every poke in order."""
        for poke_id in self.ids():
            yield self.get(poke_id)

    def refresh(self) -> Optional[List[str]]:
        """Re-read the directory (another process may have added pokes); return new ids."""
        with self._lock:
            before = set(self._index)
            self._index = self._load_index()
            return sorted(set(self._index) - before)
