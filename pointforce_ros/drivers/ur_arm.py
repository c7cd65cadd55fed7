"""Universal Robots arm driver on ur_rtde 1.6.5: motion commands, tare and a 250 Hz F/T stream.

No ur_rtde object lives in the caller's process: a ur_rtde interface whose controller died can
abort the process that destroys it (see :mod:`pointforce_ros.drivers.rtde_host`), and a node
must outlive its robot. Connections held by :class:`UrArm` (each its own TCP connection to the
controller):

- ``RTDEControlInterface`` (``frequency``, 500 Hz on an e-Series): every command, and
- ``RTDEReceiveInterface`` for status queries made by the caller's thread, both in the host
  process of :class:`~pointforce_ros.drivers.rtde_host.RtdeHost`, called through proxies; a
  host that dies is a lost connection.
- the stream: a second ``RTDEReceiveInterface``, also at ``frequency``, owned by a small worker
  process (``python -m pointforce_ros.drivers.ur_arm --stream-worker ...``, started and stopped
  by :class:`UrArm`). ur_rtde keeps only the newest controller sample, so whoever polls it must
  never be late by more than a period; in a ROS node the executor threads hold the GIL for
  milliseconds at a time (measured here: two busy Python threads cut a polling thread from
  250 Hz to ~100 Hz), so the poller has a GIL of its own. It polls every 0.5 ms, keeps one
  controller sample per ``1 / stream_hz`` slot of controller time (de-duplicated on
  ``getTimestamp``; a slot holds two 500 Hz samples, so one sample lost under load opens no
  gap), re-reads a sample whose timestamp changed mid-read, and detects the faults below. A
  slot that passed unread is never silent: the sample after it carries a :class:`StreamLoss`
  (:meth:`UrArm.stream_losses`, :attr:`UrArm.lost_samples`) with how long the poller was held
  up before it (no poll, or no new controller sample: a loaded machine, or the controller's
  samples arriving in a burst, which can overwrite a slot within a poll or two). A
  reader thread in this process hands the :class:`ArmSample` records to callbacks, a bounded
  ring buffer and any running :meth:`UrArm.push_until`; the pipe between them buffers ~2 s, so
  a late reader delays samples but loses none. ``waitPeriod`` is not used: it truncates the
  period to whole milliseconds. Where the OS permits it (root, ``CAP_SYS_NICE`` or an
  ``rtprio`` limit, as on a real-time robot PC), the worker runs under ``SCHED_FIFO``: ur_rtde's
  threads at ``rt_priority`` and the poller one below, so that a loaded machine's other work
  cannot starve them for a slot (with two busy processes beside it, the stream tests failed 4
  of 9 runs at normal priority here, 0 of 9 under ``SCHED_FIFO``); where it does not, all stay
  at normal priority and :attr:`UrArm.stream_scheduling` says why.

Faults are reported as :class:`ArmEvent` records, never silently: ``stall`` (no new controller
sample for ``stall_timeout`` of the poller's running time: a time the stream worker itself was
not run, over half ``stall_timeout``, is a stream loss, not a stall), ``ft_frozen``
(``actual_TCP_force`` bitwise identical for ``ft_freeze_timeout`` of controller time while the
timestamp advances: a real F/T sensor always has noise), ``protective_stop``,
``program_stopped`` and ``connection_lost``, each with a matching ``*_cleared`` event when the
condition ends (``connection_lost`` never ends: build a new :class:`UrArm`).

Units SI, frames as ur_rtde reports them: TCP pose ``[x, y, z, rx, ry, rz]`` (m, rotation vector
in rad) in ``base``; wrench ``[fx, fy, fz, tx, ty, tz]`` (N, N m) base-oriented, tared, the
reaction of the environment on the tool.
"""

import argparse
from collections import deque
from dataclasses import dataclass, field
import json
import math
import os
from pathlib import Path
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np
import rtde_receive

from pointforce_ros.drivers.rtde_host import RtdeHost
from pointforce_ros.errors import DeviceFault, InvalidInput, UnsafeCommand

STREAM_VARIABLES = ['timestamp', 'actual_TCP_pose', 'actual_TCP_force', 'safety_status_bits',
                    'runtime_state', 'robot_mode', 'safety_mode']
STATUS_VARIABLES = STREAM_VARIABLES + ['actual_TCP_speed', 'robot_status_bits']
STREAM_RT_PRIORITY = 80
"""Default ``SCHED_FIFO`` priority of the stream worker's ur_rtde threads (see the module)."""
RUNTIME_PLAYING = 2
CONTROLLER_PORTS = ((29999, 'dashboard'), (30004, 'RTDE'), (30003, 'script'))

EVENT_STALL = 'stall'
EVENT_FT_FROZEN = 'ft_frozen'
EVENT_PROTECTIVE_STOP = 'protective_stop'
EVENT_PROGRAM_STOPPED = 'program_stopped'
EVENT_CONNECTION_LOST = 'connection_lost'
FAULT_KINDS = (EVENT_CONNECTION_LOST, EVENT_PROTECTIVE_STOP, EVENT_PROGRAM_STOPPED,
               EVENT_STALL, EVENT_FT_FROZEN)
"""Fault kinds, most fundamental first (a protective stop also pauses the program)."""

_HEADER = struct.Struct('<cH')       # worker -> parent message: kind, payload length
_SAMPLE = struct.Struct('<14d')      # t_wall, t_controller, pose (6), wrench (6)
_LOSS = struct.Struct('<dqd')        # StreamLoss: t_controller, lost, held_s
_PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])


@dataclass(frozen=True)
class ArmSample:
    """One controller sample as the stream delivered it.

    Attributes:
        t_wall: wall-clock (ROS) time when the driver read it, s since the epoch.
        t_controller: controller timestamp, s since controller start; strictly increasing.
        pose: (6,) TCP pose ``[x, y, z, rx, ry, rz]``, m and rad, ``base``.
        wrench: (6,) ``actual_TCP_force``: N and N m, base-oriented, tared.

    """

    t_wall: float
    t_controller: float
    pose: np.ndarray
    wrench: np.ndarray


@dataclass(frozen=True)
class ArmEvent:
    """A fault or recovery the stream thread detected.

    Attributes:
        kind: one of :data:`FAULT_KINDS`, or that name with ``_cleared`` appended.
        t_wall: wall-clock time of detection, s since the epoch.
        message: what was seen, for a log or an abort message.

    """

    kind: str
    t_wall: float
    message: str


