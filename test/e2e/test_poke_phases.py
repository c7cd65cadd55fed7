"""Poke feedback names the phase (issue 21): approach, tare, push, hold, retract, in order.

The real ``ur_rtde`` drives the loopback RTDE emulator (a flat elastic top at z = 0.04 m,
k = 1000 N/m), as in ``test_poke_server.py``. Before, every feedback message said "push".
"""

import itertools

import numpy as np
import pytest
from pointforce_interfaces.action import Poke
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.parameter import Parameter

from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.types import PokeGoal

pytestmark = [pytest.mark.e2e, pytest.mark.ros]
SPRING = {'z0': 0.04, 'k': 1000.0}
START = [0.5, 0.0, 0.1, np.pi, 0.0, 0.0]
F = Poke.Feedback
PHASES = [F.PHASE_APPROACH, F.PHASE_TARE, F.PHASE_PUSH, F.PHASE_HOLD, F.PHASE_RETRACT]


@pytest.fixture
def poke_cell(ros_graph, start_emulator, tmp_path):
    emulator = start_emulator(force_model='pointforce_ros.sim.rtde.forces:HalfSpaceSpring',
                              force_model_kwargs=SPRING, initial_pose=START)
    server = ros_graph.add(PokeServerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('robot_ip', value=emulator.host),
        Parameter('store_dir', value=str(tmp_path / 'pokes'))]))
    client = ActionClient(ros_graph.add(Node('phase_client', context=ros_graph.context)), Poke,
                          '/poke_server/poke')
    assert client.wait_for_server(timeout_sec=30.0)
    return ros_graph, emulator, server, client


def _poke(graph, client, feedback, **overrides):
    values = dict(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0], force_limit=2.0,
                  depth_limit=0.008, speed=0.005, standoff=0.008)
    values.update(overrides)
    handle = graph.wait_future(client.send_goal_async(
        poke_goal_to_msg(PokeGoal(**values)), feedback_callback=lambda m: feedback.append(
            m.feedback)), 10, 'goal response')
    assert handle.accepted
    return graph.wait_future(handle.get_result_async(), 40, 'poke result')


def test_feedback_reports_each_phase_in_order_with_consistent_readings(poke_cell):
    graph, _, _, client = poke_cell
    feedback = []
    answer = _poke(graph, client, feedback)
    assert answer.result.outcome == Poke.Result.OUTCOME_FORCE_LIMIT, answer.result.message
    sequence = [phase for phase, _ in itertools.groupby(f.phase for f in feedback)]
    assert sequence == PHASES, sequence
    by_phase = {p: [f for f in feedback if f.phase == p] for p in PHASES}
    # approach and tare: the probe is out of contact, 8 mm above the surface
    for f in by_phase[F.PHASE_APPROACH][-1:] + by_phase[F.PHASE_TARE]:
        assert f.depth < -0.006 and abs(f.normal_force) < 0.3
    # the push streams feedback (feedback_rate 25 Hz over ~2 s) and reaches the force limit
    assert len(by_phase[F.PHASE_PUSH]) >= 10
    assert max(f.normal_force for f in by_phase[F.PHASE_PUSH]) > 1.0
    # hold begins at the limit: pressed in by F / k = 2 mm
    hold = by_phase[F.PHASE_HOLD][0]
    assert hold.normal_force >= 1.8 and hold.depth == pytest.approx(0.002, abs=0.0007)
    assert hold.samples > 0
    # the retract starts where the hold ended (still in contact), samples keep counting
    retract = by_phase[F.PHASE_RETRACT][0]
    assert retract.depth > 0.001 and retract.samples >= hold.samples


def test_a_canceled_poke_reports_the_same_phases(poke_cell):
    """Cancel mid-push: the arm stops (hold) and retracts, and the feedback says so."""
    graph, _, _, client = poke_cell
    feedback = []
    handles = []

    def on_feedback(msg):
        feedback.append(msg.feedback)
        if msg.feedback.depth > 0.0005 and not handles[0].get('sent'):
            handles[0]['sent'] = True
            handles[0]['handle'].cancel_goal_async()

    handles.append({})
    goal = poke_goal_to_msg(PokeGoal(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0],
                                     force_limit=8.0, depth_limit=0.012, speed=0.003,
                                     standoff=0.006))
    handle = graph.wait_future(client.send_goal_async(goal, feedback_callback=on_feedback), 10,
                               'goal response')
    handles[0]['handle'] = handle
    result = graph.wait_future(handle.get_result_async(), 40, 'poke result').result
    assert result.outcome == Poke.Result.OUTCOME_CANCELED, result.message
    sequence = [phase for phase, _ in itertools.groupby(f.phase for f in feedback)]
    assert sequence == PHASES, sequence
