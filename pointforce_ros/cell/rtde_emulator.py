r"""Loopback UR controller emulator that the real ``ur_rtde`` 1.6.5 connects to.

Run it as its own process (the ur_rtde constructors hold the Python GIL through the handshake)::

    python -m pointforce_ros.cell.rtde_emulator --host 127.0.0.2 \
        --force-model pointforce_ros.cell.rtde_emulator:HalfSpaceSpring \\
        --force-model-kwargs '{"z0": 0.0, "k": 2000.0}'

It prints one line ``rtde_emulator ready host=... rtde=30004 dashboard=29999 script=30003
control=30099 pid=...`` on stdout once every port listens (logs go to stderr), and shuts down
cleanly on SIGTERM or SIGINT.

What it emulates
----------------
- **RTDE** (port 30004, protocol version 2, see :mod:`rtde_protocol`): any number of clients,
  each with its own output recipe streamed at its requested frequency (a divisor of 500 Hz),
  input recipes numbered 1, 2, ... in arrival order, ``IN_USE`` when a second client asks for
  registers another live client writes, ``NOT_FOUND`` for unknown variables.
- **Dashboard** (port 29999): welcome line, ``PolyscopeVersion``, ``get serial number``,
  ``is in remote control``, ``stop``, ``play``, ``pause``, ``unlock protective stop``,
  ``safetystatus``, ``safetymode``, ``robotmode``, ``programState``, ``running``, ``quit``.
- **Script server** (port 30003): a complete ``def name(): ... end`` program (ur_rtde's ~42 KB
  control script) starts "the program" (runtime_state PLAYING, output_int_register_0 = 1,
  F/T re-tared as a real controller does). URScript is NOT interpreted: the emulator plays the
  ur_rtde control script's register protocol (input_int_register_0 = command,
  output_int_register_0 = 1 ready / 2 done, real-time commands answer ready at once, async
  progress in output_int_register_2) and moves the TCP kinematically.
- **Motion**: moveL (sync and async; trapezoidal speed profile, straight line, orientation
  interpolated along the geodesic), stopL / stopJ (sync and async), speedL / speedStop,
  zeroFtSensor, moveUntilContact, start/read/stopContactDetection, triggerProtectiveStop,
  stopScript, plus the read-only queries (isSteady, getTCPOffset, getForwardKinematics, ...).
  Joint-space commands (moveJ, speedJ, servoJ, forceMode, ...) have no kinematic model here:
  they raise a "script error" that stops the program, so ur_rtde returns False (never a silent
  success).
- **Sensing** at 500 Hz: ``actual_TCP_pose`` (base, [x, y, z, rx, ry, rz]), ``actual_TCP_speed``,
  ``actual_TCP_force`` = force model wrench + sensor noise floor - tare (base-oriented; the
  reaction of the environment on the tool), ``ft_raw_wrench`` (untared), timestamp, robot and
  safety modes, status bits, runtime state and the output registers.
- **Safety**: a protective stop (injected, requested by ``triggerProtectiveStop`` or caused by
  ``|F| > --force-limit``) decelerates the TCP to rest within milliseconds, sets
  ``safety_status_bits`` bit 2 and ``safety_mode`` 3 and pauses the program.

Force model plug-in
-------------------
``--force-model module:factory`` with ``--force-model-kwargs JSON`` builds an object with
``wrench(tcp_pose6: np.ndarray, t: float) -> np.ndarray`` of shape (6,): the base-oriented
wrench ``[fx, fy, fz, tx, ty, tz]`` (N, N m) the environment applies to the tool when the TCP is
at ``tcp_pose6`` at controller time ``t`` (s). An optional ``set_params(**kwargs)`` method lets
the fault channel change parameters live. An optional ``tare(t)`` method means the model owns
the sensor offset: ``zeroFtSensor`` (and a program start) then call it and the emulator
subtracts nothing; without it the emulator subtracts the mean of the last 10 raw samples.
The built-in :class:`HalfSpaceSpring` is a flat elastic table top.

Fault-injection channel (TCP, port 30099 on the same address; one command per line, one JSON
reply line ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``)
---------------------------------------------------------------------------------------------
===============================  =================================================================
``ping``                         liveness
``state``                        pose, twist, force, tare, modes, runtime state, clients, ticks
``protective_stop``              protective stop now (motion halts, program paused)
``unlock``                       clear the protective stop (the program stays paused; re-upload)
``program_stop``                 stop the control program (as the pendant's stop button)
``drop [refuse_s]``              close every RTDE / dashboard / script connection and refuse new
                                 ones for ``refuse_s`` seconds (default 0)
``stall force [seconds]``        keep streaming but freeze ``actual_TCP_force`` (0 = until unstall)
``stall stream [seconds]``       stop sending data packages (connections stay open)
``unstall``                      end both stalls
``model_params {json}``          ``force_model.set_params(**json)``
``model module:factory [json]``  replace the force model
``set_pose [x,y,z,rx,ry,rz]``    teleport the TCP (only while no motion is active)
===============================  =================================================================
:class:`EmulatorControl` is a small Python client for this channel.
"""

import argparse
from collections import deque
import importlib
import json
import logging
import math
import os
import signal
import socket
import sys
import threading
import time
from typing import Callable, Dict, List, Optional, Protocol, Sequence

import numpy as np

from pointforce_ros.cell import rtde_protocol as rp

LOG = logging.getLogger('rtde_emulator')

DT = 0.002
"""Controller period, s (e-Series: 500 Hz)."""

RTDE_PORT = 30004
DASHBOARD_PORT = 29999
SCRIPT_PORT = 30003
CONTROL_PORT = 30099

CONTROLLER_VERSION = (5, 11, 1, 108318)
POLYSCOPE_TEXT = 'URSoftware 5.11.1.108318 (Jan 25 2022)'
SERIAL_NUMBER = '20205500001'

# runtime_state values (RTDE guide)
RUNTIME_STOPPED = 1
RUNTIME_PLAYING = 2
RUNTIME_PAUSED = 4

ROBOT_MODE_RUNNING = 7
SAFETY_MODE_NORMAL = 1
SAFETY_MODE_PROTECTIVE_STOP = 3
SAFETY_BIT_NORMAL = 1 << 0
SAFETY_BIT_PROTECTIVE_STOPPED = 1 << 2
SAFETY_BIT_STOPPED_DUE_TO_SAFETY = 1 << 10
ROBOT_BIT_POWER_ON = 1 << 0
ROBOT_BIT_PROGRAM_RUNNING = 1 << 1
JOINT_MODE_RUNNING = 253

READY = 1
DONE = 2

# ur_rtde control-script command numbers (input_int_register_0)
CMD_MOVEL = 3
CMD_FORCE_MODE_STOP = 7
CMD_ZERO_FT = 8
CMD_SPEEDL = 10
CMD_SPEED_STOP = 15
CMD_SERVO_STOP = 16
CMD_SET_PAYLOAD = 17
CMD_TOOL_CONTACT = 25
CMD_GET_STEPTIME = 26
CMD_GET_TARGET_WAYPOINT = 28
CMD_SET_TCP = 29
CMD_PROTECTIVE_STOP = 31
CMD_STOPL = 33
CMD_STOPJ = 34
CMD_SET_WATCHDOG = 35
CMD_IS_POSE_SAFE = 36
CMD_POSE_TRANS = 39
CMD_GET_TCP_OFFSET = 40
CMD_FK_DEFAULT = 43
CMD_IS_STEADY = 47
CMD_MOVE_UNTIL_CONTACT = 51
CMD_FLANGE_POSE = 58
CMD_START_CONTACT = 62
CMD_STOP_CONTACT = 63
CMD_READ_CONTACT = 64
CMD_SET_TARGET_PAYLOAD = 65
CMD_INTERNAL_CONTACT = 254
CMD_STOP_SCRIPT = 255

REALTIME_COMMANDS = frozenset({24, 11, 9, 10, 6, 25, 26, 27, 38, 58})
"""Commands the control script processes and answers READY in the same cycle."""