@dataclass(frozen=True)
class StreamLoss:
    """Slots of the stream that passed without a sample (the poller read none of them).

    Attributes:
        t_controller: controller time of the first sample after the loss, s.
        lost: number of ``1 / stream_hz`` slots with no sample before it.
        held_s: the longest the poller went, since the sample before the loss, without a poll
            or without a new controller sample, wall seconds: tens of milliseconds when the
            poller or the stream was held up (a loaded machine at normal priority, a late
            controller); a few when the controller's samples came in a burst (a slot the
            poller sees is always kept, so every loss is one it never saw).

    """

    t_controller: float
    lost: int
    held_s: float


@dataclass(frozen=True)
class PushResult:
    """Samples and outcome of one :meth:`UrArm.push_until`.

    Attributes:
        t_wall: (T,) wall-clock time of each sample, s.
        t_controller: (T,) controller time, s, strictly increasing.
        tcp_pose: (T, 6) TCP pose, ``base``.
        wrench: (T, 6) tared base-oriented wrench.
        outcome: ``force_limit``, ``depth_limit``, ``canceled`` or ``aborted: <why>``.
        peak_force: largest push-back force along ``-direction`` in the record, N (the
            overshoot past a force limit included).
        max_travel: largest TCP travel along ``direction`` from the stand-off pose in the
            record, m.
        standoff: (6,) the stand-off pose the push started from.
        direction: (3,) unit push direction, ``base``.
        events: fault events seen during the push.

    """

    t_wall: np.ndarray
    t_controller: np.ndarray
    tcp_pose: np.ndarray
    wrench: np.ndarray
    outcome: str
    peak_force: float
    max_travel: float
    standoff: np.ndarray
    direction: np.ndarray
    events: Tuple[ArmEvent, ...] = field(default_factory=tuple)

    def __len__(self) -> int:
        """Return the number of samples."""
        return len(self.t_controller)

    def push_force(self) -> np.ndarray:
        """Return the (T,) push-back force along ``-direction``, N (> 0 pushing in)."""
        return -(self.wrench[:, :3] @ self.direction)

    def travel(self) -> np.ndarray:
        """Return the (T,) TCP travel along ``direction`` from the stand-off pose, m."""
        return (self.tcp_pose[:, :3] - self.standoff[:3]) @ self.direction


def active_fault_message(events: Sequence[ArmEvent], active: Sequence[str]) -> str:
    """Describe the faults in ``active`` by their newest event, most fundamental first.

    A condition that has cleared since (its newest event is ``<kind>_cleared``) is not named,
    so the message never reports a fault and its recovery together (issue 16: "no new
    controller sample for 0.050 s; controller samples flowing again; RTDE connection lost").

    Args:
        events: fault and recovery events, oldest first (:meth:`UrArm.events`).
        active: fault kinds active now.

    Returns:
        The active faults' messages joined by ``'; '``, or their kinds when no event of them
        is left in ``events``.

    """
    newest = {}
    for event in events:
        kind = event.kind[:-len('_cleared')] if event.kind.endswith('_cleared') else event.kind
        newest[kind] = event
    parts = [newest[k].message for k in FAULT_KINDS
             if k in active and k in newest and newest[k].kind == k]
    return '; '.join(parts) if parts else ', '.join(k for k in FAULT_KINDS if k in active)


class PushFault(DeviceFault):
    """A push ended on a device fault. The samples recorded up to then are kept.

    Attributes:
        kind: the fault kind (one of :data:`FAULT_KINDS` or ``timeout`` / ``command_failed``).
        result: :class:`PushResult` with every sample recorded, outcome ``aborted: <kind>``.
        detected_wall: wall-clock time the fault was detected (the arm was told to stop then).
        retracted: whether the arm was moved back to the stand-off pose.

    """

    def __init__(self, message: str, kind: str, result: PushResult, detected_wall: float,
                 retracted: bool):
        super().__init__(message)
        self.kind = kind
        self.result = result
        self.detected_wall = detected_wall
        self.retracted = retracted


def _vector(value, name: str, size: int) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise InvalidInput(f'{name}: cannot be read as {size} floats: {exc}')
    if arr.shape != (size,):
        raise InvalidInput(f'{name}: expected {size} values, got {arr.size}')
    if not np.all(np.isfinite(arr)):
        raise InvalidInput(f'{name}: NaN or infinite value in {arr.tolist()}')
    return arr


def _positive(value, name: str, upper: float, unit: str) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f'{name}: must be a number, got {value!r}')
    if not math.isfinite(value) or value <= 0.0:
        raise InvalidInput(f'{name}: must be positive and finite, got {value}')
    if value > upper:
        raise UnsafeCommand(f'{name}: {value:g} {unit} exceeds the limit of {upper:g} {unit}')
    return value


