"""The demo's and benches' private ROS domain: nodes inside it never meet the caller's graph."""

import os

from rclpy.node import Node
from std_srvs.srv import Trigger
import pytest

from pointforce_ros.bringup.domain import private_domain, private_domain_id
from pointforce_ros.bringup.launcher import InProcessLauncher


def _answer(request, response):
    response.success = True
    return response


def test_a_service_in_the_private_domain_is_unseen_by_the_callers_graph(ros_graph):
    outer = os.environ['ROS_DOMAIN_ID']
    with private_domain() as domain:
        assert os.environ['ROS_DOMAIN_ID'] == str(domain) != outer
        assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        with InProcessLauncher(threads=2) as inner:
            server = inner.add(Node('poke_server', context=inner.context))
            server.create_service(Trigger, '~/poke', _answer)
            # the same name from the caller's domain (the test's own): not there
            stranger = ros_graph.add(Node('planner', context=ros_graph.context))
            assert not stranger.create_client(Trigger, '/poke_server/poke').wait_for_service(
                timeout_sec=2.0)
            # from inside the private domain: found and answered
            friend = inner.add(Node('planner', context=inner.context))
            client = friend.create_client(Trigger, '/poke_server/poke')
            assert client.wait_for_service(timeout_sec=20.0)
            response = inner.wait_future(client.call_async(Trigger.Request()), 10, 'poke')
            assert response.success
    assert os.environ['ROS_DOMAIN_ID'] == outer


def test_a_chosen_domain_is_used_and_checked():
    saved = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
    with private_domain(42) as domain:
        assert domain == 42 and os.environ['ROS_DOMAIN_ID'] == '42'
        assert os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE') == saved
    with pytest.raises(ValueError, match='outside 0-232'):
        with private_domain(233):
            pass
    assert 100 <= private_domain_id(12345) < 200 and private_domain_id(7) != private_domain_id(8)
