"""In-process launcher: several nodes in one private rclpy context, spun in a background thread.

There is no ``launch`` wheel; ``pointforce cell``, ``pointforce demo`` and the node tests start the
nodes with this instead.

Spinning is supervised: an exception a callback lets escape (``MemoryError`` included) used to end
the executor's thread, so every node in it stayed discoverable but never answered again. Now it is
recorded in :attr:`InProcessLauncher.faults`, logged, and spinning goes on. A node added with
``isolated=True`` gets its own executor and thread, so a slow or failing callback of one node
cannot starve another.
"""

import logging
import threading
import time
from typing import List, Tuple

import rclpy
from rclpy.executors import (Executor, ExternalShutdownException, MultiThreadedExecutor,
                             SingleThreadedExecutor)
from rclpy.node import Node

from pointforce_ros.nodes.common import destroy_node, stop_executor


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
        self.faults: List[Tuple[float, str, BaseException]] = []
        """(wall time, executor name, exception) of every exception a callback let escape."""
        self._spinners: List[Tuple[Executor, threading.Thread, threading.Event]] = []
        self._own: dict = {}
        self._closed = False
        self._start(self.executor, 'ros-executor')

    def _start(self, executor: Executor, name: str) -> None:
        stop = threading.Event()
        thread = threading.Thread(target=self._spin, args=(executor, name, stop), name=name,
                                  daemon=True)
        self._spinners.append((executor, thread, stop))
        thread.start()

    def _spin(self, executor: Executor, name: str, stop: threading.Event):
        """Spin ``executor`` until ``stop``; a callback's exception is recorded, not fatal."""
        while not stop.is_set() and self.context.ok():
            try:
                executor.spin()
                return
            except ExternalShutdownException:
                return
            except Exception as exc:  # noqa: BLE001 - supervise: record, log, spin on
                if stop.is_set() or not self.context.ok():
                    return
                self.faults.append((time.time(), name, exc))
                logging.getLogger(__name__).error(
                    '%s: a callback raised %s: %s; spinning on', name, type(exc).__name__, exc)
                time.sleep(0.01)  # a fault that repeats at once must not spin the CPU

    def add(self, node: Node, isolated: bool = False, threads: int = 4) -> Node:
        """Start spinning ``node``; returns it.

        With ``isolated``, the node gets its own executor of ``threads`` threads (one fault
        domain per node), else it shares the launcher's executor. ``threads=1`` gives the
        isolated node a ``SingleThreadedExecutor``: callbacks run on the spinning thread, without
        the multi-threaded executor's hand-off to a pool (a client's round trip is about 0.4 ms
        shorter here).
        """
        self.nodes.append(node)
        if isolated:
            executor = (SingleThreadedExecutor(context=self.context) if threads == 1 else
                        MultiThreadedExecutor(num_threads=threads, context=self.context))
            executor.add_node(node)
            self._own[id(node)] = executor
            self._start(executor, f'ros-executor-{node.get_name()}')
        else:
            self.executor.add_node(node)
        return node

    def alive(self) -> List[str]:
        """Names of the executor threads that still spin (all of them unless shut down)."""
        return [thread.name for _, thread, _ in self._spinners if thread.is_alive()]

    def remove(self, node: Node) -> None:
        """Stop spinning ``node`` and destroy it (simulates a killed node)."""
        if node in self.nodes:
            self.nodes.remove(node)
            executor = self._own.pop(id(node), None)
            if executor is not None:
                spinner = next(sp for sp in self._spinners if sp[0] is executor)
                self._spinners.remove(spinner)
                _, thread, stop = spinner
                stop.set()
                stop_executor(executor, thread.name, thread)
            else:
                self.executor.remove_node(node)
            destroy_node(node)

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

        Nodes go with their action servers and clients
        (:func:`~pointforce_ros.nodes.common.destroy_node`), so the participant leaves every
        other participant's graph now, not at the next garbage collection.

        Each spinning thread ends first, then the callbacks it handed to its pool finish, then
        its executor shuts down (:func:`~pointforce_ros.nodes.common.stop_executor`), and only
        then are nodes destroyed.
        Destroying a node whose timer or subscription the spinning thread was still waiting on
        aborted the process inside rcl once (a fresh-clone test run, poke server teardown); a
        callback still running on a pool thread met its destroyed node; and a callback queued
        on the pool that started after ``Executor.shutdown`` failed signalling the executor's
        guard condition, which ``shutdown`` destroys at once (``InvalidHandle`` in the demo's
        last lines, the message it had taken dropped).
        """
        if self._closed:   # a second close (an explicit one, then the with block's) is a no-op
            return
        self._closed = True
        for _, _, stop in self._spinners:
            stop.set()
        for executor, thread, _ in self._spinners:
            stop_executor(executor, thread.name, thread)
        for node in list(self.nodes):
            self.nodes.remove(node)
            destroy_node(node)
        rclpy.try_shutdown(context=self.context)
        self.context.destroy()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
