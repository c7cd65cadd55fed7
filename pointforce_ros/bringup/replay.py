"""``pointforce replay BAG``: republish recorded rosbag2 (MCAP) topics at the recorded rate.

BAG is one bag directory, an ``.mcap`` file, or a poke store directory (every bag in it, in
order). Messages keep their recorded relative timing, scaled by ``rate``; the CDR bytes of the
bag are deserialised with rclpy, so any message type whose Python package is installed replays.
"""

import importlib
import math
import time
from pathlib import Path
from typing import List

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader

from pointforce_ros.arguments import MIN_REPLAY_RATE
from pointforce_ros.errors import DataError
from pointforce_ros.pokes.store import TYPESTORE
from pointforce_ros.bringup.launcher import InProcessLauncher

# transient local: a reader that matches a little after the first messages (DDS discovery is
# not symmetric) still gets them from the writer's history
REPLAY_QOS = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def bag_paths(path) -> List[Path]:
    """Bags under ``path``: itself if it is a bag or an .mcap file, else its poke-* bags."""
    path = Path(path)
    if not path.exists():
        raise DataError(f'no such bag or store: {path}')
    if path.suffix == '.mcap' or (path / 'metadata.yaml').exists():
        return [path]
    if not path.is_dir():
        raise DataError(f'{path} is not a bag directory, an .mcap file or a poke store')
    try:
        bags = sorted(p for p in path.iterdir() if (p / 'metadata.yaml').exists())
    except OSError as exc:
        raise DataError(f'{path}: cannot list: {exc}') from exc
    if not bags:
        raise DataError(f'{path} holds no rosbag2 bag')
    return bags


def _one_line(exc: Exception) -> str:
    """``Type: message`` of ``exc`` on one line (a YAML parser's message spans several)."""
    return f'{type(exc).__name__}: ' + ' '.join(str(exc).split())


def _message_type(name: str):
    package, kind, msg = name.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), msg)


def _connections(bag):
    try:
        with AnyReader([bag], default_typestore=TYPESTORE) as reader:
            return [(c.topic, c.msgtype) for c in reader.connections]
    except Exception as exc:  # rosbags raises many types for a corrupt file
        raise DataError(f'{bag}: cannot open: {_one_line(exc)}') from exc


def replay(node, path, rate: float = 1.0, wait_subscribers: float = 3.0, progress=print) -> int:
    """Publish every message of the bag(s) at ``path`` from ``node``; return the count.

    All publishers are created first; up to ``wait_subscribers`` seconds are given for
    subscribers to match them, so the first messages are not lost to discovery.

    Raises:
        DataError: ``rate`` not a finite number >= :data:`~pointforce_ros.arguments.
            MIN_REPLAY_RATE`, a missing or corrupt bag, or a message type that is not
            installed.

    """
    if not (math.isfinite(rate) and rate >= MIN_REPLAY_RATE):
        raise DataError(f'rate must be a finite number >= {MIN_REPLAY_RATE:g}, got {rate}')
    bags = bag_paths(path)
    publishers = {}
    for bag in bags:
        for topic, type_name in _connections(bag):
            if (topic, type_name) in publishers:
                continue
            try:
                msg_type = _message_type(type_name)
            except (ImportError, AttributeError, ValueError) as exc:
                raise DataError(f'{bag}: message type {type_name} is not installed: '
                                f'{exc}') from exc
            publishers[(topic, type_name)] = (node.create_publisher(msg_type, topic, REPLAY_QOS),
                                              msg_type)
    deadline = time.monotonic() + wait_subscribers
    while time.monotonic() < deadline and not all(
            pub.get_subscription_count() > 0 for pub, _ in publishers.values()):
        time.sleep(0.05)
    if wait_subscribers > 0:
        time.sleep(min(1.0, wait_subscribers))  # the readers' side of the match
    count = 0
    for bag in bags:
        try:
            with AnyReader([bag], default_typestore=TYPESTORE) as reader:
                start_bag, start_wall = None, time.monotonic()
                for conn, stamp, raw in reader.messages():
                    pub, msg_type = publishers[(conn.topic, conn.msgtype)]
                    if start_bag is None:
                        start_bag = stamp
                    delay = (stamp - start_bag) * 1e-9 / rate - (time.monotonic() - start_wall)
                    if delay > 0:
                        time.sleep(delay)
                    pub.publish(deserialize_message(bytes(raw), msg_type))
                    count += 1
        except DataError:
            raise
        except Exception as exc:  # rosbags raises many types for a corrupt file
            raise DataError(f'{bag}: cannot replay: {_one_line(exc)}') from exc
        progress(f'[replay] {bag.name}: done ({count} messages so far)')
    return count


def run_replay(path, rate: float = 1.0) -> int:
    """CLI body: replay into the ROS graph of this environment; returns an exit code."""
    from rclpy.node import Node

    with InProcessLauncher(threads=2) as launcher:
        node = launcher.add(Node('pointforce_replay', context=launcher.context))
        count = replay(node, path, rate)
        time.sleep(0.5)
    print(f'[replay] published {count} messages')
    return 0
