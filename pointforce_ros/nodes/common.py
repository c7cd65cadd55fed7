"""Shared node plumbing: the Jazzy ``main()`` pattern, parameters, a clean stop.

Parameters are described and bounded; a stop lets the callbacks in flight finish
(:func:`drain`).
"""

import logging
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Dict, Optional, Sequence

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import stamp_to_sec, vec
from pointforce_ros.dds import use_package_dds_profile
from pointforce_ros.errors import InvalidInput, PointforceError
from pointforce_ros.frames import Extrapolation, TransformBuffer, TransformUnavailable


def declare(node: Node, name: str, default, description: str, *,
            bounds: Optional[Sequence[float]] = None, read_only: bool = False):
    """Declare a parameter with a description (unit, frame) and optional ``(lo, hi)`` bounds.

    Returns the parameter's value after overrides.
    """
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if isinstance(default, bool):
        descriptor.type = ParameterType.PARAMETER_BOOL
    elif isinstance(default, int):
        descriptor.type = ParameterType.PARAMETER_INTEGER
        if bounds is not None:
            descriptor.integer_range = [IntegerRange(from_value=int(bounds[0]),
                                                     to_value=int(bounds[1]), step=1)]
    elif isinstance(default, float):
        descriptor.type = ParameterType.PARAMETER_DOUBLE
        if bounds is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
    elif isinstance(default, str):
        descriptor.type = ParameterType.PARAMETER_STRING
    return node.declare_parameter(name, default, descriptor).value


Applier = Callable[[object], Optional[Callable[[], None]]]
"""``applier(value)`` validates a new value (raising :class:`PointforceError` or ``ValueError``
with the reason) and returns the action that makes it take effect (or ``None``)."""


def live(node: Node, appliers: Dict[str, Applier]) -> None:
    """Make the parameters in ``appliers`` take effect when set at run time.

    rclpy has already checked the declared type and bounds. Every applier of a set runs first;
    if one refuses, the whole set is refused with its reason and nothing changes; else every
    action runs and each change is logged (``name: old -> new``). Any other exception (an
    applier's ``TypeError``, an action's ``MemoryError``) refuses the set with its reason;
    actions that ran before it stay in effect. Call it after the last
    ``declare``; declare every other parameter ``read_only`` so that no set is accepted and
    ignored.
    """
    def on_set(params):
        # a fault boundary like every callback: rclpy runs this inside the set_parameters
        # service, where an exception would leave through the executor and stop the node
        try:
            return _apply(params)
        except Exception as exc:  # noqa: BLE001 - MemoryError too; the node keeps serving
            names = ', '.join(p.name for p in params)
            reason = ('not enough memory' if isinstance(exc, MemoryError)
                      else f'{type(exc).__name__}: {exc}')
            node.get_logger().error(f'parameters {names}: could not apply ({reason})')
            return SetParametersResult(successful=False, reason=f'{names}: {reason}')

    def _apply(params):
        actions = []
        for param in params:
            applier = appliers.get(param.name)
            if applier is None:
                continue
            try:
                actions.append((param, applier(param.value)))
            except (PointforceError, ValueError) as exc:
                node.get_logger().warn(f'parameter {param.name} = {param.value!r} refused: '
                                       f'{exc}')
                return SetParametersResult(successful=False, reason=f'{param.name}: {exc}')
        for param, action in actions:
            old = node.get_parameter(param.name).value
            if action is not None:
                action()
            node.get_logger().info(f'parameter {param.name}: {_show(old)} -> '
                                   f'{_show(param.value)} (in effect)')
        return SetParametersResult(successful=True)
    node.add_on_set_parameters_callback(on_set)


def _show(value):
    return list(value) if not isinstance(value, (str, bool, int, float)) else value


def failure_reason(exc: Exception, memory_hint: str) -> str:
    """Return one line on why a request failed, whatever ``exc`` was (a service's answer).

    ``memory_hint`` says what to make smaller when it was a ``MemoryError``.
    """
    if isinstance(exc, PointforceError):
        return str(exc)
    if isinstance(exc, MemoryError):
        return f'out of memory: {memory_hint}'
    return f'the node could not answer ({type(exc).__name__}: {exc}); it keeps serving'


