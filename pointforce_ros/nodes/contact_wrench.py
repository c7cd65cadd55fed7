"""contact_wrench node: ``~/contact_wrench`` and ``~/contact_wrench_batch`` for planners.

Answers from the latest contact model: a file in ``model_dir`` (polled) or the path announced on
the learner's latched model topic. A new model is swapped in without dropping requests. Malformed
requests get ``success=False`` and a message; the node keeps serving. Accepted effects stored in
the model add their forward terms (:mod:`pointforce_ros.effects.forward`): series compliance
(``series_compliance``), a viscoelastic hold fraction (``hold_time``) and a surface offset.
"""

import time
from pathlib import Path

from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from msg_adapters.interfaces import (contact_query_from_batch_request, contact_query_from_request,
                                     fail, fill_batch_response, fill_contact_response)
from pointforce_ros.errors import PointforceError
from pointforce_ros.nodes.common import declare, run
from pointforce_ros.model.serving import WrenchServer

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                     reliability=ReliabilityPolicy.RELIABLE)


class ContactWrenchNode(Node):
    """Serves contact-wrench queries from the learned model."""

    def __init__(self, **kwargs):
        """Declare parameters, load the newest model if any, create the services."""
        super().__init__('contact_wrench', **kwargs)
        self.model_dir = declare(
            self, 'model_dir', '', 'Directory of model-v*.npz files to serve from (polled); '
            'empty: only models announced on the model topic')
        self.max_batch = declare(self, 'max_batch', 20000,
                                 'Largest number of poses in one batch request',
                                 bounds=(1, 1000000))
        spacing = declare(self, 'sample_spacing', 0.003,
                          'Rigid-mesh surface sampling distance, m (seed paper: 3 mm)',
                          bounds=(0.0005, 0.05))
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
        self.server = WrenchServer(spacing=spacing, series_compliance=series,
                                   hold_time=hold_time)
        self.requests_served = 0
        self.requests_failed = 0
        self._try_load_dir()
        group = ReentrantCallbackGroup()
        self.create_service(ContactWrench, '~/contact_wrench', self._on_single,
                            callback_group=group)
        self.create_service(ContactWrenchBatch, '~/contact_wrench_batch', self._on_batch,
                            callback_group=group)
        loader = MutuallyExclusiveCallbackGroup()
        self.create_subscription(ModelStatus, 'stiffness_learner/model', self._on_model, LATCHED,
                                 callback_group=loader)
        if self.model_dir:
            self.create_timer(poll, self._try_load_dir, callback_group=loader)
        self.get_logger().info(f'serving contact wrenches (model version {self.server.version})')

    def _try_load_dir(self):
        if not self.model_dir:
            return
        try:
            if self.server.load_latest(self.model_dir):
                self.get_logger().info(f'loaded model v{self.server.version} from '
                                       f'{self.server.loaded_path}{self._terms()}')
        except PointforceError as exc:
            self.get_logger().error(f'cannot load model from {self.model_dir}: {exc}',
                                    throttle_duration_sec=10.0)

    def _on_model(self, msg: ModelStatus):
        if not msg.model_path or msg.version <= self.server.version:
            return
        try:
            self.server.load(Path(msg.model_path))
            self.get_logger().info(f'hot-swapped to model v{self.server.version}{self._terms()}')
        except PointforceError as exc:
            self.get_logger().error(f'model v{msg.version} at {msg.model_path} rejected: {exc}')

    def _terms(self) -> str:
        terms = self.server.forward_terms
        if terms is None or not (terms.applied or terms.skipped):
            return ''
        return (f'; effects applied: {list(terms.applied)}'
                + (f', not applied: {dict(terms.skipped)}' if terms.skipped else ''))

    def _on_single(self, request, response):
        start = time.perf_counter()
        try:
            query = contact_query_from_request(request)
            result, version = self.server.answer(query)
            fill_contact_response(response, result, version, query.return_displacements)
            self.requests_served += 1
        except PointforceError as exc:
            self.requests_failed += 1
            fail(response, str(exc))
            self.get_logger().warn(f'contact_wrench refused: {exc}', throttle_duration_sec=2.0)
        self.get_logger().debug(f'contact_wrench in {1e3 * (time.perf_counter() - start):.2f} ms')
        return response

    def _on_batch(self, request, response):
        try:
            if len(request.poses) > self.max_batch:
                return fail(response, f'poses: {len(request.poses)} exceeds max_batch '
                                      f'{self.max_batch}')
            query = contact_query_from_batch_request(request)
            batch, version = self.server.answer_batch(query)
            fill_batch_response(response, batch, version)
            self.requests_served += 1
        except PointforceError as exc:
            self.requests_failed += 1
            fail(response, str(exc))
            self.get_logger().warn(f'contact_wrench_batch refused: {exc}',
                                   throttle_duration_sec=2.0)
        return response


def main(args=None):
    """Console entry point: ``contact_wrench --ros-args -p model_dir:=...``."""
    run(ContactWrenchNode, args=args)


if __name__ == '__main__':
    main()
