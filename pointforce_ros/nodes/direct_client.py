"""A blocking service client for planners, waiting on a wait set of its own (no executor).

A planner that asks one question and waits for the answer does not need an executor: with
rclpy's client the response is taken by an executor thread (a wait-set rebuild over every
entity of the node, a task, a future, a done callback) and handed to the waiting thread,
about 0.8 ms of CPU per call on this machine. :class:`DirectClient` sends the request and
waits in ``rcl_wait`` on its own client only, in the calling thread, and takes the response
when DDS delivers it: event-driven, no polling, no other thread involved.

The client is a real rcl client of the node (QoS, remapping and namespaces as usual); it is
not in ``node.clients``, so no executor takes its responses. One call at a time per client
(a lock); a response to an earlier call that timed out is discarded by its sequence number.
Replies to other clients of the same service are filtered by the middleware.

A first call right after :meth:`DirectClient.wait_for_service` can go unanswered: Fast DDS
drops a response when the server has not yet matched the client's response reader (the
server logs ``failed to send response (timeout)``; ``wait_for_service`` only says that the
client sees the server). A query that may be asked twice, as a contact-wrench query may, can
pass ``attempts`` to :meth:`DirectClient.call`: each attempt sends the request again and waits
``timeout_sec``.
"""

import threading
import time
from typing import Optional

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.client import Client
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, qos_profile_services_default
from rclpy.type_support import check_is_valid_srv_type


class ServiceTimeout(TimeoutError):
    """No response within the call's timeout (the service may be down or overloaded)."""


class DirectClient:
    """Call a service and block for its response without an executor (see the module)."""

    def __init__(self, node: Node, srv_type, name: str,
                 qos_profile: QoSProfile = qos_profile_services_default):
        """Create the client on ``node`` for service ``name`` of type ``srv_type``."""
        check_is_valid_srv_type(srv_type)   # also loads the type support, as create_client
        with node.handle:
            impl = _rclpy.Client(node.handle, srv_type, name, qos_profile.get_c_qos_profile())
        self._client = Client(node.context, impl, srv_type, name, qos_profile,
                              MutuallyExclusiveCallbackGroup())
        self._context = node.context
        self._srv_type = srv_type
        self._lock = threading.Lock()
        with self._context.handle:
            self._wait_set = _rclpy.WaitSet(0, 0, 0, 1, 0, 0, self._context.handle)

    @property
    def srv_name(self) -> str:
        """The service name as given."""
        return self._client.srv_name

    def service_is_ready(self) -> bool:
        """Whether a server of the service is matched now."""
        return self._client.service_is_ready()

    def wait_for_service(self, timeout_sec: Optional[float] = None) -> bool:
        """Wait until a server is matched (rclpy's check every 0.25 s; set-up only)."""
        return self._client.wait_for_service(timeout_sec)

    def call(self, request, timeout_sec: float = 5.0, attempts: int = 1):
        """Send ``request`` and return the service's response.

        ``attempts`` > 1 sends the request again when an attempt gets no response within
        ``timeout_sec`` (only for a request that may be served twice; see the module).

        Raises:
            ServiceTimeout: no response to any attempt within ``timeout_sec`` seconds.
            RuntimeError: the ROS context was shut down while waiting.
            ValueError: ``attempts`` below 1.

        """
        if int(attempts) < 1:
            raise ValueError(f'attempts must be >= 1, got {attempts!r}')
        for attempt in range(1, int(attempts) + 1):
            try:
                return self._call_once(request, timeout_sec)
            except ServiceTimeout:
                if attempt == int(attempts):
                    raise ServiceTimeout(
                        f'{self.srv_name}: no response within {timeout_sec:g} s'
                        + (f' to any of {attempt} attempts' if attempt > 1 else '')) from None

    def _call_once(self, request, timeout_sec: float):
        impl = self._client.handle
        with self._lock, impl, self._context.handle:
            sequence = impl.send_request(request)
            deadline = time.monotonic() + timeout_sec
            while True:
                left = deadline - time.monotonic()
                if left <= 0.0:
                    raise ServiceTimeout(f'{self.srv_name}: no response within '
                                         f'{timeout_sec:g} s')
                self._wait_set.clear_entities()
                self._wait_set.add_client(impl)
                self._wait_set.wait(int(left * 1e9))
                if not self._context.ok():
                    raise RuntimeError(f'{self.srv_name}: ROS was shut down during the call')
                if not self._wait_set.get_ready_entities('client'):
                    continue
                header, response = impl.take_response(self._srv_type.Response)
                if header is not None and header.request_id.sequence_number == sequence:
                    return response
                # a late response to an earlier call that timed out: keep waiting for ours

    def destroy(self) -> None:
        """Destroy the client (before its node)."""
        self._client.destroy()
