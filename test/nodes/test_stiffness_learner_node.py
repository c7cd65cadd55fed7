"""stiffness_learner over DDS: refits on poke_landed, latched model, restart, suggestions."""

import numpy as np
import pytest
from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import SuggestPoke
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from pointforce_ros.cell.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.cell.session import halfspace_object, simulate_campaign
from pointforce_ros.model_io import load_model, save_surface
from pointforce_ros.nodes.stiffness_learner import LATCHED, RELIABLE, StiffnessLearnerNode
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.types import Surface

pytestmark = pytest.mark.ros
OBJECT = halfspace_object(HalfSpaceContact(z0=0.04, ripple=0.3),
                          region=((0.47, 0.53), (-0.03, 0.03)))


def _setup(tmp_path):
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 15), np.linspace(-0.035, 0.035, 15))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    save_surface(Surface(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1))),
                 tmp_path / 'surface.npz')
    records = simulate_campaign(OBJECT, load_scenario('clean'), count=5, seed=3,
                                force_limit=3.0, depth_limit=0.01, speed=0.004, gap=0.5)
    store = PokeStore(tmp_path / 'pokes')
    for r in records[:4]:
        store.add(r)
    return store, records


def _learner(graph, tmp_path):
    return graph.add(StiffnessLearnerNode(context=graph.context, parameter_overrides=[
        Parameter('store_dir', value=str(tmp_path / 'pokes')),
        Parameter('model_dir', value=str(tmp_path / 'models')),
        Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
        Parameter('poll_period', value=600.0)]))


def test_refit_on_landed_poke_survives_restart_and_suggests(ros_graph, tmp_path):
    store, records = _setup(tmp_path)
    learner = _learner(ros_graph, tmp_path)
    probe = ros_graph.add(Node('learner_probe', context=ros_graph.context))
    statuses = []
    probe.create_subscription(ModelStatus, '/stiffness_learner/model', statuses.append, LATCHED)
    ros_graph.wait_for(lambda: statuses and statuses[-1].version == 4, 30, 'model v4')
    store.add(records[4])
    landed = probe.create_publisher(String, '/poke_server/poke_landed', RELIABLE)
    ros_graph.wait_for(lambda: landed.get_subscription_count() > 0, 10, 'learner subscription')
    landed.publish(String(data=records[4].poke_id))
    ros_graph.wait_for(lambda: statuses[-1].version == 5, 30, 'model v5')
    v5 = statuses[-1]
    assert v5.num_pokes == 5 and np.isfinite(v5.validation_rmse)
    before = load_model(v5.model_path).response.forces
    client = probe.create_client(SuggestPoke, '/stiffness_learner/suggest_poke')
    assert client.wait_for_service(timeout_sec=10)
    bad = ros_graph.wait_future(client.call_async(SuggestPoke.Request(count=0)), 20, 'bad')
    assert not bad.success and 'count' in bad.message
    ros_graph.remove(learner)  # the node is killed
    statuses.clear()
    _learner(ros_graph, tmp_path)
    ros_graph.wait_for(lambda: statuses and statuses[-1].version == 5, 30, 'model after restart')
    np.testing.assert_allclose(load_model(statuses[-1].model_path).response.forces, before,
                               rtol=1e-9, atol=1e-9)
