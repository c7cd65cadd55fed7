"""Shared node plumbing: the Jazzy ``main()`` pattern and described, bounded parameters."""

from typing import Callable, Optional, Sequence

import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node


def declare(node: Node, name: str, default, description: str, *,
            bounds: Optional[Sequence[float]] = None, read_only: bool = False):
    """Declare a parameter with a description (unit, frame) and optional ``(lo, hi)`` bounds.

    Returns the parameter's value after overrides.
    """
    descriptor = ParameterDescriptor(description=description, read_only=read_only)
    if isinstance(default, bool):
        descriptor.type = ParameterType.PARAMETER_BOOL
    elif isinstance(default, int):
        descriptor.type = ParameterType.PARAMETER_INTEGER
        if bounds is not None:
            descriptor.integer_range = [IntegerRange(from_value=int(bounds[0]),
                                                     to_value=int(bounds[1]), step=1)]
    elif isinstance(default, float):
        descriptor.type = ParameterType.PARAMETER_DOUBLE
        if bounds is not None:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(bounds[0]), to_value=float(bounds[1]), step=0.0)]
    elif isinstance(default, str):
        descriptor.type = ParameterType.PARAMETER_STRING
    return node.declare_parameter(name, default, descriptor).value


def qos_watch(node: Node, topic: str) -> SubscriptionEventCallbacks:
    """Event callbacks for a subscription to ``topic``: an incompatible-QoS match is logged.

    The event is also appended to ``node.incompatible_qos`` (a list the node creates), so a test
    or a supervisor can tell that a publisher was discovered but never delivers.
    """
    if not hasattr(node, 'incompatible_qos'):
        node.incompatible_qos = []

    def on_incompatible(event):
        node.incompatible_qos.append((topic, event))
        node.get_logger().error(f'{topic}: a publisher offers an incompatible QoS '
                                f'(policy {event.last_policy_kind}); its data never arrives')
    return SubscriptionEventCallbacks(incompatible_qos=on_incompatible)


def run(node_factory: Callable[[], Node], args=None, threads: int = 4) -> None:
    """Spin one node the Jazzy way (ros2/demos): init, spin, shutdown on Ctrl-C or external."""
    rclpy.init(args=args)
    node = None
    try:
        node = node_factory()
        executor = MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