UNSUPPORTED = {1: 'moveJ', 2: 'moveJ_IK', 4: 'moveL_FK', 6: 'forceMode', 9: 'speedJ',
               11: 'servoJ', 12: 'servoC', 24: 'servoL', 27: 'getActualJointPositionsHistory',
               30: 'getInverseKinematics', 41: 'jogStart', 45: 'movePath',
               52: 'freedriveMode'}
"""Commands with no kinematic model here: they stop the program with a script error."""

PROTECTIVE_DECEL = 5.0
"""Deceleration of a protective stop, m/s^2 (and rad/s^2)."""
PROGRAM_STOP_DECEL = 3.0
CONTACT_STOP_DECEL = 3.0
CONTACT_RETURN_SPEED = 0.25
CONTACT_RETURN_ACCEL = 1.2
TARE_SAMPLES = 10
HISTORY = 1000


# --------------------------------------------------------------------------------------------
# rotations (rotation vectors as UR uses them)

def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotvec_to_matrix(rotvec: Sequence[float]) -> np.ndarray:
    """(3, 3) rotation matrix of a rotation vector (axis * angle, rad)."""
    rv = np.asarray(rotvec, dtype=float)
    theta = float(np.linalg.norm(rv))
    if theta < 1e-12:
        return np.eye(3) + _skew(rv)
    k = _skew(rv / theta)
    return np.eye(3) + math.sin(theta) * k + (1.0 - math.cos(theta)) * (k @ k)


def matrix_to_rotvec(rot: np.ndarray) -> np.ndarray:
    """Rotation vector (3,) of a (3, 3) rotation matrix, angle in [0, pi]."""
    cos = min(1.0, max(-1.0, (float(np.trace(rot)) - 1.0) / 2.0))
    theta = math.acos(cos)
    vee = np.array([rot[2, 1] - rot[1, 2], rot[0, 2] - rot[2, 0], rot[1, 0] - rot[0, 1]])
    if theta < 1e-9:
        return 0.5 * vee
    if math.pi - theta < 1e-6:
        sym = 0.5 * (rot + np.eye(3))
        i = int(np.argmax(np.diag(sym)))
        axis = sym[:, i] / math.sqrt(max(sym[i, i], 1e-300))
        return theta * axis / np.linalg.norm(axis)
    return theta / (2.0 * math.sin(theta)) * vee


def pose_trans(p_from: Sequence[float], p_from_to: Sequence[float]) -> np.ndarray:
    """Compose two poses [x, y, z, rx, ry, rz] as URScript ``pose_trans`` does."""
    r1 = rotvec_to_matrix(p_from[3:6])
    r2 = rotvec_to_matrix(p_from_to[3:6])
    pos = np.asarray(p_from[:3], dtype=float) + r1 @ np.asarray(p_from_to[:3], dtype=float)
    return np.concatenate([pos, matrix_to_rotvec(r1 @ r2)])


# --------------------------------------------------------------------------------------------
# force models

class ForceModel(Protocol):
    """What the emulator asks of a force model (optionally also ``set_params(**kwargs)``)."""

    def wrench(self, tcp_pose6: np.ndarray, t: float) -> np.ndarray:
        """(6,) base-oriented wrench on the tool, N and N m, at TCP pose ``tcp_pose6``."""


class HalfSpaceSpring:
    """A flat elastic table top: ``F = k * penetration * n`` on the tool, zero torque.

    The surface is the plane through ``(0, 0, z0)`` with outward unit normal ``normal``
    (default +z, base frame). Penetration ``d = ((0, 0, z0) - p_tcp) . n`` when positive.
    Pushing into the table along ``-n`` therefore gives ``F . n = k d > 0``.

    Args:
        z0: height of the surface point on the z axis, m.
        k: stiffness, N/m (>= 0).
        normal: outward surface normal (3,), normalised here.
        noise_std: standard deviation of white Gaussian force noise per axis, N.
        torque_noise_std: same for torques, N m.
        seed: seed of the noise generator (``np.random.default_rng``).

    Raises:
        ValueError: negative stiffness or noise, or a zero normal.

    """

    def __init__(self, z0: float = 0.0, k: float = 1000.0, normal=(0.0, 0.0, 1.0),
                 noise_std: float = 0.0, torque_noise_std: float = 0.0, seed: int = 0):
        self._rng = np.random.default_rng(seed)
        self.z0 = 0.0
        self.k = 0.0
        self.normal = np.array([0.0, 0.0, 1.0])
        self.noise_std = 0.0
        self.torque_noise_std = 0.0
        self.set_params(z0=z0, k=k, normal=normal, noise_std=noise_std,
                        torque_noise_std=torque_noise_std)

    def set_params(self, **params) -> None:
        """Change any of ``z0``, ``k``, ``normal``, ``noise_std``, ``torque_noise_std``, ``seed``.

        Raises:
            ValueError: an unknown name or an invalid value.

        """
        for name, value in params.items():
            if name == 'seed':
                self._rng = np.random.default_rng(int(value))
            elif name == 'normal':
                n = np.asarray(value, dtype=float).reshape(3)
                norm = float(np.linalg.norm(n))
                if not np.isfinite(norm) or norm < 1e-9:
                    raise ValueError('HalfSpaceSpring.normal: must be a non-zero 3-vector')
                self.normal = n / norm
            elif name in ('z0', 'k', 'noise_std', 'torque_noise_std'):
                value = float(value)
                if not math.isfinite(value) or (name != 'z0' and value < 0.0):
                    raise ValueError(f'HalfSpaceSpring.{name}: must be finite'
                                     f'{"" if name == "z0" else " and >= 0"}, got {value}')
                setattr(self, name, value)
            else:
                raise ValueError(f'HalfSpaceSpring: unknown parameter {name!r}')

    def wrench(self, tcp_pose6: np.ndarray, t: float) -> np.ndarray:
        """(6,) base-oriented wrench on the tool at ``tcp_pose6`` (see class docstring)."""
        depth = (self.z0 * self.normal[2]) - float(np.dot(tcp_pose6[:3], self.normal))
        out = np.zeros(6)
        if depth > 0.0:
            out[:3] = self.k * depth * self.normal
        if self.noise_std > 0.0:
            out[:3] += self._rng.normal(0.0, self.noise_std, 3)
        if self.torque_noise_std > 0.0:
            out[3:] += self._rng.normal(0.0, self.torque_noise_std, 3)
        return out


def load_force_model(spec: str, kwargs: Optional[dict] = None):
    """Build a force model from ``module:factory`` and keyword arguments.

    Raises:
        ValueError: malformed spec, missing module or attribute, or an object without a
            callable ``wrench``.

    """
    if ':' not in spec:
        raise ValueError(f'force model spec {spec!r}: expected "module:factory"')
    module_name, _, attr = spec.partition(':')
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise ValueError(f'force model spec {spec!r}: cannot import {module_name}: {exc}')
    factory = getattr(module, attr, None)
    if factory is None:
        raise ValueError(f'force model spec {spec!r}: {module_name} has no {attr!r}')
    model = factory(**(kwargs or {}))
    if not callable(getattr(model, 'wrench', None)):
        raise ValueError(f'force model spec {spec!r}: built object has no wrench() method')
    return model


# --------------------------------------------------------------------------------------------
# kinematics

class _Kinematics:
    """TCP state: position p (3,), rotation matrix r (3, 3), linear v (3,) and angular w (3,)."""

    def __init__(self, pose6: Sequence[float]):
        self.p = np.array(pose6[:3], dtype=float)
        self.r = rotvec_to_matrix(pose6[3:6])
        self.v = np.zeros(3)
        self.w = np.zeros(3)

    def pose6(self) -> np.ndarray:
        return np.concatenate([self.p, matrix_to_rotvec(self.r)])

    def twist6(self) -> np.ndarray:
        return np.concatenate([self.v, self.w])

    def integrate(self, v_new: np.ndarray, w_new: np.ndarray, dt: float) -> None:
        self.p = self.p + 0.5 * (self.v + v_new) * dt
        self.r = rotvec_to_matrix(0.5 * (self.w + w_new) * dt) @ self.r
        self.v = v_new
        self.w = w_new


