"""deformation_force node: an FEM model of the scanned object and the contact force it sees.

Thin wiring of the deformation wing (:mod:`pointforce_ros.deformation`, seed 001):

- **Rest surface**: ``surface_file`` (.npz as cloud_capture stores it) at start-up, or the
  latched ``cloud_capture/surface``; the volume mesh (``element_size``, ``layers``) is built
  from it once per surface.
- **Residual reference**: the newest ``rest_frames`` clouds of ``cloud_topic`` received while
  no poke runs (the pushing camera's own rest frames, stacked), frozen when the next poke
  starts (:class:`pointforce_ros.deformation.observe.RestFrames`); a move of the camera pose
  forgets them. A depth bias moves each view's points along its own rays, so the merged
  multi-view surface does not cancel the pushing camera's bias and is only the fallback (no
  rest frame yet, or ``rest_frames`` 0); every answer says which reference it used. Measured
  with a 2 mm depth bias on the foam block fixtures (node defaults, 3 held-out sites x 3, 5,
  8 mm): mean magnitude error 16.0 % (worst 34 %) from the merged surface, 4.6 % (worst 10 %)
  from 4 rest frames (``test/nodes/test_deformation_force_node.py``).
- **Deformed clouds**: ``cloud_topic`` (PointCloud2). A cloud whose ``frame_id`` is
  ``frame_id`` (``base``) or empty is used as is; one in a frame that ``/tf`` or
  ``/tf_static`` connects to ``base`` is moved with that transform at the cloud's stamp
  (waiting up to ``tf_wait`` for one still in flight; a move of it forgets the rest frames);
  one in the camera's optical frame (``camera_frame``; empty: the first other frame a cloud
  comes in), for a cell without tf, is moved into ``base`` with the newest
  ``cloud_capture/camera_pose`` (PoseStamped, ``base`` <- optical frame), else the
  ``camera_pose`` parameter, as cloud_capture does; a cloud in any other frame is refused
  with the reason (:class:`~pointforce_ros.nodes.common.CameraFrame`).
  Invalid (NaN) pixels are dropped, as realsense-ros marks them; a cloud with no finite point
  is refused.
- **F/T**: ``poke_server/wrench`` (``tool0_controller``, the reaction on the tool) is rotated
  into ``base`` with the newest ``poke_server/tcp_pose`` and negated: the force on the object.
  A camera or TCP pose stamped in another frame than ``frame_id`` (no tf here), or a TCP
  with a non-finite position, is ignored with a warning.
- **A poke runs** while that force exceeds ``contact_force`` (it ends below half of it). Its
  contact point is the TCP position (the probe tip) at the first sample above the threshold:
  where the probe met the rest surface, for a normal or an oblique push, with no geometry in
  the node and no extra message from the poke server.
- **Observations for identification** (the simplest design a real cell can use, with no hold
  and no timing by the operator): while a poke runs, each new cloud is paired with the F/T
  force of the moment; the pair with the largest force (the deepest static state) becomes the
  poke's observation when the poke ends, if its force reached ``min_observation_force`` (an
  F/T hovering at the threshold is not a push: a demo run held 27 such 0.2 N observations at
  one spot), named ``contact-<n>`` and renamed to the poke id
  that ``poke_server/poke_landed`` announces next (within ``landed_window`` seconds).
  ``~/observe`` (Trigger) also snapshots the newest cloud, force and contact point by hand
  (``observe-<n>``), for a cell that holds the probe still.
- ``~/identify`` (IdentifyDeformation): (E, nu) from the chosen observations (each named
  once, at most ``MAX_IDENTIFY_POKES``; the newest that many when none are named); the model
  is saved atomically as the next ``deformation-v<k>.npz`` in ``model_dir`` and used at once.
  The newest model file is loaded at start-up.
- ``~/estimate_force`` (EstimateForce): the force at a contact point (``base``) that explains
  the newest cloud, camera only, with residual and covariance; with ``use_tip`` the fused
  force at that probe tip (below; refused, with the reason, without a point model, for a
  non-finite tip, or a tip off or above the scanned surface: a client that asked for the fused
  force never silently gets the FEM's).
- While a poke runs, every new cloud gives a camera estimate on ``~/force`` (WrenchStamped,
  ``base``, force on the object) and a ``~/ft_consistency`` report (DiagnosticStatus: OK when
  camera and F/T agree within ``consistency_sigma`` of their combined uncertainty, ERROR when
  not, e.g. a saturated or broken F/T; WARN when no camera estimate could be made).
- **Fused force** (issue 18, :mod:`pointforce_ros.deformation.fusion`): on a heterogeneous
  object the FEM's magnitude is 30 % off while its direction holds. The node holds the
  learner's point model (newest valid ``model-v*.npz`` of ``point_model_dir``, polled every
  ``point_model_poll`` s, and the path the learner announces on ``stiffness_learner/model``;
  a corrupt file is quarantined and logged, the last good model kept). Observations keep the
  probe tip (the TCP) of their deepest state; ``~/identify`` also stores, from the
  identification pushes only, their tips and F/T (the point model's depth offset is read
  there, per point model version) and the FEM's magnitude error at a site it was not
  identified on (``cross_validate_fem``: one more identification per site, each left out).
  With a point model, ``~/force`` publishes the fused force (tip = the current TCP): the
  point model's force at the tip's depth below its scan and the FEM's magnitude, averaged by
  inverse variance along the FEM's direction; else (or when the fusion is refused) the
  FEM's. ``~/ft_consistency`` checks the force published and reports both (``method``,
  ``fem_magnitude_n``, ``point_magnitude_n``, ``fused_magnitude_n`` and their stds).

Services never raise into rclpy: a missing model, surface or cloud, an empty or NaN cloud, a
contact point off the surface (the wing's ``InvalidInput``), and any other exception
(``MemoryError`` included) give ``success=False`` with the reason, and the node keeps serving.
"""

