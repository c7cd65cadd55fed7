"""stiffness_learner over DDS: refits on poke_landed, latched model, restart, suggestions."""

import dataclasses
import json

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pointforce_interfaces.msg import ModelStatus
from pointforce_interfaces.srv import SuggestPoke
from rcl_interfaces.srv import SetParameters
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from pointforce_ros.contact import ContactSimulator
from pointforce_ros.contact.simulator import DECAY_LAW
from pointforce_ros.effects.accepted import effects_to_dict
from pointforce_ros.errors import DataError
from pointforce_ros.effects.forward import model_surface
from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.model.files import load_model, save_surface
from pointforce_ros.nodes.stiffness_learner import LATCHED, RELIABLE, StiffnessLearnerNode
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.response.ours import PRODUCT_SPREAD
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


class LearnerProbe:
    """A client of the learner: its published model statuses and a parameter setter."""

    def __init__(self, graph, name: str):
        self.graph = graph
        node = graph.add(Node(name, context=graph.context))
        self.statuses = []
        node.create_subscription(ModelStatus, '/stiffness_learner/model', self.statuses.append,
                                 LATCHED)
        self.client = node.create_client(SetParameters, '/stiffness_learner/set_parameters')

    def wait_version(self, version: int):
        """Wait for the model ``version``; return its status."""
        self.graph.wait_for(lambda: self.statuses and self.statuses[-1].version == version, 30,
                            f'model v{version}')
        return self.statuses[-1]

    def set(self, name: str, value):
        """Set one learner parameter over its service; return the SetParametersResult."""
        assert self.client.wait_for_service(timeout_sec=30.0)
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()])
        return self.graph.wait_future(self.client.call_async(request), 20, name).results[0]


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
    assert client.wait_for_service(timeout_sec=30.0)
    bad = ros_graph.wait_future(client.call_async(SuggestPoke.Request(count=0)), 20, 'bad')
    assert not bad.success and 'count' in bad.message
    good = ros_graph.wait_future(client.call_async(SuggestPoke.Request(count=2)), 20, 'good')
    assert good.success and len(good.points) == 2
    assert good.header.frame_id == 'base' and good.header.stamp.sec > 0   # issue 21: stamped
    ros_graph.remove(learner)  # the node is killed
    statuses.clear()
    _learner(ros_graph, tmp_path)
    ros_graph.wait_for(lambda: statuses and statuses[-1].version == 5, 30, 'model after restart')
    np.testing.assert_allclose(load_model(statuses[-1].model_path).response.forces, before,
                               rtol=1e-9, atol=1e-9)


def test_shape_constant_set_at_run_time_saves_a_new_model(ros_graph, tmp_path):
    _setup(tmp_path)
    _learner(ros_graph, tmp_path)
    probe = LearnerProbe(ros_graph, 'c_probe')
    statuses = probe.statuses
    first = load_model(probe.wait_version(4).model_path)

    def set_c(value, name='shape_constant'):
        return probe.set(name, value)

    assert not set_c(0.5).successful            # outside [1e-4, 0.1] m: refused
    assert statuses[-1].version == 4
    assert set_c(0.0007).successful
    ros_graph.wait_for(lambda: statuses[-1].version == 5, 30, 'model v5 with the new c')
    second = load_model(statuses[-1].model_path)
    assert second.shape_constant == pytest.approx(0.0007)
    assert first.shape_constant != pytest.approx(0.0007)
    # same pokes, same response: only the shape constant changed
    np.testing.assert_allclose(second.response.forces, first.response.forces)
    assert np.isinf(second.shape_decay)
    # the tail's decay length: saved with the model, 0 turns it off again
    assert not set_c(-0.01, 'shape_decay').successful
    assert set_c(0.008, 'shape_decay').successful
    ros_graph.wait_for(lambda: statuses[-1].version == 6, 30, 'model v6 with a decay length')
    third = load_model(statuses[-1].model_path)
    assert (third.shape_constant, third.shape_decay) == pytest.approx((0.0007, 0.008))
    assert set_c(0.0, 'shape_decay').successful
    ros_graph.wait_for(lambda: statuses[-1].version == 7, 30, 'model v7 without')
    assert np.isinf(load_model(statuses[-1].model_path).shape_decay)


