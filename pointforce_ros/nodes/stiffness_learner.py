"""stiffness_learner node: refit the force-response model whenever a poke lands.

Surface: the latched ``cloud_capture/surface`` (or ``surface_file`` at start-up). Pokes: the
poke store directory the poke server writes; a refit is triggered by ``poke_server/poke_landed``
(the new poke id) and, as a fallback, by polling the store. Publishes the latched ``~/model``
(:class:`pointforce_interfaces.msg.ModelStatus`), which the contact service follows, the latched
``~/markers`` (visualization_msgs/MarkerArray for RViz/Foxglove: the surface coloured by the
learned force at ``marker_depth``, and the suggested next pokes), and serves ``~/suggest_poke``.
Cross-node names are relative (``__ns:=/cell1`` keeps a cell together). On restart it reloads the
stored pokes and produces the same model. A shape function set at run time (``shape_constant``,
``shape_decay``, ``shape_near``, ``shape_decay_law``) is persisted beside the models
(``<model_dir>/shape.json``) and wins over the start-up parameters after a restart (an effects
file's ``spatial_coupling`` still wins over both),
and so are the wrench's uncertainty sources from the same calibration (``shape_cov`` of
``(log c, 1/L)``, ``relative_std``, ``lateral_std``), which every model stores in its ``meta`` for
the contact service's standard deviations.
The published ``version`` is the one the model file was saved under (``save_model`` moves a
model to the next free version rather than reuse one).
``effects_file`` (diagnose's ``effects.json``) makes the learner remove the accepted effects from
the pokes and store them in every model, whose forward terms the contact service then applies.
"""

import dataclasses
import functools
import json
import threading
from pathlib import Path

import numpy as np

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped, WrenchStamped
from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import SuggestPoke
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from msg_adapters.geometry import sec_to_stamp, stamp_to_sec
from msg_adapters.interfaces import fail, fill_suggest_response
from msg_adapters.markers import model_markers
from msg_adapters.pointcloud2 import surface_from_msg
from pointforce_ros.contact.lcp import check_near
from pointforce_ros.contact.simulator import check_decay_law, DECAY_LAW
from pointforce_ros.contact.uncertainty import uncertainty_sources
from pointforce_ros.effects.accepted import effects_from_dict
from pointforce_ros.errors import PointforceError, read_json
from pointforce_ros.model.learner import check_region, OnlineLearner
from pointforce_ros.model.files import (load_model, load_shape, load_shape_law, load_shape_near,
                                        load_shape_uncertainty, load_surface, save_shape,
                                        version_of_path)
from pointforce_ros.nodes.common import (contained, declare, live, publish_health, qos_watch,
                                         report_folder, run)
from pointforce_ros.pokes.recorder import StreamRecorder
from pointforce_ros.response.ours import check_spread, ContactGpModel, PRODUCT_SPREAD
from pointforce_ros.pokes.store import PokeStore

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
RECORDER = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
"""The recorder's streams: volatile, so it matches the poke server's volatile publishers (a
transient-local reader never matches a volatile writer) and a bag replay's transient-local ones."""


def _decay_length(value: float) -> float:
    """Return the simulator's decay length for a ``shape_decay`` parameter (0: none, ``inf``)."""
    return float(value) if value > 0 else float('inf')