class _Trapezoid:
    """Rest-to-rest trapezoidal profile over ``length`` with speed and acceleration limits."""

    def __init__(self, length: float, speed: float, accel: float):
        self.length = length
        self.a = accel
        if length <= 0.0:
            self.ta, self.tf, self.vp = 0.0, 0.0, 0.0
        elif length >= speed * speed / accel:
            self.ta, self.vp = speed / accel, speed
            self.tf = (length - speed * speed / accel) / speed
        else:
            self.vp = math.sqrt(length * accel)
            self.ta, self.tf = self.vp / accel, 0.0
        self.duration = 2.0 * self.ta + self.tf

    def at(self, t: float):
        if t <= 0.0:
            return 0.0, 0.0
        if t < self.ta:
            return 0.5 * self.a * t * t, self.a * t
        if t < self.ta + self.tf:
            return 0.5 * self.a * self.ta ** 2 + self.vp * (t - self.ta), self.vp
        if t < self.duration:
            rest = self.duration - t
            return self.length - 0.5 * self.a * rest * rest, self.a * rest
        return self.length, 0.0


class _LinearMove:
    """moveL: straight line in position, geodesic in orientation, trapezoidal in time."""

    def __init__(self, kin: _Kinematics, target6: Sequence[float], speed: float, accel: float):
        self.p0, self.r0 = kin.p.copy(), kin.r.copy()
        self.p1 = np.array(target6[:3], dtype=float)
        self.r1 = rotvec_to_matrix(target6[3:6])
        self.dp = self.p1 - self.p0
        self.rel = matrix_to_rotvec(self.r0.T @ self.r1)
        dist = float(np.linalg.norm(self.dp))
        length = dist if dist > 1e-7 else float(np.linalg.norm(self.rel))
        self.profile = _Trapezoid(length, speed, accel)
        self.t = 0.0
        self.target = np.array(target6, dtype=float)

    def step(self, kin: _Kinematics, dt: float) -> bool:
        self.t += dt
        if self.t >= self.profile.duration:
            kin.p, kin.r = self.p1.copy(), self.r1.copy()
            kin.v, kin.w = np.zeros(3), np.zeros(3)
            return True
        s, sd = self.profile.at(self.t)
        frac, rate = s / self.profile.length, sd / self.profile.length
        kin.p = self.p0 + self.dp * frac
        kin.r = self.r0 @ rotvec_to_matrix(self.rel * frac)
        kin.v = self.dp * rate
        kin.w = self.r0 @ self.rel * rate
        return False


class _StopMove:
    """stopl: decelerate the current twist along its direction at ``decel`` until at rest."""

    def __init__(self, decel: float):
        self.decel = decel

    def step(self, kin: _Kinematics, dt: float) -> bool:
        speed = float(np.linalg.norm(kin.v))
        ang = float(np.linalg.norm(kin.w))
        ref = speed if speed > 1e-12 else ang
        if ref <= 1e-12:
            kin.v, kin.w = np.zeros(3), np.zeros(3)
            return True
        ratio = max(ref - self.decel * dt, 0.0) / ref
        kin.integrate(kin.v * ratio, kin.w * ratio, dt)
        return ratio == 0.0


class _SpeedMove:
    """speedl: approach the target twist with bounded acceleration and hold it."""

    def __init__(self, twist6: Sequence[float], accel: float):
        self.target = np.array(twist6, dtype=float)
        self.accel = accel

    def step(self, kin: _Kinematics, dt: float) -> bool:
        def approach(cur, want):
            delta = want - cur
            norm = float(np.linalg.norm(delta))
            limit = self.accel * dt
            return want.copy() if norm <= limit else cur + delta * (limit / norm)
        kin.integrate(approach(kin.v, self.target[:3]), approach(kin.w, self.target[3:]), dt)
        return False


class _Sequence:
    """Run motions one after the other; each factory builds its motion from the state then."""

    def __init__(self, *factories: Callable[[_Kinematics], object]):
        self.factories = list(factories)
        self.current = None

    def step(self, kin: _Kinematics, dt: float) -> bool:
        while True:
            if self.current is None:
                if not self.factories:
                    return True
                self.current = self.factories.pop(0)(kin)
            if not self.current.step(kin, dt):
                return False
            self.current = None
            if not self.factories:
                return True


class _Ring:
    """Fixed-size history of (ticks, width) float rows, newest last."""

    def __init__(self, size: int, width: int):
        self.data = np.zeros((size, width))
        self.count = 0

    def push(self, row: np.ndarray) -> None:
        self.data[self.count % len(self.data)] = row
        self.count += 1

    def last(self, n: int) -> np.ndarray:
        n = min(n, self.count, len(self.data))
        idx = (np.arange(self.count - n, self.count)) % len(self.data)
        return self.data[idx]


# --------------------------------------------------------------------------------------------
# the controller: kinematics, sensing, safety and the control script's register protocol

class ScriptError(RuntimeError):
    """The emulated control script hit something it cannot do; the program stops."""


