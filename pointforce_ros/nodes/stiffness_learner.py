"""stiffness_learner node: refit the force-response model whenever a poke lands.

Surface: the latched ``/cloud_capture/surface`` (or ``surface_file`` at start-up). Pokes: the
poke store directory the poke server writes; a refit is triggered by ``/poke_server/poke_landed``
(the new poke id) and, as a fallback, by polling the store. Publishes the latched ``~/model``
(:class:`pointforce_interfaces.msg.ModelStatus`), which the contact service follows, and serves
``~/suggest_poke``. On restart it reloads the stored pokes and produces the same model.
"""

import threading
from pathlib import Path

from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import SuggestPoke
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String

from msg_adapters.geometry import sec_to_stamp
from msg_adapters.interfaces import fail, fill_suggest_response
from msg_adapters.pointcloud2 import surface_from_msg
from pointforce_ros.errors import PointforceError
from pointforce_ros.learner import OnlineLearner
from pointforce_ros.model_io import load_surface
from pointforce_ros.nodes.common import declare, run

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


class StiffnessLearnerNode(Node):
    """Online learner: store in, versioned models and suggestions out."""

    def __init__(self, **kwargs):
        """Declare parameters, load the surface if a file is given, wire topics and services."""
        super().__init__('stiffness_learner', **kwargs)
        self.store_dir = declare(self, 'store_dir', 'out/cell/pokes',
                                 'Poke store directory (rosbag2 MCAP per poke)')
        self.model_dir = declare(self, 'model_dir', 'out/cell/models',
                                 'Where versioned contact models are written')
        surface_file = declare(self, 'surface_file', '',
                               'Equilibrium surface (.npz) to start from; empty: wait for '
                               '/cloud_capture/surface')
        self.shape_constant = declare(self, 'shape_constant', 0.004,
                                      'Shape-function constant c of g(r) = c/(c+r), m',
                                      bounds=(1e-4, 0.1))
        poll = declare(self, 'poll_period', 2.0, 'Seconds between poke-store polls',
                       bounds=(0.1, 600.0))
        self.exclude_radius = declare(self, 'suggest_exclude_radius', 0.01,
                                      'Suggestions keep this far from each other and from '
                                      'pokes, m', bounds=(0.0, 0.2))
        self._lock = threading.Lock()
        self.learner = None
        self.model_pub = self.create_publisher(ModelStatus, '~/model', LATCHED)
        refit_group = MutuallyExclusiveCallbackGroup()
        if surface_file:
            try:
                self._set_surface(load_surface(surface_file))
            except PointforceError as exc:
                self.get_logger().error(f'cannot load surface_file: {exc}')
        self.create_subscription(PointCloud2, '/cloud_capture/surface', self._on_surface,
                                 LATCHED, callback_group=refit_group)
        self.create_subscription(String, '/poke_server/poke_landed', self._on_poke,
                                 RELIABLE, callback_group=refit_group)
        self.create_timer(poll, self.refit, callback_group=refit_group)
        self.create_service(SuggestPoke, '~/suggest_poke', self._on_suggest,
                            callback_group=ReentrantCallbackGroup())

    def _set_surface(self, surface):
        with self._lock:
            self.learner = OnlineLearner(self.store_dir, self.model_dir, surface,
                                         shape_constant=self.shape_constant)
        self.get_logger().info(f'surface of {len(surface)} points; learning from '
                               f'{self.store_dir}')
        self.refit()

    def _on_surface(self, msg: PointCloud2):
        try:
            self._set_surface(surface_from_msg(msg))
        except PointforceError as exc:
            self.get_logger().error(f'ignoring surface: {exc}')

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
                self.get_logger().error(f'refit failed: {exc}')
                return
        if status is None:
            return
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

    def _on_suggest(self, request, response):
        learner = self.learner
        if learner is None:
            return fail(response, 'no equilibrium surface yet')
        try:
            indices, std = learner.suggest(request.count, exclude_radius=self.exclude_radius)
        except PointforceError as exc:
            return fail(response, str(exc))
        s = learner.surface
        return fill_suggest_response(response, indices, s.points[indices], s.normals[indices],
                                     std)


def main(args=None):
    """Console entry point: ``stiffness_learner --ros-args -p store_dir:=...``."""
    run(StiffnessLearnerNode, args=args)


if __name__ == '__main__':
    main()