def test_a_shape_update_survives_a_restart_and_the_saved_version_is_published(
        ros_graph, tmp_path):
    """Issue 16 item 8: c was lost on restart and the node published the version it asked for.

    After c, L, the near field and the decay law are set at run time (v5-v8) the learner is
    killed, a fifth poke lands and the learner restarts: it must use the persisted shape, and its
    model (5 pokes, requested as v5, a version taken by other content) is saved as v9, the
    version it must publish.
    """
    store, records = _setup(tmp_path)
    learner = _learner(ros_graph, tmp_path)
    probe = LearnerProbe(ros_graph, 'shape_probe')
    statuses = probe.statuses
    probe.wait_version(4)
    refused = probe.set('shape_near', 'round')       # not a near field: refused by name
    assert not refused.successful and 'shape_near' in refused.reason
    refused = probe.set('shape_decay_law', 'depth')  # not a decay law: refused by name
    assert not refused.successful and 'shape_decay_law' in refused.reason
    assert load_model(statuses[-1].model_path).shape_decay_law == DECAY_LAW != 'layer'
    for name, value, version in [('shape_constant', 0.0007, 5), ('shape_decay', 0.008, 6),
                                 ('shape_near', 'flat', 7), ('shape_decay_law', 'layer', 8)]:
        assert probe.set(name, value).successful
        probe.wait_version(version)
    last = load_model(statuses[-1].model_path)
    assert (last.shape_near, last.shape_decay_law) == ('flat', 'layer')
    ros_graph.remove(learner)  # the node is killed
    store.add(records[4])
    statuses.clear()
    restarted = _learner(ros_graph, tmp_path)
    ros_graph.wait_for(lambda: statuses and statuses[-1].num_pokes == 5, 30, 'model after restart')
    status = statuses[-1]
    model = load_model(status.model_path)
    assert (model.shape_constant, model.shape_decay) == pytest.approx((0.0007, 0.008))
    assert (model.shape_near, model.shape_decay_law) == ('flat', 'layer')
    assert status.version == model.version == 9, (status.version, status.model_path)
    assert status.model_path.endswith('model-v000009.npz')
    assert restarted.get_parameter('shape_constant').value == pytest.approx(0.0007)
    assert restarted.get_parameter('shape_decay').value == pytest.approx(0.008)
    assert restarted.get_parameter('shape_near').value == 'flat'
    assert restarted.get_parameter('shape_decay_law').value == 'layer'


def test_uncertainty_sources_go_into_every_model_and_survive_a_restart(ros_graph, tmp_path):
    """Issue 17: the calibration's (c, L) covariance and shares reach the contact service."""
    store, records = _setup(tmp_path)
    learner = _learner(ros_graph, tmp_path)
    probe = LearnerProbe(ros_graph, 'uncertainty_probe')
    statuses = probe.statuses
    assert 'shape_cov' not in load_model(probe.wait_version(4).model_path).meta
    refused = probe.set('shape_cov', [0.04, 0.5, -0.5, 400.0])      # not symmetric
    assert not refused.successful and 'symmetric' in refused.reason
    assert probe.set('shape_cov', [0.04, 0.5, 0.5, 400.0]).successful
    probe.wait_version(5)
    assert probe.set('relative_std', 0.07).successful
    probe.wait_version(6)
    meta = load_model(statuses[-1].model_path).meta
    assert meta['shape_cov'] == [[0.04, 0.5], [0.5, 400.0]] and meta['relative_std'] == 0.07
    ros_graph.remove(learner)  # the node is killed
    store.add(records[4])
    statuses.clear()
    restarted = _learner(ros_graph, tmp_path)
    ros_graph.wait_for(lambda: statuses and statuses[-1].num_pokes == 5, 30, 'model after restart')
    meta = load_model(statuses[-1].model_path).meta
    assert meta['shape_cov'] == [[0.04, 0.5], [0.5, 400.0]] and meta['relative_std'] == 0.07
    assert list(restarted.get_parameter('shape_cov').value) == [0.04, 0.5, 0.5, 400.0]


# --------------------------------------------------------------------------- accepted effects

SPOTS = np.array([[0.491, -0.01, 0.04], [0.511, 0.01, 0.04], [0.491, 0.015, 0.04]])
PLASTIC = {'plastic_set': {'max_set': 0.0008, 'n0': 3.0, 'radius': 0.004}}


def _plastic_setup(tmp_path):
    """Three spots poked five times under config/scenarios/plastic_set.yaml (0.8 mm set).

    The first four rounds are stored for the learner; the fifth round is held out.
    """
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 36), np.linspace(-0.035, 0.035, 36))
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    save_surface(Surface(points=pts, normals=np.tile([0.0, 0.0, 1.0], (len(pts), 1))),
                 tmp_path / 'surface.npz')
    records = simulate_campaign(OBJECT, load_scenario('plastic_set'), points=SPOTS,
                                normals=np.tile([0.0, 0.0, 1.0], (3, 1)), repeats=5, seed=3,
                                force_limit=3.0, depth_limit=0.01, speed=0.004, gap=0.5)
    store = PokeStore(tmp_path / 'pokes')
    for r in records[:12]:
        store.add(r)
    return records[12:]


