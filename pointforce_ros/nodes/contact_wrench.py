"""contact_wrench node: ``~/contact_wrench`` and ``~/contact_wrench_batch`` for planners.

Answers from the latest contact model: a file in ``model_dir`` (polled) or the path announced on
the learner's latched model topic. A new model is swapped in without dropping requests. Malformed
requests get ``success=False`` and a message; the node keeps serving: each callback contains
every exception (``MemoryError`` and unforeseen errors included) and answers with a reason, and
requests beyond the limits (``max_sample_poses``, ``max_request_memory``, ``max_distance``,
``max_depth``, ``max_torque_arm``) are refused before any work, and a batch past its time
budget (``max_request_seconds``) between chunks of poses. With ``uncertainty`` on, every
answer carries the standard deviation of each wrench component (``wrench_std``; a request sets
``skip_uncertainty`` to save its four extra solves); a spread that cannot be computed leaves the
wrench answered and says why in ``message``, as does an answer that presses deeper than any
poke reached (``WrenchServer.depth_note``: the force there is extrapolated). Accepted effects
stored in
the model add their forward terms (:mod:`pointforce_ros.effects.forward`): series compliance
(``series_compliance``), a viscoelastic hold fraction (``hold_time``) and a surface offset.

Run-time parameters (issue 21): every parameter but ``model_dir`` (read-only) takes effect
when set: checked, logged (old -> new) and used from the next request (``sample_spacing``
rebuilds the simulator of the model in use). ``~/last_query`` (latched MarkerArray) shows the
last answered single query's contact points and wrench arrow; a timer at ``marker_rate``
publishes it only when a new query was answered, off the service path. ``~/service_timing``
(DiagnosticStatus, every :data:`TIMING_PERIOD` s after new answers) says where each service's
answers spent their time over its latest :data:`~pointforce_ros.nodes.service_loop.
TIMING_WINDOW`: taking the request, the callback, sending the response (p50 and p99, ms).
After each answer the service thread polls for ``hot_wait`` ms before it sleeps: on a VM a
vCPU that went idle answers the next request up to twice as slowly (:data:`HOT_WAIT_MS`).
"""

import dataclasses
import time
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
import numpy as np

from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from msg_adapters.contact_markers import contact_markers
from msg_adapters.interfaces import (batch_arrays_from_request, contact_query_from_request,
                                     fail, fill_batch_response, fill_contact_response,
                                     fill_wrench_std, MODEL_FRAME)
from pointforce_ros.contact.simulator import check_neighbours, NEIGHBOURS
from pointforce_ros.errors import PointforceError
from pointforce_ros.model.files import version_of_path
from pointforce_ros.nodes.common import (build_node, declare, init_or_exit, live,
                                         publish_health, report_folder, RequestFrames)
from pointforce_ros.nodes.service_loop import ServiceLoop
from pointforce_ros.model.serving import RequestLimits, WrenchServer
from pointforce_ros.response.blas import limit_blas_for_process

REQUESTS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
"""Service requests and replies: at the default depth of 10 one reply writer for 8 busy
clients lost replies (2 of 4000 calls never answered in the load test of bench ros)."""

LIMIT_PARAMETERS = {'max_sample_poses': 'max_sample_poses', 'max_request_memory': 'max_memory',
                    'max_distance': 'max_distance', 'max_depth': 'max_depth',
                    'max_torque_arm': 'max_torque_arm', 'max_request_seconds': 'max_seconds'}
"""Parameter name -> :class:`RequestLimits` field (``max_request_memory`` in MiB)."""

HOT_WAIT_MS = 2.0
"""Default ``hot_wait``: polling after each answer, ms. Quiet-machine ``bench ros`` runs, single
query back to back (four runs): p50 1.03-1.29 ms and ROS overhead 0.58-0.93 ms against
1.31-1.65 / 1.00-1.35 ms without it, and 0.70 against 0.99 ms of service CPU per call under
load (the vCPU stays awake)."""

TIMING_PERIOD = 5.0
"""Seconds between ``~/service_timing`` reports (only after new answers)."""

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)


