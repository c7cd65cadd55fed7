"""cloud_capture node: merge depth scans into the latched equilibrium surface ``~/surface``.

Subscribes to a PointCloud2 topic (realsense-ros name by default; remap it), keeps the newest
cloud, and on ``~/add_scan`` puts it in the merge set moved into ``frame_id`` (``base``)
(:class:`~pointforce_ros.nodes.common.CameraFrame`): a cloud stamped in ``base`` as it is; one
in a frame that ``/tf`` or ``/tf_static`` connects to ``base`` with that transform at the
cloud's stamp (a real cell's camera mount; the tree is kept by
:class:`~pointforce_ros.frames.TransformBuffer`, as no tf2 wheel exists); one in the camera's
optical frame (``camera_frame``; empty: the first other frame a cloud comes in) or unstamped
with the camera pose of that moment (the ``~/camera_pose`` topic, else the ``camera_pose``
parameter, ``base`` <- optical frame), for a cell without tf; one in any other frame is
refused with the reason. ``~/capture`` builds the surface (crop,
voxel, outliers, outward normals: :mod:`pointforce_ros.surface.equilibrium`), publishes it
latched, stores it, and clears the merge set. A bad cloud is refused with a message; the node
keeps serving (every callback is a fault boundary: any exception, ``MemoryError`` included,
becomes a refusal or a log line). The merge set holds at most ``MAX_MERGE_POINTS`` raw points.
"""

import dataclasses
import threading
import time
from collections import deque
from pathlib import Path
from typing import Optional, Tuple

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PoseStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

from msg_adapters.geometry import pose_stamped_from_msg, stamp_to_sec
from msg_adapters.pointcloud2 import cloud_from_msg, surface_to_msg
from pointforce_ros.errors import InvalidInput, PointforceError
from pointforce_ros.frames import AwaitingTransform, TransformBuffer
from pointforce_ros.model.files import save_surface
from pointforce_ros.nodes.common import (CameraFrame, contained, declare, failure_reason,
                                         frame_to_base, live, publish_health, qos_watch, run,
                                         TfListener)
from pointforce_ros.nodes.service_loop import ServiceLoop
from pointforce_ros.surface.equilibrium import build_equilibrium_surface, Scan, SurfaceConfig
from pointforce_ros.rotations import pose_to_matrix
from pointforce_ros.types import Pose

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
DEFAULT_TOPIC = 'camera/camera/depth/color/points'
"""realsense-ros's topic, relative: under ``__ns:=/cell1`` a camera launched in the cell's
namespace is found (an absolute ``cloud_topic`` or a remap points elsewhere)."""
MAX_MERGE_POINTS = 20_000_000
"""Most raw points the merge set holds (about 0.5 GB as arrays, and the capture peaks near
0.5 kB per raw point: 2.7 GB for one 5-million-point scan): an ``add_scan`` beyond it is
refused, so repeated calls cannot exhaust memory."""


def _reason(exc: Exception) -> str:
    """Return one line on why a request failed, whatever ``exc`` was."""
    return failure_reason(exc, 'the clouds are too large for this machine (capture fewer '
                               'scans, a smaller roi or a larger voxel_size)')


