"""``pointforce bench streams``: what the arm's 250 Hz streams cost a node that listens.

The deformation node listens to the poke server's TCP pose and wrench, 250 Hz each. On the
node's executor rclpy rebuilds its wait set in Python for every message (a task, a future, a
guard condition); on a :class:`~pointforce_ros.nodes.service_loop.ServiceLoop` each message is
one ``rcl_wait``, one take and the callback. This benchmark measures both in the same run:

* a talker process publishes ``PoseStamped`` and ``WrenchStamped`` at ``rate`` Hz each (the
  poke server's QoS, a sequence number in ``frame_id``) for the whole run;
* the benchmark's process hosts a listener node, in turn on a ``SingleThreadedExecutor``
  spinning in a thread (``executor``, the baseline) and on a ``ServiceLoop`` (``loop``), in
  ``rounds`` alternating windows of ``seconds``; the callback only records the sequence number,
  so the figure is the cost of getting a message to a callback;
* per mode: CPU of the listener's process per message (``*_us_per_message``: every thread of
  the process, the middleware's receive threads included, over the messages taken in the
  window), the share of a core at the streams' rate (``*_core_share``) and messages lost
  (sequence gaps), and ``executor_over_loop``, the ratio of the two per-message costs.

The poke server's side of the same streams, in the same run: the CPU per arm sample of
building its two messages (:func:`~pointforce_ros.nodes.poke_server.stream_messages`) with the
closed-form rotation (``publish_us_per_sample``) against scipy's ``Rotation`` path it used
before (``publish_scipy_us_per_sample``), on ``samples`` seeded poses, alternating in rounds,
and ``scipy_over_closed_form``.

Everything runs in a private ROS domain (:func:`~pointforce_ros.bringup.domain.private_domain`).
"""

import argparse
import subprocess
import sys
import threading
import time
from typing import Dict, List

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from pointforce_ros.bringup.domain import private_domain
from pointforce_ros.drivers.ur_arm import ArmSample
from pointforce_ros.nodes.poke_server import stream_messages
from pointforce_ros.nodes.service_loop import ServiceLoop
from pointforce_ros.rotations import (matrix_to_quaternion, rotvec_matrix_and_quaternion,
                                      rotvec_to_matrix)

QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
"""The poke server's stream QoS."""

TOPICS = (('/bench_streams/tcp_pose', PoseStamped), ('/bench_streams/wrench', WrenchStamped))


class _Listener(Node):
    """Counts each topic's messages and sequence gaps; on an executor or a ServiceLoop."""

    def __init__(self, context, on_loop: bool):
        super().__init__('bench_streams_listener', context=context)
        self.lock = threading.Lock()
        self.count = 0
        self.lost = 0
        self._last: Dict[str, int] = {}
        self.loop = ServiceLoop(self) if on_loop else None
        for topic, msg_type in TOPICS:
            def callback(msg, topic=topic):
                self._on_message(topic, msg)
            if self.loop is not None:
                self.loop.add_subscription(msg_type, topic, callback, QOS)
            else:
                self.create_subscription(msg_type, topic, callback, QOS)
        if self.loop is not None:
            self.loop.start()

    def _on_message(self, topic: str, msg) -> None:
        seq = int(msg.header.frame_id)
        with self.lock:
            last = self._last.get(topic)
            if last is not None and seq > last + 1:
                self.lost += seq - last - 1
            self._last[topic] = seq
            self.count += 1

    def reset(self) -> None:
        with self.lock:
            self.count = self.lost = 0

    def destroy_node(self):
        if self.loop is not None:
            self.loop.stop()
        return super().destroy_node()


def _window(context, on_loop: bool, seconds: float) -> Dict[str, float]:
    """One listener, one measured window: messages, lost, CPU seconds of this process."""
    node = _Listener(context, on_loop)
    executor = thread = None
    if not on_loop:
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        thread = threading.Thread(target=executor.spin, daemon=True)
        thread.start()
    try:
        deadline = time.monotonic() + 20.0
        while node.count < 100:   # matched and flowing
            if time.monotonic() > deadline:
                raise RuntimeError('bench streams: no messages from the talker within 20 s')
            time.sleep(0.05)
        node.reset()
        cpu, wall = time.process_time(), time.monotonic()
        time.sleep(seconds)
        cpu, wall = time.process_time() - cpu, time.monotonic() - wall
        with node.lock:
            count, lost = node.count, node.lost
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=2.0)
            thread.join(2.0)
        node.destroy_node()
    return {'messages': count, 'lost': lost, 'cpu_s': cpu, 'wall_s': wall}


