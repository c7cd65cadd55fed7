"""Fault suite: 600 seeded malformed contact requests and 60 malformed poke goals (issue 16).

Each request goes through the node's own callback (message -> adapters -> core -> response),
in-process. Goals: 0 exceptions escaping, 0 answers over 5 s, 0 ``success=true`` answers that
hold non-finite or absurd values, every malformed request refused with a message; a valid request
answers bit-identically before and after the run. Every poke goal is rejected with nothing held.
"""

import time

import numpy as np
import pytest
from geometry_msgs.msg import Vector3
from pointforce_interfaces.action import Poke
from pointforce_interfaces.srv import ContactWrench, ContactWrenchBatch
from rclpy.action import GoalResponse
from rclpy.parameter import Parameter

from msg_adapters.geometry import mesh_to_msg, pose_to_msg, to_point
from msg_adapters.interfaces import poke_goal_to_msg
from pointforce_ros.bringup.bench_faults import ABSURD, good_request, HUGE, PLATE
from pointforce_ros.bringup.bench_faults import mutations as request_mutations
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.model.files import save_model
from pointforce_ros.nodes.contact_wrench import ContactWrenchNode
from pointforce_ros.nodes.poke_server import PokeServerNode
from pointforce_ros.pokes.limits import PokeLimits
from pointforce_ros.shapes import icosphere
from pointforce_ros.types import PokeGoal, Pose, Surface

from idle_arm import IdleArm  # noqa: I100 - the test helper beside this file

pytestmark = pytest.mark.ros
SPHERE = icosphere(0.02, 2)
"""The valid query's probe (the bench's ``good_request`` presses the same sphere)."""


def _check(response, failures, label):
    if response.success:
        w = response.wrench
        values = np.array([w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y,
                           w.torque.z, response.max_displacement])
        if not np.all(np.isfinite(values)) or np.max(np.abs(values[:6])) > ABSURD:
            failures.append(f'{label}: success with {values.tolist()}')
        else:
            failures.append(f'{label}: malformed request answered')
    elif not response.message or 'Wrench.' in response.message:
        failures.append(f'{label}: refusal without a reason about the request: '
                        f'{response.message!r}')


@pytest.fixture
def node(ros_graph, tmp_path):
    save_model(patch_contact_model(spacing=0.003), tmp_path / 'models')
    return ros_graph.add(ContactWrenchNode(
        context=ros_graph.context,
        parameter_overrides=[Parameter('model_dir', value=str(tmp_path / 'models'))]))


def test_600_malformed_contact_requests_are_refused_and_nothing_changes(node):
    rng = np.random.default_rng(16)
    mutations = request_mutations(rng)
    before = node._on_single(good_request(), ContactWrench.Response())
    assert before.success, before.message
    failures, slowest, refused = [], 0.0, 0
    for i in range(520):
        request = good_request()
        picks = rng.choice(len(mutations), size=int(rng.integers(1, 4)), replace=False)
        for k in picks:
            mutations[k](request)
        start = time.perf_counter()
        response = node._on_single(request, ContactWrench.Response())
        slowest = max(slowest, time.perf_counter() - start)
        refused += not response.success
        _check(response, failures, f'single {i} ({[mutations[k].__name__ for k in picks]})')
    for i in range(80):
        request = ContactWrenchBatch.Request(mesh=mesh_to_msg(SPHERE),
                                             approach=Vector3(x=0.0, y=0.0, z=-1.0),
                                             torque_centre=to_point([0.5, 0.0, 0.06]))
        request.poses = [pose_to_msg(Pose(position=[0.5, 0.0, 0.06 - d]))
                         for d in rng.uniform(0.0, 0.004, int(rng.integers(1, 40)))]
        kind = i % 4
        if kind == 0:
            request.poses = []
        elif kind == 1:
            request.mesh = mesh_to_msg(PLATE)
            request.poses = [pose_to_msg(Pose(position=[0.5, 0.0, 0.045]))] * 1000
        else:   # one bad pose among good ones, at a random place
            bad = request.poses[int(rng.integers(len(request.poses)))]
            if kind == 2:
                setattr(bad.position, rng.choice(('x', 'y', 'z')), float(rng.choice(HUGE)))
            else:
                bad.position.z = -0.96
        start = time.perf_counter()
        response = node._on_batch(request, ContactWrenchBatch.Response())
        slowest = max(slowest, time.perf_counter() - start)
        refused += not response.success
        if response.success:
            failures.append(f'batch {i} (kind {kind}): malformed batch answered')
        elif not response.message:
            failures.append(f'batch {i}: refusal without a reason')
    after = node._on_single(good_request(), ContactWrench.Response())
    print(f'600 malformed contact requests: {refused} refused, slowest {1e3 * slowest:.0f} ms')
    assert not failures, failures[:5]
    assert refused == 600 and node.requests_failed == 600
    assert slowest < 5.0
    assert after.success and after.model_version == before.model_version
    got = [after.wrench.force.x, after.wrench.force.y, after.wrench.force.z,
           after.wrench.torque.x, after.wrench.torque.y, after.wrench.torque.z]
    want = [before.wrench.force.x, before.wrench.force.y, before.wrench.force.z,
            before.wrench.torque.x, before.wrench.torque.y, before.wrench.torque.z]
    assert got == want   # bit-identical


