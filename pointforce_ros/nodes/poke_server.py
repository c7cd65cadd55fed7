"""poke_server node: the ``~/poke`` action, driving a UR arm through ``ur_rtde``.

One goal at a time. A goal is checked against the limits (and the latched equilibrium surface
when one is published) and rejected with a logged reason if bad. Execution: move to the
stand-off along the normal, tare, push along ``-n`` at constant speed until the force or depth
limit, retract (:meth:`pointforce_ros.drivers.ur_arm.UrArm.push_until`). The driver's own
receive interface streams TCP pose and wrench at 250 Hz, de-duplicated on controller time, to
``~/tcp_pose`` (``base``) and ``~/wrench`` (``tool0_controller``) and into the poke record.
Feedback names the phase (``PHASE_*`` of Poke.action): one message as each of approach, tare,
push, hold and retract begins, and ``feedback_rate`` messages per second during the push. A goal
stamped in another frame than ``base`` (empty: ``base``) is moved into ``base`` through the tf
tree (``/tf_static``; ``/tf`` too with ``tf_dynamic``), or rejected with the reason.
Cancel stops the arm (asynchronous moveL + stopL) and retracts. A protective stop, a lost
connection or a stalled F/T stream aborts with a message, after retracting where possible.
Every poke, completed, canceled or aborted, is written to the poke store (rosbag2 MCAP) before
the result is sent, and published as ``~/poke_record`` (the bag's JSON header, so a remote
recorder can rebuild it from the streams); completed ones are announced on ``~/poke_landed``.
If the store cannot write it, the samples are kept in a recovery file and the goal aborts with
a message that says where. The busy check and the one-goal lock are one atomic step in the goal
callback (the lock is held from acceptance to the end of execution), and no callback lets an
exception escape into the executor.
"""

import dataclasses
import json
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped, WrenchStamped
from pointforce_interfaces.action import Poke
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from msg_adapters.geometry import sec_to_stamp
from msg_adapters.interfaces import (MODEL_FRAME, poke_feedback_msg, poke_goal_from_msg,
                                     poke_result_msg)
from msg_adapters.pointcloud2 import surface_from_msg
from pointforce_ros.errors import DeviceFault, PointforceError
from pointforce_ros.nodes.common import (declare, destroy_waitables, live, publish_health,
                                         RequestFrames, run)
from pointforce_ros.pokes.limits import check_goal, PokeLimits
from pointforce_ros.pokes.store import PokeStore, record_header
from pointforce_ros.rotations import rotvec_aligning_z, rotvec_matrix_and_quaternion
from pointforce_ros.types import PokeRecord
from pointforce_ros.drivers.ur_arm import active_fault_message, STREAM_RT_PRIORITY, UrArm

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
STREAM = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
REQUESTS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
"""Goal and cancel requests: the default depth of 10 dropped goals of a burst unanswered."""


def stream_messages(sample, convert=rotvec_matrix_and_quaternion):
    """``(PoseStamped in base, WrenchStamped in tool0_controller)`` of one arm sample.

    ``convert``: rotation vector -> ``(matrix, quaternion)``; the closed form by default
    (``pointforce bench streams`` measures it against scipy's path). A non-finite pose or
    wrench raises ``ValueError``: no NaN goes out on the streams.
    """
    if not (np.all(np.isfinite(sample.pose)) and np.all(np.isfinite(sample.wrench))):
        raise ValueError(f'non-finite arm sample at controller time {sample.t_controller:.3f} s: '
                         f'pose {np.asarray(sample.pose).tolist()}, wrench '
                         f'{np.asarray(sample.wrench).tolist()}')
    rot, q = convert(sample.pose[3:])
    pose = PoseStamped()
    pose.header.frame_id = 'base'
    sec_to_stamp(sample.t_wall, pose.header.stamp)
    pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (
        float(v) for v in sample.pose[:3])
    (pose.pose.orientation.x, pose.pose.orientation.y, pose.pose.orientation.z,
     pose.pose.orientation.w) = (float(v) for v in q)
    wrench = WrenchStamped()
    wrench.header.frame_id = 'tool0_controller'
    wrench.header.stamp = pose.header.stamp
    force = rot.T @ sample.wrench[:3]
    torque = rot.T @ sample.wrench[3:]
    w = wrench.wrench
    w.force.x, w.force.y, w.force.z = (float(v) for v in force)
    w.torque.x, w.torque.y, w.torque.z = (float(v) for v in torque)
    return pose, wrench