class Controller:
    """Everything that advances at 500 Hz. Not thread-safe: the emulator holds a lock."""

    def __init__(self, model, initial_pose6: Sequence[float], *, noise_floor: float = 0.005,
                 force_limit: float = 150.0, contact_threshold: float = 1.0, seed: int = 0):
        self.model = model
        self.kin = _Kinematics(initial_pose6)
        self.rng = np.random.default_rng(seed)
        self.noise_floor = float(noise_floor)
        self.force_limit = float(force_limit)
        self.contact_threshold = float(contact_threshold)
        self.tick = 0
        self.motion = None
        self.motion_owner = None
        self.in_int = [0] * 48
        self.in_double = [0.0] * 48
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.runtime_state = RUNTIME_STOPPED
        self.protective = False
        self.raw = np.zeros(6)
        self.tare = np.zeros(6)
        self.force = np.zeros(6)
        self.frozen_force: Optional[np.ndarray] = None
        self.raw_recent = deque(maxlen=TARE_SAMPLES)
        self.force_hist = _Ring(HISTORY, 3)
        self.pose_hist = _Ring(HISTORY, 6)
        self.executing = False
        self.blocking: Optional[Callable[[], bool]] = None
        self.internal_cmd = 0
        self.async_wr_count = 0
        self.async_op_id = 0
        self.move_async = False
        self.stop_async = False
        self.contact_dir: Optional[np.ndarray] = None
        self.contact_phase = 0
        self.contact_step_back = 0
        self.events = deque(maxlen=100)
        self._sense()

    # -- time and outputs -------------------------------------------------------------------
    @property
    def timestamp(self) -> float:
        """Controller time, s since the emulator started (``tick * 0.002``)."""
        return self.tick * DT

    def outputs(self) -> Dict[str, object]:
        """Return every standard RTDE output now (registers via :meth:`output_value`)."""
        pose = tuple(self.kin.pose6())
        twist = tuple(self.kin.twist6())
        force = tuple(self.force)
        running = self.runtime_state == RUNTIME_PLAYING
        zeros6 = (0.0,) * 6
        q = (0.0, -1.57, 1.57, -1.57, -1.57, 0.0)
        return {
            'timestamp': self.timestamp,
            'actual_TCP_pose': pose, 'target_TCP_pose': pose,
            'actual_TCP_speed': twist, 'target_TCP_speed': twist,
            'actual_TCP_force': force, 'ft_raw_wrench': tuple(self.raw),
            'target_q': q, 'actual_q': q,
            'target_qd': zeros6, 'target_qdd': zeros6, 'actual_qd': zeros6,
            'actual_qdd': zeros6, 'target_current': zeros6, 'target_moment': zeros6,
            'actual_current': zeros6, 'actual_current_window': zeros6,
            'actual_moment': zeros6, 'actual_current_as_torque': zeros6,
            'joint_control_output': zeros6, 'joint_temperatures': (30.0,) * 6,
            'actual_joint_voltage': (48.0,) * 6, 'joint_mode': (JOINT_MODE_RUNNING,) * 6,
            'robot_mode': ROBOT_MODE_RUNNING,
            'safety_mode': SAFETY_MODE_PROTECTIVE_STOP if self.protective
            else SAFETY_MODE_NORMAL,
            'safety_status': SAFETY_MODE_PROTECTIVE_STOP if self.protective
            else SAFETY_MODE_NORMAL,
            'safety_status_bits': (SAFETY_BIT_PROTECTIVE_STOPPED
                                   | SAFETY_BIT_STOPPED_DUE_TO_SAFETY) if self.protective
            else SAFETY_BIT_NORMAL,
            'robot_status_bits': ROBOT_BIT_POWER_ON | (ROBOT_BIT_PROGRAM_RUNNING if running
                                                       else 0),
            'runtime_state': self.runtime_state,
            'speed_scaling': 1.0, 'target_speed_fraction': 1.0,
            'actual_execution_time': 0.2, 'actual_momentum': 0.0,
            'actual_main_voltage': 48.0, 'actual_robot_voltage': 48.0,
            'actual_robot_current': 0.8, 'actual_tool_accelerometer': (0.0, 0.0, 9.81),
            'tcp_force_scalar': float(np.linalg.norm(self.force[:3])),
            'payload': 0.0, 'payload_cog': (0.0, 0.0, 0.0), 'payload_inertia': zeros6,
            'elbow_position': (0.0, 0.0, 0.0), 'elbow_velocity': (0.0, 0.0, 0.0),
        }

    def output_value(self, snapshot: Dict[str, object], name: str):
        """Return output ``name`` from ``snapshot``, the registers, or a zero of its type."""
        value = snapshot.get(name)
        if value is not None:
            return value
        if name.startswith('output_int_register_'):
            return self.out_int[int(name.rsplit('_', 1)[1])]
        if name.startswith('output_double_register_'):
            return self.out_double[int(name.rsplit('_', 1)[1])]
        if name.startswith('input_int_register_'):
            return self.in_int[int(name.rsplit('_', 1)[1])]
        if name.startswith('input_double_register_'):
            return self.in_double[int(name.rsplit('_', 1)[1])]
        typ = rp.OUTPUT_VARIABLES[name]
        width = rp.TYPE_WIDTH.get(typ, 1)
        zero = 0.0 if 'D' in typ and typ != 'UINT64' else 0
        if typ == 'BOOL':
            zero = False
        return (zero,) * width if width > 1 else zero

    def apply_inputs(self, values: Dict[str, object]) -> None:
        """Store the registers of one input data package (other inputs are accepted, unused)."""
        for name, value in values.items():
            if name.startswith('input_int_register_'):
                self.in_int[int(name.rsplit('_', 1)[1])] = int(value)
            elif name.startswith('input_double_register_'):
                self.in_double[int(name.rsplit('_', 1)[1])] = float(value)

    # -- the 500 Hz step ----------------------------------------------------------------------
    def step(self) -> None:
        """Advance one controller period: motion, sensing, safety, then the control script."""
        self.tick += 1
        if self.motion is not None and self.motion.step(self.kin, DT):
            self._motion_finished()
        self._sense()
        if not self.protective and float(np.linalg.norm(self.force[:3])) > self.force_limit:
            self.protective_stop(f'force {np.linalg.norm(self.force[:3]):.1f} N exceeds the '
                                 f'force limit {self.force_limit:.1f} N')
        if self.runtime_state == RUNTIME_PLAYING and not self.protective:
            self._contact_thread()
            try:
                self._program_cycle()
            except ScriptError as exc:
                self.stop_program(f'script error: {exc}')

    def _sense(self) -> None:
        pose = self.kin.pose6()
        raw = np.asarray(self.model.wrench(pose, self.timestamp), dtype=float).reshape(6)
        if self.noise_floor > 0.0:
            raw = raw + self.rng.normal(0.0, 1.0, 6) * (self.noise_floor * np.array(
                [1.0, 1.0, 1.0, 0.02, 0.02, 0.02]))
        self.raw = raw
        self.raw_recent.append(raw)
        measured = raw - self.tare
        self.force = self.frozen_force if self.frozen_force is not None else measured
        self.force_hist.push(measured[:3])
        self.pose_hist.push(pose)

    def _motion_finished(self) -> None:
        owner = self.motion_owner
        self.motion, self.motion_owner = None, None
        if owner == 'move_thread' and self.move_async:
            self.move_async = False
            self._write_async_progress(-1)
        elif owner == 'stop_thread' and self.stop_async:
            self.stop_async = False
            self._write_async_progress(-1)

    def _set_motion(self, motion, owner: str) -> None:
        self.motion, self.motion_owner = motion, owner

    def is_moving(self) -> bool:
        """Return True while a motion runs or the TCP has a non-zero twist."""
        return self.motion is not None or bool(np.any(self.kin.v) or np.any(self.kin.w))

    # -- safety and program state -------------------------------------------------------------
    def protective_stop(self, reason: str) -> None:
        """Halt within milliseconds, set the safety bits and pause the program."""
        if self.protective:
            return
        self.protective = True
        self._abort_threads()
        self._set_motion(_StopMove(PROTECTIVE_DECEL), 'safety')
        if self.runtime_state == RUNTIME_PLAYING:
            self.runtime_state = RUNTIME_PAUSED
        self.events.append(f'protective stop: {reason}')
        LOG.warning('protective stop: %s', reason)

    def unlock_protective_stop(self) -> bool:
        """Release a protective stop (the program stays paused); False if there was none."""
        if not self.protective:
            return False
        self.protective = False
        self.events.append('protective stop released')
        return True

    def stop_program(self, reason: str) -> None:
        """Stop the control program (runtime_state STOPPED) and bring the TCP to rest."""
        if self.runtime_state == RUNTIME_STOPPED:
            return
        self.runtime_state = RUNTIME_STOPPED
        self._abort_threads()
        if self.is_moving() and self.motion_owner != 'safety':
            self._set_motion(_StopMove(PROGRAM_STOP_DECEL), 'program_stop')
        self.events.append(f'program stopped: {reason}')
        LOG.warning('program stopped: %s', reason)

    def start_program(self, name: str) -> bool:
        """Start the control program: PLAYING, ready, F/T re-tared; refused while stopped."""
        if self.protective:
            LOG.warning('program %s not started: the robot is protective stopped', name)
            return False
        self._abort_threads()
        if self.motion_owner not in (None, 'safety', 'program_stop'):
            self._set_motion(_StopMove(PROGRAM_STOP_DECEL), 'program_stop')
        self.runtime_state = RUNTIME_PLAYING
        self.executing = False
        self.internal_cmd = 0
        self._tare()
        self._write_async_progress(-1)
        self.out_int[0] = READY
        self.events.append(f'program {name} started')
        LOG.info('program %s started', name)
        return True

    def resume_program(self) -> bool:
        """Resume a paused program (dashboard ``play``); False when not possible."""
        if self.protective or self.runtime_state != RUNTIME_PAUSED:
            return False
        self.runtime_state = RUNTIME_PLAYING
        return True

    def pause_program(self) -> bool:
        """Pause a running program (dashboard ``pause``) and bring the TCP to rest."""
        if self.runtime_state != RUNTIME_PLAYING:
            return False
        self.runtime_state = RUNTIME_PAUSED
        self._abort_threads()
        if self.is_moving():
            self._set_motion(_StopMove(PROGRAM_STOP_DECEL), 'program_stop')
        return True

    def _abort_threads(self) -> None:
        self.blocking = None
        self.move_async = False
        self.stop_async = False
        self.contact_dir = None
        if self.motion_owner in ('move_thread', 'stop_thread', 'speed', 'sync', 'contact'):
            self.motion_owner = 'orphan'

    def _tare(self) -> None:
        model_tare = getattr(self.model, 'tare', None)
        if callable(model_tare):
            model_tare(self.timestamp)
            self.tare = np.zeros(6)
        elif self.raw_recent:
            self.tare = np.mean(np.array(self.raw_recent), axis=0)

    # -- async progress register (output_int_register_2) --------------------------------------
    def _write_async_progress(self, value: int) -> None:
        self.async_wr_count = self.async_wr_count + 1 if self.async_wr_count < 127 else 0
        if value == 0:
            self.async_op_id = self.async_op_id + 1 if self.async_op_id < 127 else 0
        reg = self.async_wr_count * 65536 + self.async_op_id * 16777216
        if value >= 0:
            reg += min(value, 32767) + 32768
        self.out_int[2] = reg

    # -- contact detection (tool_contact emulation) ---------------------------------------------
    def tool_contact(self, direction: np.ndarray) -> int:
        """Return the steps back to the onset of contact along ``direction`` (0: none)."""
        d = np.asarray(direction[:3], dtype=float)
        norm = float(np.linalg.norm(d))
        if norm < 1e-9:
            return 0
        hist = self.force_hist.last(HISTORY)
        push = -(hist @ (d / norm))
        if push[-1] < self.contact_threshold:
            return 0
        below = np.flatnonzero(push < 0.25 * self.contact_threshold)
        onset = int(below[-1]) + 1 if below.size else 0
        return max(1, len(push) - onset)

    def _contact_direction(self, direction: np.ndarray) -> np.ndarray:
        if np.linalg.norm(direction[:3]) > 1e-12:
            return direction
        return self.kin.twist6()

    def _contact_thread(self) -> None:
        if self.contact_dir is None:
            return
        step_back = self.tool_contact(self._contact_direction(self.contact_dir))
        if self.contact_phase == 0:
            if step_back == 0:
                self.contact_phase = 1
        elif step_back > 0:
            self.contact_step_back = step_back
            self.contact_dir = None
            self.internal_cmd = CMD_INTERNAL_CONTACT

    def _return_to_contact(self, step_back: int) -> None:
        back = self.pose_hist.last(step_back + 1)[0].copy()
        self._set_motion(_Sequence(
            lambda kin: _StopMove(CONTACT_STOP_DECEL),
            lambda kin: _LinearMove(kin, back, CONTACT_RETURN_SPEED, CONTACT_RETURN_ACCEL)),
            'sync')

    # -- the control script's main loop ---------------------------------------------------------
    def _program_cycle(self) -> None:
        if self.blocking is not None:
            if not self.blocking():
                return
            self.blocking = None
            self.out_int[0] = DONE
            return
        cmd = self.in_int[0]
        if cmd == 0 and self.internal_cmd:
            cmd, self.internal_cmd = self.internal_cmd, 0
        if cmd in REALTIME_COMMANDS:
            self._process(cmd)
            if self.runtime_state == RUNTIME_PLAYING:
                self.out_int[0] = READY
        elif cmd == 0:
            self.executing = False
            self.out_int[0] = READY
        elif not self.executing:
            self.executing = True
            self._process(cmd)
            if (self.blocking is None and cmd != CMD_STOP_SCRIPT
                    and self.runtime_state == RUNTIME_PLAYING):
                self.out_int[0] = DONE

    def _pose_arg(self, first: int) -> np.ndarray:
        return np.array(self.in_double[first:first + 6], dtype=float)

    def _stop_async_move(self) -> None:
        if self.move_async:
            self.move_async = False
            self._write_async_progress(-1)

    def _wait_motion_done(self) -> bool:
        return self.motion is None

    def _process(self, cmd: int) -> None:
        if cmd in UNSUPPORTED:
            raise ScriptError(f'command {cmd} ({UNSUPPORTED[cmd]}) has no kinematic model in '
                              'the emulator')
        if cmd == CMD_MOVEL:
            target = self._pose_arg(0)
            speed, accel = self.in_double[6], self.in_double[7]
            if not (np.all(np.isfinite(target)) and speed > 0.0 and accel > 0.0):
                raise ScriptError(f'movel: invalid target {target}, v={speed}, a={accel}')
            self._stop_async_move()
            move = _LinearMove(self.kin, target, speed, accel)
            if self.in_int[1] == 1:
                self._set_motion(move, 'move_thread')
                self.move_async = True
                self._write_async_progress(0)
            else:
                self._set_motion(move, 'sync')
                self.blocking = self._wait_motion_done
        elif cmd in (CMD_STOPL, CMD_STOPJ):
            decel = self.in_double[0]
            if not decel > 0.0:
                raise ScriptError(f'stopl: deceleration must be > 0, got {decel}')
            stop_move = True
            if self.stop_async:
                stop_move = False
                self.stop_async = False
                self._write_async_progress(-1)
            if stop_move:
                self._stop_async_move()
            if self.in_int[1] == 1:
                self._set_motion(_StopMove(decel), 'stop_thread')
                self.stop_async = True
                self._write_async_progress(0)
            else:
                self._set_motion(_StopMove(decel), 'sync')
                self.blocking = self._wait_motion_done
        elif cmd == CMD_SPEEDL:
            twist = np.array(self.in_double[0:6], dtype=float)
            accel = self.in_double[6]
            if not (np.all(np.isfinite(twist)) and accel > 0.0):
                raise ScriptError(f'speedl: invalid speed {twist} or acceleration {accel}')
            if self.motion_owner == 'speed':
                self.motion.target, self.motion.accel = twist, accel
            else:
                self._set_motion(_SpeedMove(twist, accel), 'speed')
        elif cmd in (CMD_SPEED_STOP, CMD_SERVO_STOP):
            decel = self.in_double[0]
            if not decel > 0.0:
                raise ScriptError(f'speed stop: deceleration must be > 0, got {decel}')
            if self.motion_owner in ('speed', 'orphan') or cmd == CMD_SERVO_STOP:
                self._set_motion(_StopMove(decel), 'sync')
                self.blocking = self._wait_motion_done
        elif cmd == CMD_ZERO_FT:
            self._tare()
        elif cmd == CMD_PROTECTIVE_STOP:
            self.protective_stop('triggerProtectiveStop() from the client')
        elif cmd == CMD_MOVE_UNTIL_CONTACT:
            self._move_until_contact()
        elif cmd == CMD_START_CONTACT:
            self.contact_dir = self._pose_arg(0)
            self.contact_phase = 0
            self.contact_step_back = 0
        elif cmd == CMD_STOP_CONTACT:
            self.contact_dir = None
            self.out_int[1] = self.contact_step_back
        elif cmd == CMD_READ_CONTACT:
            self.out_int[1] = self.contact_step_back
        elif cmd == CMD_INTERNAL_CONTACT:
            self._stop_async_move()
            self._return_to_contact(self.contact_step_back)
            self.blocking = self._wait_motion_done
        elif cmd == CMD_TOOL_CONTACT:
            self.out_int[1] = self.tool_contact(self._pose_arg(0))
        elif cmd == CMD_GET_STEPTIME:
            self.out_double[0] = DT
        elif cmd in (CMD_FK_DEFAULT, CMD_FLANGE_POSE):
            self.out_double[0:6] = list(self.kin.pose6())
        elif cmd == CMD_GET_TARGET_WAYPOINT:
            target = getattr(self.motion, 'target', None)
            pose = target if target is not None and len(target) == 6 else self.kin.pose6()
            self.out_double[0:6] = [float(x) for x in pose]
        elif cmd == CMD_GET_TCP_OFFSET:
            self.out_double[0:6] = [0.0] * 6
        elif cmd == CMD_POSE_TRANS:
            self.out_double[0:6] = list(pose_trans(self._pose_arg(0), self._pose_arg(6)))
        elif cmd == CMD_IS_STEADY:
            self.out_int[1] = 0 if self.is_moving() else 1
        elif cmd == CMD_IS_POSE_SAFE:
            self.out_int[1] = 1
        elif cmd in (CMD_FORCE_MODE_STOP, CMD_SET_PAYLOAD, CMD_SET_TARGET_PAYLOAD,
                     CMD_SET_WATCHDOG, CMD_SET_TCP):
            LOG.info('command %d accepted without effect (no payload/TCP/watchdog model)', cmd)
        elif cmd == CMD_STOP_SCRIPT:
            self.stop_program('stopScript() from the client')
        else:
            raise ScriptError(f'command {cmd} is not emulated')

    def _move_until_contact(self) -> None:
        twist = np.array(self.in_double[0:6], dtype=float)
        direction = self._pose_arg(6)
        accel = self.in_double[12]
        if not (np.all(np.isfinite(twist)) and accel > 0.0):
            raise ScriptError(f'moveUntilContact: invalid speed {twist} or acceleration {accel}')
        if np.linalg.norm(direction[:3]) < 1e-12:
            direction = twist
        self._stop_async_move()
        self._set_motion(_SpeedMove(twist, accel), 'contact')
        state = {'returning': False}

        def blocking() -> bool:
            if state['returning']:
                return self.motion is None
            step_back = self.tool_contact(direction)
            if step_back <= 0:
                return False
            state['returning'] = True
            self._return_to_contact(step_back)
            return False
        self.blocking = blocking


