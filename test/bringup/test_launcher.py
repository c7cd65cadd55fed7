"""The in-process launcher keeps spinning when a callback raises (issue 16, items 1 and 7).

A ``MemoryError`` that escaped one service callback ended the executor's only thread: every
node of ``pointforce cell`` stayed discoverable and never answered again.
"""

import pytest
from rclpy.node import Node
from std_srvs.srv import Trigger

from pointforce_ros.bringup.launcher import InProcessLauncher

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
        assert explode.wait_for_service(timeout_sec=15) and ping.wait_for_service(timeout_sec=15)
        for _ in range(3):
            explode.call_async(Trigger.Request())
        launcher.wait_for(lambda: len(launcher.faults) == 3, 15, 'three recorded faults')
        for _ in range(5):
            answer = clients.wait_future(ping.call_async(Trigger.Request()), 10, 'ping')
            assert answer.success and answer.message == 'pong'
        assert faulty.calls == 3
        assert all(isinstance(f[2], MemoryError) for f in launcher.faults)
        names = {f[1] for f in launcher.faults}
        assert names == ({'ros-executor-faulty'} if isolated else {'ros-executor'})
        assert len(launcher.alive()) == (2 if isolated else 1)
    assert launcher.alive() == []
