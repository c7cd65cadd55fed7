"""Online learner over a poke store: refits as pokes land, restart gives the same model."""

import dataclasses
import threading

import numpy as np
import pytest

from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.effects.library import count_earlier
from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.model import learner as learner_module
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.model.files import load_model
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.response.ours import ContactGpModel, PRODUCT_SPREAD
from pointforce_ros.types import PokeRecord, Surface

CONTACT = HalfSpaceContact(z0=0.04, k0=1.4e4, exponent=1.5, ripple=0.4, wavelength=0.06)
OBJECT = halfspace_object(CONTACT, region=((0.47, 0.53), (-0.03, 0.03)))


def _surface():
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 24), np.linspace(-0.035, 0.035, 24))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    return Surface(points=points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))


def _campaign(count, seed, id_prefix):
    return simulate_campaign(OBJECT, load_scenario('clean'), count=count, seed=seed,
                             force_limit=4.0, depth_limit=0.01, speed=0.004, gap=0.5,
                             id_prefix=id_prefix)


def _stored_learner(tmp_path, count: int, seed: int):
    """A store holding ``count`` clean pokes and an (unfitted) learner on it."""
    store = PokeStore(tmp_path / 'pokes')
    for record in _campaign(count, seed=seed, id_prefix='poke-0'):
        store.add(record)
    surface = _surface()
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface,
                            shape_constant=0.004)
    return store, surface, learner


def test_refits_as_pokes_land_and_restart_reproduces_the_model(tmp_path):
    store, surface, learner = _stored_learner(tmp_path, 5, seed=1)
    with pytest.raises(ModelNotReady):
        learner.suggest(1)
    first = learner.update()
    assert first.version == 5 and first.num_pokes == 5 and not first.skipped
    assert learner.update() is None  # nothing new
    for record in _campaign(3, seed=2, id_prefix='poke-1'):
        store.add(record)
    second = learner.update()
    assert second.version == 8
    # each new poke was predicted by the model before it: a held-out error, well below the
    # 4 N force scale but above the training error
    assert 0.0 < second.validation_rmse < 1.0
    assert second.training_rmse < second.validation_rmse
    saved = load_model(second.model_path)
    assert saved.version == 8 and len(saved.surface) == len(surface)
    # the deepest the 8 pokes pressed (depth limit 10 mm), for the service's extrapolation note
    deepest = max(float(np.max(c.d)) for c in learner.curves)
    assert saved.meta['learned_depth'] == pytest.approx(deepest, rel=1e-12)
    assert 0.003 < deepest < 0.013
    # past it the served table's std grows (BakedResponse.with_extrapolation), not before it
    own = learner.model.bake(surface, learner.depths).std
    past = saved.response.depths > deepest
    np.testing.assert_allclose(saved.response.std[:, ~past], own[:, ~past], rtol=1e-9,
                               atol=1e-12)
    grown = saved.response.std[:, past] - own[:, past]
    assert np.all(grown >= -1e-12) and np.median(grown[:, -1]) > 0.05
    restarted = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface,
                              shape_constant=0.004)
    again = restarted.update()
    assert again.version == 8
    np.testing.assert_allclose(load_model(again.model_path).response.forces,
                               saved.response.forces, rtol=1e-9, atol=1e-9)


def test_learned_stiffness_follows_the_true_field(tmp_path):
    store = PokeStore(tmp_path / 'pokes')
    for record in _campaign(12, seed=4, id_prefix='poke-0'):
        store.add(record)
    surface = _surface()
    status = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface,
                           shape_constant=0.004).update()
    baked = load_model(status.model_path).response
    depth = 0.004
    k = np.argmin(np.abs(baked.depths - depth))
    truth = np.array([CONTACT(np.array([p[0], p[1], 0.04 - baked.depths[k]]),
                              np.array([0.0, 0.0, -1.0]))[0][2] for p in surface.points])
    inside = (np.abs(surface.points[:, 0] - 0.5) < 0.025) & (np.abs(surface.points[:, 1]) < 0.025)
    corr = np.corrcoef(baked.forces[inside, k], truth[inside])[0, 1]
    assert corr > 0.7


def test_unusable_poke_is_skipped_with_a_reason(tmp_path):
    store = PokeStore(tmp_path / 'pokes')
    records = _campaign(3, seed=5, id_prefix='poke-0')
    for record in records:
        store.add(record)
    mcap = next((tmp_path / 'pokes' / records[1].poke_id).glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:200])
    status = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', _surface(),
                           shape_constant=0.004).update()
    assert status.num_pokes == 2 and records[1].poke_id in status.skipped


