"""Force-response models on a synthetic heterogeneous object: ours against the seed's ET."""

import json
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

from pointforce_ros.errors import DataError, InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response import ForceResponseModel
from pointforce_ros.lab.baseline import AutoEtBaseline, EtBaseline
from pointforce_ros.lab.evaluate import learning_curve
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.scoring import heldout_errors
from pointforce_ros.response.gp import FeatureFrame, FeatureGp
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.lab.model_store import (load_response_model, model_from_dict,
                                            save_response_model)
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject
from pointforce_ros.types import Surface

DEPTHS = np.linspace(-0.008, 0.014, 45)
OLD_MODEL = Path(__file__).resolve().parents[1] / 'data' / 'models' / 'contact_gp_independent.json'


@pytest.fixture(scope='module')
def world():
    """Dome with a smooth stiffness field, a stiff inclusion, camera bias; 30 pokes."""
    obj = SyntheticObject()
    surface = obj.surface(0.002)
    rng = np.random.default_rng(2024)
    idx = spread_indices(surface, 30, rng)
    curves = obj.curves(surface, idx, rng, rate=100.0, ft_noise=0.03, ft_bias=0.05)
    return obj, surface, curves


def test_models_follow_the_protocol(world):
    _, surface, curves = world
    for model in (ContactGpModel().fit(curves[:3], surface),
                  EtBaseline(params={'n_estimators': 10}).fit(curves[:3], surface)):
        assert isinstance(model, ForceResponseModel)
        assert model.version == 1 and model.poke_ids == [c.poke_id for c in curves[:3]]


def test_ours_is_monotone_and_zero_before_contact(world):
    _, surface, curves = world
    model = ContactGpModel().fit(curves[:8], surface)
    baked = model.bake(surface, DEPTHS)
    assert np.all(np.diff(baked.forces, axis=1) >= 0.0)
    assert np.all(baked.forces >= 0.0) and np.all(baked.slopes >= 0.0)
    # the mean force integrates over the onset's uncertainty: zero before the earliest onset
    # the quadrature reaches (3 standard deviations early), positive after the mean onset
    theta, sd = model.predict_params(surface.features, return_std=True)
    onset, earliest = theta[:, 0], theta[:, 0] - 3.0 * sd[:, 0]
    before = DEPTHS[None, :] <= earliest[:, None]
    after = DEPTHS[None, :] > onset[:, None]
    assert before.any() and after.any()
    assert np.all(baked.forces[before] == 0.0)
    assert np.all(baked.forces[after] > 0.0)
    # Pointwise queries at random features and depths agree: f(d + h) >= f(d).
    rng = np.random.default_rng(3)
    rows = rng.integers(0, len(surface), 500)
    d = rng.uniform(-0.01, 0.015, 500)
    f0 = model.predict(surface.features[rows], d)
    f1 = model.predict(surface.features[rows], d + 1e-4)
    assert np.all(f1 >= f0) and np.all(f0[d < earliest[rows]] == 0.0)


def test_ours_beats_the_et_baseline_on_heldout_pokes(world):
    _, surface, curves = world
    rows = learning_curve(curves, surface, {'ours': ContactGpModel, 'et': EtBaseline},
                          sizes=(5, 10), repeats=10, seed=7)
    med = {(r['model'], r['size']): r['median'] for r in rows}
    # over 40 draws (seeds 0, 1, 2, 7) ours / ET was 0.76 at 5 pokes and 0.71 at 10 with the
    # force at the mean parameters; a median over 10 draws scatters by a few hundredths around
    # that. The predictive mean force (issue 17) gives 0.855 / 0.675 on seed 7 (the force at
    # the mean parameters 0.82 / 0.68): at 5 pokes the processes' spread is prior-dominated
    for size, most in ((5, 0.9), (10, 0.8)):
        assert med[('ours', size)] < most * med[('et', size)], med


def test_std_is_larger_far_from_pokes(world):
    obj, surface, curves = world
    west = [c for c in curves if c.point[0] < -0.01]
    model = ContactGpModel().fit(west, surface)
    depth = model.reference_depth()
    near = np.array([np.argmin(np.linalg.norm(surface.points - c.point, axis=1)) for c in west])
    far = np.flatnonzero(surface.points[:, 0] > 0.03)
    std_near = model.predict_std(surface.features[near], depth)
    std_far = model.predict_std(surface.features[far], depth)
    assert np.median(std_far) > 2.0 * np.median(std_near)
    _, sd_near = model.predict_params(surface.features[near], return_std=True)
    _, sd_far = model.predict_params(surface.features[far], return_std=True)
    assert np.all(np.median(sd_far, axis=0) > np.median(sd_near, axis=0))