# --------------------------------------------------------------------------------------------
# network side

class _Client:
    """One accepted TCP connection with a non-blocking, buffered send path."""

    def __init__(self, emulator: 'Emulator', sock: socket.socket, kind: str):
        self.emulator = emulator
        self.sock = sock
        self.kind = kind
        self.send_lock = threading.Lock()
        self.pending = bytearray()
        self.closed = False

    def send(self, data: bytes) -> bool:
        """Queue ``data`` and send what the socket takes now; False once the client is gone."""
        with self.send_lock:
            if self.closed:
                return False
            self.pending.extend(data)
            return self._flush_locked()

    def flush(self) -> bool:
        with self.send_lock:
            if self.closed:
                return False
            return self._flush_locked()

    def _flush_locked(self) -> bool:
        while self.pending:
            try:
                sent = self.sock.send(self.pending, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self._close_locked()
                return False
            del self.pending[:sent]
        if len(self.pending) > 1 << 20:
            LOG.warning('%s client is not reading (%d bytes queued): dropping it',
                        self.kind, len(self.pending))
            self._close_locked()
            return False
        return True

    def close(self) -> None:
        with self.send_lock:
            self._close_locked()

    def _close_locked(self) -> None:
        if self.closed:
            return
        self.closed = True
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


class _RtdeClient(_Client):
    def __init__(self, emulator, sock):
        super().__init__(emulator, sock, 'rtde')
        self.output: Optional[rp.Recipe] = None
        self.period = 1
        self.started = False
        self.inputs: Dict[int, rp.Recipe] = {}
        self.protocol_ok = False

    def serve(self) -> None:
        buf = rp.MessageBuffer()
        while not self.closed:
            try:
                data = self.sock.recv(65536)
            except OSError:
                break
            if not data:
                break
            try:
                for msg_type, payload in buf.feed(data):
                    self._handle(msg_type, payload)
            except rp.ProtocolError as exc:
                LOG.warning('rtde client sent an invalid message (%s): closing', exc)
                break

    def _handle(self, msg_type: int, payload: bytes) -> None:
        emu = self.emulator
        if msg_type == rp.MSG_REQUEST_PROTOCOL_VERSION:
            version = int.from_bytes(payload[:2], 'big') if len(payload) >= 2 else 0
            self.protocol_ok = version == rp.PROTOCOL_VERSION
            self.send(rp.encode_message(msg_type, bytes((1 if self.protocol_ok else 0,))))
        elif msg_type == rp.MSG_GET_URCONTROL_VERSION:
            self.send(rp.encode_message(msg_type, b''.join(
                v.to_bytes(4, 'big') for v in CONTROLLER_VERSION)))
        elif msg_type == rp.MSG_SETUP_OUTPUTS:
            self._setup_outputs(payload)
        elif msg_type == rp.MSG_SETUP_INPUTS:
            self._setup_inputs(payload)
        elif msg_type == rp.MSG_START:
            self.started = self.output is not None
            self.send(rp.encode_message(msg_type, bytes((1 if self.started else 0,))))
        elif msg_type == rp.MSG_PAUSE:
            self.started = False
            self.send(rp.encode_message(msg_type, b'\x01'))
        elif msg_type == rp.MSG_DATA_PACKAGE:
            if not payload:
                return
            recipe = self.inputs.get(payload[0])
            if recipe is None:
                LOG.warning('data package for unknown input recipe %d ignored', payload[0])
                return
            try:
                values = recipe.unpack(payload[1:])
            except rp.ProtocolError as exc:
                LOG.warning('%s: ignored', exc)
                return
            emu.apply_inputs(values)
        elif msg_type == rp.MSG_TEXT_MESSAGE:
            LOG.info('rtde client text message: %r', payload)
        else:
            LOG.warning('rtde client sent unknown message type %d', msg_type)

    def _setup_outputs(self, payload: bytes) -> None:
        if len(payload) < 8:
            self.send(rp.setup_reply(rp.MSG_SETUP_OUTPUTS, 0, []))
            return
        frequency = float(np.frombuffer(payload[:8], dtype='>f8')[0])
        names = rp.parse_names(payload[8:])
        types = rp.resolve_types(names, rp.OUTPUT_VARIABLES)
        if 'NOT_FOUND' in types or not (0.0 < frequency <= 1.0 / DT + 1e-9):
            if 'NOT_FOUND' not in types:
                LOG.warning('output frequency %.3f Hz outside (0, 500]', frequency)
            self.send(rp.setup_reply(rp.MSG_SETUP_OUTPUTS, 0, types))
            return
        self.output = rp.Recipe(1, tuple(names), tuple(types))
        self.period = max(1, int(round(1.0 / (frequency * DT))))
        LOG.debug('output recipe at %g Hz: %s', frequency, ','.join(names))
        self.send(rp.setup_reply(rp.MSG_SETUP_OUTPUTS, 1, types))

    def _setup_inputs(self, payload: bytes) -> None:
        names = rp.parse_names(payload)
        types = rp.resolve_types(names, rp.INPUT_VARIABLES)
        types = self.emulator.claim_inputs(self, names, types)
        if 'NOT_FOUND' in types or 'IN_USE' in types:
            self.send(rp.setup_reply(rp.MSG_SETUP_INPUTS, 0, types))
            return
        recipe_id = len(self.inputs) + 1
        self.inputs[recipe_id] = rp.Recipe(recipe_id, tuple(names), tuple(types))
        LOG.debug('input recipe %d: %s', recipe_id, ','.join(names))
        self.send(rp.setup_reply(rp.MSG_SETUP_INPUTS, recipe_id, types))


class Emulator:
    """The emulator process: listeners, client threads, the 500 Hz tick thread."""

    def __init__(self, host: str, controller: Controller, *, rtde_port: int = RTDE_PORT,
                 dashboard_port: int = DASHBOARD_PORT, script_port: int = SCRIPT_PORT,
                 control_port: int = CONTROL_PORT):
        self.host = host
        self.controller = controller
        self.ports = {'rtde': rtde_port, 'dashboard': dashboard_port, 'script': script_port,
                      'control': control_port}
        self.lock = threading.RLock()
        self.stop_event = threading.Event()
        self.clients: List[_Client] = []
        self.input_owner: Dict[str, _RtdeClient] = {}
        self.refuse_until = 0.0
        self.force_stall_until: Optional[float] = None
        self.stream_stall_until: Optional[float] = None
        self.late_ticks = 0
        """Controller periods skipped because the process was starved (the clock dilated)."""
        self.threads: List[threading.Thread] = []
        self.listeners: List[socket.socket] = []

    # -- lifecycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Bind every port (raises OSError if one is taken) and start all threads."""
        handlers = {'rtde': self._serve_rtde, 'dashboard': self._serve_dashboard,
                    'script': self._serve_script, 'control': self._serve_control}
        for kind, port in self.ports.items():
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                sock.bind((self.host, port))
            except OSError:
                sock.close()
                for other in self.listeners:
                    other.close()
                raise
            sock.listen(16)
            sock.settimeout(0.2)
            self.listeners.append(sock)
            self._spawn(self._accept_loop, sock, kind, handlers[kind])
        self._spawn(self._tick_loop)

    def _spawn(self, target, *args) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True)
        thread.start()
        self.threads.append(thread)

    def shutdown(self) -> None:
        """Stop all threads and close every socket."""
        self.stop_event.set()
        self.drop_connections()
        for sock in self.listeners:
            sock.close()
        for thread in self.threads:
            thread.join(timeout=2.0)

    # -- connection management -------------------------------------------------------------------
    def _accept_loop(self, listener: socket.socket, kind: str, handler) -> None:
        while not self.stop_event.is_set():
            try:
                sock, _ = listener.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            if kind != 'control' and time.monotonic() < self.refuse_until:
                sock.close()
                continue
            sock.settimeout(None)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._spawn(self._run_client, handler, sock, kind)

    def _run_client(self, handler, sock: socket.socket, kind: str) -> None:
        client = _RtdeClient(self, sock) if kind == 'rtde' else _Client(self, sock, kind)
        with self.lock:
            self.clients.append(client)
        try:
            handler(client)
        except OSError:
            pass
        finally:
            client.close()
            with self.lock:
                if client in self.clients:
                    self.clients.remove(client)
                for name in [n for n, c in self.input_owner.items() if c is client]:
                    del self.input_owner[name]

    def claim_inputs(self, client: _RtdeClient, names: Sequence[str],
                     types: List[str]) -> List[str]:
        """Mark input registers as written by ``client``; ``IN_USE`` where another holds one."""
        with self.lock:
            out = [('IN_USE' if typ != 'NOT_FOUND' and self.input_owner.get(name) not in
                    (None, client) else typ) for name, typ in zip(names, types)]
            if 'IN_USE' not in out and 'NOT_FOUND' not in out:
                for name in names:
                    self.input_owner[name] = client
            return out

    def drop_connections(self, refuse_s: float = 0.0) -> int:
        """Close every RTDE, dashboard and script connection; refuse new ones for a while."""
        with self.lock:
            self.refuse_until = time.monotonic() + max(0.0, refuse_s)
            victims = [c for c in self.clients if c.kind != 'control']
        for client in victims:
            client.close()
        return len(victims)

    def apply_inputs(self, values: Dict[str, object]) -> None:
        """Apply one decoded input data package to the controller registers."""
        with self.lock:
            self.controller.apply_inputs(values)

    # -- the 500 Hz loop ----------------------------------------------------------------------
    def _tick_loop(self) -> None:
        # One controller period per pass. When the process was starved for more than one
        # period the backlog is dropped rather than sent in a burst: the controller clock then
        # runs slower than the wall clock, but every period is computed and streamed (a burst
        # would make ur_rtde keep only its last package, i.e. drop samples a real controller
        # would have delivered).
        next_time = time.perf_counter()
        while not self.stop_event.is_set():
            now = time.perf_counter()
            if now < next_time:
                time.sleep(next_time - now)
            elif now - next_time > DT:
                self.late_ticks += int((now - next_time) / DT)
                next_time = now
            next_time += DT
            with self.lock:
                ctl = self.controller
                ctl.step()
                now_mono = time.monotonic()
                stall_force = self.force_stall_until is not None and (
                    self.force_stall_until == 0.0 or now_mono < self.force_stall_until)
                if stall_force and ctl.frozen_force is None:
                    ctl.frozen_force = ctl.force.copy()
                elif not stall_force and ctl.frozen_force is not None:
                    ctl.frozen_force = None
                    self.force_stall_until = None
                stall_stream = self.stream_stall_until is not None and (
                    self.stream_stall_until == 0.0 or now_mono < self.stream_stall_until)
                if not stall_stream:
                    self.stream_stall_until = None
                snapshot = ctl.outputs()
                clients = [c for c in self.clients if isinstance(c, _RtdeClient)]
                messages = []
                for client in clients:
                    if client.started and not stall_stream and ctl.tick % client.period == 0:
                        messages.append((client, client.output.pack(
                            lambda name: ctl.output_value(snapshot, name))))
                    elif client.pending:
                        messages.append((client, b''))
            for client, data in messages:
                if data:
                    client.send(data)
                else:
                    client.flush()

    # -- RTDE, dashboard, script and control handlers ------------------------------------------
    def _serve_rtde(self, client: _RtdeClient) -> None:
        client.serve()

    def _lines(self, client: _Client):
        buf = b''
        while not client.closed:
            try:
                data = client.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            buf += data
            while b'\n' in buf:
                line, buf = buf.split(b'\n', 1)
                yield line.decode('utf-8', errors='replace').strip()

    def _serve_dashboard(self, client: _Client) -> None:
        client.send(b'Connected: Universal Robots Dashboard Server\n')
        for line in self._lines(client):
            reply = self._dashboard_reply(line)
            client.send((reply + '\n').encode())
            if line == 'quit':
                return

    def _dashboard_reply(self, line: str) -> str:
        ctl = self.controller
        with self.lock:
            if line == 'PolyscopeVersion':
                return POLYSCOPE_TEXT
            if line == 'get serial number':
                return SERIAL_NUMBER
            if line == 'is in remote control':
                return 'true'
            if line == 'get robot model':
                return 'UR5'
            if line == 'robotmode':
                return 'Robotmode: RUNNING'
            if line == 'safetymode':
                return 'Safetymode: ' + ('PROTECTIVE_STOP' if ctl.protective else 'NORMAL')
            if line == 'safetystatus':
                return 'Safetystatus: ' + ('PROTECTIVE_STOP' if ctl.protective else 'NORMAL')
            if line == 'running':
                return 'Program running: ' + str(ctl.runtime_state == RUNTIME_PLAYING).lower()
            if line == 'programState':
                state = {RUNTIME_PLAYING: 'PLAYING', RUNTIME_PAUSED: 'PAUSED'}.get(
                    ctl.runtime_state, 'STOPPED')
                return f'{state} rtde_control'
            if line == 'stop':
                ctl.stop_program('dashboard stop')
                return 'Stopped'
            if line == 'pause':
                return 'Pausing program' if ctl.pause_program() else 'Failed to execute: pause'
            if line == 'play':
                return 'Starting program' if ctl.resume_program() else 'Failed to execute: play'
            if line == 'unlock protective stop':
                if ctl.unlock_protective_stop():
                    return 'Protective stop releasing'
                return 'Cannot unlock protective stop until 5s after occurrence. Always ' \
                       'inspect cause of protective stop before unlocking'
            if line == 'close safety popup':
                return 'closing safety popup'
            if line in ('power on', 'brake release', 'power off'):
                return {'power on': 'Powering on', 'brake release': 'Brake releasing',
                        'power off': 'Powering off'}[line]
            if line == 'quit':
                return 'Disconnected'
        return f"could not understand: '{line}'"

    def _serve_script(self, client: _Client) -> None:
        text = ''
        while not client.closed:
            try:
                data = client.sock.recv(65536)
            except OSError:
                return
            if not data:
                return
            text += data.decode('utf-8', errors='replace')
            text = self._consume_programs(text)

    def _consume_programs(self, text: str) -> str:
        """Start every complete ``def|sec name(): ... end`` program in ``text``; keep the rest."""
        while True:
            lines = text.split('\n')
            start = next((i for i, ln in enumerate(lines[:-1])
                          if ln.startswith('def ') or ln.startswith('sec ')), None)
            if start is None:
                if len(lines) > 1:
                    for ln in lines[:-1]:
                        if ln.strip():
                            LOG.info('script line outside a program ignored: %r', ln[:80])
                    return lines[-1]
                return text
            end = next((i for i in range(start + 1, len(lines) - 1)
                        if lines[i].rstrip() == 'end'), None)
            if end is None:
                return '\n'.join(lines[start:])
            name = lines[start][4:].split('(', 1)[0].strip()
            with self.lock:
                self.controller.start_program(name)
            text = '\n'.join(lines[end + 1:])

    def _serve_control(self, client: _Client) -> None:
        for line in self._lines(client):
            if not line:
                continue
            try:
                reply = self._control(line)
                reply.setdefault('ok', True)
            except (ValueError, TypeError, KeyError) as exc:
                reply = {'ok': False, 'error': f'{type(exc).__name__}: {exc}'}
            client.send((json.dumps(reply) + '\n').encode())

    def _control(self, line: str) -> dict:
        word, _, rest = line.partition(' ')
        rest = rest.strip()
        ctl = self.controller
        if word == 'ping':
            return {}
        if word == 'state':
            with self.lock:
                return {
                    'timestamp': ctl.timestamp, 'tick': ctl.tick,
                    'pose': list(ctl.kin.pose6()), 'twist': list(ctl.kin.twist6()),
                    'force': list(map(float, ctl.force)), 'raw': list(map(float, ctl.raw)),
                    'tare': list(map(float, ctl.tare)), 'runtime_state': ctl.runtime_state,
                    'protective': ctl.protective, 'moving': ctl.is_moving(),
                    'motion': ctl.motion_owner, 'out_int_0': ctl.out_int[0],
                    'clients': sorted(c.kind for c in self.clients),
                    'late_ticks': self.late_ticks, 'events': list(ctl.events)[-20:],
                }
        if word == 'protective_stop':
            with self.lock:
                ctl.protective_stop('injected on the fault channel')
            return {}
        if word == 'unlock':
            with self.lock:
                return {'released': ctl.unlock_protective_stop()}
        if word == 'program_stop':
            with self.lock:
                ctl.stop_program('injected on the fault channel')
            return {}
        if word == 'drop':
            return {'dropped': self.drop_connections(float(rest) if rest else 0.0)}
        if word == 'stall':
            what, _, secs = rest.partition(' ')
            seconds = float(secs) if secs.strip() else 0.0
            until = 0.0 if seconds <= 0.0 else time.monotonic() + seconds
            with self.lock:
                if what == 'force':
                    self.force_stall_until = until
                elif what == 'stream':
                    self.stream_stall_until = until
                else:
                    raise ValueError(f'stall: expected "force" or "stream", got {what!r}')
            return {}
        if word == 'unstall':
            with self.lock:
                self.force_stall_until = None
                self.stream_stall_until = None
                ctl.frozen_force = None
            return {}
        if word == 'model_params':
            params = json.loads(rest) if rest else {}
            with self.lock:
                setter = getattr(ctl.model, 'set_params', None)
                if setter is None:
                    raise ValueError(f'{type(ctl.model).__name__} has no set_params()')
                setter(**params)
            return {}
        if word == 'model':
            spec, _, kwargs = rest.partition(' ')
            model = load_force_model(spec, json.loads(kwargs) if kwargs.strip() else {})
            with self.lock:
                ctl.model = model
            return {}
        if word == 'set_pose':
            pose = np.asarray(json.loads(rest), dtype=float).reshape(6)
            with self.lock:
                if ctl.is_moving():
                    raise ValueError('set_pose: the TCP is moving')
                ctl.kin = _Kinematics(pose)
            return {}
        raise ValueError(f'unknown command {word!r}')