class UrArm:
    """A UR arm through ur_rtde, with a 250 Hz pose + wrench stream and fault detection.

    Args:
        host: controller address (a real robot, or the loopback emulator).
        frequency: RTDE frequency of every interface, Hz (500 on an e-Series).
        stream_hz: rate of delivered samples, Hz (<= ``frequency``).
        connect_timeout: deadline to reach the controller ports and get the first sample, s.
        stall_timeout: no new controller sample for this long is a ``stall``, s.
        ft_freeze_timeout: a bitwise-constant wrench for this long (controller time) is
            ``ft_frozen``, s; ``None`` disables the check (a noise-free simulated sensor).
        buffer_size: capacity of the ring buffer of recent samples.
        max_speed: largest accepted TCP speed for moves, m/s.
        max_accel: largest accepted TCP acceleration, m/s^2.
        rt_priority: ``SCHED_FIFO`` priority (1-98) of the stream worker's ur_rtde threads (the
            poller gets one less, at least 1), where the OS permits it; 0 leaves the worker
            at normal priority.

    Raises:
        InvalidInput: malformed arguments.
        DeviceFault: a controller port does not answer, ur_rtde fails to connect, or no sample
            arrives before the deadline; the message names the host.

    """

    def __init__(self, host: str, frequency: float = 500.0, stream_hz: float = 250.0, *,
                 connect_timeout: float = 5.0, stall_timeout: float = 0.05,
                 ft_freeze_timeout: Optional[float] = 0.05, buffer_size: int = 15000,
                 max_speed: float = 0.5, max_accel: float = 3.0,
                 rt_priority: int = STREAM_RT_PRIORITY):
        if not isinstance(host, str) or not host.strip():
            raise InvalidInput('host: must be a non-empty address string')
        self.host = host
        self.frequency = _positive(frequency, 'frequency', 500.0, 'Hz')
        self.stream_hz = _positive(stream_hz, 'stream_hz', self.frequency, 'Hz')
        self.stall_timeout = _positive(stall_timeout, 'stall_timeout', 10.0, 's')
        self.ft_freeze_timeout = (None if ft_freeze_timeout is None else
                                  _positive(ft_freeze_timeout, 'ft_freeze_timeout', 10.0, 's'))
        self.max_speed = _positive(max_speed, 'max_speed', 3.0, 'm/s')
        self.max_accel = _positive(max_accel, 'max_accel', 150.0, 'm/s^2')
        if int(buffer_size) < 1:
            raise InvalidInput(f'buffer_size: must be >= 1, got {buffer_size}')
        if (isinstance(rt_priority, bool) or not isinstance(rt_priority, (int, np.integer))
                or not 0 <= rt_priority <= 98):
            raise InvalidInput(f'rt_priority: must be an integer in 0-98, got {rt_priority!r}')
        self.rt_priority = int(rt_priority)
        self.stream_scheduling: Optional[str] = None
        connect_timeout = _positive(connect_timeout, 'connect_timeout', 600.0, 's')

        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._cmd_lock = threading.RLock()
        self._ring = deque(maxlen=int(buffer_size))
        self._recorders: List[list] = []
        self._sample_callbacks: List[Callable[[ArmSample], None]] = []
        self._event_callbacks: List[Callable[[ArmEvent], None]] = []
        self._events = deque(maxlen=1000)
        self._losses = deque(maxlen=1000)
        self.lost_samples = 0
        """Stream slots that passed without a sample since the stream started (every one is in
        a :class:`StreamLoss`; the newest 1000 records are kept)."""
        self._event_count = 0
        self._active = set()
        self._sample_count = 0
        self._speeding = False
        self._closed = False
        self._ctrl = self._rx = None
        self._host: Optional[RtdeHost] = None
        self._worker: Optional[subprocess.Popen] = None
        self._reader: Optional[threading.Thread] = None
        self._worker_state = {'ready': False, 'error': None}
        self.callback_errors = 0
        """Sample and event callbacks that raised (each counted, the stream thread went on)."""
        self.last_callback_error: Optional[str] = None

        deadline = time.monotonic() + connect_timeout
        self._probe_ports(deadline)
        try:
            self._host = RtdeHost(host, self.frequency, STATUS_VARIABLES,
                                  max(deadline - time.monotonic(), 1.0))
        except (RuntimeError, ValueError, OSError) as exc:
            raise DeviceFault(f'UR controller {host}: ur_rtde could not connect: {exc}') from exc
        self._ctrl, self._rx = self._host.ctrl, self._host.rx
        self._start_worker()
        with self._cond:
            while (self._sample_count == 0 and self._worker_state['error'] is None
                   and time.monotonic() < deadline):
                self._cond.wait(0.05)
            got_sample = self._sample_count > 0
            error = self._worker_state['error']
        if not got_sample:
            self.close()
            raise DeviceFault(f'UR controller {host}: no RTDE sample on the stream within '
                              f'{connect_timeout:g} s of connecting'
                              + (f': {error}' if error else ''))

    # -- connection ---------------------------------------------------------------------------
    def _probe_ports(self, deadline: float) -> None:
        for port, name in CONTROLLER_PORTS:
            left = deadline - time.monotonic()
            if left <= 0.0:
                raise DeviceFault(f'UR controller {self.host}: connect deadline passed before '
                                  f'the {name} port {port} was reached')
            try:
                with socket.create_connection((self.host, port), timeout=left):
                    pass
            except OSError as exc:
                raise DeviceFault(f'UR controller {self.host}: {name} port {port} does not '
                                  f'answer ({exc}); is the robot on and reachable?') from exc

    def close(self) -> None:
        """Stop the stream worker, stop the control script and disconnect (idempotent)."""
        if self._closed:
            return
        self._closed = True
        if self._worker is not None and self._worker.poll() is None:
            self._worker.send_signal(signal.SIGTERM)   # it disconnects while we do
        if (self._ctrl is not None and self._safe_connected(self._ctrl)
                and self._controller_alive()):
            try:
                if self._ctrl.isProgramRunning():
                    self._ctrl.stopScript()
            except RuntimeError:
                pass
        self._disconnect_all()
        self._stop_worker()

    def _disconnect_all(self) -> None:
        if self._host is not None:
            self._host.close()

    @staticmethod
    def _safe_connected(iface) -> bool:
        try:
            return bool(iface.isConnected())
        except RuntimeError:
            return False

    def __enter__(self) -> 'UrArm':
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- stream worker ------------------------------------------------------------------------
    def _start_worker(self) -> None:
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(
            [_PACKAGE_ROOT] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
        freeze = 'none' if self.ft_freeze_timeout is None else repr(self.ft_freeze_timeout)
        cmd = [sys.executable, '-m', 'pointforce_ros.drivers.ur_arm', '--stream-worker',
               self.host, repr(self.frequency), repr(self.stream_hz), repr(self.stall_timeout),
               freeze, str(os.getpid()), str(self.rt_priority)]
        try:
            self._worker = subprocess.Popen(cmd, stdin=subprocess.DEVNULL,
                                            stdout=subprocess.PIPE, env=env)
        except OSError as exc:
            self._disconnect_all()
            raise DeviceFault(f'UR controller {self.host}: cannot start the stream worker: '
                              f'{exc}') from exc
        self._reader = threading.Thread(target=self._read_worker, daemon=True,
                                        name=f'ur_arm_stream_{self.host}')
        self._reader.start()

    @property
    def stream_pid(self) -> Optional[int]:
        """Process id of the stream worker (``None`` before it started)."""
        return None if self._worker is None else self._worker.pid

    def _stop_worker(self) -> None:
        worker = self._worker
        if worker is not None and worker.poll() is None:
            worker.send_signal(signal.SIGTERM)
            try:
                worker.wait(3.0)
            except subprocess.TimeoutExpired:
                worker.kill()
                worker.wait(3.0)
        if self._reader is not None:
            self._reader.join(timeout=2.0)
        if worker is not None and worker.stdout is not None:
            worker.stdout.close()

    def _read_worker(self) -> None:
        pipe = self._worker.stdout
        while True:
            head = pipe.read(_HEADER.size)
            if len(head) < _HEADER.size:
                break
            kind, size = _HEADER.unpack(head)
            payload = pipe.read(size) if size else b''
            if len(payload) < size:
                break
            if kind == b'S':
                row = _SAMPLE.unpack(payload)
                self._deliver(ArmSample(row[0], row[1], np.array(row[2:8]),
                                        np.array(row[8:14])))
            elif kind == b'E':
                info = json.loads(payload)
                if info['cleared']:
                    self._clear(info['kind'], info['message'], info['t_wall'])
                else:
                    self._emit(info['kind'], info['message'], info['t_wall'])
            elif kind == b'L':
                loss = StreamLoss(*_LOSS.unpack(payload))
                with self._cond:
                    self._losses.append(loss)
                    self.lost_samples += loss.lost
            elif kind == b'P':
                self.stream_scheduling = json.loads(payload)['scheduling']
            elif kind == b'X':
                with self._cond:
                    self._worker_state['error'] = json.loads(payload)['message']
                    self._cond.notify_all()
        code = self._worker.wait()
        if not self._closed:
            with self._cond:
                if self._worker_state['error'] is None and self._sample_count == 0:
                    self._worker_state['error'] = f'stream worker exited with code {code}'
                    self._cond.notify_all()
            self._emit(EVENT_CONNECTION_LOST,
                       f'stream from {self.host} ended (worker exit code {code})'
                       + (f': {self._worker_state["error"]}'
                          if self._worker_state['error'] else ''))

    def _deliver(self, sample: ArmSample) -> None:
        with self._cond:
            self._ring.append(sample)
            self._sample_count += 1
            for rec in self._recorders:
                rec.append(sample)
            callbacks = list(self._sample_callbacks)
            self._cond.notify_all()
        for callback in callbacks:
            self._call(callback, sample)

    def _emit(self, kind: str, message: str, t_wall: Optional[float] = None) -> None:
        with self._cond:
            if kind in self._active:
                return
            self._active.add(kind)
        self._publish(ArmEvent(kind, time.time() if t_wall is None else t_wall, message))

    def _clear(self, kind: str, message: str, t_wall: Optional[float] = None) -> None:
        with self._cond:
            if kind not in self._active:
                return
            self._active.discard(kind)
        self._publish(ArmEvent(kind + '_cleared', time.time() if t_wall is None else t_wall,
                               message))

    def _publish(self, event: ArmEvent) -> None:
        with self._cond:
            self._events.append(event)
            self._event_count += 1
            callbacks = list(self._event_callbacks)
            self._cond.notify_all()
        for callback in callbacks:
            self._call(callback, event)

    def _call(self, callback, item) -> None:
        """Run one subscriber's callback; whatever it raises is counted, never the stream's end.

        The stream thread also feeds the ring buffer, the push recorders and every other
        subscriber: one that raises (a message it cannot build, a full queue, MemoryError) must
        not stop them. ``callback_errors`` counts such failures, ``last_callback_error`` says
        the last one.
        """
        try:
            callback(item)
        except Exception as exc:  # noqa: BLE001 - a subscriber never ends the stream thread
            with self._cond:
                self.callback_errors += 1
                self.last_callback_error = (f'{getattr(callback, "__qualname__", callback)}: '
                                            f'{type(exc).__name__}: {exc}')

    # -- stream access ------------------------------------------------------------------------
    def add_sample_callback(self, callback: Callable[[ArmSample], None]) -> None:
        """Call ``callback(sample)`` from the stream thread for every sample (keep it short).

        An exception it raises is counted in ``callback_errors`` and the stream goes on.
        """
        with self._lock:
            self._sample_callbacks.append(callback)

    def remove_sample_callback(self, callback: Callable[[ArmSample], None]) -> None:
        """Stop calling ``callback``; unknown callbacks are ignored."""
        with self._lock:
            if callback in self._sample_callbacks:
                self._sample_callbacks.remove(callback)

    def add_event_callback(self, callback: Callable[[ArmEvent], None]) -> None:
        """Call ``callback(event)`` from the stream thread for every fault or recovery."""
        with self._lock:
            self._event_callbacks.append(callback)

    def samples(self) -> List[ArmSample]:
        """Return a copy of the ring buffer, oldest first."""
        with self._lock:
            return list(self._ring)

    def latest(self) -> ArmSample:
        """Return the newest sample (the constructor guarantees there is one)."""
        with self._lock:
            return self._ring[-1]

    def events(self) -> List[ArmEvent]:
        """Return a copy of the recent fault and recovery records, oldest first."""
        with self._lock:
            return list(self._events)

    def stream_losses(self) -> List[StreamLoss]:
        """Return a copy of the recent stream losses, oldest first (see :class:`StreamLoss`)."""
        with self._lock:
            return list(self._losses)

    def active_faults(self) -> List[str]:
        """Return the fault kinds in effect now, in :data:`FAULT_KINDS` order."""
        with self._lock:
            return [k for k in FAULT_KINDS if k in self._active]

    def wait_samples(self, count: int, timeout: float) -> bool:
        """Block until ``count`` more samples arrived; False on timeout."""
        deadline = time.monotonic() + timeout
        with self._cond:
            target = self._sample_count + count
            while self._sample_count < target:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    return False
                self._cond.wait(left)
            return True

    # -- status ---------------------------------------------------------------------------------
    @property
    def host_pid(self) -> int:
        """Pid of the process that holds the ur_rtde control and status interfaces."""
        return self._host.process.pid

    def is_connected(self) -> bool:
        """Return True while every ur_rtde interface is connected."""
        worker_alive = self._worker is not None and self._worker.poll() is None
        return (worker_alive and self._host.alive() and EVENT_CONNECTION_LOST not in self._active
                and all(self._safe_connected(i) for i in (self._ctrl, self._rx)))

    def is_protective_stopped(self) -> bool:
        """Return True if the status interface or the stream thread sees a protective stop.

        Raises:
            DeviceFault: the connection is lost.

        """
        self._require_connection('isProtectiveStopped')
        with self._lock:
            seen_by_stream = EVENT_PROTECTIVE_STOP in self._active
        return seen_by_stream or bool(self._rx.isProtectiveStopped())

    def is_program_running(self) -> bool:
        """Return True while the ur_rtde control script runs on the controller."""
        self._require_connection('getRuntimeState')
        return self._rx.getRuntimeState() == RUNTIME_PLAYING

    def tcp_pose(self) -> np.ndarray:
        """Return the (6,) current TCP pose, ``base``."""
        self._require_connection('getActualTCPPose')
        return np.array(self._rx.getActualTCPPose(), dtype=float)

    def tcp_wrench(self) -> np.ndarray:
        """Return the (6,) current tared base-oriented wrench."""
        self._require_connection('getActualTCPForce')
        return np.array(self._rx.getActualTCPForce(), dtype=float)

    def _controller_alive(self, window: float = 0.03) -> bool:
        """Return True when the status interface sees the controller timestamp advance."""
        if self._rx is None or not self._safe_connected(self._rx):
            return False
        try:
            first = self._rx.getTimestamp()
            deadline = time.monotonic() + window
            while time.monotonic() < deadline:
                time.sleep(0.002)
                if self._rx.getTimestamp() != first:
                    return True
        except RuntimeError:
            return False
        return False

    def _require_connection(self, what: str) -> None:
        if self._closed:
            raise DeviceFault(f'UR arm {self.host}: {what} after close()')
        if not self.is_connected():
            raise DeviceFault(f'UR arm {self.host}: {what}: connection lost')

    def _diagnose(self, what: str) -> str:
        if not self.is_connected():
            return f'{what} on {self.host} failed: connection lost'
        if self.is_protective_stopped():
            return f'{what} on {self.host} failed: protective stop'
        if self._rx.getRuntimeState() != RUNTIME_PLAYING:
            return (f'{what} on {self.host} failed: control program not running '
                    f'(runtime_state {self._rx.getRuntimeState()})')
        return f'{what} on {self.host} failed: the controller rejected or timed out the command'

    def _check_ready(self, what: str) -> None:
        if self.is_protective_stopped():
            raise DeviceFault(f'{what} on {self.host}: the robot is protective stopped')
        if self._rx.getRuntimeState() != RUNTIME_PLAYING:
            raise DeviceFault(f'{what} on {self.host}: control program not running')

    # -- commands -------------------------------------------------------------------------------
    def tare(self) -> None:
        """Zero the F/T sensor (``zeroFtSensor``); do it right before every contact.

        Raises:
            DeviceFault: the controller refused (protective stop, program stopped, lost link).

        """
        self._check_ready('zeroFtSensor')
        with self._cmd_lock:
            ok = self._ctrl.zeroFtSensor()
        if not ok:
            raise DeviceFault(self._diagnose('zeroFtSensor'))

    def move_linear(self, pose6: Sequence[float], speed: float = 0.25, accel: float = 1.2,
                    asynchronous: bool = False) -> None:
        """Move linearly (moveL) to ``pose6`` (``base``); asynchronous moves return at once.

        A synchronous move cannot be cancelled: use ``asynchronous=True`` and :meth:`stop`.

        Raises:
            InvalidInput: malformed pose, speed or acceleration.
            UnsafeCommand: speed or acceleration above the configured limits.
            DeviceFault: the controller refused or lost the command (the message says why).

        """
        pose = _vector(pose6, 'pose6', 6)
        speed = _positive(speed, 'speed', self.max_speed, 'm/s')
        accel = _positive(accel, 'accel', self.max_accel, 'm/s^2')
        self._check_ready('moveL')
        with self._cmd_lock:
            self._speeding = False
            ok = self._ctrl.moveL(pose.tolist(), speed, accel, asynchronous)
        if not ok:
            raise DeviceFault(self._diagnose('moveL'))

    def is_moving(self) -> bool:
        """Return True while an asynchronous move started by :meth:`move_linear` runs."""
        self._require_connection('getAsyncOperationProgress')
        return self._ctrl.getAsyncOperationProgress() >= 0

    def wait_motion(self, timeout: float) -> None:
        """Wait for an asynchronous move to end, watching the stream for faults.

        Raises:
            DeviceFault: a fault event, or the move still running after ``timeout`` s.

        """
        deadline = time.monotonic() + timeout
        while self.is_moving():
            faults = self.active_faults()
            if faults:
                raise DeviceFault(f'UR arm {self.host}: move interrupted by {", ".join(faults)}')
            if time.monotonic() > deadline:
                raise DeviceFault(f'UR arm {self.host}: move still running after {timeout:g} s')
            self.wait_samples(1, 0.05)

    def stop(self, decel: float = 2.0) -> None:
        """Decelerate to rest: ``speedStop`` after :meth:`speed_linear`, else ``stopL``.

        Raises:
            InvalidInput: non-positive deceleration.
            DeviceFault: the connection is lost.

        """
        decel = _positive(decel, 'decel', 150.0, 'm/s^2')
        self._require_connection('stop')
        with self._cmd_lock:
            if self._speeding:
                self._speeding = False
                self._ctrl.speedStop(decel)
            else:
                self._ctrl.stopL(decel)

    def speed_linear(self, twist6: Sequence[float], accel: float = 0.5,
                     time_s: float = 0.0) -> None:
        """Move the TCP at ``twist6`` (speedL; m/s, rad/s, ``base``) until :meth:`stop`.

        Raises:
            InvalidInput: malformed twist or acceleration.
            UnsafeCommand: linear speed or acceleration above the configured limits.
            DeviceFault: the controller refused the command.

        """
        twist = _vector(twist6, 'twist6', 6)
        if float(np.linalg.norm(twist[:3])) > self.max_speed:
            raise UnsafeCommand(f'twist6: linear speed {np.linalg.norm(twist[:3]):g} m/s '
                                f'exceeds the limit of {self.max_speed:g} m/s')
        accel = _positive(accel, 'accel', self.max_accel, 'm/s^2')
        self._check_ready('speedL')
        with self._cmd_lock:
            ok = self._ctrl.speedL(twist.tolist(), accel, float(time_s))
            self._speeding = bool(ok)
        if not ok:
            raise DeviceFault(self._diagnose('speedL'))

    # -- the poke primitive ---------------------------------------------------------------------
    def push_until(self, standoff_pose6: Sequence[float], direction: Sequence[float], *,
                   force_limit: float, travel_limit: float, speed: float = 0.002,
                   accel: float = 0.1, approach_speed: float = 0.05, retract_speed: float = 0.01,
                   stop_decel: float = 10.0, cancel: Optional[Callable[[], bool]] = None,
                   settle_samples: int = 5, max_force: float = 100.0,
                   max_travel: float = 0.1,
                   phase: Optional[Callable[[str], None]] = None) -> PushResult:
        """Push from a stand-off pose along ``direction`` until a limit, then retract.

        Sequence: moveL to ``standoff_pose6`` (asynchronous, watched for faults), wait
        ``settle_samples``, tare, async moveL towards ``standoff + travel_limit * direction`` at
        ``speed`` (the controller itself never goes past the travel limit), and on every sample
        check the push-back force ``-wrench[:3] . direction`` against ``force_limit``,
        ``cancel()`` and the fault events. On a stop condition: ``stopL(stop_decel)``, settle,
        retract to the stand-off pose. Samples are recorded from just before the push starts
        until the retract ends. ``phase(name)`` is called as each step begins: ``approach``,
        ``tare``, ``push``, ``hold`` (stopped at the limit, settling) and ``retract``.

        Args:
            standoff_pose6: (6,) start pose, ``base``.
            direction: (3,) push direction in ``base`` (normalised here), e.g. ``-n``.
            force_limit: push-back force that ends the push, N.
            travel_limit: largest travel along ``direction`` from the stand-off pose, m.
            speed: constant push speed, m/s.
            accel: acceleration to reach ``speed``, m/s^2.
            approach_speed: speed of the move to the stand-off pose, m/s.
            retract_speed: speed of the retract, m/s.
            stop_decel: deceleration of the stop at a limit, m/s^2.
            cancel: polled once per sample; returning True ends the push as ``canceled``.
            settle_samples: samples to wait after arriving and after stopping.
            max_force: upper bound accepted for ``force_limit``, N.
            max_travel: upper bound accepted for ``travel_limit``, m.
            phase: called with the name of each step as it begins (the Poke action's
                ``PHASE_*`` values), on this thread; it must return quickly and not raise.

        Returns:
            :class:`PushResult` with outcome ``force_limit``, ``depth_limit`` or ``canceled``.

        Raises:
            InvalidInput: malformed pose, direction or limits.
            UnsafeCommand: a limit or speed above its bound.
            DeviceFault: the robot was not ready before the push started.
            PushFault: a protective stop, lost connection, stalled or frozen F/T stream, stopped
                program, failed command or timeout during the push; ``.result`` holds every
                sample recorded, the arm was stopped and, where the controller still accepts
                commands, retracted.

        """
        standoff = _vector(standoff_pose6, 'standoff_pose6', 6)
        unit = _vector(direction, 'direction', 3)
        norm = float(np.linalg.norm(unit))
        if norm < 1e-9:
            raise InvalidInput('direction: must be a non-zero 3-vector')
        unit = unit / norm
        force_limit = _positive(force_limit, 'force_limit', max_force, 'N')
        travel_limit = _positive(travel_limit, 'travel_limit', max_travel, 'm')
        speed = _positive(speed, 'speed', min(0.05, self.max_speed), 'm/s')
        accel = _positive(accel, 'accel', self.max_accel, 'm/s^2')
        approach_speed = _positive(approach_speed, 'approach_speed', self.max_speed, 'm/s')
        retract_speed = _positive(retract_speed, 'retract_speed', self.max_speed, 'm/s')
        stop_decel = _positive(stop_decel, 'stop_decel', 150.0, 'm/s^2')
        self._check_ready('push_until')

        target = standoff.copy()
        target[:3] += unit * travel_limit
        push_timeout = travel_limit / speed + 2.0 * speed / accel + 5.0
        recorder: list = []
        state = {'peak': 0.0, 'travel': 0.0, 'events_seen': 0}

        def result(outcome: str) -> PushResult:
            with self._lock:
                if recorder in self._recorders:
                    self._recorders.remove(recorder)
                rows = list(recorder)
                events = tuple(list(self._events)[-(self._event_count - state['events_seen']):]
                               if self._event_count > state['events_seen'] else ())
            pose = np.array([s.pose for s in rows], dtype=float).reshape(-1, 6)
            wrench = np.array([s.wrench for s in rows], dtype=float).reshape(-1, 6)
            return PushResult(
                t_wall=np.array([s.t_wall for s in rows], dtype=float),
                t_controller=np.array([s.t_controller for s in rows], dtype=float),
                tcp_pose=pose, wrench=wrench, outcome=outcome,
                peak_force=float(max(0.0, (-(wrench[:, :3] @ unit)).max(initial=0.0))),
                max_travel=float(max(0.0, ((pose[:, :3] - standoff[:3]) @ unit).max(
                    initial=0.0))),
                standoff=standoff, direction=unit, events=events)

        def enter(name: str) -> None:
            if phase is not None:
                phase(name)

        # approach and tare (no recording yet)
        enter('approach')
        self._move_watched(standoff, approach_speed, 1.2, 'approach')
        self.wait_samples(settle_samples, 1.0)
        enter('tare')
        self.tare()
        with self._cond:
            state['events_seen'] = self._event_count
            self._recorders.append(recorder)
        self.wait_samples(settle_samples, 1.0)

        outcome = None
        fault = None
        enter('push')
        try:
            with self._cmd_lock:
                ok = self._ctrl.moveL(target.tolist(), speed, accel, True)
            if not ok:
                fault = ('command_failed', self._diagnose('moveL (push)'), time.time())
            deadline = time.monotonic() + push_timeout
            seen = 0
            while fault is None and outcome is None:
                with self._cond:
                    if len(recorder) == seen and not self._active:
                        self._cond.wait(0.02)
                    fresh = recorder[seen:]
                    seen = len(recorder)
                    active = [k for k in FAULT_KINDS if k in self._active]
                for sample in fresh:
                    push_force = -float(sample.wrench[:3] @ unit)
                    travel = float((sample.pose[:3] - standoff[:3]) @ unit)
                    state['peak'] = max(state['peak'], push_force)
                    state['travel'] = max(state['travel'], travel)
                    if push_force >= force_limit:
                        outcome = 'force_limit'
                        break
                if outcome is not None:
                    break
                if active:
                    fault = (active[0], f'push on {self.host} aborted: '
                             + active_fault_message(self.events(), active), time.time())
                    break
                if cancel is not None and cancel():
                    outcome = 'canceled'
                    break
                if self._ctrl.getAsyncOperationProgress() < 0:
                    outcome = 'depth_limit'
                    break
                if time.monotonic() > deadline:
                    fault = ('timeout', f'push on {self.host} did not finish within '
                             f'{push_timeout:.1f} s', time.time())
        except RuntimeError as exc:
            fault = ('command_failed', f'push on {self.host}: ur_rtde error: {exc}', time.time())

        detected = time.time()
        stoppable = fault is None or fault[0] in (EVENT_FT_FROZEN, 'timeout') or (
            fault[0] == EVENT_STALL and self._controller_alive())
        if fault is None:
            enter('hold')
        if stoppable and self._safe_connected(self._ctrl):
            try:
                with self._cmd_lock:
                    self._ctrl.stopL(stop_decel)
            except RuntimeError:
                pass
        if fault is None:
            self.wait_samples(settle_samples, 1.0)
            enter('retract')
            try:
                self._move_watched(standoff, retract_speed, 0.5, 'retract')
            except DeviceFault as exc:
                kind = self.active_faults()[0] if self.active_faults() else 'command_failed'
                fault = (kind, f'retract after {outcome} failed: {exc}', time.time())
                detected = fault[2]
            else:
                self.wait_samples(settle_samples, 1.0)
                return result(outcome)
        kind, message, detected = fault[0], fault[1], fault[2] if fault[2] else detected
        retracted = False
        if stoppable and self.is_connected():
            try:
                self.wait_samples(settle_samples, 0.5)
                enter('retract')
                self._move_watched(standoff, retract_speed, 0.5, 'retract', ignore=kind)
                retracted = True
            except DeviceFault:
                retracted = False
        raise PushFault(message, kind, result(f'aborted: {kind}'), detected, retracted)

    def _move_watched(self, pose: np.ndarray, speed: float, accel: float, what: str,
                      ignore: Optional[str] = None) -> None:
        """Async moveL watched for faults (a synchronous one could hang on a lost link)."""
        speed = min(speed, self.max_speed)
        accel = min(accel, self.max_accel)
        self._require_connection(what)
        with self._cmd_lock:
            self._speeding = False
            ok = self._ctrl.moveL(pose.tolist(), speed, accel, True)
        if not ok:
            raise DeviceFault(self._diagnose(f'moveL ({what})'))
        current = self.latest().pose[:3]
        distance = float(np.linalg.norm(pose[:3] - current))
        timeout = distance / speed + 2.0 * speed / accel + 5.0
        deadline = time.monotonic() + timeout
        while self._ctrl.getAsyncOperationProgress() >= 0:
            faults = [f for f in self.active_faults() if f != ignore]
            if faults:
                with self._cmd_lock:
                    if self._safe_connected(self._ctrl) and EVENT_PROTECTIVE_STOP not in faults:
                        self._ctrl.stopL(2.0)
                raise DeviceFault(f'{what} on {self.host} interrupted by {", ".join(faults)}')
            if time.monotonic() > deadline:
                raise DeviceFault(f'{what} on {self.host} still running after {timeout:.1f} s')
            self.wait_samples(1, 0.05)


# ------------------------------------------------------------------------------------------------
# the stream worker process

class _StreamPoller:
    """Polling loop over one ``RTDEReceiveInterface``: slots, de-duplication, fault detection.

    ``on_sample(t_wall, t_controller, pose, wrench)`` gets every kept sample;
    ``on_event(kind, message, cleared)`` gets each change of a fault condition;
    ``on_loss(t_controller, lost, held_s)`` (a :class:`StreamLoss`) comes before a sample that
    follows slots with none.
    """

    def __init__(self, rx, host: str, frequency: float, stream_hz: float, stall_timeout: float,
                 ft_freeze_timeout: Optional[float], on_sample, on_event, on_loss=None):
        self.rx = rx
        self.host = host
        self.slot_period = 1.0 / stream_hz
        self.slot_offset = 0.5 / frequency
        self.stall_timeout = stall_timeout
        self.ft_freeze_timeout = ft_freeze_timeout
        self.on_sample = on_sample
        self.on_event = on_event
        self.on_loss = on_loss
        self.active = set()

    def _event(self, kind: str, message: str, cleared: bool = False) -> None:
        if cleared == (kind not in self.active):
            return
        if cleared:
            self.active.discard(kind)
        else:
            self.active.add(kind)
        self.on_event(kind, message, cleared)

    def _read(self, t: float):
        for _ in range(3):
            pose = self.rx.getActualTCPPose()
            wrench = self.rx.getActualTCPForce()
            t_after = self.rx.getTimestamp()
            if t_after == t:
                return t, pose, wrench
            t = t_after
        return None

    def run(self, should_stop: Callable[[], bool]) -> None:
        """Poll every 0.5 ms until ``should_stop()`` or the connection is lost."""
        rx = self.rx
        last_t = None
        last_slot = None
        last_new = time.monotonic()
        last_wrench = None
        frozen_since = None
        protective = False
        playing = None
        polled = time.monotonic()
        held = 0.0        # longest without a poll or a new sample since the last kept sample
        while not should_stop():
            try:
                if not rx.isConnected():
                    self._event(EVENT_CONNECTION_LOST, f'RTDE connection to {self.host} lost')
                    return
                t = rx.getTimestamp()
                now = time.monotonic()
                gap = now - polled
                held = max(held, gap)
                polled = now
                if gap > 0.5 * self.stall_timeout:
                    # this poller did not run for `gap` (SIGSTOP, a loaded machine), nor did
                    # ur_rtde's receive thread beside it: whether the controller was silent
                    # then is unknown, and that time does not count towards a stall (the
                    # slots it let pass are reported as a stream loss; a poller that resumes
                    # before the receive thread took a hold of 60 ms for a stall, session 44)
                    last_new += gap
                if t == last_t:
                    if now - last_new > self.stall_timeout:
                        self._event(EVENT_STALL,
                                    f'no new controller sample for {now - last_new:.3f} s')
                    time.sleep(0.0005)
                    continue
                held = max(held, now - last_new)
                last_new = now
                if last_t is not None and t < last_t:
                    last_slot = None
                last_t = t
                self._event(EVENT_STALL, 'controller samples flowing again', cleared=True)
                slot = math.floor((t + self.slot_offset) / self.slot_period)
                if last_slot is None or slot > last_slot:
                    got = self._read(t)
                    if got is not None:
                        t, pose, wrench = got
                        last_t = t
                        slot = math.floor((t + self.slot_offset) / self.slot_period)
                        if (last_slot is not None and slot > last_slot + 1
                                and self.on_loss is not None):
                            self.on_loss(t, slot - last_slot - 1, held)
                        last_slot, held = slot, 0.0
                        self.on_sample(time.time(), t, pose, wrench)
                        if self.ft_freeze_timeout is not None:
                            if wrench == last_wrench:
                                if frozen_since is None:
                                    frozen_since = t
                                elif t - frozen_since >= self.ft_freeze_timeout - 1e-9:
                                    self._event(EVENT_FT_FROZEN, 'actual_TCP_force bitwise '
                                                f'constant for {t - frozen_since:.3f} s of '
                                                'controller time')
                            else:
                                frozen_since = None
                                self._event(EVENT_FT_FROZEN, 'F/T values changing again',
                                            cleared=True)
                            last_wrench = wrench
                now_protective = bool(rx.isProtectiveStopped())
                runtime = rx.getRuntimeState()
            except RuntimeError as exc:
                self._event(EVENT_CONNECTION_LOST, f'RTDE read from {self.host} failed: {exc}')
                return
            if now_protective != protective:
                self._event(EVENT_PROTECTIVE_STOP,
                            f'{self.host} is protective stopped' if now_protective
                            else 'protective stop released', cleared=not now_protective)
            protective = now_protective
            now_playing = runtime == RUNTIME_PLAYING
            if playing and not now_playing:
                self._event(EVENT_PROGRAM_STOPPED, f'control program on {self.host} is no '
                            f'longer running (runtime_state {runtime})')
            elif now_playing and playing is False:
                self._event(EVENT_PROGRAM_STOPPED, 'control program running', cleared=True)
            playing = now_playing
            time.sleep(0.0005)


def missing_slots(t_controller, stream_hz: float = 250.0,
                  frequency: float = 500.0) -> Tuple[np.ndarray, np.ndarray]:
    """``(after, count)``: where a recorded stream has slots without a sample, and how many.

    ``t_controller``: (T,) controller times of the delivered samples, s, increasing. A slot is
    ``1 / stream_hz`` of controller time, as the stream poller counts them (one sample kept per
    slot, a half ``1 / frequency`` period early so that a slot holds whole controller periods).
    ``after``: (G,) indices of the first sample after each run of empty slots; ``count``: (G,)
    the empty slots of each run. The stream reports the same runs as :class:`StreamLoss`.
    """
    t = np.asarray(t_controller, dtype=float).reshape(-1)
    slots = np.floor((t + 0.5 / frequency) / (1.0 / stream_hz))
    empty = np.diff(slots) - 1
    after = np.flatnonzero(empty > 0) + 1
    return after, empty[after - 1].astype(np.int64)


def unreported_runs(t_controller, losses, stream_hz: float = 250.0,
                    frequency: float = 500.0) -> List[Tuple[float, int, Optional[int]]]:
    """Return the runs of empty slots in a record that ``losses`` does not report as such.

    ``losses``: :class:`StreamLoss` records, or ``[t_controller, lost, ...]`` rows as a poke's
    ``meta['stream_losses']`` holds them. Each run :func:`missing_slots` finds must have a loss
    at the controller time of the sample after it with the same ``lost``; the others come
    back as ``(controller time after the run, empty slots, slots reported there or None)``.
    """
    t = np.asarray(t_controller, dtype=float).reshape(-1)
    reported = {}
    for loss in losses:
        at, lost = (loss.t_controller, loss.lost) if isinstance(loss, StreamLoss) else loss[:2]
        reported[round(float(at), 6)] = int(lost)
    out = []
    for k, count in zip(*missing_slots(t, stream_hz, frequency)):
        got = reported.get(round(float(t[k]), 6))
        if got != count:
            out.append((float(t[k]), int(count), got))
    return out


def _realtime_poller(rt_priority: int) -> str:
    """Put the calling thread under ``SCHED_FIFO`` one below ``rt_priority``, the others at it.

    Returns a line for :attr:`UrArm.stream_scheduling`: the priorities got and how many of
    the process's threads (ur_rtde's among them) run under ``SCHED_FIFO``, or why none does.
    """
    if rt_priority <= 0:
        return 'normal priority (rt_priority 0)'
    me = threading.get_native_id()
    poller = max(rt_priority - 1, 1)
    try:
        os.sched_setscheduler(me, os.SCHED_FIFO, os.sched_param(poller))
    except (OSError, AttributeError) as exc:
        return (f'normal priority: SCHED_FIFO {poller} refused ({exc}); grant '
                'CAP_SYS_NICE or an rtprio limit to keep the stream on a loaded machine')
    # ur_rtde 1.6.5's Python interface leaves its receive thread at normal priority whatever
    # its rt_priority argument says: the worker's other threads are ur_rtde's, set them here
    fifo = []
    for tid in sorted(int(t) for t in os.listdir('/proc/self/task')):
        try:
            if tid != me:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(rt_priority))
            fifo.append(os.sched_getparam(tid).sched_priority)
        except OSError:
            continue
    return (f'SCHED_FIFO: poller {poller}, ur_rtde\'s threads {rt_priority} '
            f'({len(fifo)} of the worker\'s threads under SCHED_FIFO)')


