"""The in-process launcher keeps spinning when a callback raises (issue 16, items 1 and 7).

A ``MemoryError`` that escaped one service callback ended the executor's only thread: every
node of ``pointforce cell`` stayed discoverable and never answered again. And it stops cleanly:
no node is destroyed under a callback still running on an executor's thread pool.
"""

import logging
import threading
import time

import pytest
from pointforce_interfaces.action import Poke
from rclpy.action import ActionClient, ActionServer
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Trigger

from pointforce_ros.bringup.launcher import InProcessLauncher
from pointforce_ros.nodes.common import drain, DRAIN_TIMEOUT

pytestmark = pytest.mark.ros


class _Faulty(Node):
    """A node whose service raises ``error`` on every call."""

    def __init__(self, error, **kwargs):
        super().__init__('faulty', **kwargs)
        self.calls = 0

        def explode(request, response):
            self.calls += 1
            raise error
        self.create_service(Trigger, '~/explode', explode)


class _Healthy(Node):
    def __init__(self, **kwargs):
        super().__init__('healthy', **kwargs)
        self.create_service(Trigger, '~/ping', lambda req, resp: Trigger.Response(
            success=True, message='pong'))


@pytest.mark.parametrize('isolated', [False, True])
def test_a_callback_that_raises_memory_error_does_not_stop_the_other_nodes(isolated):
    with InProcessLauncher(threads=2) as launcher, InProcessLauncher(threads=2) as clients:
        faulty = launcher.add(_Faulty(MemoryError('cannot allocate 41.9 GiB'),
                                      context=launcher.context), isolated=isolated)
        launcher.add(_Healthy(context=launcher.context))
        caller = clients.add(Node('caller', context=clients.context))
        explode = caller.create_client(Trigger, '/faulty/explode')
        ping = caller.create_client(Trigger, '/healthy/ping')
        assert explode.wait_for_service(timeout_sec=30) and ping.wait_for_service(timeout_sec=30)
        for _ in range(3):
            explode.call_async(Trigger.Request())
        launcher.wait_for(lambda: len(launcher.faults) == 3, 30, 'three recorded faults')
        for _ in range(5):
            answer = clients.wait_future(ping.call_async(Trigger.Request()), 10, 'ping')
            assert answer.success and answer.message == 'pong'
        assert faulty.calls == 3
        assert all(isinstance(f[2], MemoryError) for f in launcher.faults)
        names = {f[1] for f in launcher.faults}
        assert names == ({'ros-executor-faulty'} if isolated else {'ros-executor'})
        assert len(launcher.alive()) == (2 if isolated else 1)
    assert launcher.alive() == []


class _Slow(Node):
    """A node whose service works for ``seconds`` and then publishes (its node must exist)."""

    def __init__(self, seconds, **kwargs):
        super().__init__('slow', **kwargs)
        self.started = threading.Event()
        self.outcome = []
        self.calls = 0
        publisher = self.create_publisher(String, '~/done', 10)

        def work(request, response):
            self.calls += 1
            self.started.set()
            time.sleep(seconds)
            try:
                publisher.publish(String(data='done'))
                self.outcome.append('published')
            except Exception as exc:  # noqa: BLE001 - the test records what close() did
                self.outcome.append(f'{type(exc).__name__}: {exc}')
            response.success = True
            return response
        self.create_service(Trigger, '~/work', work, callback_group=ReentrantCallbackGroup())


def _busy(launcher, clients, seconds, isolated):
    """Add a ``_Slow`` node to ``launcher``, call its service and return once it is working."""
    slow = launcher.add(_Slow(seconds, context=launcher.context), isolated=isolated)
    caller = clients.add(Node('caller', context=clients.context))
    work = caller.create_client(Trigger, '/slow/work')
    assert work.wait_for_service(timeout_sec=30.0)
    work.call_async(Trigger.Request())
    assert slow.started.wait(15)
    return slow