LIMITS = ('max_force', 'max_depth', 'max_speed', 'max_push_time', 'surface_tolerance',
          'max_normal_angle', 'max_tilt')
"""The goal limits (:class:`PokeLimits` fields), each a parameter of the same name."""


def _losses_within(arm, t_controller) -> list:
    """``[[t_controller, lost, held_s], ...]``: the stream's losses inside one push's samples.

    Each is a :class:`~pointforce_ros.drivers.ur_arm.StreamLoss` whose first sample after the
    empty slots lies in the record; stored in the poke's ``meta['stream_losses']`` so that a
    record says where it has no samples and how long the poller was held up there. An arm
    without the accounting gives none; nor does one whose accounting fails (the arm moved:
    the samples are stored whatever this says).
    """
    try:
        t = np.asarray(t_controller, dtype=float)
        losses = getattr(arm, 'stream_losses', lambda: [])()
        return [[float(x.t_controller), int(x.lost), float(x.held_s)] for x in losses
                if len(t) and t[0] < x.t_controller <= t[-1]]
    except Exception:  # noqa: BLE001 - never between a push and the store
        return []


STREAM_SILENCE = 0.5
"""Seconds without an arm sample that make the stream's report an ERROR."""
STREAM_LOSS_WARN = 0.01
"""Share of a report period's stream slots missed that makes the report a WARN: a slot now
and then goes when the controller's samples come in a burst (one in a few seconds seen on an
idle machine); a held-up stream worker misses runs of them."""
STREAM_RATE_WARN = 0.8
"""Share of the stream's rate below which a report is a WARN (a controller or a reader that
cannot keep up; the loopback emulator's clock slows when its process is starved)."""