def test_no_contact_poke_is_skipped_and_suggestions_stay_on_pokeable_points(tmp_path):
    store = PokeStore(tmp_path / 'pokes')
    records = _campaign(3, seed=6, id_prefix='poke-0')
    for record in records:
        store.add(record)
    # a poke 30 mm beside the object: the probe meets nothing
    miss = simulate_campaign(OBJECT, load_scenario('clean'), points=[[0.5, 0.0, 0.07]],
                             normals=[[0.0, 0.0, 1.0]], force_limit=4.0, depth_limit=0.01,
                             speed=0.004, id_prefix='poke-9')[0]
    store.add(miss)
    surface = _surface()
    normals = surface.normals.copy()
    wall = surface.points[:, 0] > 0.52
    normals[wall] = [1.0, 0.0, 0.0]  # a vertical side wall beyond x = 0.52 m
    walled = Surface(points=surface.points, normals=normals)
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', walled,
                            shape_constant=0.004)
    status = learner.update()
    assert status.num_pokes == 3 and 'no contact' in status.skipped[miss.poke_id]
    indices, std = learner.suggest(5, edge_margin=0.008)
    assert len(indices) == 5 and np.all(walled.normals[indices, 2] > 0.8)
    edge = walled.points[wall, 0].min()
    assert np.all(walled.points[indices, 0] <= edge - 0.008 + 1e-9)


def test_rim_points_and_failed_locations_are_not_suggested(tmp_path):
    store, surface, learner = _stored_learner(tmp_path, 3, seed=7)
    learner.update()
    indices, _ = learner.suggest(20, exclude_radius=0.004, edge_margin=0.008)
    chosen = surface.points[indices]
    # the surface is a 70 x 70 mm grid around (0.5, 0): nothing within 4 mm of its border
    assert np.all(np.abs(chosen[:, 0] - 0.5) <= 0.035 - 0.004)
    assert np.all(np.abs(chosen[:, 1]) <= 0.035 - 0.004)
    # a poke that meets nothing there: no more suggestions next to it
    first = chosen[0]
    miss = simulate_campaign(OBJECT, load_scenario('clean'), points=[first + [0, 0, 0.03]],
                             normals=[[0.0, 0.0, 1.0]], force_limit=4.0, depth_limit=0.01,
                             speed=0.004, id_prefix='poke-9')[0]
    store.add(miss)
    learner.update()
    again, _ = learner.suggest(20, exclude_radius=0.004, edge_margin=0.008)
    gap = np.linalg.norm(surface.points[again] - miss.point, axis=1)
    assert np.all(gap >= 0.008 - 1e-9)


def test_a_shape_constant_fitted_by_diagnose_replaces_the_given_one(tmp_path):
    store, surface, _ = _stored_learner(tmp_path, 3, seed=1)
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface,
                            shape_constant=0.004,
                            effects={'spatial_coupling': {'shape_constant': 0.0021}})
    status = learner.update()
    assert learner.shape_constant == pytest.approx(0.0021)
    assert load_model(status.model_path).shape_constant == pytest.approx(0.0021)


def test_the_tail_decay_length_reaches_the_saved_model_and_the_wrench_server(tmp_path):
    from pointforce_ros.model.serving import WrenchServer

    _, surface, _ = _stored_learner(tmp_path, 3, seed=1)
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface,
                            shape_constant=0.004, shape_decay=0.008)
    model = load_model(learner.update().model_path)
    assert (model.shape_constant, model.shape_decay) == pytest.approx((0.004, 0.008))
    server = WrenchServer()
    server.swap(model)
    assert server.simulator().decay == pytest.approx(0.008)
    paper = load_model(learner.set_shape_constant(0.004, np.inf).model_path)
    assert np.isinf(paper.shape_decay) and paper.version == model.version + 1
    with pytest.raises(InvalidInput, match='shape_decay'):
        learner.set_shape_constant(0.004, 0.0)
    with pytest.raises(InvalidInput, match='shape_decay'):
        OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', surface, shape_constant=0.004,
                      shape_decay=float('nan'))
    # the near field reaches the next model and its server too
    flat = load_model(learner.set_shape_constant(0.004, 0.008, near='flat').model_path)
    assert flat.shape_near == 'flat' and model.shape_near == 'paper'
    server.swap(flat)
    assert server.simulator().near == 'flat'
    with pytest.raises(InvalidInput, match='shape_near'):
        learner.set_shape_constant(0.004, near='round')