def contained(node: Node, what: str, callback: Callable) -> Callable:
    """Wrap a topic or timer callback so that no exception (``MemoryError`` too) reaches rclpy.

    An exception is logged (throttled to one line per 5 s per callback) and the callback returns
    ``None``; the node keeps serving. Services fill their response with the reason instead.
    """
    def wrapper(*args):
        try:
            return callback(*args)
        except Exception as exc:  # noqa: BLE001 - a callback never raises into the executor
            node.get_logger().error(f'{what}: {type(exc).__name__}: {exc}',
                                    throttle_duration_sec=5.0)
            return None
    wrapper.__name__ = getattr(callback, '__name__', what)
    return wrapper


def qos_watch(node: Node, topic: str) -> SubscriptionEventCallbacks:
    """Event callbacks for a subscription to ``topic``: an incompatible-QoS match is logged.

    The event is also appended to ``node.incompatible_qos`` (a list the node creates), so a test
    or a supervisor can tell that a publisher was discovered but never delivers.
    """
    if not hasattr(node, 'incompatible_qos'):
        node.incompatible_qos = []

    def on_incompatible(event):
        node.incompatible_qos.append((topic, event))
        node.get_logger().error(f'{topic}: a publisher offers an incompatible QoS '
                                f'(policy {event.last_policy_kind}); its data never arrives')
    return SubscriptionEventCallbacks(incompatible_qos=on_incompatible)


DRAIN_TIMEOUT = 10.0
"""Longest wait (s) for an executor's callbacks in flight when it stops (:func:`drain`): a
poke in flight at Ctrl-C finishes (bounded by its force and depth limits, it ends retracted)
before the arm connection closes, if it can within this."""


def drain(executor: Executor, name: str, timeout: float) -> bool:
    """Wait until the callbacks ``executor`` started have finished; True if they did in time.

    Call it after the executor stopped spinning and before ``Executor.shutdown``
    (:func:`stop_executor` does both in that order). rclpy Jazzy's
    ``shutdown`` marks itself shut down before it tests that mark, so it never waits for the
    work in flight, and it destroys the executor's guard condition at once, while a
    ``MultiThreadedExecutor`` keeps running the callbacks it handed to its thread pool. A
    handler that started after that failed signalling the destroyed guard condition
    (``InvalidHandle``: "cannot use Destroyable because destruction was requested", the message
    it had taken dropped), and a node destroyed next was met by its own running callback
    (printed at exit as "The following exception was never retrieved" in about half the demo
    runs). This waits on the executor's own bookkeeping (the pool's handler tasks and its work
    tracker, private attributes read defensively: an rclpy that fixes ``shutdown`` needs none
    of it), then logs what a finished callback raised instead of leaving it to the garbage
    collector.
    """
    tasks = list(getattr(executor, '_futures', ()))
    tracker = getattr(executor, '_work_tracker', None)
    deadline = time.monotonic() + timeout
    while not all(t.done() or t.cancelled() for t in tasks) \
            or (tracker is not None and not tracker.wait(0.0)):
        if time.monotonic() > deadline:
            logging.getLogger(__name__).error(
                '%s: callbacks still running %.0f s after shutdown; destroying the nodes anyway',
                name, timeout)
            return False
        time.sleep(0.005)
    for task in tasks:
        error = task.exception() if task.done() else None
        if error is not None:
            logging.getLogger(__name__).warning('%s: a callback raised %s at shutdown: %s',
                                                name, type(error).__name__, error)
    return True


def destroy_node(node: Node) -> None:
    """Destroy ``node`` with its action servers and clients, so its participant goes at once.

    ``Node.destroy_node`` destroys publishers, services and timers but not waitables: an action
    server's or client's handle keeps the node, and so the context's DDS participant, alive
    until garbage collection. Such ghosts stay on every other participant's graph; a test
    process gathered dozens, and then a new launcher could not discover its own poke server in
    30 s. Destroying a node twice is harmless.
    """
    destroy_waitables(node)
    node.destroy_node()


def destroy_waitables(node: Node) -> None:
    """Destroy the action servers and clients (any waitable with ``destroy``) of ``node``."""
    for waitable in list(node.waitables):
        destroy = getattr(waitable, 'destroy', None)
        if callable(destroy):
            destroy()


