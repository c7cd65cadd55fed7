"""The emulated controller: kinematics, sensing, safety, the control script register protocol."""

from collections import deque
import logging
from typing import Callable, Dict, Optional, Sequence

import numpy as np

from pointforce_ros.sim.rtde import protocol as rp
from pointforce_ros.rotations import pose_trans
from pointforce_ros.sim.rtde.constants import (CMD_FK_DEFAULT, CMD_FLANGE_POSE,
                                               CMD_FORCE_MODE_STOP, CMD_GET_STEPTIME,
                                               CMD_GET_TARGET_WAYPOINT, CMD_GET_TCP_OFFSET,
                                               CMD_INTERNAL_CONTACT, CMD_IS_POSE_SAFE,
                                               CMD_IS_STEADY, CMD_MOVE_UNTIL_CONTACT, CMD_MOVEL,
                                               CMD_POSE_TRANS, CMD_PROTECTIVE_STOP,
                                               CMD_READ_CONTACT, CMD_SERVO_STOP, CMD_SET_PAYLOAD,
                                               CMD_SET_TARGET_PAYLOAD, CMD_SET_TCP,
                                               CMD_SET_WATCHDOG, CMD_SPEED_STOP, CMD_SPEEDL,
                                               CMD_START_CONTACT, CMD_STOP_CONTACT,
                                               CMD_STOP_SCRIPT, CMD_STOPJ, CMD_STOPL,
                                               CMD_TOOL_CONTACT, CMD_ZERO_FT, CONTACT_RETURN_ACCEL,
                                               CONTACT_RETURN_SPEED, CONTACT_STOP_DECEL, DONE, DT,
                                               HISTORY, JOINT_MODE_RUNNING, PROGRAM_STOP_DECEL,
                                               PROTECTIVE_DECEL, READY, REALTIME_COMMANDS,
                                               ROBOT_BIT_POWER_ON, ROBOT_BIT_PROGRAM_RUNNING,
                                               ROBOT_MODE_RUNNING, RUNTIME_PAUSED, RUNTIME_PLAYING,
                                               RUNTIME_STOPPED, SAFETY_BIT_NORMAL,
                                               SAFETY_BIT_PROTECTIVE_STOPPED,
                                               SAFETY_BIT_STOPPED_DUE_TO_SAFETY,
                                               SAFETY_MODE_NORMAL, SAFETY_MODE_PROTECTIVE_STOP,
                                               TARE_SAMPLES, UNSUPPORTED)
from pointforce_ros.sim.rtde.motion import (Kinematics, LinearMove, MoveSequence, Ring, SpeedMove,
                                            StopMove)

LOG = logging.getLogger('rtde_emulator')


class ScriptError(RuntimeError):
    """The emulated control script hit something it cannot do; the program stops."""


class Controller:
    """Everything that advances at 500 Hz. Not thread-safe: the emulator holds a lock."""

    def __init__(self, model, initial_pose6: Sequence[float], *, noise_floor: float = 0.005,
                 force_limit: float = 150.0, contact_threshold: float = 1.0, seed: int = 0):
        self.model = model
        self.kin = Kinematics(initial_pose6)
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
        self.force_hist = Ring(HISTORY, 3)
        self.pose_hist = Ring(HISTORY, 6)
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
        self._set_motion(StopMove(PROTECTIVE_DECEL), 'safety')
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
            self._set_motion(StopMove(PROGRAM_STOP_DECEL), 'program_stop')
        self.events.append(f'program stopped: {reason}')
        LOG.warning('program stopped: %s', reason)

    def start_program(self, name: str) -> bool:
        """Start the control program: PLAYING, ready, F/T re-tared; refused while stopped."""
        if self.protective:
            LOG.warning('program %s not started: the robot is protective stopped', name)
            return False
        self._abort_threads()
        if self.motion_owner not in (None, 'safety', 'program_stop'):
            self._set_motion(StopMove(PROGRAM_STOP_DECEL), 'program_stop')
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
            self._set_motion(StopMove(PROGRAM_STOP_DECEL), 'program_stop')
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
        self._set_motion(MoveSequence(
            lambda kin: StopMove(CONTACT_STOP_DECEL),
            lambda kin: LinearMove(kin, back, CONTACT_RETURN_SPEED, CONTACT_RETURN_ACCEL)),
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
            move = LinearMove(self.kin, target, speed, accel)
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
                self._set_motion(StopMove(decel), 'stop_thread')
                self.stop_async = True
                self._write_async_progress(0)
            else:
                self._set_motion(StopMove(decel), 'sync')
                self.blocking = self._wait_motion_done
        elif cmd == CMD_SPEEDL:
            twist = np.array(self.in_double[0:6], dtype=float)
            accel = self.in_double[6]
            if not (np.all(np.isfinite(twist)) and accel > 0.0):
                raise ScriptError(f'speedl: invalid speed {twist} or acceleration {accel}')
            if self.motion_owner == 'speed':
                self.motion.target, self.motion.accel = twist, accel
            else:
                self._set_motion(SpeedMove(twist, accel), 'speed')
        elif cmd in (CMD_SPEED_STOP, CMD_SERVO_STOP):
            decel = self.in_double[0]
            if not decel > 0.0:
                raise ScriptError(f'speed stop: deceleration must be > 0, got {decel}')
            if self.motion_owner in ('speed', 'orphan') or cmd == CMD_SERVO_STOP:
                self._set_motion(StopMove(decel), 'sync')
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
        self._set_motion(SpeedMove(twist, accel), 'contact')
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