class _NoArm(IdleArm):
    def __init__(self, host):
        super().__init__(host)
        self.pushes = 0


def _goals(rng):
    base = dict(point=[0.5, 0.0, 0.04], normal=[0.0, 0.0, 1.0], force_limit=3.0,
                depth_limit=0.008, speed=0.005, standoff=0.008)
    tilt = np.radians(rng.uniform(35, 89))
    bad = [
        {'normal': [0.0, 0.0, -1.0]}, {'normal': [1.0, 0.0, 0.0]},
        {'normal': [np.sin(tilt), 0.0, np.cos(tilt)]}, {'normal': [0.0, 0.0, 0.5]},
        {'point': [0.5, 0.0, 0.07]}, {'point': [0.5, 0.0, 0.0375], 'standoff': 0.004},
        {'surface_index': int(rng.integers(-2 ** 31, -1))}, {'surface_index': 30},
        {'surface_index': 2 ** 31 - 1}, {'force_limit': float(rng.choice([0.0, -1.0, 50.0]))},
        {'depth_limit': float(rng.choice([0.0, -0.001, 0.5]))},
        {'speed': float(rng.choice([0.0, -0.01, 1.0]))},
        {'standoff': float(rng.choice([0.0, 0.001, 0.2]))},
        {'point': [float(rng.choice([0.1, 0.95])), 0.0, 0.04]},
    ]
    for _ in range(60):
        values = dict(base)
        values.update(bad[int(rng.integers(len(bad)))])
        yield poke_goal_to_msg(PokeGoal(**values))
    for field in ('point', 'normal'):   # non-finite fields cannot be built as a PokeGoal
        message = poke_goal_to_msg(PokeGoal(**base))
        getattr(message, field).x = float('nan')
        yield message


def test_60_malformed_poke_goals_are_rejected_and_the_lock_stays_free(ros_graph, tmp_path):
    server = ros_graph.add(PokeServerNode(
        arm_factory=_NoArm, context=ros_graph.context,
        parameter_overrides=[Parameter('store_dir', value=str(tmp_path / 'pokes'))]))
    points = np.column_stack([np.linspace(0.45, 0.55, 30), np.zeros(30), np.full(30, 0.04)])
    server.surface = Surface(points=points, normals=np.tile([0, 0, 1.0], (30, 1)))
    assert server.limits == PokeLimits()
    rejected = 0
    for goal in _goals(np.random.default_rng(16)):
        assert isinstance(goal, Poke.Goal)
        rejected += server._on_goal(goal) == GoalResponse.REJECT
        assert not server._busy.locked()
    print(f'62 malformed poke goals: {rejected} rejected')
    assert rejected == 62