def stop_executor(executor: Executor, name: str,
                  thread: Optional[threading.Thread] = None) -> bool:
    """Stop ``executor`` in the order its work needs; True if its callbacks finished in time.

    ``Executor.shutdown`` does two things at once: it ends ``spin()`` and it destroys the
    executor's guard condition, which a callback queued on the pool signals when it starts and
    ends. This does the first half alone (the shut-down mark ``spin()`` tests, set under the
    executor's lock as ``shutdown`` sets it, and a wake), waits for ``thread`` (the one
    spinning, if any) to return, lets the callbacks in flight finish (:func:`drain`), and only
    then calls ``shutdown``. (A loop of ``spin_once`` with a timeout also ends on a flag, but
    it changes the executor's wait path, a timer per wait: ``pointforce bench ros --quick``
    lost replies in two of its three runs with it, one of six with this, none of six before.)
    """
    lock = getattr(executor, '_shutdown_lock', None)
    if lock is not None and hasattr(executor, '_is_shutdown'):
        with lock:
            executor._is_shutdown = True
        executor.wake()
    else:                        # an rclpy without these: its public shutdown
        executor.shutdown(timeout_sec=0.0)
    if thread is not None:
        thread.join(timeout=DRAIN_TIMEOUT)
    finished = drain(executor, name, DRAIN_TIMEOUT)
    executor.shutdown(timeout_sec=0.0)
    return finished


def report_folder(node: Node, name: str, path: str, polled: bool = False) -> None:
    """Log once, at start, a folder parameter that cannot work.

    A file where the folder should be is an error (nothing can be read from or written to it
    until the parameter is fixed); with ``polled`` (a folder the node only reads, filled by
    another node) one that does not exist yet is a warning, and so is a folder the node may
    not look into (it still starts). An empty ``path`` is not checked.
    """
    if not path:
        return
    where = Path(path)
    logger = node.get_logger()
    try:
        exists, folder = where.exists(), where.is_dir()
    except OSError as exc:
        logger.warning(f'{name} {where} cannot be checked: {exc}')
        return
    if exists and not folder:
        logger.error(f'{name} {where} is a file, not a folder: nothing is read or written there')
    elif polled and not exists:
        logger.warning(f'{name} {where} does not exist yet: polling it')


def init_or_exit(args=None) -> None:
    """Initialise rclpy with ``args``, or end the process with rcl's reason and status 2.

    A command line rcl refuses (a params file it cannot parse, a malformed ``--ros-args``)
    ends in one line, not a traceback.

    Raises:
        SystemExit: rcl did not initialise.

    """
    use_package_dds_profile()   # before the first rclpy.init of the process
    try:
        rclpy.init(args=args)
    except Exception as exc:  # noqa: BLE001 - rclpy raises its pybind RCLError here
        cannot_start(exc)


def cannot_start(reason) -> None:
    """End a node's process before it serves: ``<program>: cannot start: reason``, status 2.

    For what the user must fix first (a command line rcl refuses, a node's configuration it
    refuses, such as a poke store that is a file): one line, no traceback.

    Raises:
        SystemExit: always.

    """
    name = Path(sys.argv[0]).name or 'node'
    print(f'{name}: cannot start: {str(reason).strip()}', file=sys.stderr)
    raise SystemExit(2) from None


def build_node(node_factory: Callable[[], Node]) -> Node:
    """Return ``node_factory()``; a configuration the node refuses ends the process.

    What is refused while the node is built, before it serves, goes through
    :func:`cannot_start`: a :class:`~pointforce_ros.errors.PointforceError` (a poke store that
    is a file, a camera pose that is no pose), a parameter rclpy refuses (out of its declared
    range, of another type) and a topic or service name that is not valid.
    """
    try:
        return node_factory()
    except (PointforceError, ParameterException, NameValidationException) as exc:
        cannot_start(exc)


def run(node_factory: Callable[[], Node], args=None, threads: int = 4) -> None:
    """Spin one node the Jazzy way (ros2/demos): init, spin, shutdown on Ctrl-C or external."""
    init_or_exit(args)
    node = executor = None
    try:
        node = build_node(node_factory)
        executor = MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if executor is not None:     # callbacks in flight finish before the node goes
            stop_executor(executor, node.get_name())
        if node is not None:
            destroy_node(node)
        rclpy.try_shutdown()


TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
"""QoS of ``/tf`` (tf2_ros's listener: reliable, volatile, 100 deep)."""