class CloudCaptureNode(Node):
    """Builds and publishes the equilibrium surface from merged depth scans."""

    def __init__(self, **kwargs):
        """Declare parameters, subscribe to the camera, create the services."""
        super().__init__('cloud_capture', **kwargs)
        topic = declare(self, 'cloud_topic', DEFAULT_TOPIC,
                        'PointCloud2 input (realsense-ros layout: x y z float32 + packed rgb)',
                        read_only=True)
        pose7 = declare(self, 'camera_pose', [0.5, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0],
                        'Camera optical frame in base when no ~/camera_pose topic is published: '
                        '[x y z (m), qx qy qz qw]')
        roi = declare(self, 'roi', [0.35, -0.15, 0.0, 0.65, 0.15, 0.2],
                      'Region of interest in base, m: [xmin ymin zmin xmax ymax zmax]')
        voxel = declare(self, 'voxel_size', 0.002, 'Voxel edge for downsampling, m',
                        bounds=(0.0002, 0.05))
        orientation = declare(self, 'normal_orientation', 'camera',
                              'Outward-normal rule: camera | centroid | up')
        self.store_path = Path(declare(self, 'surface_file', 'out/cell/surface.npz',
                                       'Where the captured surface is stored (.npz)',
                                       read_only=True))
        self.frame = declare(self, 'frame_id', 'base', 'Frame of the published surface',
                             read_only=True)
        self.tf_wait = declare(self, 'tf_wait', 0.2, 'Seconds ~/add_scan waits for a /tf '
                               'transform at the cloud\'s stamp still in flight',
                               bounds=(0.0, 5.0), read_only=True)
        self.tf = TransformBuffer()
        self.camera_frame = CameraFrame(self.frame, declare(
            self, 'camera_frame', '', 'Optical frame of the camera the camera pose places, for '
            'a cell without tf: clouds in it (or unstamped) are moved to base with that pose, '
            'clouds in frame_id taken as they are, clouds in a frame /tf or /tf_static connect '
            'to frame_id moved with that transform; empty: the first other frame a cloud comes '
            'in. Any other frame is refused', read_only=True), say=self.get_logger().info,
            tf=self.tf)
        try:
            self.config = SurfaceConfig(roi_min=roi[:3], roi_max=roi[3:], voxel_size=voxel,
                                        orientation=orientation)
            self.default_pose = Pose(position=pose7[:3], orientation=pose7[3:])
        except PointforceError as exc:
            raise InvalidInput(f'roi / camera_pose: {exc}') from exc
        self._lock = threading.Lock()
        self._latest = None
        self._camera_pose = None
        self._pose_history = deque(maxlen=50)
        self._pose_waiting = AwaitingTransform()   # camera poses whose /tf has not come yet
        self._scans = []
        self.max_merge_points = MAX_MERGE_POINTS
        self.surface = None
        self.surface_pub = self.create_publisher(PointCloud2, '~/surface', LATCHED)
        self.create_subscription(PointCloud2, topic, contained(self, 'cloud', self._on_cloud),
                                 qos_profile_sensor_data,
                                 event_callbacks=qos_watch(self, topic))
        self.create_subscription(PoseStamped, '~/camera_pose',
                                 contained(self, 'camera_pose', self._on_pose), 10,
                                 event_callbacks=qos_watch(self, '~/camera_pose'))
        # /tf runs at the arm's rate on a real cell (500 Hz from a UR driver): taken on a wait
        # loop of its own, off the executor (for the 250 Hz F/T stream `pointforce bench
        # streams` measured 256 against 461-493 us of CPU per message)
        self._tf_loop = ServiceLoop(self)
        self.tf_listener = TfListener(self, self.tf, loop=self._tf_loop)
        group = MutuallyExclusiveCallbackGroup()
        self.create_service(Trigger, '~/add_scan', self._on_add, callback_group=group)
        self.create_service(Trigger, '~/capture', self._on_capture, callback_group=group)
        self.create_service(Trigger, '~/clear', self._on_clear, callback_group=group)
        self._refusal = ''      # why the last add_scan / capture was refused
        publish_health(self, 'surface capture', self.health)
        live(self, {'roi': self._new_roi, 'voxel_size': self._new_voxel,
                    'normal_orientation': self._new_orientation,
                    'camera_pose': self._new_camera_pose})
        self._tf_loop.start()
        self.get_logger().info(f'listening for clouds on {self.resolve_topic_name(topic)}')

    def destroy_node(self):
        """Stop the tf loop, then destroy the node."""
        self._tf_loop.stop()
        return super().destroy_node()

    # run-time parameters: validated here, in effect from the next add_scan / capture
    def _new_roi(self, roi):
        if len(roi) != 6:
            raise ValueError(f'6 values [xmin ymin zmin xmax ymax zmax] needed, got {len(roi)}')
        config = dataclasses.replace(self.config, roi_min=roi[:3], roi_max=roi[3:])
        return lambda: setattr(self, 'config', config)

    def _new_voxel(self, voxel):
        config = dataclasses.replace(self.config, voxel_size=voxel)
        return lambda: setattr(self, 'config', config)

    def _new_orientation(self, orientation):
        config = dataclasses.replace(self.config, orientation=orientation)
        return lambda: setattr(self, 'config', config)

    def health(self) -> tuple:
        """Return ``(level, message, values)`` for ``/diagnostics``.

        WARN: no cloud received yet on the camera topic, or no surface captured yet (the
        learner and the poke server wait for it), naming the last refusal if there was one;
        else OK, naming the surface's size.
        """
        with self._lock:
            latest = self._latest
        surface = self.surface
        values = {'scans_in_merge_set': len(self._scans),
                  'surface_points': 0 if surface is None else len(surface),
                  'camera_frame': self.camera_frame.camera or '',
                  'tf_frames': len(self.tf.frames()),
                  'tf_refused': self.tf.refused,
                  'poses_held_for_tf': self._pose_waiting.held_back,
                  'last_refusal': self._refusal}
        why = f' (last refusal: {self._refusal})' if self._refusal else ''
        if latest is None and surface is None:
            return (DiagnosticStatus.WARN, 'no cloud received yet on the camera topic' + why,
                    values)
        if surface is None:
            return (DiagnosticStatus.WARN, f'no surface captured yet ({len(self._scans)} scans '
                    'in the merge set: ~/add_scan, then ~/capture)' + why, values)
        return (DiagnosticStatus.OK, f'surface of {len(surface)} points published', values)

    def _new_camera_pose(self, pose7):
        if len(pose7) != 7:
            raise ValueError(f'7 values [x y z qx qy qz qw] needed, got {len(pose7)}')
        pose = Pose(position=pose7[:3], orientation=pose7[3:])
        return lambda: setattr(self, 'default_pose', pose)

    def _on_cloud(self, msg: PointCloud2):
        stamp = stamp_to_sec(msg.header.stamp)
        with self._lock:
            # the pose of the same instant if one was published (like a tf lookup at the
            # cloud's stamp), else the newest pose, else the camera_pose parameter
            self._latest = (msg, self._pose_at(stamp) or self._camera_pose)

    def _pose_at(self, stamp: float) -> Optional[Pose]:
        """Return the camera pose published for ``stamp`` (within 1 ms) or None; hold the lock."""
        return next((p for t, p in reversed(self._pose_history) if abs(t - stamp) < 1e-3),
                    None)

    def _on_pose(self, msg: PoseStamped):
        try:
            stamp = stamp_to_sec(msg.header.stamp)
            placed, refused = self._pose_waiting.offer(stamp, msg, self._pose_in_base)
        except Exception as exc:  # noqa: BLE001 - a callback must not end the executor
            placed, refused = [], [(msg, failure_reason(exc, 'a smaller pose'))]
        for _, reason in refused:
            self.get_logger().warn(f'ignoring camera pose: {reason}', throttle_duration_sec=5.0)
        with self._lock:
            for stamp, pose in placed:
                self._camera_pose = pose
                self._pose_history.append((stamp, pose))

    def _pose_in_base(self, msg: PoseStamped) -> Tuple[float, Pose]:
        """``(stamp, pose in base)``: through the tf tree, or refused (was taken as base)."""
        pose, stamp = pose_stamped_from_msg(msg), stamp_to_sec(msg.header.stamp)
        if pose.frame != self.frame:
            m = frame_to_base(self.tf, self.frame, pose.frame, stamp)
            pose = Pose.from_matrix(m @ pose_to_matrix(pose), frame=self.frame)
        return stamp, pose

    def _scan_from_latest(self) -> Scan:
        with self._lock:
            latest = self._latest
            if latest is not None:      # a pose of the cloud's instant placed since it came
                same = self._pose_at(stamp_to_sec(latest[0].header.stamp))  # (it waited)
        if latest is None:
            raise PointforceError('no cloud received yet on the camera topic')
        msg, pose = latest[0], same or latest[1] or self.default_pose
        transform = self.camera_frame.to_base(msg.header.frame_id, stamp_to_sec(msg.header.stamp),
                                              'camera', lambda: pose_to_matrix(pose),
                                              wait=self.tf_wait)
        cloud = cloud_from_msg(msg, drop_nan=True)
        if len(cloud.points) == 0:
            raise PointforceError('the latest cloud has no valid (finite) point')
        return Scan(points=cloud.points, colors=cloud.rgb, transform=transform)

    def _on_add(self, request, response):
        try:
            scan = self._scan_from_latest()
            held = sum(len(s.points) for s in self._scans)
            if held + len(scan.points) > self.max_merge_points:
                raise InvalidInput(f'add_scan: the merge set holds {held} points and this scan '
                                   f'{len(scan.points)}, over the {self.max_merge_points} '
                                   'allowed; call ~/capture or ~/clear first')
            self._scans.append(scan)
            response.success = True
            response.message = f'{len(self._scans)} scan(s) in the merge set'
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            response.success, response.message = False, _reason(exc)
            self._refusal = response.message
            self.get_logger().warn(f'add_scan refused: {response.message}',
                                   throttle_duration_sec=2.0)
        return response

    def _on_clear(self, request, response):
        self._scans.clear()
        response.success, response.message = True, 'merge set cleared'
        return response

    def _on_capture(self, request, response):
        try:
            scans = list(self._scans) or [self._scan_from_latest()]
            start = time.perf_counter()
            surface, report = build_equilibrium_surface(scans, self.config)
            self.surface = surface
            self.surface_pub.publish(surface_to_msg(surface,
                                                    stamp=self.get_clock().now().nanoseconds
                                                    * 1e-9))
            save_surface(surface, self.store_path)
            self._scans.clear()
            response.success = True
            response.message = (f'surface of {len(surface)} points from {len(scans)} scan(s) '
                                f'({report.n_input} raw, {report.n_outliers} outliers removed) '
                                f'in {time.perf_counter() - start:.2f} s -> {self.store_path}')
            self.get_logger().info(response.message)
        except Exception as exc:  # noqa: BLE001 - a service never raises into rclpy
            response.success, response.message = False, _reason(exc)
            self._refusal = response.message
            self.get_logger().warn(f'capture refused: {response.message}')
        return response


def main(args=None):
    """Console entry point: ``cloud_capture --ros-args -p cloud_topic:=/my/points``."""
    run(CloudCaptureNode, args=args)


if __name__ == '__main__':
    main()
