"""In-process launcher: several nodes in one private rclpy context, spun in a background thread.

There is no ``launch`` wheel; ``pointforce cell``, ``pointforce demo`` and the node tests start the
nodes with this instead.
"""

import threading
import time
from typing import List

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node


class InProcessLauncher:
    """Own an rclpy context and a multi-threaded executor spinning in a daemon thread.

    Use as a context manager; nodes must be created with ``context=launcher.context``.
    """

    def __init__(self, threads: int = 8, args=None):
        """Initialise a new context (``args`` are ROS arguments such as remappings)."""
        self.context = rclpy.Context()
        rclpy.init(args=args, context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=threads, context=self.context)
        self.nodes: List[Node] = []
        self._thread = threading.Thread(target=self._spin, name='ros-executor', daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except (ExternalShutdownException, RuntimeError):
            pass

    def add(self, node: Node) -> Node:
        """Start spinning ``node``; returns it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def remove(self, node: Node) -> None:
        """Stop spinning ``node`` and destroy it (simulates a killed node)."""
        if node in self.nodes:
            self.nodes.remove(node)
            self.executor.remove_node(node)
            node.destroy_node()

    def wait_for(self, predicate, timeout: float, what: str, period: float = 0.01):
        """Poll ``predicate()`` until truthy; raise RuntimeError naming ``what`` on timeout."""
        deadline = time.monotonic() + timeout
        while True:
            value = predicate()
            if value:
                return value
            if time.monotonic() > deadline:
                raise RuntimeError(f'timed out after {timeout:.1f} s waiting for {what}')
            time.sleep(period)

    def wait_future(self, future, timeout: float, what: str):
        """Wait for an rclpy future spun by the executor thread; return its result."""
        self.wait_for(future.done, timeout, what)
        return future.result()

    def close(self) -> None:
        """Stop spinning, then destroy every node and shut the context down.

        The executor stops (and its thread ends) before any node is destroyed: destroying a
        node whose timer or subscription the spinning thread was still waiting on aborted
        the process inside rcl once (a fresh-clone test run, poke server teardown).
        """
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        for node in list(self.nodes):
            self.nodes.remove(node)
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