TF_STATIC_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
"""QoS of ``/tf_static`` (transient local: a node started later still gets the mounts)."""

TF_REQUEST_WAIT = 0.1
"""Default seconds a request or goal stamped newer than ``/tf`` has reached waits for it
(``tf_wait`` of the contact service and the poke server, with ``tf_dynamic``)."""


class TfListener:
    """Feed a :class:`~pointforce_ros.frames.TransformBuffer` from ``/tf`` and ``/tf_static``.

    tf2_ros's ``TransformListener`` does this on a real install; no wheel carries it. Each
    ``geometry_msgs/TransformStamped`` of a ``tf2_msgs/TFMessage`` goes into the buffer; one it
    refuses (NaN, a quaternion that is not unit, a loop) is counted, its reason kept in
    :attr:`last_refusal` and logged (throttled), and the others of the message still go in.
    The two subscriptions have a callback group of their own, so a callback that waits for a
    transform (:meth:`TransformBuffer.wait_transform`) does not hold them up on a
    multi-threaded executor; or, with ``loop`` (a node's
    :class:`~pointforce_ros.nodes.service_loop.ServiceLoop`, not started yet), they are taken
    on that loop's thread, off the executor (a real cell's ``/tf`` runs at the arm's rate:
    500 Hz from a UR driver).
    """

    def __init__(self, node: Node, buffer: TransformBuffer, tf_topic: str = '/tf',
                 static_topic: str = '/tf_static', loop=None):
        """Subscribe ``node`` to the two topics (absolute by default, as tf2_ros does).

        An empty name subscribes to none.
        """
        self.node, self.buffer = node, buffer
        self.received = 0
        """Transforms taken since the start."""
        self.last_refusal = ''
        group = MutuallyExclusiveCallbackGroup()
        for topic, static, qos in ((tf_topic, False, TF_QOS),
                                   (static_topic, True, TF_STATIC_QOS)):
            if not topic:
                continue
            callback = contained(node, topic, lambda m, s=static: self._on(m, s))
            if loop is None:
                node.create_subscription(TFMessage, topic, callback, qos, callback_group=group)
            else:
                loop.add_subscription(TFMessage, topic, callback, qos)

    def _on(self, msg: TFMessage, static: bool) -> None:
        for t in msg.transforms:
            q = t.transform.rotation
            try:
                self.buffer.set_transform(t.header.frame_id, t.child_frame_id,
                                          stamp_to_sec(t.header.stamp),
                                          vec(t.transform.translation), [q.x, q.y, q.z, q.w],
                                          static=static)
                self.received += 1
            except InvalidInput as exc:
                self.last_refusal = str(exc)
                self.node.get_logger().warn(f'ignoring a transform on '
                                            f'{"/tf_static" if static else "/tf"}: {exc}',
                                            throttle_duration_sec=5.0)


def frame_to_base(tf: Optional[TransformBuffer], base: str, frame: str,
                  stamp: float) -> np.ndarray:
    """Return the (4, 4) transform ``base <- frame`` for a message stamped ``stamp`` (s).

    ``frame`` empty or ``base``: the identity; any other: the tf tree's at ``stamp`` (0: the
    latest), without waiting (for pose streams).

    Raises:
        InvalidInput: no tree, or the tree cannot give it (the reason).

    """
    frame = str(frame or '')
    if not frame or frame == base:
        return np.eye(4)
    if tf is None:
        raise InvalidInput(f'frame {frame!r} is not {base!r}, and there is no tf tree')
    return tf.lookup(base, frame, float(stamp) or None)