import re
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import replace
from pathlib import Path
from typing import Optional, Tuple

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseStamped, WrenchStamped
from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import EstimateForce, IdentifyDeformation
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger

from msg_adapters.geometry import pose_stamped_from_msg, sec_to_stamp, stamp_to_sec, vec
from msg_adapters.interfaces import fail
from msg_adapters.pointcloud2 import cloud_from_msg, surface_from_msg
from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.deformation.force import estimate_force, ForceConfig, pull_reason
from pointforce_ros.deformation.fusion import (DEFAULT_FEM_SPREAD, fuse_estimate,
                                               fused_covariance, fusion_data, point_calibration)
from pointforce_ros.deformation.identify import identify_elasticity, IdentifyConfig, Poke
from pointforce_ros.deformation.mesh import volume_mesh_from_surface
from pointforce_ros.deformation.observe import rest_offsets, RestFrames
from pointforce_ros.deformation.store import (DeformationModel, ft_consistency, load_latest,
                                              save_model)
from pointforce_ros.errors import InvalidInput, PointforceError
from pointforce_ros.frames import AwaitingTransform, TransformBuffer
from pointforce_ros.model.files import (load_latest_model, load_model, load_surface,
                                        version_of_path)
from pointforce_ros.nodes.common import (CameraFrame, declare, failure_reason, frame_to_base,
                                         live, publish_health, report_folder, run, TfListener)
from pointforce_ros.nodes.service_loop import ServiceLoop
from pointforce_ros.rotations import pose_to_matrix, quaternion_to_matrix
from pointforce_ros.types import Pose

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
STREAM = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
DEFAULT_TOPIC = '/camera/camera/depth/color/points'
OBSERVATION_BYTES = 512 << 20
"""Most bytes of clouds the held observations keep (oldest dropped first, as past
``max_observations``): a depth camera's cloud is about 10 MB, so 100 observations at the
default would have held 1 GB and the parameter's bound of 10 000 far more."""
MAX_IDENTIFY_POKES = 16
"""Most observations one ~/identify uses (none named: the newest). Its time grows with them
(0.12 s per poke on the test mesh) and the fused force's cross-validation identifies once per
site; a request naming one observation 1000 times would have run for minutes."""


def _moved(a: Pose, b: Pose) -> bool:
    """Return whether a camera moved from ``a`` to ``b``: over 1 mm, or about 0.5 degrees."""
    return bool(np.linalg.norm(b.position - a.position) > 1e-3
                or abs(float(np.dot(b.orientation, a.orientation))) < 0.99999)


def _reason(exc: Exception) -> str:
    """Return one line on why a request failed, whatever ``exc`` was."""
    return failure_reason(exc, 'the mesh or the cloud is too large for this machine (raise '
                               'element_size, lower layers)')