_KEPT = []
"""The stream worker's receive interfaces, referenced until ``os._exit`` (no destructor runs)."""


def _stream_worker(argv: Sequence[str]) -> int:
    """Entry of the stream worker process; writes framed messages to its original stdout."""
    parser = argparse.ArgumentParser(prog='ur_arm --stream-worker')
    parser.add_argument('host')
    parser.add_argument('frequency', type=float)
    parser.add_argument('stream_hz', type=float)
    parser.add_argument('stall_timeout', type=float)
    parser.add_argument('ft_freeze_timeout')
    parser.add_argument('parent_pid', type=int)
    parser.add_argument('rt_priority', type=int, nargs='?', default=0)
    args = parser.parse_args(argv)
    out_fd = os.dup(1)
    os.dup2(2, 1)   # anything ur_rtde prints goes to stderr, never into the message pipe
    stop = {'flag': False}

    def on_signal(signum, frame):
        stop['flag'] = True
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    def send(kind: bytes, payload: bytes) -> None:
        data = _HEADER.pack(kind, len(payload)) + payload
        while data:
            data = data[os.write(out_fd, data):]

    def on_sample(t_wall, t, pose, wrench):
        send(b'S', _SAMPLE.pack(t_wall, t, *pose, *wrench))

    def on_loss(t, lost, held_s):
        send(b'L', _LOSS.pack(t, lost, held_s))

    def on_event(kind, message, cleared):
        send(b'E', json.dumps({'kind': kind, 'message': message, 'cleared': cleared,
                               't_wall': time.time()}).encode())
    try:
        try:
            rx = rtde_receive.RTDEReceiveInterface(args.host, args.frequency, STREAM_VARIABLES)
            _KEPT.append(rx)   # never destroyed: the process leaves with os._exit
        except (RuntimeError, ValueError, OSError) as exc:
            send(b'X', json.dumps({'message': f'stream RTDEReceiveInterface: {exc}'}).encode())
            return 1
        freeze = None if args.ft_freeze_timeout == 'none' else float(args.ft_freeze_timeout)
        send(b'P', json.dumps({'scheduling': _realtime_poller(args.rt_priority)}).encode())
        poller = _StreamPoller(rx, args.host, args.frequency, args.stream_hz,
                               args.stall_timeout, freeze, on_sample, on_event, on_loss)
        checks = {'n': 0}

        def should_stop() -> bool:
            checks['n'] += 1
            if checks['n'] % 200 == 0 and os.getppid() != args.parent_pid:
                return True
            return stop['flag']
        poller.run(should_stop)
        if rx.isConnected():
            rx.disconnect()
        return 0
    except BrokenPipeError:
        return 0


if __name__ == '__main__':
    if len(sys.argv) > 1 and sys.argv[1] == '--stream-worker':
        _code = _stream_worker(sys.argv[2:])
        sys.stderr.flush()
        os._exit(_code)   # skip the interface's destructor, as the rtde_host process does
    sys.exit('usage: python -m pointforce_ros.drivers.ur_arm --stream-worker HOST FREQUENCY '
             'STREAM_HZ STALL_TIMEOUT FT_FREEZE_TIMEOUT|none PARENT_PID [RT_PRIORITY]')