def test_bake_matches_predict(world):
    _, surface, curves = world
    model = ContactGpModel().fit(curves[:10], surface)
    baked = model.bake(surface, DEPTHS)
    rng = np.random.default_rng(4)
    idx = rng.integers(0, len(surface), 300)
    k = rng.integers(0, len(DEPTHS), 300)
    feats = surface.features[idx]
    np.testing.assert_allclose(baked.forces[idx, k], model.predict(feats, DEPTHS[k]),
                               rtol=2e-5, atol=1e-6)
    # the table's std is sqrt(E f^2 - (E f)^2) in float32: the difference loses digits
    np.testing.assert_allclose(baked.std[idx, k], model.predict_std(feats, DEPTHS[k]),
                               rtol=1e-3, atol=1e-4)
    # Between grid nodes the table interpolates the smooth law closely.
    d = rng.uniform(DEPTHS[0], DEPTHS[-1], 300)
    np.testing.assert_allclose(baked.force(idx, d), model.predict(feats, d), atol=0.15)
    # Beyond the grid its slope continues the law's tangent.
    h = 1e-4
    ahead = model.predict(feats, np.full(300, DEPTHS[-1] + h))
    at = model.predict(feats, np.full(300, DEPTHS[-1]))
    np.testing.assert_allclose(baked.slopes[idx], (ahead - at) / h, rtol=0.02, atol=1.0)


def test_partial_fit_equals_batch_fit(world):
    _, surface, curves = world
    online = ContactGpModel().fit(curves[:1], surface)
    for c in curves[1:6]:
        online.partial_fit(c)
    batch = ContactGpModel().fit(curves[:6], surface)
    x = surface.features[::7]
    np.testing.assert_allclose(online.predict(x, 0.004), batch.predict(x, 0.004), rtol=1e-9)
    assert online.version == 6 and batch.version == 1
    with pytest.raises(InvalidInput, match='already'):
        online.partial_fit(curves[0])


def test_rigid_camera_error_onset_is_learned_from_few_pokes():
    """An onset field that is exactly a camera extrinsic error is linear in [n, p x n]."""
    obj = SyntheticObject(radius=0.06, bias_amplitude=0.0)
    surface = obj.surface(0.004)
    rng = np.random.default_rng(8)
    train = rng.choice(len(surface), 8, replace=False)
    onset = obj.onset(surface.points)
    frame = FeatureFrame.of_surface(surface.points, surface.colors)
    gp = FeatureGp(frame, prior_scale=0.003, basis='rigid')
    gp.fit(surface.features[train], onset[train])
    err = gp.predict(surface.features) - onset
    assert np.sqrt(np.mean(err ** 2)) < 0.05 * onset.std()
    plain = FeatureGp(frame, prior_scale=0.003, basis='none')
    plain.fit(surface.features[train], onset[train])
    assert np.sqrt(np.mean(err ** 2)) < np.sqrt(np.mean((plain.predict(surface.features)
                                                         - onset) ** 2))


def test_gp_interpolates_and_reverts_to_the_prior():
    frame = FeatureFrame(centre=(0.0, 0.0, 0.0), scale=0.1)
    x = np.zeros((1, 9))
    x[0, 8] = 1.0
    gp = FeatureGp(frame, prior_scale=0.5, prior_dof=1.0)
    gp.fit(x, np.array([2.0]))
    far = x.copy()
    far[0, 0] = 10.0
    mean_at, std_at = gp.predict(x, return_std=True, include_nugget=False)
    mean_far, std_far = gp.predict(far, return_std=True)
    nug = gp.state.nugget
    assert mean_at[0] == pytest.approx(2.0) and mean_far[0] == pytest.approx(2.0)
    # One point, prior s2 = prior_scale^2: at the point only the nugget is left; far away,
    # the prior variance plus the unknown mean's variance (1 + nug) plus the nugget.
    assert gp.state.s2 == pytest.approx(0.25)
    assert std_at[0] == pytest.approx(0.5 * np.sqrt(nug), rel=1e-6)
    assert std_far[0] == pytest.approx(0.5 * np.sqrt(2.0 + 2.0 * nug), rel=1e-6)


