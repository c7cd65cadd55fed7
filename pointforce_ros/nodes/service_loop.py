"""Services answered on a wait loop of their own, off the node's executor.

rclpy's executors rebuild their wait set from every entity of every node in Python on each
iteration (a handle context per entity, a task per callback, a guard condition triggered twice
per callback, so two or three iterations per request). For the contact service, with its
parameter services, lanes, timers and model topic, that cost about 1 ms of CPU per request
on this machine, as much as the query's own solve. :class:`ServiceLoop` serves a fixed set of
services from one thread: one wait set over those services and a wake-up guard condition,
built once; per request it takes the request, calls the callback and sends the response, all
in rclpy's own C calls. The node's executor keeps everything else (parameters, timers,
subscriptions) and is not involved in answering.

The services are real rcl services on the node (discoverable, remappable, the node's
namespace and QoS); they are not in ``node.services``, so no executor takes their requests.
Requests are answered one at a time, in arrival order per service. A callback must contain
its own exceptions and return the response (the contact node's do); an exception that
escapes one anyway, or a take or send that fails, is logged and the loop keeps serving.

The same loop takes high-rate topics off the executor (:meth:`ServiceLoop.add_subscription`):
the deformation node's two 250 Hz streams cost its executor about 0.8 ms of CPU per message
(40 % of a core at rest); on the loop each message is one take and one callback
(``pointforce bench streams`` measures both in the same run). Every message is handed over,
in arrival order per topic; a callback that raises is logged and counted, and the next
message is taken.
"""

import threading
import time
from collections import deque
from contextlib import ExitStack
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.service import Service
from rclpy.subscription import Subscription
from rclpy.type_support import check_is_valid_msg_type, check_is_valid_srv_type

WAKE_PERIOD_NS = 500_000_000
"""Longest wait before the loop looks at its stop flag again (a missed wake-up costs this)."""

MESSAGES_PER_WAKE = 64
"""Most messages taken from one topic per wake-up, so that no topic starves the services."""

TIMING_WINDOW = 1000
"""Requests per service whose stage times :meth:`ServiceLoop.timing` summarises (the latest)."""

STAGES = ('take', 'callback', 'send')
"""Stages of one answer :meth:`ServiceLoop.timing` times: taking the request from the
middleware (its deserialisation into a message), the callback, sending the response (its
serialisation and the middleware's write)."""