def test_contact_threshold_is_relative_to_the_data():
    # a soft region: pokes stopped at 0.2 N, well under the old fixed 0.3 N threshold, with the
    # F/T noise of a real sensor (0.03 N per sample); they are learned from, a poke in the air
    # is not (its peak is within its own noise)
    soft = simulate_campaign(OBJECT, load_scenario('ft_noise'), count=3, seed=4,
                             force_limit=0.2, depth_limit=0.01, speed=0.004, gap=0.5,
                             id_prefix='soft-')
    air = simulate_campaign(OBJECT, load_scenario('ft_noise'), points=[[0.5, 0.0, 0.07]],
                            normals=[[0.0, 0.0, 1.0]], force_limit=4.0, depth_limit=0.01,
                            speed=0.004, id_prefix='air-')[0]
    assert all(r.normal_force().max() < 0.3 for r in soft)
    learner = OnlineLearner(None, None, _surface(), shape_constant=0.004)
    status = learner.learn_records(soft + [air])
    assert status.num_pokes == 3 and list(status.skipped) == [air.poke_id]
    assert 'no contact' in status.skipped[air.poke_id]
    # the fixed threshold is still there when asked for, and skips the soft pokes
    fixed = OnlineLearner(None, None, _surface(), shape_constant=0.004, min_peak_force=0.3)
    assert fixed.learn_records(soft) is None and len(fixed.skipped) == 3
    with pytest.raises(InvalidInput, match='contact_snr'):
        OnlineLearner(None, None, _surface(), shape_constant=0.004, contact_snr=-1.0)


@pytest.mark.parametrize('scale', [1e300, 1e150, 1e8])
def test_implausible_force_poke_is_skipped_and_later_pokes_learn(tmp_path, scale):
    """A mis-scaled F/T poke neither stops the learner nor makes it refuse the real pokes."""
    store, _, learner = _stored_learner(tmp_path, 2, seed=1)
    assert learner.update().num_pokes == 2
    good = _campaign(2, seed=4, id_prefix='poke-9')
    store.add(dataclasses.replace(good[0], poke_id='poke-000900',
                                  wrench=good[0].wrench * scale))
    store.add(dataclasses.replace(good[1], poke_id='poke-000950'))
    status = learner.update()
    assert 'poke-000900' in status.skipped and 'implausible force' in status.skipped['poke-000900']
    assert status.num_pokes == 3 and 'poke-000950' not in status.skipped
    assert np.isfinite(status.training_rmse) and status.training_rmse < 1.0


def _record(poke_id, point, force, depth, seed, speed=0.004, rate=250.0, noise=0.01):
    """A synthetic point poke: hold at the stand-off, push at ``speed`` to ``depth``, retract."""
    rng = np.random.default_rng(seed)
    d = np.concatenate([np.full(int(0.3 * rate), -0.005),
                        np.arange(-0.005, depth, speed / rate),
                        np.full(int(0.1 * rate), depth), np.linspace(depth, -0.005, 125)])
    f = force(np.maximum(d, 0.0)) + noise * rng.standard_normal(len(d))
    t = 10.0 * seed + np.arange(len(d)) / rate
    pose = np.zeros((len(d), 6))
    pose[:, :3] = np.asarray(point) - d[:, None] * np.array([0.0, 0.0, 1.0])
    wrench = np.zeros((len(d), 6))
    wrench[:, 2] = f
    return PokeRecord(poke_id=poke_id, point=point, normal=[0.0, 0.0, 1.0], t=t,
                      t_controller=t, tcp_pose=pose, wrench=wrench, speed=speed)


def test_steep_shallow_pokes_give_a_finite_model():
    """Strain stiffening seen to 1 mm only: the table baked to 25 mm stays finite."""
    surface = _surface()
    points = surface.points[np.random.default_rng(3).choice(len(surface), 8, replace=False)]
    records = [_record(f'poke-{k:06d}', p, lambda s: 0.05 * np.expm1(s / 2e-4), 0.001, k)
               for k, p in enumerate(points)]
    learner = OnlineLearner(None, None, surface, shape_constant=0.004)
    status = learner.learn_records(records)
    assert status is not None and status.num_pokes == 8 and not status.skipped
    table = learner.contact_model().response
    assert np.all(np.isfinite(table.forces)) and np.all(np.isfinite(table.std))
    assert np.all(np.diff(table.forces, axis=1) >= 0.0)
    # where the pokes were, the table still says what they measured
    idx = np.argmin(np.linalg.norm(surface.points[:, None] - points[None], axis=2), axis=0)
    measured = 0.05 * np.expm1(0.001 / 2e-4)
    np.testing.assert_allclose(table.force(idx, np.full(len(idx), 0.001)), measured, rtol=0.2)
    # past twice the learned depth no row grows faster than its tangent there: the law's own
    # continuation to 25 mm was 1e26 N; the cap keeps it within that tangent's kilonewtons
    deep = learner.model.bake(surface, learner.depths).forces[idx, -1]
    at = np.searchsorted(table.depths, 2 * table.meta['learned_depth'])
    tangent = (table.forces[idx, at] - table.forces[idx, at - 1]) / np.diff(table.depths)[0]
    bound = table.forces[idx, at] + tangent * (table.depths[-1] - table.depths[at])
    np.testing.assert_allclose(table.forces[idx, -1], np.minimum(deep, bound), rtol=1e-9)
    assert np.all(table.forces[idx, -1] < 1e-3 * deep) and np.all(table.forces < 1e5)


