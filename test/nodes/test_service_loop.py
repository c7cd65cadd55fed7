"""ServiceLoop (services off the executor) and DirectClient (calls without one), over real DDS."""

import threading
import time

import pytest
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import Int64
from std_srvs.srv import Trigger

from pointforce_ros.nodes.contact_wrench import REQUESTS
from pointforce_ros.nodes.direct_client import DirectClient, ServiceTimeout
from pointforce_ros.nodes.service_loop import ServiceLoop

pytestmark = pytest.mark.ros


class _Served(Node):
    """A node with one Trigger service on a ServiceLoop and one on its executor.

    ``answers`` (a list of callables, one per call) decides each answer of the loop's service;
    a call past the list answers ``success=True``. The executor's ``blocked`` Event, once set
    by a timer callback, holds the executor for ``hold`` seconds.
    """

    def __init__(self, context, answers=(), hold: float = 0.0):
        super().__init__('loop_test', context=context)
        self.answers = list(answers)
        self.calls = 0
        self.loop = ServiceLoop(self)
        self.loop.add(Trigger, '~/on_loop', self._answer, REQUESTS)
        self.create_service(Trigger, '~/on_executor', self._answer_plainly)
        self.blocked = threading.Event()
        self._hold = hold
        self._timer = self.create_timer(0.05, self._block) if hold > 0 else None
        self.loop.start()

    def _answer(self, request, response):
        self.calls += 1
        step = self.answers.pop(0) if self.answers else None
        if step is not None:
            step()
        response.success = True
        response.message = f'call {self.calls}'
        return response

    def _answer_plainly(self, request, response):
        response.success = True
        return response

    def _block(self):
        self.destroy_timer(self._timer)
        self.blocked.set()
        time.sleep(self._hold)   # an executor callback busy for a while (a model load)

    def destroy_node(self):
        self.loop.stop()
        return super().destroy_node()


def _client(graph, name):
    node = Node(f'loop_test_client_{name}', context=graph.context)
    client = DirectClient(node, Trigger, f'/loop_test/{name}', REQUESTS)
    assert client.wait_for_service(timeout_sec=30.0)
    graph.nodes.append(node)   # destroyed with the graph
    return client


def test_loop_services_answer_while_the_node_executor_is_busy(ros_graph):
    node = ros_graph.add(_Served(ros_graph.context, hold=3.0), isolated=True, threads=1)
    on_loop = _client(ros_graph, 'on_loop')
    assert node.blocked.wait(10.0)
    start = time.monotonic()
    assert on_loop.call(Trigger.Request(), timeout_sec=1.0).success
    assert time.monotonic() - start < 1.0
    # the same call to a service on the executor waits until the executor is free
    on_executor = _client(ros_graph, 'on_executor')
    with pytest.raises(ServiceTimeout, match='on_executor'):
        on_executor.call(Trigger.Request(), timeout_sec=0.3)


def test_a_callback_that_raises_is_answered_with_a_refusal_and_the_loop_serves_on(ros_graph):
    def fail():
        raise ValueError('a bug in the callback')
    node = ros_graph.add(_Served(ros_graph.context, answers=[fail]))
    client = _client(ros_graph, 'on_loop')
    first = client.call(Trigger.Request(), timeout_sec=5.0)
    assert not first.success and 'ValueError: a bug in the callback' in first.message
    second = client.call(Trigger.Request(), timeout_sec=5.0)
    assert second.success and second.message == 'call 2'
    assert node.loop.faults == 1 and node.loop.requests_taken == 2


def test_a_timed_out_call_does_not_take_a_later_calls_answer(ros_graph):
    node = ros_graph.add(_Served(ros_graph.context, answers=[lambda: time.sleep(0.6)]))
    client = _client(ros_graph, 'on_loop')
    with pytest.raises(ServiceTimeout, match='no response within 0.2 s'):
        client.call(Trigger.Request(), timeout_sec=0.2)
    time.sleep(0.8)   # the late answer to call 1 arrives meanwhile
    answer = client.call(Trigger.Request(), timeout_sec=5.0)
    assert answer.message == 'call 2', answer.message
    assert node.calls == 2