def _learn(graph, tmp_path, effects_file):
    statuses = []
    probe = graph.add(Node(f'probe_{tmp_path.name}', context=graph.context))
    probe.create_subscription(ModelStatus, '/stiffness_learner/model', statuses.append, LATCHED)
    node = graph.add(StiffnessLearnerNode(context=graph.context, parameter_overrides=[
        Parameter('store_dir', value=str(tmp_path / 'pokes')),
        Parameter('model_dir', value=str(tmp_path / 'models')),
        Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
        Parameter('effects_file', value=str(effects_file)),
        Parameter('poll_period', value=600.0)]))
    graph.wait_for(lambda: statuses and statuses[-1].version == 12, 60, 'model v12')
    status = statuses[-1]
    shape_constant = node.get_parameter('shape_constant').value
    graph.remove(node)
    graph.remove(probe)
    return status, load_model(status.model_path), shape_constant


def _heldout_rmse(model, records):
    """Normal-force RMSE (N) of a point probe at the held-out pokes' tips, loading phase.

    Answered by the contact simulator on the surface the contact service uses.
    """
    sim = ContactSimulator(model_surface(model), model.response, model.shape_constant)
    err = []
    for r in records:
        top = int(np.argmax(r.displacement()))
        for i in range(0, top, 4):
            tip = r.tcp_pose[i, :3]
            force = sim.query_points(tip[None], -r.normal, tip).wrench.force
            err.append(force @ r.normal - r.normal_force()[i])
    return float(np.sqrt(np.mean(np.square(err))))


def test_effects_file_corrects_the_pokes_and_lowers_the_heldout_error(ros_graph, tmp_path):
    results = {}
    for name, effects in (('plain', None), ('effects', PLASTIC), ('broken', 'broken')):
        folder = tmp_path / name
        folder.mkdir()
        held = _plastic_setup(folder)
        path = ''
        if effects == 'broken':
            path = folder / 'effects.json'
            path.write_text(json.dumps({'plastic_set': {'max_set': 'deep'}}))
        elif effects:
            path = folder / 'effects.json'
            path.write_text(json.dumps(effects_to_dict(effects)))
        status, model, _ = _learn(ros_graph, folder, path)
        results[name] = (status, model, _heldout_rmse(model, held))
    plain, corrected, broken = results['plain'], results['effects'], results['broken']
    assert list(corrected[0].effects) == ['plastic_set'] and list(plain[0].effects) == []
    assert corrected[1].effects == effects_to_dict(PLASTIC)
    assert corrected[1].meta['surface_corrected'] == ['plastic_set']
    # the model surface sank by the set after four pokes at each spot, elsewhere it did not
    z = corrected[1].surface.points[:, 2]
    near = np.min(np.linalg.norm(corrected[1].surface.points[:, None, :2] - SPOTS[None, :, :2],
                                 axis=2), axis=1) < 0.004
    np.testing.assert_allclose(0.04 - z[near], 0.0008 * -np.expm1(-4 / 3.0), rtol=1e-9)
    np.testing.assert_array_equal(z[~near], 0.04)
    # held-out fifth pokes: the set moved their onset 0.59 mm deeper than the first poke's;
    # the plain learner averaged onsets over four pokes, the corrected one knows where it is
    assert plain[2] > 0.05
    assert corrected[2] < 0.2 * plain[2]
    # a bad effects file: error logged, the node learns without effects (same as plain)
    assert list(broken[0].effects) == [] and broken[1].effects == {}
    assert broken[2] == pytest.approx(plain[2], rel=1e-6)


def test_a_shape_constant_in_the_effects_file_sets_the_parameter_and_model(ros_graph, tmp_path):
    _plastic_setup(tmp_path)
    path = tmp_path / 'effects.json'
    path.write_text(json.dumps({'spatial_coupling': {'shape_constant': 0.0021}}))
    status, model, shape_constant = _learn(ros_graph, tmp_path, path)
    assert shape_constant == pytest.approx(0.0021)
    assert model.shape_constant == pytest.approx(0.0021)