class _BreaksOn(ContactGpModel):
    """Ours, except that conditioning on poke ``poke-000002`` fails (not a PointforceError)."""

    def _fit_processes(self, states=None):
        if 'poke-000002' in self._ids:
            raise np.linalg.LinAlgError('Matrix is not positive definite')
        super()._fit_processes(states)


def _learner_of(tmp_path, factory, count: int, stored: int, seed: int):
    """``(store, records, learner)``: ``count`` clean pokes named poke-000000 on, the first
    ``stored`` in the store, and a learner on it with ``factory`` as its model."""
    store = PokeStore(tmp_path / 'pokes')
    records = [dataclasses.replace(r, poke_id=f'poke-{k:06d}')
               for k, r in enumerate(_campaign(count, seed=seed, id_prefix='poke-0'))]
    for record in records[:stored]:
        store.add(record)
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', _surface(),
                            shape_constant=0.004, model_factory=factory)
    return store, records, learner


def test_a_poke_that_breaks_the_refit_is_skipped_and_later_pokes_learn(tmp_path):
    store, records, learner = _learner_of(tmp_path, _BreaksOn, 6, 4, seed=3)
    status = learner.update()
    assert status.num_pokes == 3 and list(status.skipped) == ['poke-000002']
    assert 'LinAlgError' in status.skipped['poke-000002']
    assert learner.model.poke_ids == ['poke-000000', 'poke-000001', 'poke-000003']
    for record in records[4:]:
        store.add(record)
    again = learner.update()
    assert again.num_pokes == 5 and again.version == 5
    assert load_model(again.model_path).meta['pokes'] == learner.model.poke_ids


class _FallsWith(ContactGpModel):
    """Ours, except that with poke ``poke-000003`` the baked force falls at the deepest depth."""

    def bake(self, surface, depths):
        table = super().bake(surface, depths)
        if 'poke-000003' not in self._ids:
            return table
        forces = table.forces.copy()
        forces[:, -1] = 0.5 * forces[:, -2]
        return dataclasses.replace(table, forces=forces)


def test_a_model_that_is_not_sane_is_refused_and_the_previous_one_kept(tmp_path):
    store, records, learner = _learner_of(tmp_path, _FallsWith, 5, 3, seed=8)
    first = learner.update()
    assert first.version == 3
    store.add(records[3])
    assert learner.update() is None      # refused: nothing new is saved
    assert 'falls' in learner.skipped['poke-000003']
    assert learner.current_model_path() == first.model_path
    assert learner.model.poke_ids == ['poke-000000', 'poke-000001', 'poke-000002']
    store.add(records[4])
    later = learner.update()
    assert later.num_pokes == 4 and 'poke-000003' in later.skipped
    saved = load_model(later.model_path).response.forces
    assert np.all(np.diff(saved, axis=1) >= 0.0)


def test_an_update_of_many_pokes_checks_once_and_finds_the_one_that_breaks_the_model(
        tmp_path):
    """Many new pokes at once (a restart) are checked as one model; when it is not sane, each
    group is checked again and only the poke that breaks it is skipped."""
    _, _, learner = _learner_of(tmp_path, _FallsWith, 5, 5, seed=8)
    status = learner.update()
    assert status.num_pokes == 4 and list(status.skipped) == ['poke-000003']
    assert 'falls' in status.skipped['poke-000003']
    assert learner.model.poke_ids == ['poke-000000', 'poke-000001', 'poke-000002',
                                      'poke-000004']
    assert len(learner._prequential) == 3   # the first poke has none; the skipped one none
    saved = load_model(status.model_path).response.forces
    assert np.all(np.diff(saved, axis=1) >= 0.0)