class PokeServerNode(Node):
    """The Poke action server on a UR arm."""

    START_TIMEOUT = 10.0
    """Seconds an accepted goal may take to start executing before its lock is taken back."""

    def __init__(self, arm_factory=None, **kwargs):
        """Declare parameters, connect the arm (retried per goal), create the action server.

        ``arm_factory(host) -> UrArm`` is injectable for a different driver; the default is
        :class:`pointforce_ros.drivers.ur_arm.UrArm`.
        """
        super().__init__('poke_server', **kwargs)
        self.robot_ip = declare(self, 'robot_ip', '127.0.0.2',
                                'UR controller address (the simulated cell listens on 127.0.0.2)',
                                read_only=True)
        self.store = PokeStore(declare(self, 'store_dir', 'out/cell/pokes',
                                       'Poke store directory (one rosbag2 MCAP bag per poke)',
                                       read_only=True))
        self.limits = PokeLimits(
            max_force=declare(self, 'max_force', 15.0, 'Largest accepted force limit, N',
                              bounds=(0.1, 100.0)),
            max_depth=declare(self, 'max_depth', 0.03, 'Largest accepted depth limit, m',
                              bounds=(0.001, 0.1)),
            max_speed=declare(self, 'max_speed', 0.01, 'Largest accepted push speed, m/s',
                              bounds=(0.0001, 0.05)),
            max_push_time=declare(self, 'max_push_time', 300.0,
                                  'Longest accepted push (stand-off plus depth limit over the '
                                  'goal speed), s', bounds=(1.0, 3600.0)),
            surface_tolerance=declare(self, 'surface_tolerance', 0.003,
                                      'Largest goal distance from the equilibrium surface, m',
                                      bounds=(0.0, 0.05)),
            max_normal_angle=declare(self, 'max_normal_angle', 30.0,
                                     'Largest angle between a goal normal and the surface '
                                     'normal at the goal point, deg', bounds=(1.0, 89.0)),
            max_tilt=declare(self, 'max_tilt', 80.0,
                             'Largest angle between a goal normal and base +z, deg',
                             bounds=(0.0, 89.0)))
        self.retract_speed = declare(self, 'retract_speed', 0.01, 'Retract speed, m/s',
                                     bounds=(0.0005, 0.1))
        self.approach_speed = declare(self, 'approach_speed', 0.05,
                                      'Speed of the move to the stand-off, m/s',
                                      bounds=(0.001, 0.25))
        self.feedback_hz = declare(self, 'feedback_rate', 25.0, 'Action feedback rate, Hz',
                                   bounds=(1.0, 250.0))
        self.stream_rt_priority = declare(
            self, 'stream_rt_priority', STREAM_RT_PRIORITY,
            'SCHED_FIFO priority of the F/T stream worker where the OS permits it (root, '
            'CAP_SYS_NICE or an rtprio limit); 0 keeps it at normal priority',
            bounds=(0, 98), read_only=True)
        self._arm_factory = arm_factory or self._default_arm
        self._arm = None
        self._arm_lock = threading.Lock()
        self._busy = threading.Lock()     # one goal from acceptance to the end of execution
        self._goal_mutex = threading.Lock()
        self._accepted_at = 0.0
        self._executing = False
        self.samples_streamed = 0
        self.samples_refused = 0
        self.last_rejection = ''   # why the last goal was rejected (also logged)
        self.surface = None
        self.frames = RequestFrames(self, 'goals')
        self.tf = self.frames.buffer
        group = ReentrantCallbackGroup()
        self.wrench_pub = self.create_publisher(WrenchStamped, '~/wrench', STREAM)
        self.pose_pub = self.create_publisher(PoseStamped, '~/tcp_pose', STREAM)
        self.landed_pub = self.create_publisher(String, '~/poke_landed', STREAM)
        self.record_pub = self.create_publisher(String, '~/poke_record', STREAM)
        self.create_subscription(PointCloud2, 'cloud_capture/surface', self._on_surface,
                                 LATCHED, callback_group=group)
        self.create_service(Trigger, '~/zero_ftsensor', self._on_zero, callback_group=group)
        self._diag_last = (time.monotonic(), 0, 0, 0)   # when; samples, refused, slots missed
        publish_health(self, 'arm and F/T stream', self.diagnostics, lambda: self.robot_ip)
        self._server = ActionServer(self, Poke, '~/poke', execute_callback=self._execute,
                                    goal_callback=self._on_goal, cancel_callback=self._on_cancel,
                                    callback_group=group, goal_service_qos_profile=REQUESTS,
                                    cancel_service_qos_profile=REQUESTS)
        # limits and speeds apply from the next goal: a poke in progress keeps the values it
        # started with (they were passed to the arm); robot_ip and store_dir are read-only
        live(self, {**{name: self._new_limit(name) for name in LIMITS},
                    'retract_speed': lambda v: lambda: setattr(self, 'retract_speed', v),
                    'approach_speed': lambda v: lambda: setattr(self, 'approach_speed', v),
                    'feedback_rate': lambda v: lambda: setattr(self, 'feedback_hz', v)})
        try:
            self._connect()
        except PointforceError as exc:
            self.get_logger().warn(f'arm not connected yet ({exc}); will retry on the next goal')

    def _new_limit(self, name):
        """Return the applier of the goal limit ``name`` (a new PokeLimits, checked)."""
        def applier(value):
            limits = dataclasses.replace(self.limits, **{name: value})
            return lambda: setattr(self, 'limits', limits)
        return applier

    # ------------------------------------------------------------------ arm and streaming
    def _default_arm(self, host):
        return UrArm(host, rt_priority=self.stream_rt_priority)

    def _connect(self):
        with self._arm_lock:
            if self._arm is not None and self._arm.is_connected():
                return self._arm
            if self._arm is not None:
                self._arm.close()
                self._arm = None
            arm = self._arm_factory(self.robot_ip)
            # the next health report counts from here (a new arm counts its losses from 0)
            self._diag_last = (time.monotonic(), self.samples_streamed, self.samples_refused, 0)
            arm.add_sample_callback(self._stream_sample)
            self._arm = arm
            self.get_logger().info(f'connected to the UR controller at {self.robot_ip}')
            scheduling = getattr(arm, 'stream_scheduling', None)
            if scheduling is not None:
                log = (self.get_logger().warn if 'refused' in scheduling
                       else self.get_logger().info)
                log(f'F/T stream worker: {scheduling}')
            return arm

    def diagnostics(self) -> tuple:
        """Return ``(level, message, values)``: arm and F/T stream health since the last call.

        For ``/diagnostics`` (:func:`~pointforce_ros.nodes.common.publish_health`); it makes no
        call to the robot.

        ERROR: no arm, an active fault (connection lost, protective stop, program stopped,
        stall, frozen F/T), or no sample for :data:`STREAM_SILENCE`; WARN: more than
        :data:`STREAM_LOSS_WARN` of the stream's slots missed since the last report
        (:class:`~pointforce_ros.drivers.ur_arm.StreamLoss`), a sample rate under
        :data:`STREAM_RATE_WARN` of the stream's, samples refused since then, or a refused
        real-time priority; else OK. ``values``: the sample rate and the counts, the
        scheduling, whether a poke runs, the last goal rejection.
        """
        now = time.monotonic()
        then, streamed, refused, missed = self._diag_last
        arm = self._arm
        lost = int(getattr(arm, 'lost_samples', 0)) if arm is not None else missed
        self._diag_last = (now, self.samples_streamed, self.samples_refused, lost)
        values = {'robot_ip': self.robot_ip,
                  'sample_rate_hz': round((self.samples_streamed - streamed)
                                          / max(now - then, 1e-3), 1),
                  'slots_missed': lost, 'slots_missed_since_last': lost - missed,
                  'samples_refused': self.samples_refused,
                  'poke_running': self._busy.locked(), 'last_rejection': self.last_rejection}
        if arm is None:
            return (DiagnosticStatus.ERROR, 'no arm connected (tried again on the next goal)',
                    values)
        scheduling = getattr(arm, 'stream_scheduling', None) or ''
        values['stream_scheduling'] = scheduling
        # another driver (arm_factory) may not keep faults or a ring buffer: not checked then
        faults = list(getattr(arm, 'active_faults', list)())
        values['active_faults'] = ','.join(faults)
        latest = getattr(arm, 'latest', None)
        newest = latest() if latest is not None and self.samples_streamed else None
        silent = 0.0 if newest is None else time.time() - newest.t_wall
        values['newest_sample_age_s'] = round(silent, 3)
        if faults:
            events = getattr(arm, 'events', list)()
            return DiagnosticStatus.ERROR, active_fault_message(events, faults), values
        if silent > STREAM_SILENCE:
            return DiagnosticStatus.ERROR, f'no arm sample for {silent:.1f} s', values
        warnings = []
        stream_hz = float(getattr(arm, 'stream_hz', 250.0))
        expected = max(now - then, 1e-3) * stream_hz
        if values['sample_rate_hz'] < STREAM_RATE_WARN * stream_hz:
            warnings.append(f'the stream delivered {values["sample_rate_hz"]:g} samples/s of '
                            f'{stream_hz:g}')
        if lost - missed > STREAM_LOSS_WARN * expected:
            warnings.append(f'{lost - missed} stream slots missed since the last report '
                            f'({100 * (lost - missed) / expected:.1f} %: the stream worker was '
                            'held up; each poke lists its own in meta stream_losses)')
        if self.samples_refused > refused:
            warnings.append(f'{self.samples_refused - refused} samples not published')
        if 'refused' in scheduling:
            warnings.append(f'F/T stream worker at normal priority: {scheduling}')
        if warnings:
            return DiagnosticStatus.WARN, '; '.join(warnings), values
        return DiagnosticStatus.OK, f'streaming at {values["sample_rate_hz"]:g} Hz', values

    def _stream_sample(self, sample):
        """Publish one 250 Hz sample (driver thread; must neither block nor raise).

        A sample that cannot be published (non-finite from the controller, or any fault of
        the publishers) is counted in ``samples_refused`` and logged at most every 5 s; the
        stream goes on.
        """
        self.samples_streamed += 1
        try:
            pose, wrench = stream_messages(sample)
            self.pose_pub.publish(pose)
            self.wrench_pub.publish(wrench)
        except Exception as exc:  # noqa: BLE001 - the driver's stream thread must go on
            self.samples_refused += 1
            self.get_logger().warn(f'arm sample not published ({self.samples_refused} so far): '
                                   f'{type(exc).__name__}: {exc}', throttle_duration_sec=5.0)

    def _on_surface(self, msg):
        try:
            self.surface = surface_from_msg(msg)
            self.get_logger().info(f'equilibrium surface of {len(self.surface)} points')
        except PointforceError as exc:
            self.get_logger().error(f'ignoring surface: {exc}')

    def _on_zero(self, request, response):
        if not self._busy.acquire(blocking=False):
            response.success = False
            response.message = 'a poke is running: the F/T sensor is not zeroed while pressed'
            return response
        try:
            self._connect().tare()
            response.success, response.message = True, 'F/T sensor zeroed'
        except PointforceError as exc:
            response.success, response.message = False, str(exc)
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            response.success = False
            response.message = f'cannot zero the F/T sensor: {type(exc).__name__}: {exc}'
        finally:
            self._busy.release()
        return response

    # ------------------------------------------------------------------ action callbacks
    def _on_goal(self, goal_msg):
        """Accept a good goal only if the one-goal lock is free, taking it in the same step.

        The lock stays held until :meth:`_execute` of the accepted goal ends, so a second goal
        is rejected here rather than accepted and then aborted. Should an accepted goal never
        start executing (rclpy failed to create its handle), the lock is taken back after
        ``START_TIMEOUT`` seconds.
        """
        with self._goal_mutex:
            if not self._busy.acquire(blocking=False):
                stale = (not self._executing
                         and time.monotonic() - self._accepted_at > self.START_TIMEOUT)
                if not stale:
                    self.last_rejection = 'another poke is running'
                    self.get_logger().warn(f'poke goal rejected: {self.last_rejection}')
                    return GoalResponse.REJECT
                self.get_logger().error(f'the last accepted poke goal did not start within '
                                        f'{self.START_TIMEOUT:g} s; taking its lock back')
            try:
                check_goal(self._goal(goal_msg), self.limits, self.surface)
            except Exception as exc:  # noqa: BLE001 - every bad goal is rejected with a reason
                self._busy.release()
                reason = str(exc) if isinstance(exc, PointforceError) else (
                    f'{type(exc).__name__}: {exc}')
                self.last_rejection = reason
                self.get_logger().warn(f'poke goal rejected: {reason}')
                return GoalResponse.REJECT
            self._accepted_at = time.monotonic()
            self._executing = False
            return GoalResponse.ACCEPT

    def _on_cancel(self, goal_handle):
        self.get_logger().info('poke cancel requested')
        return CancelResponse.ACCEPT

    def _execute(self, goal_handle):
        self._executing = True
        try:
            return self._run_poke(goal_handle)
        except Exception as exc:  # noqa: BLE001 - every exit ends in abort() with a message
            message = f'poke failed: {type(exc).__name__}: {exc}'
            self.get_logger().error(message)
            try:
                goal_handle.abort()
            except Exception:  # noqa: BLE001 - a state already final stays as it is
                pass
            return poke_result_msg('', 0, 0.0, 0.0, 'aborted', message)
        finally:
            self._executing = False
            self._busy.release()   # taken by _on_goal when this goal was accepted

    def _goal(self, goal_msg):
        """Return the goal in base: one stamped in another frame is placed through tf."""
        return poke_goal_from_msg(goal_msg, self.frames.to_base(MODEL_FRAME, goal_msg.header))

    def _run_poke(self, goal_handle):
        try:
            goal = self._goal(goal_handle.request)
            point, normal = check_goal(goal, self.limits, self.surface)
            arm = self._connect()
        except PointforceError as exc:
            goal_handle.abort()
            return poke_result_msg('', 0, 0.0, 0.0, 'aborted', str(exc))
        standoff = np.concatenate([point + goal.standoff * normal, rotvec_aligning_z(-normal)])
        period = 1.0 / self.feedback_hz
        last = {'t': 0.0, 'first': self.samples_streamed, 'phase': Poke.Feedback.PHASE_APPROACH}

        def send_feedback():
            sample = arm.latest()
            depth = force = 0.0
            if sample is not None:
                depth = float(-(sample.pose[:3] - point) @ normal)
                force = float(sample.wrench[:3] @ normal)
            last['t'] = time.monotonic()
            goal_handle.publish_feedback(poke_feedback_msg(
                depth, force, self.samples_streamed - last['first'], last['phase']))

        def try_feedback():
            try:
                send_feedback()
            except Exception as exc:  # noqa: BLE001 - feedback never breaks the arm's sequence
                self.get_logger().warn(f'{last["phase"]} feedback not sent: {exc}',
                                       throttle_duration_sec=5.0)

        def on_phase(name):
            """Report each step as it begins (approach, tare, push, hold, retract)."""
            last['phase'] = name
            try_feedback()

        def cancel_and_feedback():
            if time.monotonic() - last['t'] >= period and arm.latest() is not None:
                try_feedback()
            return goal_handle.is_cancel_requested

        try:
            poke_id = self.store.next_id()
        except OSError as exc:     # a full disk or a read-only store: before the arm moves
            message = (f'poke store {self.store.root} cannot take a new poke '
                       f'({type(exc).__name__}: {exc}); the arm did not move')
            self.get_logger().error(message)
            goal_handle.abort()
            return poke_result_msg('', 0, 0.0, 0.0, 'aborted', message)
        fault = None
        try:
            result = arm.push_until(standoff, -normal, force_limit=goal.force_limit,
                                    travel_limit=goal.standoff + goal.depth_limit,
                                    speed=goal.speed, approach_speed=self.approach_speed,
                                    retract_speed=self.retract_speed,
                                    cancel=cancel_and_feedback,
                                    max_force=self.limits.max_force,
                                    max_travel=self.limits.max_depth + 0.05, phase=on_phase)
        except DeviceFault as exc:
            fault = exc
            result = getattr(exc, 'result', None)
        except PointforceError as exc:
            goal_handle.abort()
            return poke_result_msg('', 0, 0.0, 0.0, 'aborted', str(exc))
        saved_id, samples, peak, depth, losses = '', 0, 0.0, 0.0, []
        if result is not None and len(result) > 1:
            losses = _losses_within(arm, result.t_controller)
            meta = {'standoff': goal.standoff, 'force_limit': goal.force_limit,
                    'depth_limit': goal.depth_limit, 'surface_index': goal.surface_index,
                    'robot_ip': self.robot_ip,
                    'stream_losses': losses}
            try:
                record = PokeRecord(poke_id=poke_id, point=point, normal=normal,
                                    t=result.t_wall, t_controller=result.t_controller,
                                    tcp_pose=result.tcp_pose, wrench=result.wrench,
                                    speed=goal.speed, probe='point', outcome=result.outcome,
                                    meta=meta)
                samples = len(record)
                peak = float(np.max(record.normal_force()))
                depth = float(np.max(record.displacement()))
                stored = self._store(record)  # on disk before any result is sent
            except PointforceError as exc:    # samples a record refuses: kept raw
                samples = len(result)
                stored = self._store_raw(poke_id, result, point, normal, meta, exc)
            if stored is not None:
                if fault is not None:
                    stored = f'{getattr(fault, "kind", "device_fault")}: {fault}; {stored}'
                self.get_logger().error(f'poke aborted: {stored}')
                goal_handle.abort()
                return poke_result_msg('', samples, peak, depth, 'aborted', stored)
            self.record_pub.publish(String(data=json.dumps(record_header(record))))
            saved_id = poke_id
        if fault is not None:
            kind = getattr(fault, 'kind', 'device_fault')
            message = (f'{kind}: {fault} (the {samples} samples recorded are stored as '
                       f'{saved_id or "nothing: no sample was recorded"})')
            self.get_logger().error(f'poke aborted: {message}')
            goal_handle.abort()
            return poke_result_msg(saved_id, samples, peak, depth, 'aborted', message)
        if result.outcome == 'canceled':
            goal_handle.canceled()
            return poke_result_msg(saved_id, samples, peak, depth, 'canceled',
                                   'canceled; the arm stopped and retracted')
        self.landed_pub.publish(String(data=saved_id))
        goal_handle.succeed()
        lost = sum(loss[1] for loss in losses)
        self.get_logger().info(f'{saved_id}: {result.outcome}, peak {peak:.2f} N at '
                               f'{1e3 * depth:.1f} mm, {samples} samples'
                               + (f', {lost} stream slots empty (meta stream_losses)'
                                  if lost else ''))
        return poke_result_msg(saved_id, samples, peak, depth, result.outcome, '')

    def _store(self, record: PokeRecord):
        """Store ``record``; on failure keep its samples in a recovery file.

        Returns ``None`` when stored, else the abort message (what failed and where the
        samples are).
        """
        try:
            self.store.add(record)
            return None
        except Exception as exc:  # noqa: BLE001 - the arm moved: the samples must survive
            error = f'{type(exc).__name__}: {exc}'
            try:
                where = f'kept in {self.store.save_recovery(record, exc)}'
            except OSError as lost:
                where = f'could not be kept either ({lost})'
            return (f'{record.outcome}: the poke ran but storing {record.poke_id} failed '
                    f'({error}); its {len(record)} samples are {where}')

    def _store_raw(self, poke_id, result, point, normal, meta, error):
        """Keep the arrays of a push a PokeRecord refused; return the abort message."""
        arrays = dict(t=result.t_wall, t_controller=result.t_controller,
                      tcp_pose=result.tcp_pose, wrench=result.wrench)
        header = dict(poke_id=poke_id, point=np.asarray(point).tolist(),
                      normal=np.asarray(normal).tolist(), outcome=result.outcome, meta=meta)
        try:
            where = f'kept in {self.store.save_raw_recovery(poke_id, arrays, header, error)}'
        except OSError as lost:
            where = f'could not be kept either ({lost})'
        return (f'{result.outcome}: the poke ran but its samples are not a valid record '
                f'({type(error).__name__}: {error}); its {len(result)} samples are {where}')

    def destroy_node(self):
        """Close the arm connection and the action server with the node."""
        with self._arm_lock:
            if self._arm is not None:
                self._arm.close()
                self._arm = None
        destroy_waitables(self)
        return super().destroy_node()


def main(args=None):
    """Console entry point: ``poke_server --ros-args -p robot_ip:=192.168.1.10``."""
    run(PokeServerNode, args=args)


if __name__ == '__main__':
    main()