class ContactWrenchNode(Node):
    """Serves contact-wrench queries from the learned model."""

    def __init__(self, **kwargs):
        """Declare parameters, load the newest model if any, create the services."""
        super().__init__('contact_wrench', **kwargs)
        self.model_dir = declare(
            self, 'model_dir', '', 'Directory of model-v*.npz files to serve from (polled); '
            'empty: only models announced on the model topic (read-only)', read_only=True)
        report_folder(self, 'model_dir', self.model_dir, polled=True)
        self.max_batch = declare(self, 'max_batch', 20000,
                                 'Largest number of poses in one batch request',
                                 bounds=(1, 1000000))
        spacing = declare(self, 'sample_spacing', 0.003,
                          'Rigid-mesh surface sampling distance, m (seed paper: 3 mm)',
                          bounds=(0.0005, 0.05))
        neighbours = declare(
            self, 'neighbour_weights', NEIGHBOURS,
            "How a rigid sample averages its 3 nearest surface points: 'equal' (the seed "
            "paper) or 'smooth' (weights that vanish where a point leaves the three: an answer "
            'without most of its sideways steps, for finite differences; on the demo 0.1-0.25 '
            '% of the largest force less accurate)')
        check_neighbours(neighbours, 'neighbour_weights')
        poll = declare(self, 'poll_period', 1.0, 'Seconds between model_dir polls',
                       bounds=(0.05, 60.0))
        series = declare(self, 'series_compliance', True,
                         'Apply an accepted series compliance of the model (the table or the '
                         'arm gives way by compliance x normal force); false when it was only '
                         "the poking arm's and the planner drives another robot")
        hold_time = declare(self, 'hold_time', 0.0,
                            'For a viscoelastic model: seconds the pose is held after a fast '
                            'approach (0: instantaneous force, the upper bound), s',
                            bounds=(0.0, 1e6))
        limits = RequestLimits(
            max_sample_poses=declare(
                self, 'max_sample_poses', 100_000_000,
                'Largest rigid-mesh samples x poses of one request (the work it asks for)',
                bounds=(1000, 10_000_000_000)),
            max_memory=int(2 ** 20 * declare(
                self, 'max_request_memory', 256.0,
                'Largest working-memory estimate of one request, MiB (batches are cut into '
                'chunks that fit; a mesh whose single pose does not fit is refused)',
                bounds=(16.0, 65536.0))),
            max_distance=declare(
                self, 'max_distance', 10.0,
                'Largest distance of a pose or the torque centre from the surface bounding '
                'box, and of a mesh vertex from its origin, m (base)', bounds=(0.1, 1000.0)),
            max_depth=declare(
                self, 'max_depth', 0.1,
                'Largest depth of a mesh vertex past the deepest surface point along the '
                'approach, m (base)', bounds=(0.001, 10.0)),
            max_torque_arm=declare(
                self, 'max_torque_arm', 5.0,
                'Largest distance from the torque centre to a pose, m (base)',
                bounds=(0.01, 1000.0)),
            max_seconds=declare(
                self, 'max_request_seconds', 30.0,
                'Time budget of one batch request, s (checked between chunks of poses)',
                bounds=(0.01, 3600.0)))
        lanes = declare(self, 'client_lanes', 0,
                        'Extra single-query services ~/lane_<k>/contact_wrench, k < client_lanes, '
                        'one per busy planner: every client of a service receives and discards '
                        "the replies to all the others' calls (ros2/rclpy's rmw behaviour, "
                        'ros2/rclcpp#2397), which costs each Python client about 0.4 ms of CPU '
                        'per foreign reply (read-only)', bounds=(0, 64), read_only=True)
        self.uncertainty = declare(self, 'uncertainty', True,
                                   'Answer each wrench with its standard deviation '
                                   '(wrench_std: four more solves; a request can skip it)')
        self.marker_scale = declare(self, 'marker_force_scale', 0.01,
                                    'Length of the wrench arrow on ~/last_query per newton, m/N',
                                    bounds=(1e-5, 1.0))
        marker_rate = declare(self, 'marker_rate', 2.0,
                              'Hz at which ~/last_query is refreshed (only after a new answer)',
                              bounds=(0.1, 50.0))
        hot_wait = declare(self, 'hot_wait', HOT_WAIT_MS,
                           'Milliseconds the service thread keeps polling after each answer '
                           'before it sleeps (0: sleep at once). On a VM an idle vCPU answers '
                           'its next request up to 2x slower; a planner that sends bursts of '
                           'queries gets them faster for this much CPU per burst, ms',
                           bounds=(0.0, 100.0))
        self.frames = RequestFrames(self, 'requests')
        self.tf = self.frames.buffer
        self.server = WrenchServer(spacing=spacing, series_compliance=series,
                                   hold_time=hold_time, limits=limits, neighbours=neighbours)
        self.requests_served = 0
        self.requests_failed = 0
        self.markers_published = 0
        self._last = None       # (result, version) of the last answered single query
        self._shown = None
        self._try_load_dir()
        # answered on a wait loop of their own: the executor's per-request cost (about 1 ms of
        # CPU here) was as large as the query's solve
        self._service_loop = ServiceLoop(self)
        self._service_loop.set_hot_wait(hot_wait)
        self._service_loop.add(ContactWrench, '~/contact_wrench', self._on_single, REQUESTS)
        self._service_loop.add(ContactWrenchBatch, '~/contact_wrench_batch', self._on_batch,
                               REQUESTS)
        for lane in range(lanes):
            self._service_loop.add(ContactWrench, f'~/lane_{lane}/contact_wrench',
                                   self._on_single, REQUESTS)
        loader = MutuallyExclusiveCallbackGroup()
        self.create_subscription(ModelStatus, 'stiffness_learner/model', self._on_model, LATCHED,
                                 callback_group=loader)
        self._loader = loader
        self._poll = (self.create_timer(poll, self._try_load_dir, callback_group=loader)
                      if self.model_dir else None)
        self.marker_pub = self.create_publisher(MarkerArray, '~/last_query', LATCHED)
        self._marker_timer = self.create_timer(1.0 / marker_rate, self._publish_markers,
                                               callback_group=loader)
        self.timing_pub = self.create_publisher(DiagnosticStatus, '~/service_timing', 10)
        self._timed = -1
        self.create_timer(TIMING_PERIOD, self._publish_timing, callback_group=loader)
        live(self, {'max_batch': lambda v: lambda: setattr(self, 'max_batch', v),
                    'uncertainty': lambda v: lambda: setattr(self, 'uncertainty', v),
                    'sample_spacing': lambda v: self._configure(spacing=v),
                    'neighbour_weights': lambda v: self._configure(
                        neighbours=check_neighbours(v, 'neighbour_weights')),
                    'series_compliance': lambda v: self._configure(series_compliance=v),
                    'hold_time': lambda v: self._configure(hold_time=v),
                    **{name: self._limit(name) for name in LIMIT_PARAMETERS},
                    'poll_period': self._new_poll_period,
                    'marker_rate': lambda v: lambda: self._set_marker_rate(v),
                    'marker_force_scale': lambda v: lambda: setattr(self, 'marker_scale', v),
                    'hot_wait': lambda v: lambda: self._service_loop.set_hot_wait(v)})
        self._health = (0, 0, 0)     # answered, refused, callback faults at the last report
        publish_health(self, 'contact service', self.health)
        self._service_loop.start()
        self.get_logger().info(f'serving contact wrenches (model version {self.server.version})')

    def health(self) -> tuple:
        """Return ``(level, message, values)`` for ``/diagnostics`` since the last call.

        ERROR: no model loaded (every request is refused); WARN: a request callback failed
        past its own checks (``ServiceLoop.faults``) since the last report; else OK, naming the
        model version and the requests answered and refused since then (a refused request is
        the client's: its answer says why).
        """
        served, failed, faults = (self.requests_served, self.requests_failed,
                                  self._service_loop.faults)
        before = self._health
        self._health = (served, failed, faults)
        version = self.server.version
        values = {'model_version': version, 'model_dir': self.model_dir or '',
                  'answered': served, 'refused': failed, 'callback_faults': faults,
                  'answered_since_last': served - before[0],
                  'refused_since_last': failed - before[1],
                  'refused_unwaited_frame': self.tf.not_waited}
        if version < 0:
            return (DiagnosticStatus.ERROR, 'no contact model loaded: every request is refused '
                    '(waiting for model_dir or stiffness_learner/model)', values)
        if faults > before[2]:
            return (DiagnosticStatus.WARN, f'{faults - before[2]} request callback faults since '
                    'the last report (see the log)', values)
        return (DiagnosticStatus.OK, f'serving model v{version}: {served - before[0]} answered, '
                f'{failed - before[1]} refused since the last report', values)

    def destroy_node(self):
        """Stop the service loop (its services first), then destroy the node."""
        self._service_loop.stop()
        return super().destroy_node()

    def _configure(self, **settings):
        """Applier: the server takes ``settings`` from the next request (checked here)."""
        return lambda: self.server.configure(**settings)

    def _limit(self, name):
        """Return the applier of the request limit parameter ``name`` (checked when set)."""
        def applier(value):
            value = int(2 ** 20 * value) if name == 'max_request_memory' else value
            limits = dataclasses.replace(self.server.limits, **{LIMIT_PARAMETERS[name]: value})
            return lambda: self.server.configure(limits=limits)
        return applier

    def _new_poll_period(self, value):
        if self._poll is None:
            raise ValueError('no model_dir is polled (model_dir is empty and read-only)')

        def apply():   # a new timer: a changed period alone waits out the old one first
            self.destroy_timer(self._poll)
            self._poll = self.create_timer(value, self._try_load_dir,
                                           callback_group=self._loader)
        return apply

    def _set_marker_rate(self, hz: float):
        self.destroy_timer(self._marker_timer)
        self._marker_timer = self.create_timer(1.0 / hz, self._publish_markers,
                                               callback_group=self._loader)

    def _publish_markers(self):
        """Timer: publish ~/last_query when a new single query was answered (off the hot path)."""
        last = self._last
        if last is None or last is self._shown:
            return
        try:
            result, version = last
            self.marker_pub.publish(contact_markers(
                result, version, self.get_clock().now().nanoseconds * 1e-9,
                force_scale=self.marker_scale))
            self.markers_published += 1
        except Exception as exc:  # noqa: BLE001 - a timer callback must not end the executor
            self.get_logger().error(f'~/last_query not published: {type(exc).__name__}: {exc}',
                                    throttle_duration_sec=10.0)
        self._shown = last

    def _publish_timing(self):
        """Timer: publish ~/service_timing when requests were answered since the last one."""
        try:
            taken = self._service_loop.requests_taken
            if taken == self._timed:
                return
            self._timed = taken
            keys = [KeyValue(key='requests_taken', value=str(taken)),
                    KeyValue(key='faults', value=str(self._service_loop.faults))]
            for name, row in sorted(self._service_loop.timing().items()):
                keys += [KeyValue(key=f'{name} {key}', value=f'{value:.4f}')
                         for key, value in row.items()]
            self.timing_pub.publish(DiagnosticStatus(
                level=DiagnosticStatus.OK, name=f'{self.get_fully_qualified_name()}: service '
                'timing', message='take / callback / send per service, ms', values=keys))
        except Exception as exc:  # noqa: BLE001 - a timer callback must not end the executor
            self.get_logger().error(f'~/service_timing not published: {type(exc).__name__}: '
                                    f'{exc}', throttle_duration_sec=10.0)

    def _try_load_dir(self):
        if not self.model_dir:
            return
        try:
            if self.server.load_latest(self.model_dir, log=self.get_logger().error):
                self.get_logger().info(f'loaded model v{self.server.version} from '
                                       f'{self.server.loaded_path}{self._terms()}')
        except PointforceError as exc:
            self.get_logger().error(f'cannot load model from {self.model_dir}: {exc}',
                                    throttle_duration_sec=10.0)
        except Exception as exc:  # noqa: BLE001 - a timer callback must not end the executor
            self.get_logger().error(f'cannot load model from {self.model_dir}: '
                                    f'{type(exc).__name__}: {exc}', throttle_duration_sec=10.0)

    def _on_model(self, msg: ModelStatus):
        # the file's name carries the version it was saved under: a save bumps a version that
        # was taken by other content, past the one the learner announces
        announced = max(msg.version, version_of_path(msg.model_path) or -1)
        if not msg.model_path or announced <= self.server.version:
            return
        try:
            self.server.load(Path(msg.model_path))
            self.get_logger().info(f'hot-swapped to model v{self.server.version}{self._terms()}')
        except PointforceError as exc:
            self.get_logger().error(f'model v{msg.version} at {msg.model_path} rejected: {exc}')
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            self.get_logger().error(f'model v{msg.version} at {msg.model_path} rejected: '
                                    f'{type(exc).__name__}: {exc}')

    def _terms(self) -> str:
        terms = self.server.forward_terms
        if terms is None or not (terms.applied or terms.skipped):
            return ''
        return (f'; effects applied: {list(terms.applied)}'
                + (f', not applied: {dict(terms.skipped)}' if terms.skipped else ''))

    def _on_single(self, request, response):
        start = time.perf_counter()
        deadline = time.monotonic() + self.server.limits.max_seconds   # answer and spread
        try:
            m = self.frames.to_base(MODEL_FRAME, request.header)
            rotation = None if m is None else m[:3, :3].T      # the request's frame <- base
            query = contact_query_from_request(request, m)
            result, version = self.server.answer(query)
            fill_contact_response(response, result, version, query.return_displacements,
                                  rotation)
            response.message = self.server.depth_note(result)
            if self.uncertainty and not request.skip_uncertainty:
                pose = query.poses[0]
                self._add_uncertainty(response, query.mesh,
                                      np.concatenate([pose.position, pose.orientation])[None],
                                      query.approach, query.torque_centre, version, deadline,
                                      rotation)
            self.requests_served += 1
            self._last = (result, version)      # one reference store; the timer draws it
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            self._refuse(response, 'contact_wrench', exc)
        self.get_logger().debug(f'contact_wrench in {1e3 * (time.perf_counter() - start):.2f} ms')
        return response

    def _on_batch(self, request, response):
        deadline = time.monotonic() + self.server.limits.max_seconds   # answer and spread
        try:
            if len(request.poses) > self.max_batch:
                self.requests_failed += 1
                return fail(response, f'poses: {len(request.poses)} exceeds max_batch '
                                      f'{self.max_batch}')
            m = self.frames.to_base(MODEL_FRAME, request.header)
            rotation = None if m is None else m[:3, :3].T
            query = batch_arrays_from_request(request, m)
            batch, version = self.server.answer_rows(*query)
            fill_batch_response(response, batch, version, rotation)
            response.message = self.server.depth_note(batch)
            if self.uncertainty and not request.skip_uncertainty:
                self._add_uncertainty(response, *query, version, deadline, rotation)
            self.requests_served += 1
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            self._refuse(response, 'contact_wrench_batch', exc)
        return response

    def _add_uncertainty(self, response, mesh, rows, approach, torque_centre, version,
                         deadline, rotation=None):
        """Fill the answer's standard deviations; a failure keeps the answer, says why.

        ``deadline`` (``time.monotonic()``) is the request's: the answer and its spread share
        one ``max_request_seconds``. ``rotation``: the request's frame <- base, or None.
        """
        try:
            fill_wrench_std(response, self.server.uncertainty(mesh, rows, approach,
                                                              torque_centre, version,
                                                              deadline), rotation)
        except Exception as exc:  # noqa: BLE001 - the wrench stands without its spread
            reason = str(exc) if isinstance(exc, PointforceError) else (
                'not enough memory' if isinstance(exc, MemoryError)
                else f'{type(exc).__name__}: {exc}')
            response.message = '; '.join(filter(None, [
                response.message, f'no wrench standard deviation: {reason}']))

    def _refuse(self, response, service: str, exc: Exception):
        """Answer ``success=False`` with a reason about the request, whatever ``exc`` was."""
        self.requests_failed += 1
        if isinstance(exc, PointforceError):
            message = str(exc)
        elif isinstance(exc, MemoryError):
            message = ('the request needs more memory than the service has; send fewer poses '
                       'or a smaller mesh (limits: max_sample_poses, max_request_memory)')
        else:
            message = (f'the service could not answer this request ({type(exc).__name__}: '
                       f'{exc}); it keeps serving others')
        fail(response, message)
        if isinstance(exc, PointforceError):
            self.get_logger().warn(f'{service} refused: {message}', throttle_duration_sec=2.0)
        else:
            self.get_logger().error(f'{service} failed on a request: {type(exc).__name__}: '
                                    f'{exc!r}', throttle_duration_sec=2.0)


def spin_single_threaded(node_factory, args=None) -> None:
    """Spin one node on a SingleThreadedExecutor, the Jazzy way (ros2/demos).

    The contact node's executor runs its parameters, timers and model topic; its services are
    answered on the node's own :class:`ServiceLoop` (rclpy's MultiThreadedExecutor, which hands
    every callback to a thread pool, cost 1.8 ms more per round trip here when it answered
    them). A batch's chunks run on the server's worker threads; while one batch is solved,
    single queries wait for it.
    """
    init_or_exit(args)
    node = None
    try:
        node = build_node(node_factory)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()


def main(args=None):
    """Console entry point: ``contact_wrench --ros-args -p model_dir:=...``."""
    limit_blas_for_process()   # small solves one after another: BLAS threads only cost
    spin_single_threaded(ContactWrenchNode, args=args)


if __name__ == '__main__':
    main()