class EmulatorControl:
    """Client of the emulator's fault-injection channel (see the module docstring).

    Every call opens a short TCP connection, so the object is cheap and thread-safe.

    Raises:
        ConnectionError: the channel does not answer within ``timeout`` seconds.
        RuntimeError: the emulator rejected the command (its message is included).

    """

    def __init__(self, host: str, port: int = CONTROL_PORT, timeout: float = 2.0):
        self.host, self.port, self.timeout = host, port, timeout

    def command(self, line: str) -> dict:
        """Send one command line and return the decoded JSON reply."""
        try:
            with socket.create_connection((self.host, self.port), timeout=self.timeout) as s:
                s.sendall(line.encode() + b'\n')
                buf = b''
                while b'\n' not in buf:
                    chunk = s.recv(65536)
                    if not chunk:
                        break
                    buf += chunk
        except OSError as exc:
            raise ConnectionError(f'rtde_emulator control channel {self.host}:{self.port}: '
                                  f'{exc}') from exc
        if b'\n' not in buf:
            raise ConnectionError(f'rtde_emulator control channel {self.host}:{self.port}: '
                                  'connection closed without a reply')
        reply = json.loads(buf.split(b'\n', 1)[0])
        if not reply.get('ok'):
            raise RuntimeError(f'rtde_emulator rejected {line!r}: {reply.get("error")}')
        return reply

    def state(self) -> dict:
        """Return a snapshot: pose, twist, force, modes, clients, recent events."""
        return self.command('state')

    def protective_stop(self) -> None:
        """Inject a protective stop."""
        self.command('protective_stop')

    def unlock(self) -> bool:
        """Release the protective stop; False if there was none."""
        return bool(self.command('unlock')['released'])

    def program_stop(self) -> None:
        """Stop the control program."""
        self.command('program_stop')

    def drop(self, refuse_s: float = 0.0) -> int:
        """Close every client connection, refuse new ones for ``refuse_s``; return count."""
        return int(self.command(f'drop {refuse_s}')['dropped'])

    def stall(self, what: str = 'force', seconds: float = 0.0) -> None:
        """Freeze the force (``force``) or stop the data (``stream``); 0 s = until unstall."""
        self.command(f'stall {what} {seconds}')

    def unstall(self) -> None:
        """End both kinds of stall."""
        self.command('unstall')

    def model_params(self, **params) -> None:
        """Call ``set_params(**params)`` on the live force model."""
        self.command('model_params ' + json.dumps(params))

    def set_model(self, spec: str, **kwargs) -> None:
        """Replace the force model by ``module:factory(**kwargs)``."""
        self.command(f'model {spec} {json.dumps(kwargs)}')

    def set_pose(self, pose6: Sequence[float]) -> None:
        """Teleport the TCP (refused while it moves)."""
        self.command('set_pose ' + json.dumps([float(x) for x in pose6]))