class RequestFrames:
    """Where a node's requests (contact queries, poke goals) stamped in other frames are placed.

    Declares ``tf_dynamic`` and ``tf_wait``, keeps the node's tf tree (:attr:`buffer`) fed by
    a :class:`TfListener`: ``/tf_static``, and ``/tf`` too with ``tf_dynamic`` (it costs the
    executor CPU at ``/tf``'s rate, 500 Hz from a UR driver).
    """

    def __init__(self, node: Node, what: str):
        """Declare the two parameters of ``node``; ``what``: the requests, for their help."""
        self.dynamic = declare(node, 'tf_dynamic', False,
                               'Also listen on /tf (transforms that move), not only '
                               f'/tf_static, for {what} stamped in a frame other than base: '
                               'costs CPU at the rate /tf is published (500 Hz from a UR '
                               'driver)', read_only=True)
        self.wait = declare(node, 'tf_wait', TF_REQUEST_WAIT,
                            f'With tf_dynamic: seconds {what} stamped newer than /tf has '
                            'reached yet wait for their transform', bounds=(0.0, 2.0),
                            read_only=True)
        self.buffer = TransformBuffer()
        self.listener = TfListener(node, self.buffer, tf_topic='/tf' if self.dynamic else '')

    def to_base(self, base: str, header) -> Optional[np.ndarray]:
        """``None`` for a request stamped in ``base`` (or unstamped), else ``base <- frame_id``.

        A request in another frame is placed through the tf tree at its stamp (0: the latest).
        With ``tf_dynamic``, a stamp newer than ``/tf`` has reached yet (a planner stamps its
        query with ``now``) is waited for up to ``tf_wait``, as tf2's ``lookup_transform``
        with a timeout would; so is a frame not heard of yet, once: until a transform names
        it, later requests in it are refused at once (a client asking again and again in a
        frame nobody publishes would hold a service thread ``tf_wait`` each time).

        Raises:
            InvalidInput: the tree cannot place the frame (the reason, about the request).

        """
        frame = header.frame_id
        if frame in ('', base):
            return None
        waits = self.dynamic and self.wait > 0.0
        started = time.monotonic()
        try:
            stamp = stamp_to_sec(header.stamp)
            if waits:
                return self.buffer.wait_transform(base, frame, stamp or None, self.wait)
            return frame_to_base(self.buffer, base, frame, stamp)
        except InvalidInput as exc:
            # said only where it did wait (a time too old, frames not connected or a frame
            # waited for in vain before are refused at once)
            waited = f' (waited {self.wait:g} s)' if (
                waits and time.monotonic() - started >= 0.5 * self.wait) else ''
            raise InvalidInput(f'header.frame_id {frame!r}: {exc}{waited}; publish its '
                               f'transform to {base!r} on /tf_static'
                               + ('' if self.dynamic else ' (or set tf_dynamic for /tf)')
                               + f', or send the request in {base!r}') from None


