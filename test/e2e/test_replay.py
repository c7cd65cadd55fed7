"""Bag replay: committed poke bags, republished over DDS, teach the learner the offline model."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from pointforce_interfaces.msg import ModelStatus
from rclpy.node import Node
from rclpy.parameter import Parameter

from pointforce_ros.errors import DataError
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.model.files import load_model, save_surface
from pointforce_ros.bringup.replay import bag_paths, replay
from pointforce_ros.nodes.stiffness_learner import LATCHED, StiffnessLearnerNode
from pointforce_ros.pokes.store import read_poke_bag
from pointforce_ros.types import Surface

pytestmark = [pytest.mark.e2e, pytest.mark.ros]
BAGS = Path(__file__).resolve().parents[1] / 'data' / 'bags' / 'pokes'


def _surface():
    xs, ys = np.meshgrid(np.linspace(0.47, 0.53, 13), np.linspace(-0.03, 0.03, 13))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    return Surface(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1)))


def test_replayed_bags_give_the_offline_model(ros_graph, tmp_path):
    surface = _surface()
    save_surface(surface, tmp_path / 'surface.npz')
    offline = OnlineLearner(BAGS, tmp_path / 'offline_models', surface,
                            shape_constant=0.004).update()
    assert offline.num_pokes == 4
    ros_graph.add(StiffnessLearnerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('store_dir', value=str(tmp_path / 'recorded')),
        Parameter('model_dir', value=str(tmp_path / 'models')),
        Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
        Parameter('record_topics', value=True), Parameter('poll_period', value=600.0)]))
    player = ros_graph.add(Node('player', context=ros_graph.context))
    statuses = []
    player.create_subscription(ModelStatus, '/stiffness_learner/model', statuses.append, LATCHED)
    count = replay(player, BAGS, rate=2.0, progress=lambda line: None)
    expected = sum(len(offline_store_record) for offline_store_record in
                   (read_poke_bag(p) for p in bag_paths(BAGS)))
    assert count == 2 * expected + 4  # pose + wrench per sample, one poke_record per poke
    ros_graph.wait_for(lambda: statuses and statuses[-1].version == 4, 90, 'model v4')
    live = load_model(statuses[-1].model_path).response
    np.testing.assert_allclose(live.forces, load_model(offline.model_path).response.forces,
                               rtol=1e-7, atol=1e-7)


def test_missing_and_corrupt_bags_are_clear_errors(tmp_path, ros_graph):
    with pytest.raises(DataError, match='no such bag'):
        bag_paths(tmp_path / 'nothing')
    (tmp_path / 'notes.txt').write_text('not a bag')
    with pytest.raises(DataError, match='not a bag directory'):
        bag_paths(tmp_path / 'notes.txt')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(DataError, match='holds no rosbag2 bag'):
        bag_paths(tmp_path / 'empty')
    bad = tmp_path / 'bad' / 'poke-000001'
    shutil.copytree(BAGS / 'poke-000001', bad)
    mcap = next(bad.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:500])
    node = ros_graph.add(Node('bad_player', context=ros_graph.context))
    with pytest.raises(DataError, match='poke-000001'):
        replay(node, bad, rate=100.0, wait_subscribers=0.0, progress=lambda line: None)