# --------------------------------------------------------------------------------------------
# command line

def _parse_args(argv):
    parser = argparse.ArgumentParser(
        prog='rtde_emulator',
        description='Loopback UR controller emulator for the real ur_rtde (see module doc).')
    parser.add_argument('--host', default='127.0.0.2',
                        help='loopback address to listen on (default 127.0.0.2)')
    parser.add_argument('--rtde-port', type=int, default=RTDE_PORT)
    parser.add_argument('--dashboard-port', type=int, default=DASHBOARD_PORT)
    parser.add_argument('--script-port', type=int, default=SCRIPT_PORT)
    parser.add_argument('--control-port', type=int, default=CONTROL_PORT,
                        help='fault-injection channel port (default 30099)')
    parser.add_argument('--force-model', default=f'{__name__}:HalfSpaceSpring',
                        help='force model factory as module:attribute')
    parser.add_argument('--force-model-kwargs', default='{}',
                        help='JSON object of keyword arguments for the factory')
    parser.add_argument('--initial-pose', default='[0.3, 0.0, 0.3, 3.14159265, 0.0, 0.0]',
                        help='JSON [x, y, z, rx, ry, rz] of the TCP at start (m, rad, base)')
    parser.add_argument('--ft-noise-floor', type=float, default=0.005,
                        help='std of the F/T sensor noise added to every model, N '
                             '(torques get 0.02 m times this); a real sensor is never '
                             'bitwise constant and the driver relies on it to spot a frozen '
                             'sensor')
    parser.add_argument('--force-limit', type=float, default=150.0,
                        help='|F| above this (N) triggers a protective stop')
    parser.add_argument('--contact-threshold', type=float, default=1.0,
                        help='push-back force (N) that tool_contact reports as contact')
    parser.add_argument('--seed', type=int, default=0, help='seed of the sensor noise floor')
    parser.add_argument('--log-level', default='WARNING')
    return parser.parse_args(argv)