class DeformationForceNode(Node):
    """Identifies the object's FEM model and estimates contact forces from depth clouds."""

    def __init__(self, **kwargs):
        """Declare parameters, load the newest model and the surface, wire topics/services."""
        super().__init__('deformation_force', **kwargs)
        self.model_dir = declare(self, 'model_dir', 'out/cell/deformation',
                                 'Directory of versioned deformation-v*.npz models (newest '
                                 'loaded at start, identified ones saved there); empty: keep '
                                 'identified models in memory only', read_only=True)
        report_folder(self, 'model_dir', self.model_dir)
        surface_file = declare(self, 'surface_file', '',
                               'Rest (equilibrium) surface .npz to mesh at start-up; empty: '
                               'wait for the latched cloud_capture/surface', read_only=True)
        self.cloud_topic = declare(self, 'cloud_topic', DEFAULT_TOPIC,
                                   'PointCloud2 of the deformed object, in frame_id or in the '
                                   'camera frame (moved to base with the camera pose)',
                                   read_only=True)
        pose7 = declare(self, 'camera_pose', [0.5, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0],
                        'Camera optical frame in base when no cloud_capture/camera_pose is '
                        'published: [x y z (m), qx qy qz qw]', read_only=True)
        self.frame = declare(self, 'frame_id', 'base',
                             'Robot base frame: clouds in it are not transformed, outputs are '
                             'in it', read_only=True)
        self.tf_wait = declare(self, 'tf_wait', 0.1, 'Seconds a cloud waits for its /tf '
                               'transform (at its stamp) still in flight', bounds=(0.0, 2.0),
                               read_only=True)
        self.tf = TransformBuffer()
        self.camera_frame = CameraFrame(self.frame, declare(
            self, 'camera_frame', '', 'Optical frame of the camera the camera pose places, for '
            'a cell without tf: clouds in it are moved to base with that pose; empty: the first '
            'frame other than frame_id a cloud comes in. Clouds in a frame /tf or /tf_static '
            'connect to frame_id are moved with that transform; any other frame is refused',
            read_only=True), say=self.get_logger().info, tf=self.tf)
        self.element_size = declare(self, 'element_size', 0.004,
                                    'Volume mesh element size in x-y, m (base)',
                                    bounds=(0.001, 0.05), read_only=True)
        self.layers = declare(self, 'layers', 6, 'Volume mesh element layers through the '
                              'object height (finer towards the top)', bounds=(1, 40),
                              read_only=True)
        self.sigma = declare(self, 'consistency_sigma', 3.0,
                             'Camera and F/T disagree beyond this many standard deviations of '
                             'their combined uncertainty (Mahalanobis distance)',
                             bounds=(0.5, 100.0))
        self.ft_sigma = declare(self, 'ft_sigma', 0.1, 'F/T noise per axis, N',
                                bounds=(0.001, 10.0))
        self.contact_force = declare(self, 'contact_force', 0.2,
                                     'A poke runs while the F/T force on the object exceeds '
                                     'this (ends below half of it), N', bounds=(0.01, 100.0))
        self.min_observation_force = declare(
            self, 'min_observation_force', 0.5,
            'A poke becomes an observation only if its force reached this, N (smaller ones '
            'are the F/T hovering at contact_force, not pushes)', bounds=(0.0, 100.0))
        self.landed_window = declare(self, 'landed_window', 30.0,
                                     'A poke id on poke_server/poke_landed names the last '
                                     'observation if it ended this recently, s',
                                     bounds=(0.0, 3600.0))
        self.max_observations = declare(self, 'max_observations', 100,
                                        'Observations held (oldest dropped; their clouds '
                                        'take at most 512 MiB)', bounds=(1, 10000))
        rest_frames = declare(self, 'rest_frames', 4,
                              'Clouds received while no poke runs, stacked as the residual\'s '
                              'reference when the next poke starts (the pushing camera\'s own '
                              'rest frames); 0: the merged rest surface', bounds=(0, 50),
                              read_only=True)
        self.point_model_dir = declare(
            self, 'point_model_dir', 'out/cell/models',
            "The learner's model-v*.npz (its model_dir): the point model the fused force "
            'uses (newest valid one, polled); empty: only models announced on '
            'stiffness_learner/model', read_only=True)
        report_folder(self, 'point_model_dir', self.point_model_dir)
        poll = declare(self, 'point_model_poll', 2.0, 'Seconds between point_model_dir polls',
                       bounds=(0.1, 600.0), read_only=True)
        self.cross_validate = declare(
            self, 'cross_validate_fem', True,
            "~/identify measures the FEM's error at a site it was not identified on (the "
            "fused force's FEM spread): one more identification per site; false: the sites' "
            'modulus spread')
        # thresholds and sizes apply from the next message; paths, topic, frame, camera pose
        # and mesh settings are read-only (the mesh is built once per surface)
        live(self, {'consistency_sigma': lambda v: lambda: setattr(self, 'sigma', v),
                    'ft_sigma': lambda v: lambda: setattr(self, 'ft_sigma', v),
                    'contact_force': lambda v: lambda: setattr(self, 'contact_force', v),
                    'min_observation_force':
                        lambda v: lambda: setattr(self, 'min_observation_force', v),
                    'landed_window': lambda v: lambda: setattr(self, 'landed_window', v),
                    'max_observations':
                        lambda v: lambda: setattr(self, 'max_observations', v),
                    'cross_validate_fem': lambda v: lambda: setattr(self, 'cross_validate', v)})
        try:
            self.default_pose = Pose(position=pose7[:3], orientation=pose7[3:])
        except PointforceError as exc:
            raise InvalidInput(f'camera_pose: {exc}') from exc
        self._lock = threading.Lock()
        self._camera_pose = None
        self._tf_camera = None      # (frame, Pose in base) of the last cloud moved by tf
        self._tcp = None            # (position (3,), rotation (3, 3)) in base
        self._tcp_waiting = AwaitingTransform()   # TCP poses whose /tf has not come yet
        self._ft = None             # force on the object, base, N
        self._contact = None        # contact point of the running poke, or None
        self._candidate = None      # (|F|, Poke) deepest state of the running poke
        self._cloud = None          # (points (P, 3) base, stamp) or an error string
        self._observations = OrderedDict()
        self._last_ended = None     # (id, monotonic time) of the last automatic observation
        self._count = 0
        self._rest = None           # (mesh, rest offsets) of the rest surface
        self._rest_frames = RestFrames(rest_frames)  # the pushing camera's rest frames
        self._scan_fem = None       # its model factorised at the reference nu (for identify)
        self._model = None
        self._fem = None
        self._point = None          # the learner's point model (ContactModel), or None
        self._calibration = None    # (deformation model, point version, DepthCalibration|None,
        #                             note): the point model's depth offset for that pair
        self.clouds_received = 0
        self.estimates_published = 0
        self._health_clouds = 0     # clouds received at the last /diagnostics report
        self._load_model()
        if surface_file:
            try:
                self._set_surface(load_surface(surface_file))
            except Exception as exc:  # noqa: BLE001 - start without a surface, say why
                self.get_logger().error(f'cannot use surface_file {surface_file}: '
                                        f'{_reason(exc)}')
        publish_health(self, 'deformation model', self.health)
        work = MutuallyExclusiveCallbackGroup()
        # the arm's and camera's streams on a wait loop of their own, one thread as before:
        # the executor spent about 0.8 ms of CPU per 250 Hz message (see ServiceLoop)
        self._stream_loop = ServiceLoop(self)
        self.tf_listener = TfListener(self, self.tf, loop=self._stream_loop)
        self.force_pub = self.create_publisher(WrenchStamped, '~/force', 10)
        self.consistency_pub = self.create_publisher(DiagnosticStatus, '~/ft_consistency', 10)
        self.create_subscription(PointCloud2, 'cloud_capture/surface', self._on_surface,
                                 LATCHED, callback_group=work)
        self.create_subscription(PointCloud2, self.cloud_topic, self._on_cloud,
                                 qos_profile_sensor_data, callback_group=work)
        self._stream_loop.add_subscription(PoseStamped, 'cloud_capture/camera_pose',
                                           self._on_camera, QoSProfile(depth=10))
        self._stream_loop.add_subscription(PoseStamped, 'poke_server/tcp_pose', self._on_tcp,
                                           STREAM)
        self._stream_loop.add_subscription(WrenchStamped, 'poke_server/wrench',
                                           self._on_wrench, STREAM)
        self._stream_loop.add_subscription(String, 'poke_server/poke_landed', self._on_landed,
                                           STREAM)
        self.create_service(IdentifyDeformation, '~/identify', self._on_identify,
                            callback_group=work)
        self.create_service(EstimateForce, '~/estimate_force', self._on_estimate,
                            callback_group=work)
        self.create_service(Trigger, '~/observe', self._on_observe, callback_group=work)
        loader = MutuallyExclusiveCallbackGroup()
        self.create_subscription(ModelStatus, 'stiffness_learner/model', self._on_point_model,
                                 LATCHED, callback_group=loader)
        if self.point_model_dir:
            self._poll_point_models()
            self.create_timer(poll, self._poll_point_models, callback_group=loader)
        self._stream_loop.start()
        self.get_logger().info(f'clouds on {self.cloud_topic}; model '
                               + (f'v{self._model.version}' if self._model else 'none yet'))

    def destroy_node(self):
        """Stop the stream loop, then destroy the node."""
        self._stream_loop.stop()
        return super().destroy_node()

    @property
    def point_model(self):
        """The learner's point model the fused force uses (ContactModel), or None."""
        return self._point

    # ------------------------------------------------------------------ model and surface
    def _load_model(self):
        if not self.model_dir:
            return
        try:
            model = load_latest(self.model_dir, log=self.get_logger().error)
            if model is not None:
                self._model, self._fem = model, model.build()
                self.get_logger().info(f'loaded deformation model v{model.version}: E '
                                       f'{model.young if np.ndim(model.young) == 0 else "field"}'
                                       f' Pa, nu {model.poisson:.3f}')
        except Exception as exc:  # noqa: BLE001 - start without a model, say why
            self.get_logger().error(f'cannot load a model from {self.model_dir}: '
                                    f'{_reason(exc)}')

    def _poll_point_models(self):
        """Swap in a newer valid point model of ``point_model_dir``.

        Corrupt files are quarantined beside it and logged; the model held stays.
        """
        try:
            held = -1 if self._point is None else self._point.version
            found = load_latest_model(self.point_model_dir, newer_than=held,
                                      log=self.get_logger().error)
            if found is not None:
                self._use_point_model(*found)
        except Exception as exc:  # noqa: BLE001 - a timer callback must not end the executor
            self.get_logger().error(f'cannot load a point model from {self.point_model_dir}: '
                                    f'{_reason(exc)}', throttle_duration_sec=10.0)

    def _on_point_model(self, msg: ModelStatus):
        announced = max(msg.version, version_of_path(msg.model_path) or -1)
        if not msg.model_path or (self._point is not None
                                  and announced <= self._point.version):
            return
        try:
            self._use_point_model(load_model(msg.model_path), msg.model_path)
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            self.get_logger().error(f'point model v{msg.version} at {msg.model_path} '
                                    f'rejected, keeping the one held: {_reason(exc)}')

    def _use_point_model(self, model, path):
        if model.response.std is None:
            self.get_logger().error(f'point model {path} has no predictive std (the fusion '
                                    f'needs one): not used')
            return
        self._point = model
        self.get_logger().info(f'point model v{model.version} from {path}: the fused force '
                               f'is on')

    def _fusable(self, tip):
        """Return the point model if one is held and ``tip`` is finite; else raise."""
        point = self._point
        if point is None:
            raise InvalidInput('use_tip: no point model loaded (point_model_dir '
                               f'{self.point_model_dir or "empty"}, nor announced on '
                               'stiffness_learner/model): ask without use_tip for the FEM force')
        if tip is None or not np.all(np.isfinite(tip)):
            raise InvalidInput(f'tip: need a finite probe tip in {self.frame}, m; got '
                               f'{None if tip is None else np.asarray(tip).tolist()}')
        return point

    def _fuse(self, est, tip):
        """``FusedForce`` of the FEM estimate ``est`` at ``tip``, and a note on its inputs.

        Raises:
            InvalidInput: no point model; the tip or the point model refused.

        """
        point, model = self._fusable(tip), self._model
        fusion = model.fusion
        cached = self._calibration
        if cached is None or cached[0] is not model or cached[1] != point.version:
            calibration, note = None, 'point model uncalibrated (no identification tips)'
            if fusion is not None:
                try:
                    calibration = point_calibration(point, fusion)
                    note = (f'point model depth offset {calibration.offset * 1e3:+.2f} +- '
                            f'{calibration.std * 1e3:.2f} mm')
                except PointforceError as exc:
                    note = f'point model uncalibrated ({exc})'
            cached = self._calibration = (model, point.version, calibration, note)
        spread = fusion.fem_spread if fusion is not None else DEFAULT_FEM_SPREAD
        fused = fuse_estimate(est, tip, point, spread, calibration=cached[2])
        source = (fusion.spread_source if fusion is not None
                  else 'default: a model identified before the fused force')
        return fused, (f'{cached[3]}; FEM spread {spread:.2f} ({source}); point model '
                       f'v{point.version}')

    def _set_surface(self, surface):
        mesh = volume_mesh_from_surface(surface.points, surface.normals,
                                        element_size=self.element_size, layers=self.layers)
        offset = rest_offsets(mesh, surface.points)
        # the object's model, factorised at the reference nu while nothing waits on it: an
        # identification starts from it instead of factorising first (about 1 s of 2.5)
        scanned = CorotationalFem(mesh, 5e4, IdentifyConfig().reference_poisson)
        with self._lock:
            self._rest = (mesh, offset)
            self._scan_fem = scanned
        self.get_logger().info(f'rest surface of {len(surface)} points: mesh of '
                               f'{mesh.n_nodes} nodes, {len(mesh.tets)} tetrahedra')

    def health(self) -> tuple:
        """Return ``(level, message, values)`` for ``/diagnostics`` since the last call.

        WARN: no rest surface (nothing to mesh), the latest cloud refused (its reason), or no
        identified model (estimates are refused); else OK, naming the model's moduli.
        """
        with self._lock:
            cloud, model, rest = self._cloud, self._model, self._rest
            held = len(self._observations)
        received, before = self.clouds_received, self._health_clouds
        self._health_clouds = received
        values = {'clouds_received': received, 'clouds_since_last': received - before,
                  'observations_held': held,
                  'model_version': -1 if model is None else model.version,
                  'rest_mesh_nodes': 0 if rest is None else rest[0].n_nodes,
                  'tf_frames': len(self.tf.frames()), 'tf_refused': self.tf.refused,
                  'tcp_poses_held_for_tf': self._tcp_waiting.held_back}
        if model is not None:
            young = np.atleast_1d(np.asarray(model.young, dtype=float))
            values.update(young_pa=f'{np.median(young):.4g}', poisson=f'{model.poisson:.3f}')
        if rest is None:
            return (DiagnosticStatus.WARN, 'no rest surface yet: waiting for '
                    'cloud_capture/surface (or surface_file)', values)
        if isinstance(cloud, str):
            return DiagnosticStatus.WARN, cloud, values
        if model is None:
            return (DiagnosticStatus.WARN, 'no deformation model yet: call ~/identify after '
                    'pokes with clouds', values)
        return (DiagnosticStatus.OK, f'model v{model.version}: E {values["young_pa"]} Pa, '
                f'nu {values["poisson"]}', values)

    def _on_surface(self, msg: PointCloud2):
        try:
            self._set_surface(surface_from_msg(msg))
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            self.get_logger().error(f'ignoring rest surface: {_reason(exc)}')

    # ------------------------------------------------------------------ streams
    def _to_base(self, msg) -> Optional[np.ndarray]:
        """``None`` for a pose stamped in ``frame_id`` (or unstamped), else ``base <- frame``.

        A pose in another frame is moved through the tf tree at its stamp; one the tree cannot
        place (``map`` with no tf, a typo) raises InvalidInput: taking it as base moved every
        cloud or contact by that frame's offset.
        """
        frame = msg.header.frame_id
        if not frame or frame == self.frame:
            return None
        return frame_to_base(self.tf, self.frame, frame, stamp_to_sec(msg.header.stamp))

    def _on_camera(self, msg: PoseStamped):
        try:
            pose, m = pose_stamped_from_msg(msg), self._to_base(msg)
            if m is not None:
                pose = Pose.from_matrix(m @ pose_to_matrix(pose), frame=self.frame)
        except PointforceError as exc:
            self.get_logger().warn(f'ignoring camera pose: {exc}', throttle_duration_sec=5.0)
            return
        with self._lock:
            moved = self._camera_pose is not None and _moved(self._camera_pose, pose)
            self._camera_pose = pose
        if moved:   # the rest frames were of another viewpoint
            self._rest_frames.clear()
            self.get_logger().info('camera pose moved: rest frames forgotten')

    def _on_tcp(self, msg: PoseStamped):
        try:
            placed, refused = self._tcp_waiting.offer(stamp_to_sec(msg.header.stamp), msg,
                                                      self._tcp_in_base)
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            placed, refused = [], [(msg, failure_reason(exc, 'a smaller pose'))]
        for _, reason in refused:
            self.get_logger().warn(f'ignoring TCP pose: {reason}', throttle_duration_sec=5.0)
        if placed:
            with self._lock:
                self._tcp = placed[-1]

    def _tcp_in_base(self, msg: PoseStamped) -> Tuple[np.ndarray, np.ndarray]:
        """``(position, rotation)`` of a TCP pose in ``base``, or InvalidInput/Extrapolation."""
        q = msg.pose.orientation
        position = vec(msg.pose.position)
        if not np.all(np.isfinite(position)):
            raise InvalidInput(f'non-finite position {position.tolist()}')
        rot = quaternion_to_matrix([q.x, q.y, q.z, q.w])
        m = self._to_base(msg)
        if m is not None:
            position, rot = m[:3, :3] @ position + m[:3, 3], m[:3, :3] @ rot
        return position, rot

    def _on_wrench(self, msg: WrenchStamped):
        with self._lock:
            if self._tcp is None:
                self.get_logger().warn('F/T sample before any poke_server/tcp_pose: cannot '
                                       'rotate it into base; ignored', throttle_duration_sec=5.0)
                return
            position, rot = self._tcp
            force = -(rot @ vec(msg.wrench.force))  # reaction on the tool -> force on object
            if not np.all(np.isfinite(force)):
                return
            self._ft = force
            magnitude = float(np.linalg.norm(force))
            if self._contact is None and magnitude > self.contact_force:
                self._contact, self._candidate = position.copy(), None
                self._rest_frames.freeze()  # the clouds before this poke are its reference
            elif self._contact is not None and magnitude < 0.5 * self.contact_force:
                self._contact = None
                if (self._candidate is not None
                        and self._candidate[0] >= self.min_observation_force):
                    self._count += 1
                    name = f'contact-{self._count}'
                    self._add_observation(name, self._candidate[1])
                    self._last_ended = (name, time.monotonic())
                    self._candidate = None

    def _on_landed(self, msg: String):
        with self._lock:
            last = self._last_ended
            if (last is None or last[0] not in self._observations
                    or time.monotonic() - last[1] > self.landed_window):
                return
            self._observations = OrderedDict(
                (msg.data if k == last[0] else k, v) for k, v in self._observations.items())
            self._last_ended = None
        self.get_logger().info(f'observation {last[0]} is poke {msg.data}')

    def _add_observation(self, name: str, poke: Poke):
        """Hold one observation (caller holds the lock)."""
        self._observations[name] = poke
        held = sum(p.cloud.nbytes for p in self._observations.values())
        while len(self._observations) > 1 and (len(self._observations) > self.max_observations
                                               or held > OBSERVATION_BYTES):
            _, dropped = self._observations.popitem(last=False)
            held -= dropped.cloud.nbytes
        self.get_logger().info(f'observation {name}: |F| {np.linalg.norm(poke.force):.2f} N at '
                               f'{np.round(poke.contact_point, 4).tolist()} m, '
                               f'{len(poke.cloud)} points')

    def _cloud_in_base(self, msg: PointCloud2):
        """(P, 3) finite points in base, or raise InvalidInput (no finite point)."""
        cloud = cloud_from_msg(msg)
        raw = cloud.points.reshape(-1, 3)
        points = raw[np.all(np.isfinite(raw), axis=1)]
        if len(raw) and not len(points):
            raise InvalidInput(f'cloud: all {len(raw)} points are NaN or inf (no valid depth)')
        frame = msg.header.frame_id
        if not frame or frame == self.frame:        # in base already (unstamped: base too)
            return points
        m = self.camera_frame.to_base(frame, stamp_to_sec(msg.header.stamp), 'base',
                                      self._camera_matrix, wait=self.tf_wait)
        if self.tf.knows(frame):
            self._tf_camera_moved(frame, m)
        return points @ m[:3, :3].T + m[:3, 3]

    def _camera_matrix(self) -> np.ndarray:
        with self._lock:
            return pose_to_matrix(self._camera_pose or self.default_pose)

    def _tf_camera_moved(self, frame: str, m: np.ndarray) -> None:
        """Forget the rest frames when the tf pose of the clouds' frame moved (:func:`_moved`)."""
        pose = Pose.from_matrix(m)
        last, self._tf_camera = self._tf_camera, (frame, pose)
        if last is None or (last[0] == frame and not _moved(last[1], pose)):
            return
        self._rest_frames.clear()
        self.get_logger().info(f'camera frame {frame!r} moved (tf): rest frames forgotten')

    def _on_cloud(self, msg: PointCloud2):
        try:
            self._take_cloud(msg)
        finally:
            # counted once taken: the F/T and TCP callbacks run on other threads, so a count
            # raised on arrival let a caller end the poke before this cloud saw its contact
            self.clouds_received += 1

    def _take_cloud(self, msg: PointCloud2):
        stamp = stamp_to_sec(msg.header.stamp)
        try:
            points = self._cloud_in_base(msg)
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            with self._lock:
                self._cloud = f'latest cloud refused: {_reason(exc)}'
            self.get_logger().warn(self._cloud, throttle_duration_sec=5.0)
            return
        with self._lock:
            # the same frame delivered again (a republishing driver, a best-effort resend)
            # is not a new rest frame nor a new observation
            repeat = (isinstance(self._cloud, tuple) and stamp > 0.0
                      and self._cloud[1] == stamp and len(self._cloud[0]) == len(points))
            self._cloud = (points, stamp)
            if repeat:
                return
            contact, ft = self._contact, self._ft
            tip = None if self._tcp is None else self._tcp[0].copy()
            if contact is None:
                self._rest_frames.add(points)
            if contact is not None and len(points):
                magnitude = float(np.linalg.norm(ft))
                if self._candidate is None or magnitude >= self._candidate[0]:
                    try:
                        self._candidate = (magnitude, Poke(contact, ft, points, tip=tip))
                    except PointforceError:
                        pass
        if contact is not None and self._fem is not None:
            self._publish_estimate(contact, points, ft, stamp, tip)

    def _reference(self, mesh, fallback, fallback_name):
        """``(rest offsets (N,), what they are)`` on ``mesh``: the rest frames, else fallback."""
        offset = self._rest_frames.offsets(mesh)
        if offset is None:
            return fallback, fallback_name
        return offset, f'{self._rest_frames.frozen} rest frame(s) of this camera'

    def _publish_estimate(self, contact, points, ft, stamp, tip):
        """Publish the camera estimate on ``~/force``, its F/T check on ``~/ft_consistency``.

        The estimate is fused at ``tip`` with a point model when one is held, else the FEM's.
        """
        status = DiagnosticStatus(name=f'{self.get_name()}: camera vs F/T force',
                                  hardware_id='ft_sensor')
        try:
            model = self._model
            offset, reference = self._reference(model.mesh, model.rest_offset,
                                                "the model's stored reference")
            est = estimate_force(self._fem, contact, points,
                                 ForceConfig(load_radius=model.load_radius), rest_offset=offset)
            fem = est
            fused, method, note = None, 'fem', 'no point model'
            if self._point is not None:
                try:
                    fused, note = self._fuse(est, tip)
                    method = 'fused'
                    est = replace(est, force=fused.force, covariance=fused_covariance(est, fused))
                except Exception as exc:  # noqa: BLE001 - the FEM's force is still published
                    note = f'fusion refused, FEM force published: {_reason(exc)}'
            fem_std = fem.magnitude_std if fused is None else fused.fem_std
            out = WrenchStamped()
            out.header.frame_id = self.frame
            sec_to_stamp(stamp, out.header.stamp)
            (out.wrench.force.x, out.wrench.force.y,
             out.wrench.force.z) = (float(v) for v in est.force)
            self.force_pub.publish(out)
            self.estimates_published += 1
            check = ft_consistency(est, ft, ft_sigma=self.ft_sigma, threshold=self.sigma)
            status.level = DiagnosticStatus.OK if check.consistent else DiagnosticStatus.ERROR
            status.message = check.message
            status.values = [KeyValue(key='distance_sigma', value=f'{check.distance:.3f}'),
                             KeyValue(key='threshold_sigma', value=f'{self.sigma:g}'),
                             KeyValue(key='camera_force_n',
                                      value=str(np.round(est.force, 4).tolist())),
                             KeyValue(key='ft_force_n', value=str(np.round(ft, 4).tolist())),
                             KeyValue(key='camera_magnitude_std_n',
                                      value=f'{est.magnitude_std:.4f}'),
                             KeyValue(key='residual_rms_m', value=f'{est.residual_rms:.3g}'),
                             KeyValue(key='reference', value=reference),
                             KeyValue(key='method', value=method),
                             KeyValue(key='fusion', value=note),
                             KeyValue(key='fem_magnitude_n',
                                      value=f'{np.linalg.norm(fem.force):.4f}'),
                             KeyValue(key='fem_magnitude_std_n', value=f'{fem_std:.4f}'),
                             KeyValue(key='point_magnitude_n',
                                      value='nan' if fused is None
                                      else f'{fused.point_magnitude:.4f}'),
                             KeyValue(key='point_magnitude_std_n',
                                      value='nan' if fused is None else f'{fused.point_std:.4f}'),
                             KeyValue(key='fused_magnitude_n',
                                      value='nan' if fused is None
                                      else f'{np.linalg.norm(fused.force):.4f}'),
                             KeyValue(key='fused_magnitude_std_n',
                                      value='nan' if fused is None else f'{fused.std:.4f}')]
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            status.level = DiagnosticStatus.WARN
            status.message = f'no camera estimate for this cloud: {_reason(exc)}'
            self.get_logger().warn(status.message, throttle_duration_sec=5.0)
        self.consistency_pub.publish(status)

    # ------------------------------------------------------------------ services
    def _latest_cloud(self) -> np.ndarray:
        with self._lock:
            cloud = self._cloud
        if cloud is None:
            raise InvalidInput(f'no cloud received yet on {self.cloud_topic}')
        if isinstance(cloud, str):
            raise InvalidInput(cloud)
        return cloud[0]

    def _on_observe(self, request, response):
        try:
            points = self._latest_cloud()
            with self._lock:
                contact, ft = self._contact, self._ft
                if contact is None:
                    raise InvalidInput(f'no poke is running (F/T force on the object below '
                                       f'{self.contact_force:g} N): nothing to observe')
                tip = None if self._tcp is None else self._tcp[0].copy()
                self._count += 1
                name = f'observe-{self._count}'
                self._add_observation(name, Poke(contact, ft, points, tip=tip))
            response.success, response.message = True, name
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            fail(response, _reason(exc))
        return response

    def _on_identify(self, request, response):
        try:
            with self._lock:
                held = OrderedDict(self._observations)
            names = list(request.poke_ids)
            repeated = sorted(n for n, k in Counter(names).items() if k > 1)[:10]
            if repeated:
                raise InvalidInput(f'poke_ids: {repeated} named more than once (each '
                                   f'observation counts once)')
            if len(names) > MAX_IDENTIFY_POKES:
                raise InvalidInput(f'poke_ids: {len(names)} observations named, at most '
                                   f'{MAX_IDENTIFY_POKES} per identification')
            newest = '' if names or len(held) <= MAX_IDENTIFY_POKES else ' (the newest)'
            names = names or list(held)[-MAX_IDENTIFY_POKES:]
            missing = [n for n in names if n not in held]
            if missing:
                raise InvalidInput(f'poke_ids: no observation {missing[:10]}; held: '
                                   f'{list(held)}')
            if not names:
                raise InvalidInput('no observations held: run pokes (a cloud while the F/T '
                                   'force exceeds contact_force) or call ~/observe first')
            with self._lock:
                rest = self._rest
                # taken, not shared: the identification refactorises it in place and it then
                # serves the estimates
                scanned, self._scan_fem = self._scan_fem, None
            if rest is not None:
                mesh, offset = rest
            elif self._model is not None:
                mesh, offset = self._model.mesh, self._model.rest_offset
            else:
                raise InvalidInput('no rest surface: set surface_file or publish '
                                   'cloud_capture/surface')
            offset, reference = self._reference(mesh, offset, 'merged rest surface')
            config = IdentifyConfig()
            warm = scanned is not None and scanned.mesh is mesh
            pokes = [held[n] for n in names]
            fit, fem = identify_elasticity(mesh, pokes, config, rest_offset=offset,
                                           fem=scanned if warm else None)
            try:
                fusion, fusion_note = fusion_data(mesh, pokes, fit, config, rest_offset=offset,
                                                  cross=self.cross_validate)
                fusion_note += f' in {fusion.seconds:.2f} s'
            except Exception as exc:  # noqa: BLE001 - the identification stands without it
                fusion, fusion_note = None, f'no fusion data ({_reason(exc)})'
            model = DeformationModel(mesh=mesh, young=fit.young, poisson=fit.poisson,
                                     rest_offset=offset, load_radius=config.load_radius,
                                     residual_rms=fit.residual_rms, fusion=fusion)
            where = 'kept in memory (model_dir is empty)'
            if self.model_dir:
                path = save_model(self.model_dir, model)
                model = replace(model, version=int(re.search(r'-v(\d+)\.npz$', path).group(1)))
                where = f'saved as {Path(path).name}'
            self._model, self._fem = model, fem
            response.success = True
            response.young, response.poisson = float(fit.young), float(fit.poisson)
            response.residual_rms = float(fit.residual_rms)
            response.model_version = int(model.version)
            response.message = (f'E {fit.young:.0f} Pa, nu {fit.poisson:.3f} from {len(names)} '
                                f'observation(s){newest}, {fit.points} points, residual '
                                f'{fit.residual_rms * 1e3:.3f} mm in {fit.seconds:.2f} s'
                                + (' from the scan-time model' if warm else '')
                                + f'; reference: {reference}; nu interval '
                                f'{fit.poisson_interval[0]:.3f}-'
                                f'{fit.poisson_interval[1]:.3f}; fused force: {fusion_note}; '
                                f'{where}')
            self.get_logger().info(response.message)
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            fail(response, _reason(exc))
            self.get_logger().warn(f'identify refused: {response.message}',
                                   throttle_duration_sec=2.0)
        return response

    def _on_estimate(self, request, response):
        try:
            if self._fem is None:
                raise InvalidInput('no deformation model: call ~/identify or put a '
                                   'deformation-v*.npz in model_dir')
            if request.use_tip:
                self._fusable(vec(request.tip))   # refused before any work
            points = self._latest_cloud()
            model = self._model
            offset, reference = self._reference(model.mesh, model.rest_offset,
                                                "the model's stored reference")
            config = ForceConfig(load_radius=model.load_radius)
            est = estimate_force(self._fem, vec(request.contact_point), points, config,
                                 rest_offset=offset)
            pull = pull_reason(self._fem, vec(request.contact_point), est, config)
            if pull:
                raise InvalidInput(pull)
            fem, fused, note = est, None, ''
            if request.use_tip:
                fused, note = self._fuse(est, vec(request.tip))
                est = replace(est, force=fused.force, covariance=fused_covariance(est, fused))
            response.method = 'fem' if fused is None else 'fused'
            response.fem_magnitude = float(np.linalg.norm(fem.force))
            response.fem_magnitude_std = float(fem.magnitude_std if fused is None
                                               else fused.fem_std)
            response.point_magnitude = float('nan') if fused is None else fused.point_magnitude
            response.point_magnitude_std = float('nan') if fused is None else fused.point_std
            response.point_weight = 0.0 if fused is None else float(fused.point_weight)
            response.success = True
            response.wrench.header.frame_id = self.frame
            response.wrench.header.stamp = self.get_clock().now().to_msg()
            f = response.wrench.wrench.force
            f.x, f.y, f.z = (float(v) for v in est.force)
            response.residual_rms = float(est.residual_rms)
            response.covariance = [float(v) for v in np.asarray(est.covariance).ravel()]
            response.magnitude_std = float(est.magnitude_std if fused is None else fused.std)
            response.points = int(est.points)
            response.message = (f'{response.method}: |F| {np.linalg.norm(est.force):.3f} +- '
                                f'{response.magnitude_std:.3f} N from {est.points} points '
                                f'(model v{model.version}; reference: {reference}) in '
                                f'{est.seconds * 1e3:.0f} ms')
            if fused is not None:
                response.message += (f'; FEM {fused.fem_magnitude:.3f} +- {fused.fem_std:.3f} N, '
                                     f'point model {fused.point_magnitude:.3f} +- '
                                     f'{fused.point_std:.3f} N (weight '
                                     f'{fused.point_weight:.2f}); {note}')
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            fail(response, _reason(exc))
            self.get_logger().warn(f'estimate_force refused: {response.message}',
                                   throttle_duration_sec=2.0)
        return response


def main(args=None):
    """Console entry point: ``deformation_force --ros-args -p surface_file:=...``."""
    run(DeformationForceNode, args=args)


if __name__ == '__main__':
    main()