def test_save_load_round_trip_predicts_identically(world, tmp_path):
    _, surface, curves = world
    x = surface.features[::5]
    d = np.linspace(-0.005, 0.012, len(x))
    for k, model in enumerate((ContactGpModel().fit(curves[:7], surface),
                               ContactGpModel(decorrelate=False).fit(curves[:7], surface),
                               ContactGpModel(law='stiffening', relevance='auto').fit(
                                   curves[:7], surface),
                               EtBaseline(params={'n_estimators': 20}).fit(curves[:7], surface))):
        path = save_response_model(model, tmp_path / f'{k}{model.kind}.json')
        loaded = load_response_model(path)
        assert type(loaded) is type(model) and loaded.version == model.version
        np.testing.assert_array_equal(loaded.predict(x, d), model.predict(x, d))
        np.testing.assert_array_equal(loaded.predict_std(x, d), model.predict_std(x, d))
        again = model_from_dict(json.loads(json.dumps(model.to_dict())))
        np.testing.assert_array_equal(again.bake(surface, DEPTHS).forces,
                                      model.bake(surface, DEPTHS).forces)
    # a model saved before decorrelation existed (test/data/models/make_old_model.py) loads
    # with independent processes and no outlier screen, as it was fitted, and predicts what
    # they predict now
    old = load_response_model(OLD_MODEL)
    assert not old.decorrelate and old.poke_ids == [c.poke_id for c in curves[:7]]
    assert old.robust_z is None
    independent = ContactGpModel(decorrelate=False, law='power', mean='median',
                                 robust_z=None).fit(curves[:7], surface)
    # a re-fit is not bit-stable across machines (the optimiser's result moved by 2e-7
    # relative on another machine of this kind): compare at what the fit guarantees, far
    # below the 0.01 N that tells the two parametrisations apart
    np.testing.assert_allclose(old.predict(x, d), independent.predict(x, d), rtol=1e-5,
                               atol=1e-5)
    # (which the decorrelated default does not: the fixture tells the two apart)
    decorrelated = ContactGpModel().fit(curves[:7], surface)
    assert np.max(np.abs(old.predict(x, d) - decorrelated.predict(x, d))) > 0.01
    (tmp_path / 'bad.json').write_text('{"format": "something-else"}')
    with pytest.raises(DataError, match='format'):
        load_response_model(tmp_path / 'bad.json')
    with pytest.raises(DataError, match='not found'):
        load_response_model(tmp_path / 'missing.json')


def test_et_slope_extrapolation_is_linear_beyond_the_trained_range(world):
    _, surface, curves = world
    model = EtBaseline(params={'n_estimators': 30}).fit(curves[:6], surface)
    x = surface.features[::40]
    m = len(x)
    top = model.d_top
    steps = top + np.array([0.0, 0.001, 0.002, 0.005])
    f = np.stack([model.predict(x, np.full(m, s)) for s in steps], axis=1)
    slope = model.slope(x)
    assert np.all(slope >= 0.0) and np.any(slope > 0.0)
    np.testing.assert_allclose(f[:, 1:] - f[:, :1], slope[:, None] * (steps[1:] - top)[None],
                               rtol=1e-9, atol=1e-9)
    # The slope is the least-squares slope of the trees' own prediction just below d_top.
    window = np.linspace(top - model.slope_window, top, model.slope_points)
    below = np.stack([model.predict(x, np.full(m, s)) for s in window], axis=1)
    expect = np.maximum(np.polyfit(window, below.T, 1)[0], 0.0)
    np.testing.assert_allclose(slope, expect, rtol=1e-6, atol=1e-6)
    baked = model.bake(surface, np.linspace(-0.008, top + 0.004, 40))
    np.testing.assert_allclose(baked.forces[::40, -1], model.predict(x, np.full(m, top + 0.004)),
                               rtol=1e-9, atol=1e-9)


def test_auto_et_is_time_boxed_and_grouped(world):
    _, surface, curves = world
    model = AutoEtBaseline(budget_s=1.0, folds=3, max_rows_per_poke=60).fit(curves[:6], surface)
    log = model.search_log
    assert len(log) >= 1
    assert all(entry['t'] < 1.0 for entry in log[:-1])    # no configuration starts late
    assert log[0]['params'] == {}                          # the default is always scored
    best = min(log, key=lambda e: e['cv_rmse'])
    assert model.best_params == best['params']
    assert model.estimator.get_params()['n_estimators'] == best['params'].get('n_estimators',
                                                                              100)