def main(argv=None) -> int:
    """Run the emulator until SIGTERM or SIGINT."""
    args = _parse_args(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(stream=sys.stderr, level=args.log_level.upper(),
                        format='%(asctime)s rtde_emulator %(levelname)s %(message)s')
    try:
        kwargs = json.loads(args.force_model_kwargs)
        model = load_force_model(args.force_model, kwargs)
        pose = np.asarray(json.loads(args.initial_pose), dtype=float).reshape(6)
    except (ValueError, TypeError) as exc:
        print(f'rtde_emulator: {exc}', file=sys.stderr)
        return 2
    controller = Controller(model, pose, noise_floor=args.ft_noise_floor,
                            force_limit=args.force_limit,
                            contact_threshold=args.contact_threshold, seed=args.seed)
    emulator = Emulator(args.host, controller, rtde_port=args.rtde_port,
                        dashboard_port=args.dashboard_port, script_port=args.script_port,
                        control_port=args.control_port)
    try:
        emulator.start()
    except OSError as exc:
        print(f'rtde_emulator: cannot listen on {args.host}: {exc}', file=sys.stderr)
        return 3
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    ports = emulator.ports
    print(f'rtde_emulator ready host={args.host} rtde={ports["rtde"]} '
          f'dashboard={ports["dashboard"]} script={ports["script"]} '
          f'control={ports["control"]} pid={os.getpid()}', flush=True)
    while not stop.wait(0.2):
        pass
    emulator.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