class CameraFrame:
    """How a node moves a cloud from its ``frame_id`` into the base frame.

    In this order:

    - a cloud stamped in the robot base frame ``base`` is used as it is;
    - a cloud in a frame the tf tree (``/tf``, ``/tf_static``; :attr:`tf`) connects to ``base``
      is moved with the transform at the cloud's stamp, as a real cell publishes its camera
      mounts; a stamp the tree does not hold refuses the cloud, and so does a frame the tree
      holds beside ``base`` without connecting the two (unless it is the pinned camera frame);
      a tree without ``base`` (a camera driver's own optical mounts alone) is not used;
    - a cloud in the camera's optical frame is moved with the camera pose (the nodes'
      ``camera_pose`` topic or parameter, for a cell without tf). ``pinned`` names that frame
      (the ``camera_frame`` parameter); empty, the first frame other than ``base`` a cloud
      arrives in is taken as the camera's, once, and said so (:attr:`adopted`);
    - a cloud in any other frame is refused: moving it with this camera's pose would place it
      wrong by that frame's offset, silently.
    """

    def __init__(self, base: str, pinned: str = '', say: Callable[[str], None] = None,
                 tf: Optional[TransformBuffer] = None):
        """Keep the base frame, the pinned camera frame ('' = the first one seen) and ``say``.

        ``say(line)`` is told once which frame was taken as the camera's (a node's logger).
        ``tf``: the tree of ``/tf`` and ``/tf_static`` (:class:`TfListener` fills it), or
        ``None`` for none.
        """
        self.base = str(base)
        self.pinned = str(pinned or '')
        self.say = say
        self.tf = tf
        self._lock = threading.Lock()
        self.adopted = None
        """The frame taken as the camera's when none was pinned (``None`` until one came)."""

    @property
    def camera(self) -> Optional[str]:
        """The camera's optical frame: pinned, or adopted, or ``None`` before either."""
        return self.pinned or self.adopted

    def classify(self, frame: str, empty: str) -> str:
        """Return ``'base'`` or ``'camera'`` for a cloud stamped ``frame``.

        ``empty``: what an unstamped cloud (``frame`` ``''``) is, ``'base'`` or ``'camera'``.

        Raises:
            InvalidInput: ``frame`` is neither the base frame nor the camera's.

        """
        frame = str(frame or '')
        if not frame:
            return empty
        if frame == self.base:
            return 'base'
        with self._lock:
            adopt = not self.pinned and self.adopted is None
            if adopt:
                self.adopted = frame
            camera = self.pinned or self.adopted
        if adopt and self.say is not None:
            self.say(f'taking frame {frame!r} as the camera\'s optical frame (the first cloud '
                     f'not in {self.base!r}); clouds in any other frame are refused: set '
                     'camera_frame to name it')
        if frame == camera:
            return 'camera'
        known = self.tf.frames() if self.tf is not None else []
        raise InvalidInput(f'cloud in frame {frame!r}: neither the base frame {self.base!r} nor '
                           f'the camera frame {camera!r}' + ('' if self.pinned else
                                                             ' (the first one a cloud came in)')
                           + (f', and not in the tf tree ({len(known)} frames heard on /tf '
                              'and /tf_static)' if self.tf is not None else '')
                           + ': publish its transform on /tf or /tf_static, set camera_frame, '
                           'or publish the cloud in the base frame')

    def to_base(self, frame: str, stamp: float, empty: str,
                camera: Callable[[], np.ndarray], wait: float = 0.0) -> np.ndarray:
        """Return the (4, 4) transform ``base <- frame`` for a cloud stamped ``stamp`` (s).

        ``empty`` as in :meth:`classify`; ``camera()`` gives the camera pose's matrix; ``wait``:
        seconds to wait for a transform of the tf tree still in flight (a stamp of 0 takes
        the latest).

        Raises:
            InvalidInput: the frame cannot be moved into base, with the reason.

        """
        frame = str(frame or '')
        tf = self.tf
        if (frame and frame != self.base and tf is not None and tf.knows(frame)
                and tf.knows(self.base)):
            try:
                return tf.wait_transform(self.base, frame, float(stamp) or None, wait)
            except Extrapolation:
                raise       # connected, not at this stamp
            except TransformUnavailable:
                if frame != self.pinned:
                    raise   # the tree holds both and does not connect them
        # the camera pose: the tree has no base (a camera driver's own optical mounts alone),
        # or the pinned camera frame is not connected to it
        return np.eye(4) if self.classify(frame, empty) == 'base' else camera()


DIAGNOSTICS_PERIOD = 1.0
"""Seconds between a node's ``/diagnostics`` reports (the diagnostic_updater convention)."""


def publish_health(node: Node, task: str, report: Callable[[], tuple],
                   hardware: Callable[[], str] = lambda: '') -> None:
    """Publish ``report()`` on ``/diagnostics`` every :data:`DIAGNOSTICS_PERIOD` seconds.

    ``report() -> (level, message, values)``: a ``DiagnosticStatus`` level (``OK``, ``WARN``,
    ``ERROR``), one line, and a mapping of key -> value (stringified). Each report is a
    ``DiagnosticArray`` holding one status named ``'<node name>: <task>'`` with
    ``hardware()`` as its id, what rqt_robot_monitor and diagnostic_aggregator read. The timer
    is a fault boundary: a report that raises is published as an ERROR saying so.
    """
    publisher = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
    name = f'{node.get_name()}: {task}'

    def tick():
        try:
            level, message, values = report()
        except Exception as exc:  # noqa: BLE001 - a timer must not end the executor
            level, message, values = (DiagnosticStatus.ERROR,
                                      f'health unknown: {type(exc).__name__}: {exc}', {})
        try:
            msg = DiagnosticArray(status=[DiagnosticStatus(
                level=level, name=name, message=str(message), hardware_id=str(hardware()),
                values=[KeyValue(key=str(k), value=str(v)) for k, v in values.items()])])
            msg.header.stamp = node.get_clock().now().to_msg()
            publisher.publish(msg)
        except Exception as exc:  # noqa: BLE001 - a timer must not end the executor
            node.get_logger().warn(f'/diagnostics not published: {type(exc).__name__}: {exc}',
                                   throttle_duration_sec=10.0)
    node.create_timer(DIAGNOSTICS_PERIOD, tick, callback_group=MutuallyExclusiveCallbackGroup())