def test_heldout_evaluation_refuses_training_pokes(world):
    _, surface, curves = world
    model = ContactGpModel().fit(curves[:4], surface)
    with pytest.raises(InvalidInput, match='training pokes'):
        heldout_errors(model, curves[2:6], surface)
    e = heldout_errors(model, curves[4:6], surface, region='all')
    assert len(e) == sum(len(c) for c in curves[4:6])


def test_bad_queries_and_inputs_raise(world):
    _, surface, curves = world
    for model in (ContactGpModel(), EtBaseline()):
        with pytest.raises(ModelNotReady):
            model.predict(surface.features[:2], 0.001)
    model = ContactGpModel().fit(curves[:3], surface)
    with pytest.raises(InvalidInput, match='features'):
        model.predict(np.zeros((3, 8)), 0.001)
    with pytest.raises(InvalidInput, match='non-finite'):
        model.predict(surface.features[:2], np.array([0.0, np.nan]))
    with pytest.raises(InvalidInput, match='depths'):
        model.bake(surface, np.array([0.002, 0.001]))
    far = curves[0]
    moved = PokeCurve(poke_id='far', point=far.point + np.array([0.0, 0.0, 0.05]),
                      normal=far.normal, d=far.d, f=far.f, onset_d=far.onset_d, t=far.t)
    with pytest.raises(InvalidInput, match='same frame'):
        ContactGpModel().fit([moved], surface)
    with pytest.raises(InvalidInput, match='kind'):
        model_from_dict({'kind': 'nope'})
    with pytest.raises(InvalidInput, match='not a'):
        ContactGpModel.from_dict({'kind': 'pointforce.response.et_baseline', 'format': 1})


def test_decorrelated_processes_beat_independent_ones_where_the_parameters_trade_off():
    """Lamb's per-poke (d0, log F, p) correlate 0.98-0.99; spreading them independently mixes
    sets off the curve family. Held-out pokes of its committed poke fixture, 10 training pokes,
    the same draws for both."""
    from pointforce_ros.lab.figures import load_poke_fixture
    surface, curves, _ = load_poke_fixture('lamb', say=lambda m: None)
    theta = np.array([ContactGpModel().fit_curve(c)[0] for c in curves])
    corr = np.corrcoef(theta.T)
    assert np.min(np.abs(corr[np.triu_indices(3, 1)])) > 0.9, corr
    rows = learning_curve(curves, surface,
                          {'dec': ContactGpModel,
                           'indep': lambda: ContactGpModel(decorrelate=False)},
                          sizes=(10,), repeats=10, seed=0)
    res = {r['model']: r for r in rows}
    # the independent processes fail badly on some draws (its mean), and are no better at the
    # median
    assert res['dec']['mean'] < 0.9 * res['indep']['mean'], res
    assert res['dec']['median'] < res['indep']['median'], res


def _peak_bytes(call):
    tracemalloc.start()
    try:
        result = call()
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_gp_grid_search_memory_stays_bounded_with_many_points():
    rng = np.random.default_rng(5)
    n = 240
    features = np.zeros((n, 9))
    features[:, :2] = rng.uniform(0.0, 0.1, (n, 2))
    features[:, 3:6] = 0.5
    features[:, 8] = 1.0
    y = np.sin(40.0 * features[:, 0]) + 0.05 * rng.standard_normal(n)
    gp = FeatureGp(FeatureFrame.of_surface(features[:, :3], features[:, 3:6]), 1.0)
    state, peak = _peak_bytes(lambda: gp.fit(features, y))
    assert peak < 120e6
    # the same hyperparameters as a search one grid point at a time
    one = FeatureGp(FeatureFrame.of_surface(features[:, :3], features[:, 3:6]), 1.0)
    assert one.fit(features, y, chunk=1) == state
    np.testing.assert_allclose(gp.predict(features[:5]), y[:5], atol=0.2)


def test_poke_features_of_many_pokes_on_a_large_cloud_stay_bounded():
    rng = np.random.default_rng(9)
    xs, ys = np.meshgrid(np.linspace(0.0, 0.2, 200), np.linspace(0.0, 0.2, 200))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    surface = Surface(points=points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))
    index = rng.integers(len(points), size=400)
    curves = [PokeCurve(poke_id=f'p{k}', point=points[i] + [0.0, 0.0, 1e-4],
                        normal=[0.0, 0.0, 1.0], d=[0.0, 1e-3], f=[0.0, 1.0], onset_d=0.0,
                        t=[0.0, 1.0]) for k, i in enumerate(index)]
    feats, peak = _peak_bytes(lambda: curve_features(curves, surface))
    assert peak < 60e6
    np.testing.assert_array_equal(feats, surface.features[index])
