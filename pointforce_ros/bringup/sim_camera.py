"""sim_camera node: the simulated cell's depth camera, publishing like realsense-ros.

Renders the object's visible surface (with the scenario's depth bias and noise, occlusion and
NaN holes) as an organised PointCloud2 in ``camera_depth_optical_frame`` on
``camera/camera/depth/color/points``, and the camera's pose in ``base`` twice, stamped as the
cloud and published before it: on ``tf`` (``base`` <- optical frame, as a real cell's
robot_state_publisher and hand-eye mount give it; the nodes listen on ``/tf``) and on
``cloud_capture/camera_pose`` (for a cell without tf). All three names are relative, so a
namespaced cell keeps its camera: there the nodes hear no ``/tf`` of it (remap ``/tf:=tf`` to
have them) and place its clouds by the camera pose. ``~/next_view`` (std_srvs/Trigger) moves
it to the next viewpoint of its ring, as a wrist camera would be moved between scans.
"""

import threading

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from msg_adapters.geometry import pose_stamped_to_msg, transform_to_msg
from msg_adapters.pointcloud2 import msg_from_cloud
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints
from pointforce_ros.nodes.cloud_capture import DEFAULT_TOPIC
from pointforce_ros.nodes.common import declare, TF_QOS
from pointforce_ros.types import Pose


class SimCameraNode(Node):
    """Publishes rendered depth clouds of a mesh from a ring of viewpoints."""

    def __init__(self, mesh, rgb, target, camera_kwargs=None, **kwargs):
        """Render ``mesh`` (base frame) with per-vertex ``rgb``; cameras look at ``target``."""
        super().__init__('sim_camera', **kwargs)
        rate = declare(self, 'rate', 2.0, 'Frames per second', bounds=(0.1, 30.0))
        distance = declare(self, 'distance', 0.35, 'Camera distance to the object, m',
                           bounds=(0.12, 2.0))
        views = declare(self, 'views', 2, 'Viewpoints on the ring', bounds=(1, 12))
        self.mesh, self.rgb = mesh, rgb
        self.camera = DepthCamera(**(camera_kwargs or {}))
        self.poses = ring_viewpoints(target, distance, count=views)
        self.view = 0
        self.vertices = None  # displaced vertices to render a deformed surface
        self._lock = threading.Lock()
        self.cloud_pub = self.create_publisher(PointCloud2, DEFAULT_TOPIC,
                                               qos_profile_sensor_data)
        self.pose_pub = self.create_publisher(PoseStamped, 'cloud_capture/camera_pose', 10)
        self.tf_pub = self.create_publisher(TFMessage, 'tf', TF_QOS)
        self.create_service(Trigger, '~/next_view', self._on_next)
        self.create_timer(1.0 / rate, self.publish_frame)

    def publish_frame(self):
        """Render and publish one frame and the camera pose it was taken from."""
        with self._lock:
            pose = self.poses[self.view]
            vertices = self.vertices
        stamp = self.get_clock().now().nanoseconds * 1e-9
        frame = self.camera.render(self.mesh, pose, rgb=self.rgb, vertices=vertices,
                                   organised=True, stamp=stamp)
        self.tf_pub.publish(TFMessage(transforms=[transform_to_msg(pose, 'base', frame.frame,
                                                                   stamp)]))
        self.pose_pub.publish(pose_stamped_to_msg(Pose.from_matrix(pose), stamp=stamp))
        self.cloud_pub.publish(msg_from_cloud(frame.points, frame.rgb, frame_id=frame.frame,
                                              stamp=stamp))

    def _on_next(self, request, response):
        with self._lock:
            self.view = (self.view + 1) % len(self.poses)
            view = self.view
        self.publish_frame()
        response.success, response.message = True, f'view {view} of {len(self.poses)}'
        return response