@pytest.mark.parametrize('isolated', [False, True])
def test_close_waits_for_a_callback_in_flight_before_destroying_its_node(isolated):
    # rclpy Jazzy's executor shutdown does not wait for the thread pool: the node used to be
    # destroyed under the running callback (InvalidHandle, "never retrieved" at exit)
    launcher = InProcessLauncher(threads=2)
    with InProcessLauncher(threads=2) as clients:
        slow = _busy(launcher, clients, 0.8, isolated)
        start = time.monotonic()
        launcher.close()
        waited = time.monotonic() - start
    assert slow.outcome == ['published']
    assert 0.3 < waited < DRAIN_TIMEOUT
    assert launcher.alive() == []


def test_drain_gives_up_after_its_timeout_and_says_so(caplog):
    launcher = InProcessLauncher(threads=2)
    with InProcessLauncher(threads=2) as clients:
        slow = _busy(launcher, clients, 3.0, True)
        executor = launcher._own[id(slow)]
        executor.shutdown(timeout_sec=0.0)
        with caplog.at_level(logging.ERROR):
            assert not drain(executor, 'ros-executor-slow', 0.2)
        assert 'still running' in caplog.text
        assert drain(executor, 'ros-executor-slow', 10.0)
        launcher.close()
    assert slow.outcome == ['published']


@pytest.mark.filterwarnings('ignore:MultiThreadedExecutor is used with a single thread')
def test_a_callback_queued_on_the_pool_at_close_still_runs_and_nothing_is_dropped(caplog):
    # A handler queued behind a busy pool used to start after Executor.shutdown had destroyed
    # the guard condition: InvalidHandle at its signal, the request it had taken dropped.
    launcher = InProcessLauncher(threads=1)   # one pool thread: the second call waits in line
    with InProcessLauncher(threads=2) as clients:
        slow = _busy(launcher, clients, 0.8, False)
        client = clients.nodes[-1].create_client(Trigger, '/slow/work')
        assert client.wait_for_service(timeout_sec=30.0)
        answer = client.call_async(Trigger.Request())
        launcher.wait_for(lambda: len(getattr(launcher.executor, '_futures', [])) >= 2, 10,
                          'the second call queued on the pool')
        with caplog.at_level(logging.WARNING):
            launcher.close()
        clients.wait_for(answer.done, 10, 'the queued call answered')
    assert slow.calls == 2 and slow.outcome == ['published', 'published']
    assert 'InvalidHandle' not in caplog.text and 'raised' not in caplog.text


def test_close_takes_every_participant_off_the_graph_action_servers_and_clients_included():
    """Closing a launcher removes its nodes from other participants' graphs at once.

    ``Node.destroy_node`` leaves action servers and clients alone, and their handles keep the
    node, and so its DDS participant, alive until garbage collection: a test suite collected
    dozens of such ghosts in one process, and once a run's 27th launcher could no longer
    discover its own poke server within 30 s (a CI failure).
    """
    with InProcessLauncher(threads=2) as observer:
        watcher = observer.add(Node('watcher', context=observer.context))
        launcher = InProcessLauncher(threads=2)
        server_node = launcher.add(Node('ghost_server', context=launcher.context))
        server = ActionServer(server_node, Poke, '~/poke', lambda handle: Poke.Result())
        client_node = launcher.add(Node('ghost_client', context=launcher.context))
        client = ActionClient(client_node, Poke, '/ghost_server/poke')
        ghosts = {'ghost_server', 'ghost_client'}
        observer.wait_for(lambda: ghosts <= set(watcher.get_node_names()), 30, 'both nodes')
        assert client.wait_for_server(timeout_sec=30)
        launcher.close()        # server and client stay referenced: no collector helps
        assert server not in list(server_node.waitables)
        assert client not in list(client_node.waitables)
        observer.wait_for(lambda: not ghosts & set(watcher.get_node_names()), 10,
                          'both nodes gone from the graph')
        launcher.close()        # a second close, as a with block after an explicit one
        assert not launcher.nodes and launcher.alive() == []