def test_a_call_with_attempts_asks_again_and_takes_only_its_own_answer(ros_graph):
    # the first request is answered late (as if its response had been lost): the second
    # attempt's answer comes back, the late one to the first is discarded
    slow = lambda: time.sleep(1.2)   # noqa: E731
    node = ros_graph.add(_Served(ros_graph.context, answers=[slow, None, slow, slow]))
    client = _client(ros_graph, 'on_loop')
    answer = client.call(Trigger.Request(), timeout_sec=1.0, attempts=3)
    assert answer.message == 'call 2', answer.message
    # two slow answers in a row and two attempts: no answer, and the message says so
    with pytest.raises(ServiceTimeout, match='no response within 1 s to any of 2 attempts'):
        client.call(Trigger.Request(), timeout_sec=1.0, attempts=2)
    time.sleep(1.0)
    assert client.call(Trigger.Request(), timeout_sec=5.0).message == 'call 5'
    assert node.calls == 5
    with pytest.raises(ValueError, match='attempts'):
        client.call(Trigger.Request(), attempts=0)


def test_the_loop_times_each_stage_of_its_answers(ros_graph):
    # eight answers, the last three with a 30 ms callback: the callback stage holds them,
    # taking and sending stay small, and p99 sees the slow ones where p50 does not
    steps = [None] * 5 + [lambda: time.sleep(0.03)] * 3
    node = ros_graph.add(_Served(ros_graph.context, answers=steps))
    assert node.loop.timing() == {}
    client = _client(ros_graph, 'on_loop')
    for _ in steps:
        assert client.call(Trigger.Request(), timeout_sec=5.0).success
    (name, row), = node.loop.timing().items()
    assert name == '/loop_test/on_loop' and row['answers'] == len(steps)
    assert row['callback_p99_ms'] >= 29.0 and row['callback_p50_ms'] < 20.0
    for stage in ('take', 'send'):
        assert 0.0 < row[f'{stage}_p50_ms'] < 20.0 and row[f'{stage}_p99_ms'] < 29.0


def test_stop_ends_the_loop_thread_and_its_services(ros_graph):
    node = ros_graph.add(_Served(ros_graph.context))
    client = _client(ros_graph, 'on_loop')
    assert client.call(Trigger.Request(), timeout_sec=5.0).success
    thread = node.loop._thread
    node.loop.stop()
    assert not thread.is_alive()
    assert node.loop.services == []
    ros_graph.wait_for(lambda: not client.service_is_ready(), 10.0, 'the service to go away')


class _Listener(Node):
    """A node whose ServiceLoop takes ``/loop_test_topic`` (std_msgs/Int64) and a service.

    The callback records each value; a value in ``raise_on`` raises what the dict names there.
    """

    def __init__(self, context, raise_on=None):
        super().__init__('loop_test', context=context)
        self.values = []
        self.raise_on = dict(raise_on or {})
        self.loop = ServiceLoop(self)
        self.loop.add_subscription(Int64, '/loop_test_topic', self._on_value,
                                   QoSProfile(depth=500))
        self.loop.add(Trigger, '~/ping', lambda req, res: Trigger.Response(success=True),
                      REQUESTS)
        self.loop.start()

    def _on_value(self, msg):
        self.values.append(msg.data)
        if msg.data in self.raise_on:
            raise self.raise_on[msg.data]

    def destroy_node(self):
        self.loop.stop()
        return super().destroy_node()


def test_loop_subscriptions_take_every_message_in_order_past_callbacks_that_raise(ros_graph):
    # a publisher of 600 numbers at about 2 kHz; the listener's callback raises on four of
    # them (a MemoryError among them): every message still arrives, once and in order, the
    # faults are counted, and the loop's service answers all along
    node = ros_graph.add(_Listener(ros_graph.context, raise_on={
        10: ValueError('bad'), 200: MemoryError(), 201: RuntimeError('x'), 599: KeyError(3)}))
    talker = Node('loop_talker', context=ros_graph.context)
    ros_graph.nodes.append(talker)
    pub = talker.create_publisher(Int64, '/loop_test_topic', QoSProfile(depth=500))
    ros_graph.wait_for(lambda: pub.get_subscription_count() > 0, 15.0, 'the loop to subscribe')
    ping = _client(ros_graph, 'ping')
    for value in range(600):
        pub.publish(Int64(data=value))
        if value % 100 == 0:
            assert ping.call(Trigger.Request(), timeout_sec=5.0).success
        time.sleep(0.0005)
    ros_graph.wait_for(lambda: len(node.values) >= 600, 15.0, 'all 600 messages')
    assert node.values == list(range(600))
    assert node.loop.messages_taken == 600 and node.loop.faults == 4
    assert node.count_subscribers('/loop_test_topic') == 1
    node.loop.stop()
    assert node.count_subscribers('/loop_test_topic') == 0
    pub.publish(Int64(data=600))
    time.sleep(0.3)
    assert len(node.values) == 600