class StiffnessLearnerNode(Node):
    """Online learner: store in, versioned models and suggestions out."""

    def __init__(self, **kwargs):
        """Declare parameters, load the surface if a file is given, wire topics and services."""
        super().__init__('stiffness_learner', **kwargs)
        self.store_dir = declare(self, 'store_dir', 'out/cell/pokes',
                                 'Poke store directory (rosbag2 MCAP per poke)', read_only=True)
        self.model_dir = declare(self, 'model_dir', 'out/cell/models',
                                 'Where versioned contact models are written', read_only=True)
        for name, folder in (('store_dir', self.store_dir), ('model_dir', self.model_dir)):
            report_folder(self, name, folder)
        surface_file = declare(self, 'surface_file', '',
                               'Equilibrium surface (.npz) to start from; empty: wait for '
                               'cloud_capture/surface', read_only=True)
        self.shape_constant = declare(self, 'shape_constant', 0.004,
                                      'Shape-function constant c of g(r) = c/(c+r), m',
                                      bounds=(1e-4, 0.1))
        self.shape_decay = declare(self, 'shape_decay', 0.0,
                                   'Decay length of the shape function\'s tail, '
                                   'g(r) = c/(c+r) exp(-r/L), m; 0: none (the paper\'s g)',
                                   bounds=(0.0, 1.0))
        shape_cov = declare(self, 'shape_cov', [0.0, 0.0, 0.0, 0.0],
                            'Covariance of (log c, 1/L [1/m]) from the calibration that '
                            'identified c and L, row-major 2x2; zeros: none. With '
                            'relative_std and lateral_std stored in every model: the contact '
                            "service's wrench standard deviation")
        relative_std = declare(self, 'relative_std', 0.0,
                               'Share of the wrench the contact model does not explain (the '
                               "calibration fit's relative residual), added to its standard "
                               'deviation (over 1: the calibration explained less than the '
                               'residual it left)', bounds=(0.0, 10.0))
        lateral_std = declare(self, 'lateral_std', 0.0,
                              'Share of the normal force taken as the standard deviation of '
                              'the force across the approach (no friction in the model)',
                              bounds=(0.0, 1.0))
        try:
            self.uncertainty = self._checked_uncertainty(
                {'shape_cov': shape_cov, 'relative_std': relative_std,
                 'lateral_std': lateral_std})
        except PointforceError as exc:
            self.get_logger().error(f'uncertainty sources refused, models carry none: {exc}')
            self.uncertainty = {}
        self.near = self._choice(
            'shape_near', 'paper', check_near,
            "Near field of the shape function: 'paper', c/(c+r), or 'flat', (1 + r/c) exp(-r/c) "
            '(a skin or layer that spreads a dent flat); the one (c, L) were identified with')
        self.decay_law = self._choice(
            'shape_decay_law', DECAY_LAW, check_decay_law,
            "How the shape function's tail decay length applies: 'fixed' (one length), "
            "'penetration' (grows with each contact's penetration) or 'layer' (that, times the "
            'layer proxy the point response shows under the query); the law (c, L) were '
            'identified under')
        self._restore_shape()
        self.point_spread = check_spread(declare(
            self, 'point_spread', PRODUCT_SPREAD,
            "How the per-poke laws are spread over the surface: 'mix' (both below in equal "
            "parts: better held out than either on figure 2's wide probes and than 'gp' on "
            "every cell of figure 1; a refit about 4 s), 'gp' (Gaussian processes over "
            'position, colour and normal: smooth fields, a spread that grows away from the '
            "pokes; a refit 0.1-0.8 s) or 'trees' (Extra Trees over the same features: "
            'materials told apart by colour or height, but its spread does not grow away '
            'from the pokes)', read_only=True), 'point_spread')
        poll = declare(self, 'poll_period', 2.0, 'Seconds between poke-store polls',
                       bounds=(0.1, 600.0), read_only=True)
        self.exclude_radius = declare(self, 'suggest_exclude_radius', 0.01,
                                      'Suggestions keep this far from each other and from '
                                      'pokes, m', bounds=(0.0, 0.2))
        self.max_tilt = declare(self, 'suggest_max_tilt_deg', 35.0,
                                'Suggestions only where the normal is within this angle of '
                                'base +z, degrees', bounds=(0.0, 90.0))
        region = declare(self, 'suggest_region', [0.0, 0.0, 0.0, 0.0],
                         'Where a planner will ask for wrenches: (x, y, z, radius) rows, m, '
                         'base, flattened; suggestions then lie within radius (across base +z) '
                         'of a row, where the model is least sure; radius 0: none')
        try:
            self.region = check_region(region)
        except PointforceError as exc:
            self.get_logger().error(f'suggest_region refused, suggestions use the whole '
                                    f'surface: {exc}')
            self.region = check_region([])
        self.min_peak_force = declare(self, 'min_peak_force', 0.0,
                                      'A poke that never exceeded this force made no contact '
                                      'and is not learned from, N; 0: relative to the data '
                                      "(the larger of 5x the poke's own noise and 2 % of the "
                                      'largest peak learned), so soft regions and step data '
                                      'are learned', bounds=(0.0, 50.0), read_only=True)
        effects_file = declare(self, 'effects_file', '',
                               'Accepted effects (effects.json written by pointforce diagnose): '
                               'removed from every poke before learning and stored in each '
                               'model for the contact service; empty: none', read_only=True)
        self.effects = self._load_effects(effects_file)
        coupling = self.effects.get('spatial_coupling')
        if coupling is not None:
            # c fitted by diagnose on probe trials: the learner uses it, the parameter says so
            c = float(coupling['shape_constant'])
            result = self.set_parameters([Parameter('shape_constant', Parameter.Type.DOUBLE,
                                                    c)])[0]
            self.shape_constant = c
            self.get_logger().info(f'shape constant c = {1e3 * c:.3f} mm from {effects_file} '
                                   f'(spatial_coupling)'
                                   + ('' if result.successful else
                                      f'; the parameter refused it: {result.reason}'))
        self.marker_depth = declare(self, 'marker_depth', 0.005,
                                    'Reference depth of the ~/markers stiffness colours, m',
                                    bounds=(0.0005, 0.05))
        self.marker_suggestions = declare(self, 'marker_suggestions', 5,
                                          'Suggested next pokes drawn in ~/markers',
                                          bounds=(0, 50))
        record = declare(self, 'record_topics', False,
                         'Rebuild pokes from the poke_server/tcp_pose, wrench and poke_record '
                         'topics into store_dir (a learner away from the poke server, or a bag '
                         'replay)', read_only=True)
        self._lock = threading.Lock()
        self.learner = None
        self._last_status = None   # the newest model's status, for redrawing the markers
        self._health_skipped = 0   # pokes skipped at the last /diagnostics report
        self._health_errors = 0    # refit failures at the last report
        self.refit_errors = 0
        self.last_refit_error = ''
        publish_health(self, 'stiffness learner', self.health)
        self.recorder = StreamRecorder() if record else None
        self.model_pub = self.create_publisher(ModelStatus, '~/model', LATCHED)
        self.marker_pub = self.create_publisher(MarkerArray, '~/markers', LATCHED)
        refit_group = MutuallyExclusiveCallbackGroup()
        if surface_file:
            try:
                self._set_surface(load_surface(surface_file))
            except PointforceError as exc:
                self.get_logger().error(f'cannot load surface_file: {exc}')
        self.create_subscription(PointCloud2, 'cloud_capture/surface',
                                 contained(self, 'surface', self._on_surface),
                                 LATCHED, callback_group=refit_group,
                                 event_callbacks=qos_watch(self, 'cloud_capture/surface'))
        self.create_subscription(String, 'poke_server/poke_landed',
                                 contained(self, 'poke_landed', self._on_poke),
                                 RELIABLE, callback_group=refit_group,
                                 event_callbacks=qos_watch(self, 'poke_server/poke_landed'))
        self.create_timer(poll, contained(self, 'refit', self.refit), callback_group=refit_group)
        if self.recorder is not None:
            self._record_store = PokeStore(self.store_dir)
            stream = ReentrantCallbackGroup()
            self.create_subscription(PoseStamped, 'poke_server/tcp_pose',
                                     contained(self, 'tcp_pose', self._on_pose),
                                     RECORDER, callback_group=stream,
                                     event_callbacks=qos_watch(self, 'poke_server/tcp_pose'))
            self.create_subscription(WrenchStamped, 'poke_server/wrench',
                                     contained(self, 'wrench', self._on_wrench),
                                     RECORDER, callback_group=stream,
                                     event_callbacks=qos_watch(self, 'poke_server/wrench'))
            self.create_subscription(String, 'poke_server/poke_record',
                                     contained(self, 'poke_record', self._on_record),
                                     RELIABLE, callback_group=refit_group,
                                     event_callbacks=qos_watch(self, 'poke_server/poke_record'))
        self.create_service(SuggestPoke, '~/suggest_poke', self._on_suggest,
                            callback_group=ReentrantCallbackGroup())
        live(self, {
            'shape_constant': lambda v: lambda: self._set_shape('shape_constant', v),
            'shape_decay': lambda v: lambda: self._set_shape('shape_decay', v),
            'shape_near': self._choice_applier('shape_near', check_near, 'near'),
            'shape_decay_law': self._choice_applier('shape_decay_law', check_decay_law,
                                                    'decay_law'),
            **{name: self._uncertainty_applier(name)
               for name in ('shape_cov', 'relative_std', 'lateral_std')},
            'suggest_exclude_radius': lambda v: lambda: setattr(self, 'exclude_radius', v),
            'suggest_max_tilt_deg': lambda v: lambda: setattr(self, 'max_tilt', v),
            'suggest_region': self._region_applier,
            'marker_depth': lambda v: lambda: self._set_marker('marker_depth', v),
            'marker_suggestions': lambda v: lambda: self._set_marker('marker_suggestions', v)})

    def _choice(self, name: str, default: str, check, description: str) -> str:
        """Declare text parameter ``name``; a value ``check`` refuses is logged, ``default``."""
        value = declare(self, name, default, description)
        try:
            return check(value, name)
        except PointforceError as exc:
            self.get_logger().error(f'{exc}; using {default!r}')
            return default

    def _restore_shape(self):
        """Take the shape function last set at run time (``shape.json``) over the parameters."""
        try:
            shape = load_shape(self.model_dir)
        except PointforceError as exc:
            self.get_logger().error(f'ignoring the persisted shape function: {exc}')
            return
        if shape is None:
            return
        c, decay = shape
        try:
            law = load_shape_law(self.model_dir)
            near = load_shape_near(self.model_dir)
        except PointforceError as exc:
            self.get_logger().error(f'ignoring the persisted shape function: {exc}')
            return
        try:
            sources = load_shape_uncertainty(self.model_dir)
        except PointforceError as exc:
            self.get_logger().error(f'ignoring the persisted uncertainty sources: {exc}')
            sources = self.uncertainty
        decay_param = float(decay) if np.isfinite(decay) else 0.0
        cov = np.asarray(sources.get('shape_cov', np.zeros((2, 2))), dtype=float).ravel()
        results = self.set_parameters([
            Parameter('shape_constant', Parameter.Type.DOUBLE, c),
            Parameter('shape_decay', Parameter.Type.DOUBLE, decay_param),
            Parameter('shape_cov', Parameter.Type.DOUBLE_ARRAY, cov.tolist()),
            Parameter('relative_std', Parameter.Type.DOUBLE,
                      float(sources.get('relative_std', 0.0))),
            Parameter('lateral_std', Parameter.Type.DOUBLE,
                      float(sources.get('lateral_std', 0.0))),
            Parameter('shape_near', Parameter.Type.STRING, near),
            Parameter('shape_decay_law', Parameter.Type.STRING, law)])
        refused = [r.reason for r in results if not r.successful]
        if refused:
            self.get_logger().error(f'persisted shape function refused: {refused}')
            return
        self.shape_constant, self.shape_decay, self.uncertainty = c, decay_param, sources
        self.decay_law, self.near = law, near
        self.get_logger().info(f'shape function restored from {self.model_dir}/shape.json: '
                               f'c = {1e3 * c:.3f} mm, decay '
                               + (f'{1e3 * decay:.3f} mm ({law} law)' if np.isfinite(decay)
                                  else 'none') + f', {near} near field')

    def _set_shape(self, name: str, value: float):
        """Take a new ``shape_constant`` or ``shape_decay`` (identified from data) into use.

        rclpy has already refused values outside the declared bounds; an accepted value is
        persisted (``shape.json`` beside the models, atomically: a restart keeps it) and, once a
        model exists, saved as a new model version the contact service hot-swaps to.
        """
        setattr(self, name, float(value))
        self._persist_shape(name, value)
        learner = self.learner
        if learner is not None:
            status = learner.set_shape_constant(self.shape_constant,
                                                _decay_length(self.shape_decay),
                                                self.decay_law, self.near)
            if status is not None:
                self._publish(status, learner)

    def _choice_applier(self, name: str, check, attribute: str):
        """Return the applier factory of ``shape_near`` or ``shape_decay_law``.

        ``check`` refuses an unknown value by name; an accepted one is kept in ``attribute``
        (``near`` or ``decay_law``), persisted and, once a model exists, saved as a new model
        version (the learner's keyword is ``attribute``).
        """
        def applier(value):
            value = check(value, name)

            def apply():
                setattr(self, attribute, value)
                self._persist_shape(name, value)
                learner = self.learner
                if learner is not None:
                    status = learner.set_shape_constant(learner.shape_constant,
                                                        **{attribute: value})
                    if status is not None:
                        self._publish(status, learner)
            return apply
        return applier

    def _persist_shape(self, name: str, value) -> None:
        try:
            save_shape(self.model_dir, self.shape_constant, _decay_length(self.shape_decay),
                       self.uncertainty, decay_law=self.decay_law, near=self.near)
        except (OSError, PointforceError) as exc:
            self.get_logger().error(f'{name} = {value} is in use but NOT persisted (a restart '
                                    f'loses it): {exc}')

    @staticmethod
    def _checked_uncertainty(sources: dict) -> dict:
        """Return ``sources`` checked (:func:`uncertainty_sources`); raises InvalidInput."""
        return uncertainty_sources(**sources)

    def _uncertainty_applier(self, name: str):
        """Return the applier of ``shape_cov`` / ``relative_std`` / ``lateral_std``.

        The value is checked with the other two (a covariance that is not symmetric, or has a
        negative variance, is refused with the reason); in effect it is persisted in
        ``shape.json`` and, once a model exists, saved as a new model version.
        """
        def applier(value):
            current = {key: self.get_parameter(key).value
                       for key in ('shape_cov', 'relative_std', 'lateral_std')}
            checked = self._checked_uncertainty({**current, name: value})

            def apply():
                self.uncertainty = checked
                self._persist_shape(name, value)
                learner = self.learner
                if learner is not None:
                    status = learner.set_uncertainty(checked)
                    if status is not None:
                        self._publish(status, learner)
            return apply
        return applier

    def _set_marker(self, name: str, value):
        """Take a new marker setting into use: the latched markers are drawn again."""
        setattr(self, name, value)
        if self._last_status is not None and self.learner is not None:
            self._publish_markers(self._last_status, self.learner)

    def _load_effects(self, path: str) -> dict:
        """Read and validate ``effects_file``; on any problem log it and learn without effects."""
        if not path:
            return {}
        try:
            effects = effects_from_dict(read_json(path, 'effects file'))
        except (PointforceError, ValueError, TypeError) as exc:
            self.get_logger().error(f'effects_file {path}: {exc}; learning WITHOUT effects')
            return {}
        self.get_logger().info(f'accepted effects from {path}: {sorted(effects) or "none"}')
        return effects

    def _set_surface(self, surface):
        with self._lock:
            self.learner = OnlineLearner(self.store_dir, self.model_dir, surface,
                                         shape_constant=self.shape_constant,
                                         shape_decay=_decay_length(self.shape_decay),
                                         shape_decay_law=self.decay_law,
                                         shape_near=self.near,
                                         min_peak_force=self.min_peak_force or None,
                                         effects=self.effects,
                                         model_factory=functools.partial(
                                             ContactGpModel, spread=self.point_spread),
                                         progress=self.get_logger().info)
            self.learner.set_uncertainty(self.uncertainty)
        self.get_logger().info(f'surface of {len(surface)} points; learning from '
                               f'{self.store_dir}')
        self.refit()

    def _on_surface(self, msg: PointCloud2):
        try:
            self._set_surface(surface_from_msg(msg))
        except PointforceError as exc:
            self.get_logger().error(f'ignoring surface: {exc}')

    def _on_pose(self, msg: PoseStamped):
        p, q = msg.pose.position, msg.pose.orientation
        self.recorder.add_pose(stamp_to_sec(msg.header.stamp), (p.x, p.y, p.z),
                               (q.x, q.y, q.z, q.w))

    def _on_wrench(self, msg: WrenchStamped):
        f, m = msg.wrench.force, msg.wrench.torque
        self.recorder.add_wrench(stamp_to_sec(msg.header.stamp), (f.x, f.y, f.z),
                                 (m.x, m.y, m.z))

    def _on_record(self, msg: String):
        try:
            header = json.loads(msg.data)
            record = self.recorder.finish(header)
            if record.poke_id not in self._record_store.ids():
                self._record_store.add(record)
            self.get_logger().info(f'recorded {record.poke_id} ({len(record)} samples) from '
                                   'the topics')
        except (ValueError, PointforceError) as exc:
            self.get_logger().error(f'cannot record poke from the topics: {exc}')
            return
        self.refit()

    def _on_poke(self, msg: String):
        self.get_logger().info(f'poke {msg.data} landed')
        self.refit()

    def refit(self):
        """Fit whatever arrived; publish the new model status. Never raises into rclpy."""
        with self._lock:
            learner = self.learner
            if learner is None:
                return
            try:
                status = learner.update()
            except PointforceError as exc:
                self.refit_errors += 1
                self.last_refit_error = str(exc)
                self.get_logger().error(f'refit failed: {exc}')
                return
        if status is None:
            return
        self._publish(status, learner)

    def health(self) -> tuple:
        """Return ``(level, message, values)`` for ``/diagnostics`` since the last call.

        ERROR: an update failed since the last report (the reason); WARN: no surface yet, no
        model yet, or pokes skipped since the last report (the newest named with its reason:
        they are not in the model); else OK, naming the model and its prequential error.
        """
        learner, status = self.learner, self._last_status
        skipped = getattr(learner, 'skipped', None) or {}
        count = len(skipped)
        new, self._health_skipped = count - self._health_skipped, count
        errors, self._health_errors = self.refit_errors - self._health_errors, self.refit_errors
        values = {'model_version': -1 if status is None else status.version,
                  'pokes': 0 if status is None else status.num_pokes,
                  'pokes_skipped': count, 'refit_errors': self.refit_errors}
        if status is not None:
            values.update(training_rmse_n=round(status.training_rmse, 4),
                          prequential_rmse_n=round(status.validation_rmse, 4))
        if errors > 0:
            return (DiagnosticStatus.ERROR, f'{errors} model updates failed since the last '
                    f'report: {self.last_refit_error}', values)
        if learner is None:
            return (DiagnosticStatus.WARN, 'no surface yet: waiting for cloud_capture/surface '
                    '(or surface_file)', values)
        if status is None:
            return DiagnosticStatus.WARN, 'no model yet: no poke learned', values
        if new > 0:
            try:
                poke, why = list(skipped.items())[-1]
                newest = f' (newest {poke}: {why})'
            except (RuntimeError, IndexError):    # changed by an update meanwhile
                newest = ''
            return (DiagnosticStatus.WARN, f'{new} pokes skipped since the last report, not in '
                    f'the model{newest}', values)
        return (DiagnosticStatus.OK, f'model v{status.version} from {status.num_pokes} pokes, '
                f'prequential RMSE {status.validation_rmse:.3f} N', values)

    def _publish(self, status, learner):
        saved = version_of_path(status.model_path) if status.model_path is not None else None
        if saved is not None and saved != status.version:
            # save_model gave the model the next free version: publish the one on disk
            status = dataclasses.replace(status, version=saved)
        msg = ModelStatus(version=status.version, num_pokes=status.num_pokes,
                          training_rmse=status.training_rmse,
                          validation_rmse=status.validation_rmse,
                          model_path=str(Path(status.model_path).resolve()),
                          effects=sorted(learner.effects))
        msg.header.frame_id = 'base'
        sec_to_stamp(self.get_clock().now().nanoseconds * 1e-9, msg.header.stamp)
        self.model_pub.publish(msg)
        self.get_logger().info(
            f'model v{status.version}: {status.num_pokes} pokes, training RMSE '
            f'{status.training_rmse:.3f} N, prequential RMSE {status.validation_rmse:.3f} N, '
            f'fit {status.fit_seconds:.2f} s' +
            (f', skipped {sorted(status.skipped)}' if status.skipped else ''))
        self._publish_markers(status, learner)

    def _publish_markers(self, status, learner):
        """Publish the latched MarkerArray of the model just saved and its suggestions."""
        self._last_status = status
        try:
            model = load_model(status.model_path)
            n = len(model.surface)
            forces = model.response.force(np.arange(n), np.full(n, self.marker_depth))
            points = normals = None
            if self.marker_suggestions > 0:
                indices, _ = learner.suggest(self.marker_suggestions,
                                             exclude_radius=self.exclude_radius,
                                             max_tilt_deg=self.max_tilt)
                points = learner.surface.points[indices]
                normals = learner.surface.normals[indices]
        except PointforceError as exc:
            self.get_logger().warn(f'no markers for model v{status.version}: {exc}')
            return
        self.marker_pub.publish(model_markers(
            model.surface.points, forces, self.marker_depth, suggestions=points,
            suggestion_normals=normals, frame='base',
            stamp=self.get_clock().now().nanoseconds * 1e-9))

    def _region_applier(self, value):
        """Validate a new ``suggest_region`` (raises with the reason); return its setter."""
        rows = check_region(value)
        return lambda: setattr(self, 'region', rows)

    def _on_suggest(self, request, response):
        try:
            return self._suggest(request, response)
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            self.get_logger().error(f'suggest_poke: {type(exc).__name__}: {exc}')
            return fail(response, f'suggest_poke failed: {type(exc).__name__}: {exc}')

    def _suggest(self, request, response):
        learner = self.learner
        if learner is None:
            return fail(response, 'no equilibrium surface yet')
        try:
            indices, std = learner.suggest(request.count, exclude_radius=self.exclude_radius,
                                           max_tilt_deg=self.max_tilt,
                                           region=self.region if len(self.region) else None)
        except PointforceError as exc:
            return fail(response, str(exc))
        s = learner.surface
        fill_suggest_response(response, indices, s.points[indices], s.normals[indices], std,
                              frame=s.frame)
        sec_to_stamp(self.get_clock().now().nanoseconds * 1e-9, response.header.stamp)
        return response


def main(args=None):
    """Console entry point: ``stiffness_learner --ros-args -p store_dir:=...``."""
    run(StiffnessLearnerNode, args=args)


if __name__ == '__main__':
    main()