class _CountsRefits(ContactGpModel):
    """Ours as the product uses it, counting its process refits."""

    refits = 0

    def __init__(self):
        super().__init__(spread=PRODUCT_SPREAD)

    def _fit_processes(self, states=None):
        type(self).refits += 1
        super()._fit_processes(states)


def test_many_new_pokes_are_learned_in_a_bounded_number_of_refits(monkeypatch):
    """A restart over a large store: one refit per group of pokes, the same model."""
    records = _campaign(12, seed=11, id_prefix='poke-0')
    surface = _surface()
    one_by_one = OnlineLearner(None, None, surface, shape_constant=0.004)
    expected = one_by_one.learn_records(records)
    monkeypatch.setattr(learner_module, 'MAX_REFITS_PER_UPDATE', 3)
    lines = []
    grouped = OnlineLearner(None, None, surface, shape_constant=0.004,
                            model_factory=_CountsRefits, progress=lines.append)
    status = grouped.learn_records(records)
    # three groups of four: the first poke's own fit, then one refit per group
    assert _CountsRefits.refits == 4 and len(lines) == 3 and '12 of 12' in lines[-1]
    assert status.version == expected.version == 12 and not status.skipped
    np.testing.assert_allclose(grouped.contact_model().response.forces,
                               one_by_one.contact_model().response.forces,
                               rtol=1e-6, atol=1e-9)
    assert np.isfinite(status.validation_rmse) and status.validation_rmse < 1.0


def test_suggestions_are_answered_between_the_groups_of_a_long_update(monkeypatch):
    surface = _surface()
    records = _campaign(10, seed=12, id_prefix='poke-0')
    monkeypatch.setattr(learner_module, 'MAX_REFITS_PER_UPDATE', 2)
    reached, answered = threading.Event(), threading.Event()

    def progress(line):
        reached.set()
        answered.wait(20.0)      # the update stays in progress until a suggestion came back

    learner = OnlineLearner(None, None, surface, shape_constant=0.004)
    assert learner.learn_records(records[:3]).num_pokes == 3
    learner.progress = progress
    update = threading.Thread(target=learner.learn_records, args=(records[3:],))
    update.start()
    try:
        assert reached.wait(60.0)
        result = []
        ask = threading.Thread(target=lambda: result.append(learner.suggest(1)))
        ask.start()
        ask.join(10.0)
        assert not ask.is_alive() and len(result[0].indices) == 1
        assert update.is_alive()       # answered in the middle of the update
    finally:
        answered.set()
        update.join(60.0)
    assert learner.status.num_pokes == 10


def test_plastic_set_counts_are_blocked_and_the_newest_poke_is_counted_alone():
    """Audit 39: the counts built (P, P, 3) arrays (216 MB at 3000 pokes) and a learner
    counted every poke again for each poke it read (cubic in the pokes on a restart)."""
    rng = np.random.default_rng(5)
    n = 700
    points = np.column_stack([rng.uniform(0.0, 0.02, (n, 2)), np.full(n, 0.04)])
    normals = rng.normal([0.0, 0.0, 1.0], 0.2, (n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    peak = rng.uniform(0.0, 2.0, n)
    # the definition, written out pair by pair
    rel = points[None, :, :] - points[:, None, :]
    across = rel - np.einsum('ijk,ik->ij', rel, normals)[:, :, None] * normals[:, None, :]
    near = np.linalg.norm(across, axis=2) <= 0.002
    truth = np.array([np.count_nonzero(near[i, :i] & (peak[:i] >= 0.5)) for i in range(n)])
    counts = count_earlier(points, normals, peak, 0.002)
    np.testing.assert_array_equal(counts, truth)
    assert truth[0] == 0 and truth.max() > 5   # two blocks of rows, counts that differ
    np.testing.assert_array_equal(count_earlier(points, normals, peak, 0.002, start=n - 3),
                                  truth[-3:])


def test_the_learner_counts_each_new_plastic_set_poke_as_the_whole_history_does(tmp_path):
    records = _campaign(6, seed=3, id_prefix='poke-0')
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', _surface(),
                            shape_constant=0.004,
                            effects={'plastic_set': {'max_set': 0.0008, 'n0': 3.0,
                                                     'radius': 0.05}})
    # out of time order on purpose: a late record read first is not earlier than the rest
    got, whole = [], []
    for i in [0, 3, 1, 2, 5, 4]:
        got.append(learner._remember(records[i], 1.0))
        counts, index = learner._spot_counts()   # every remembered poke, in time order
        whole.append(int(counts[np.flatnonzero(index == len(index) - 1)[0]]))
    assert got == whole and max(got) > 0
