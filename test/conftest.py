"""Suite-wide fixtures: an isolated ROS 2 graph per test process, and seeded randomness."""

import os
import threading

import pytest


def _isolate_ros_graph():
    """Give this test process its own DDS domain on localhost only, before rclpy starts.

    Parallel or repeated runs on one machine then never see each other's nodes.
    """
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    index = int(worker[2:]) if worker.startswith('gw') and worker[2:].isdigit() else 0
    domain = 1 + (os.getpid() * 7 + index * 31) % 100
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


_isolate_ros_graph()


class RosGraph:
    """A private rclpy context with a spinning multi-threaded executor (for node tests)."""

    def __init__(self):
        import rclpy
        from rclpy.executors import MultiThreadedExecutor
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=6, context=self.context)
        self.nodes = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except (ExternalShutdownException, RuntimeError):
            pass

    def add(self, node):
        """Add a node to the executor; returns it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def close(self):
        import rclpy
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown(timeout_sec=5.0)
        rclpy.try_shutdown(context=self.context)
        self._thread.join(timeout=5.0)


@pytest.fixture
def ros_graph():
    """A live, isolated ROS 2 graph; nodes added to it spin until the test ends."""
    graph = RosGraph()
    try:
        yield graph
    finally:
        graph.close()