def _scipy_convert(rotvec):
    """Convert as the stream did before the closed form: scipy's matrix, then its quaternion."""
    matrix = rotvec_to_matrix(rotvec)
    return matrix, matrix_to_quaternion(matrix)


def publisher_cost(samples: int = 2000, rounds: int = 3, seed: int = 0) -> Dict[str, float]:
    """CPU per arm sample of the poke server's two stream messages, both rotation paths."""
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(samples, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    rotvecs = axes * rng.uniform(0.0, np.pi, size=(samples, 1))
    arm = [ArmSample(1.7e9 + 0.004 * k, 0.002 * k,
                     np.r_[rng.uniform(-0.5, 0.5, 3), rotvecs[k]], rng.normal(size=6))
           for k in range(samples)]
    cpu = {'closed': 0.0, 'scipy': 0.0}
    for _ in range(rounds):
        for name, convert in (('closed', rotvec_matrix_and_quaternion),
                              ('scipy', _scipy_convert)):
            start = time.process_time()
            for sample in arm:
                stream_messages(sample, convert)
            cpu[name] += time.process_time() - start
    count = samples * rounds
    return {'publish_samples': count,
            'publish_us_per_sample': 1e6 * cpu['closed'] / count,
            'publish_scipy_us_per_sample': 1e6 * cpu['scipy'] / count,
            'scipy_over_closed_form': cpu['scipy'] / max(cpu['closed'], 1e-12)}


def bench_streams(seconds: float = 6.0, rounds: int = 2, rate: float = 250.0,
                  quick: bool = False) -> Dict[str, float]:
    """Run the benchmark (see the module); ``quick``: 2 s windows, one round."""
    if quick:
        seconds, rounds = 2.0, 1
    publisher = publisher_cost(rounds=1 if quick else 3)
    print(f'[bench streams] poke server messages: {publisher}', file=sys.stderr, flush=True)
    total = rounds * 2 * (seconds + 8.0) + 20.0
    with private_domain():
        talker = subprocess.Popen([sys.executable, '-m', 'pointforce_ros.bringup.bench_streams',
                                   '--talk', repr(total), repr(rate)],
                                  stdout=subprocess.DEVNULL)
        context = rclpy.Context()
        rclpy.init(context=context)
        windows: Dict[str, List[Dict[str, float]]] = {'executor': [], 'loop': []}
        try:
            for _ in range(rounds):
                for mode in ('executor', 'loop'):
                    windows[mode].append(_window(context, mode == 'loop', seconds))
                    print(f'[bench streams] {mode}: {windows[mode][-1]}', file=sys.stderr,
                          flush=True)
        finally:
            rclpy.shutdown(context=context)
            talker.terminate()
            talker.wait(10.0)
    out: Dict[str, float] = {'rate_hz_per_topic': rate, 'topics': len(TOPICS),
                             'window_s': seconds, 'rounds': rounds}
    for mode, rows in windows.items():
        messages = sum(r['messages'] for r in rows)
        cpu = sum(r['cpu_s'] for r in rows)
        out[f'{mode}_messages'] = messages
        out[f'{mode}_lost'] = sum(r['lost'] for r in rows)
        out[f'{mode}_us_per_message'] = 1e6 * cpu / max(messages, 1)
        out[f'{mode}_core_share'] = cpu / sum(r['wall_s'] for r in rows)
    out['executor_over_loop'] = (out['executor_us_per_message']
                                 / max(out['loop_us_per_message'], 1e-9))
    out.update(publisher)
    return out


def _talk(seconds: float, rate: float) -> int:
    """Publish both topics at ``rate`` Hz for ``seconds`` (the talker process)."""
    rclpy.init()
    node = Node('bench_streams_talker')
    publishers = [(node.create_publisher(msg_type, topic, QOS), msg_type)
                  for topic, msg_type in TOPICS]
    period = 1.0 / rate
    start = time.monotonic()
    tick = start
    seq = 0
    try:
        while time.monotonic() - start < seconds and rclpy.ok():
            for publisher, msg_type in publishers:
                msg = msg_type()
                msg.header.frame_id = str(seq)
                publisher.publish(msg)
            seq += 1
            tick += period
            time.sleep(max(0.0, tick - time.monotonic()))
    except (KeyboardInterrupt, _rclpy.RCLError):   # stopped: rclpy's handler shut it down
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    parser = argparse.ArgumentParser(prog='bench_streams --talk')
    parser.add_argument('--talk', nargs=2, type=float, metavar=('SECONDS', 'RATE'),
                        required=True)
    sys.exit(_talk(*parser.parse_args().talk))