class ServiceLoop:
    """Serve some of a node's services from a thread of their own (see the module)."""

    def __init__(self, node: Node):
        """Prepare a loop for ``node``'s services; :meth:`add` them, then :meth:`start`."""
        self._node = node
        self._services: List[Service] = []
        self._subscriptions: List[Subscription] = []
        self.messages_taken = 0
        self._group = MutuallyExclusiveCallbackGroup()
        self._stop = threading.Event()
        self._thread: Optional[threading.Thread] = None
        self._stopped = False
        with node.context.handle:
            self._wake = _rclpy.GuardCondition(node.context.handle)
        self.requests_taken = 0
        self.faults = 0
        self.hot_window = 0.0
        """Seconds the loop keeps polling after an answer before it sleeps again (0: never).
        A zero-timeout wait returns after about 60 us here (the kernel's timer slack), so
        polling keeps the thread's vCPU awake at about a fifth of a core."""
        self.polls = 0
        """Zero-timeout waits made in hot windows so far."""
        self._times: Dict[Service, Tuple[str, deque]] = {}   # full name, stage times
        self._times_lock = threading.Lock()

    def add(self, srv_type, name: str, callback: Callable, qos_profile: QoSProfile) -> Service:
        """Create service ``name`` on the node, answered by ``callback(request, response)``.

        Raises:
            RuntimeError: the loop is already running (its wait set is fixed when it starts).

        """
        if self._thread is not None:
            raise RuntimeError('ServiceLoop.add: the loop is running; add services before start')
        check_is_valid_srv_type(srv_type)   # also loads the type support, as create_service
        with self._node.handle:
            impl = _rclpy.Service(self._node.handle, srv_type, name,
                                  qos_profile.get_c_qos_profile())
        service = Service(impl, srv_type, name, callback, self._group, qos_profile)
        self._services.append(service)
        self._times[service] = (self._node.resolve_service_name(name),
                                deque(maxlen=TIMING_WINDOW))
        return service

    def add_subscription(self, msg_type, topic: str, callback: Callable,
                         qos_profile: QoSProfile) -> Subscription:
        """Subscribe the node to ``topic``; the loop calls ``callback(msg)`` for every message.

        Raises:
            RuntimeError: the loop is already running (its wait set is fixed when it starts).

        """
        if self._thread is not None:
            raise RuntimeError('ServiceLoop.add_subscription: the loop is running; add '
                               'subscriptions before start')
        check_is_valid_msg_type(msg_type)   # also loads the type support
        with self._node.handle:
            impl = _rclpy.Subscription(self._node.handle, msg_type, topic,
                                       qos_profile.get_c_qos_profile())
        subscription = Subscription(
            impl, msg_type, topic, callback, self._group, qos_profile, False,
            event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))
        self._subscriptions.append(subscription)
        return subscription

    def timing(self) -> Dict[str, Dict[str, float]]:
        """Where each service's answers spent their time, over its latest answers.

        Returns:
            per service (its full name) that has answered: ``answers`` (in the window, at most
            :data:`TIMING_WINDOW`) and, for each of :data:`STAGES`, ``<stage>_p50_ms`` and
            ``<stage>_p99_ms`` (wall time on the loop's thread, milliseconds).

        """
        with self._times_lock:
            copies = {name: np.array(times) for name, times in self._times.values() if times}
        out = {}
        for name, times in copies.items():
            row = {'answers': float(len(times))}
            for k, stage in enumerate(STAGES):
                p50, p99 = np.percentile(times[:, k], [50, 99])
                row[f'{stage}_p50_ms'], row[f'{stage}_p99_ms'] = 1e3 * p50, 1e3 * p99
            out[name] = row
        return out

    @property
    def services(self) -> List[Service]:
        """The services this loop answers."""
        return list(self._services)

    def set_hot_wait(self, milliseconds: float) -> None:
        """Set :attr:`hot_window` from a ``hot_wait`` parameter in milliseconds (>= 0)."""
        self.hot_window = 1e-3 * max(0.0, float(milliseconds))

    def start(self) -> None:
        """Start answering (a daemon thread); the context's shutdown stops it."""
        if self._thread is not None:
            return
        self._node.context.on_shutdown(self._on_shutdown)
        self._thread = threading.Thread(target=self._run, daemon=True,
                                        name=f'{self._node.get_name()}_services')
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop answering and destroy the services (call before the node is destroyed).

        A second call does nothing.
        """
        if self._stopped:
            return
        self._stopped = True
        self._stop.set()
        self._trigger()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        for entity in (*self._services, *self._subscriptions):
            entity.destroy()
        self._services = []
        self._subscriptions = []
        self._wake.destroy_when_not_in_use()

    def _on_shutdown(self) -> None:
        self._stop.set()
        self._trigger()

    def _trigger(self) -> None:
        try:
            with self._wake:
                self._wake.trigger_guard_condition()
        except InvalidHandle:
            pass

    def _run(self) -> None:
        logger = self._node.get_logger()
        context = self._node.context
        while not self._stop.is_set() and context.ok():
            try:
                self._serve(context)
            except Exception as exc:  # noqa: BLE001 - logged; the loop starts over
                if self._stop.is_set() or not context.ok():
                    return
                self.faults += 1
                logger.error(f'service loop fault, restarting it: {type(exc).__name__}: {exc}',
                             throttle_duration_sec=2.0)
                self._stop.wait(0.1)

    def _serve(self, context) -> None:
        """Wait on the services and answer what arrives until stopped."""
        logger = self._node.get_logger()
        handles = [s.handle for s in self._services]
        by_pointer = {h.pointer: s for h, s in zip(handles, self._services)}
        topics = [s.handle for s in self._subscriptions]
        topic_by_pointer = {h.pointer: s for h, s in zip(topics, self._subscriptions)}
        with ExitStack() as held:
            for handle in (*handles, *topics, self._wake, context.handle):
                held.enter_context(handle)
            wait_set = _rclpy.WaitSet(len(topics), 1, 0, 0, len(handles), 0, context.handle)
            hot_until = 0.0
            while not self._stop.is_set():
                wait_set.clear_entities()
                for handle in handles:
                    wait_set.add_service(handle)
                for handle in topics:
                    wait_set.add_subscription(handle)
                wait_set.add_guard_condition(self._wake)
                if time.perf_counter() < hot_until:
                    self.polls += 1
                    wait_set.wait(0)
                else:
                    wait_set.wait(WAKE_PERIOD_NS)
                if self._stop.is_set() or not context.ok():
                    return
                if topics:
                    for pointer in wait_set.get_ready_entities('subscription'):
                        self._deliver(topic_by_pointer[pointer], logger)
                ready = wait_set.get_ready_entities('service')
                for pointer in ready:
                    self._answer(by_pointer[pointer], logger)
                if ready and self.hot_window > 0.0:
                    hot_until = time.perf_counter() + self.hot_window

    def _deliver(self, subscription: Subscription, logger) -> None:
        """Take the messages ``subscription`` holds (a wake's worth) and hand each over."""
        for _ in range(MESSAGES_PER_WAKE):
            try:
                taken = subscription.handle.take_message(subscription.msg_type, False)
            except Exception as exc:  # noqa: BLE001 - one topic never stops the others
                self.faults += 1
                logger.error(f'{subscription.topic_name}: message not taken: '
                             f'{type(exc).__name__}: {exc}', throttle_duration_sec=2.0)
                return
            if taken is None:
                return
            self.messages_taken += 1
            try:
                subscription.callback(taken[0])
            except Exception as exc:  # noqa: BLE001 - logged; the next message is taken
                self.faults += 1
                logger.error(f'{subscription.topic_name}: callback failed: '
                             f'{type(exc).__name__}: {exc}', throttle_duration_sec=2.0)

    def _answer(self, service: Service, logger) -> None:
        """Take one request of ``service``, answer it; any fault is logged, never raised.

        A callback that raises is answered with a fresh response, ``success=False`` and the
        reason in ``message`` where the type has those fields, so the caller is not left
        waiting.
        """
        start = time.perf_counter()
        try:
            request, header = service.handle.service_take_request(service.srv_type.Request)
        except Exception as exc:  # noqa: BLE001 - a service never stops answering others
            self.faults += 1
            logger.error(f'{service.srv_name}: request not taken: {type(exc).__name__}: {exc}',
                         throttle_duration_sec=2.0)
            return
        if header is None:
            return
        self.requests_taken += 1
        taken = time.perf_counter()
        try:
            response = service.callback(request, service.srv_type.Response())
        except Exception as exc:  # noqa: BLE001 - the caller gets a refusal, not silence
            self.faults += 1
            logger.error(f'{service.srv_name}: callback failed: {type(exc).__name__}: {exc}',
                         throttle_duration_sec=2.0)
            response = _refusal(service.srv_type.Response(), exc)
        answered = time.perf_counter()
        try:
            service.send_response(response, header)
        except Exception as exc:  # noqa: BLE001 - a service never stops answering others
            self.faults += 1
            logger.error(f'{service.srv_name}: response not sent: {type(exc).__name__}: '
                         f'{exc}', throttle_duration_sec=2.0)
            return
        sent = time.perf_counter()
        with self._times_lock:
            self._times[service][1].append((taken - start, answered - taken, sent - answered))


def _refusal(response, exc: Exception):
    """``response`` with ``success=False`` and ``message`` saying ``exc``, where it has them."""
    if hasattr(response, 'success'):
        response.success = False
    if hasattr(response, 'message'):
        response.message = (f'the service could not answer this request '
                            f'({type(exc).__name__}: {exc}); it keeps serving others')
    return response