@pytest.mark.parametrize('spread', [None, 'gp', 'trees'])
def test_the_point_spread_parameter_chooses_how_the_laws_are_spread(ros_graph, tmp_path, spread):
    _setup(tmp_path)
    overrides = [Parameter('store_dir', value=str(tmp_path / 'pokes')),
                 Parameter('model_dir', value=str(tmp_path / 'models')),
                 Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
                 Parameter('poll_period', value=600.0)]
    if spread is not None:
        overrides.append(Parameter('point_spread', value=spread))
    node = ros_graph.add(StiffnessLearnerNode(context=ros_graph.context,
                                              parameter_overrides=overrides))
    probe = LearnerProbe(ros_graph, f'spread_probe_{spread or "default"}')
    saved = load_model(probe.wait_version(4).model_path)
    spread = spread or PRODUCT_SPREAD      # unset: the product's, both processes and trees
    assert saved.response.meta['spread'] == spread
    assert node.learner.model.spread == spread
    assert np.all(np.isfinite(saved.response.forces)) and saved.response.forces.max() > 0


@pytest.mark.parametrize('threshold, learned', [(None, 4), (0.3, 0)])
def test_soft_pokes_are_learned_by_default_and_skipped_under_a_fixed_threshold(
        ros_graph, tmp_path, threshold, learned):
    # pokes stopped at 0.25 N (a soft region): far above their own noise, below the old
    # fixed 0.3 N threshold, which skipped every one of them (issue 17)
    _setup(tmp_path)
    soft = simulate_campaign(OBJECT, load_scenario('clean'), count=4, seed=5,
                             force_limit=0.25, depth_limit=0.01, speed=0.004, gap=0.5)
    store = PokeStore(tmp_path / 'soft')
    for r in soft:
        store.add(r)
    overrides = [Parameter('store_dir', value=str(tmp_path / 'soft')),
                 Parameter('model_dir', value=str(tmp_path / 'models')),
                 Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
                 Parameter('poll_period', value=600.0)]
    if threshold is not None:
        overrides.append(Parameter('min_peak_force', value=threshold))
    node = ros_graph.add(StiffnessLearnerNode(context=ros_graph.context,
                                              parameter_overrides=overrides))
    ros_graph.wait_for(lambda: node.learner is not None
                       and len(node.learner.curves) + len(node.learner.skipped) >= 4, 30,
                       'every poke considered')
    assert len(node.learner.curves) == learned, node.learner.skipped


def test_diagnostics_say_what_the_learner_lacks_and_which_pokes_it_skipped(
        ros_graph, tmp_path, monkeypatch):
    """``/diagnostics`` (1 Hz): WARN with no model yet, OK with one, WARN naming a poke that
    could not be learned, ERROR for an update that failed."""
    _, records = _setup(tmp_path)                   # the surface; the pokes go in one by one
    store = PokeStore(tmp_path / 'fresh')
    node = ros_graph.add(StiffnessLearnerNode(context=ros_graph.context, parameter_overrides=[
        Parameter('store_dir', value=str(tmp_path / 'fresh')),
        Parameter('model_dir', value=str(tmp_path / 'models')),
        Parameter('surface_file', value=str(tmp_path / 'surface.npz')),
        Parameter('poll_period', value=600.0)]))
    probe = ros_graph.add(Node('health_probe', context=ros_graph.context))
    got = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda m: got.extend(
        s for s in m.status if s.name == 'stiffness_learner: stiffness learner'), 10)

    def report(what, level, text):
        """The first report at ``level`` since ``got`` was last cleared (a report says what
        changed since the one before, so clear before the change)."""
        try:
            ros_graph.wait_for(lambda: any(s.level == level for s in got), 10, what)
        except RuntimeError as exc:
            raise AssertionError(f'{what}: {[(s.level, s.message) for s in got[-2:]]}') from exc
        status = next(s for s in got if s.level == level)
        assert text in status.message, status.message
        got.clear()
        return {v.key: v.value for v in status.values}

    report('no model yet', DiagnosticStatus.WARN, 'no model yet')
    got.clear()
    for record in records[:3]:
        store.add(record)
    node.refit()
    values = report('a model', DiagnosticStatus.OK, 'model v3 from 3 pokes')
    assert values['pokes'] == '3' and float(values['prequential_rmse_n']) > 0
    air = dataclasses.replace(simulate_campaign(
        OBJECT, load_scenario('clean'), points=[[0.5, 0.0, 0.07]], normals=[[0.0, 0.0, 1.0]],
        force_limit=3.0, depth_limit=0.005, speed=0.004)[0], poke_id=store.next_id())
    got.clear()
    store.add(air)                          # a push into the air: no contact to learn from
    node.refit()
    report('a skipped poke', DiagnosticStatus.WARN, f'newest {air.poke_id}: ')
    report('OK again', DiagnosticStatus.OK, 'model v3')

    def fails():
        raise DataError('poke store index unreadable (injected)')
    monkeypatch.setattr(node.learner, 'update', fails)
    got.clear()
    node.refit()
    report('a failed update', DiagnosticStatus.ERROR, 'index unreadable (injected)')
