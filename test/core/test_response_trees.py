"""Ours with the laws spread by Extra Trees (``ContactGpModel(spread='trees')``)."""

import json
import tracemalloc

import numpy as np
import pytest

from pointforce_ros.errors import InvalidInput
from pointforce_ros.lab.model_store import load_response_model, save_response_model
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.response.trees import (calibrated_scatter, CALIBRATION_PRIOR, MAX_FEATURES,
                                           TreeSpread, TreeState)

DEPTHS = np.linspace(-0.008, 0.014, 45)


@pytest.fixture(scope='module')
def world():
    """Dome with a smooth stiffness field, a stiff inclusion, camera bias; 12 pokes."""
    obj = SyntheticObject()
    surface = obj.surface(0.002)
    rng = np.random.default_rng(2024)
    idx = spread_indices(surface, 12, rng)
    curves = obj.curves(surface, idx, rng, rate=100.0, ft_noise=0.03, ft_bias=0.05)
    return obj, surface, curves


def test_the_scatter_makes_the_held_out_residuals_average_one():
    rng = np.random.default_rng(0)
    r = rng.normal(0.0, 0.3, (20, 2))
    v = np.column_stack([np.zeros(20), np.full(20, 1.0)])
    s = calibrated_scatter(r, v)
    # no tree variance: (sum r^2 / s^2 + prior) / (n + prior) = 1 gives s^2 = mean r^2
    assert s[0] ** 2 == pytest.approx(np.mean(r[:, 0] ** 2), rel=1e-9)
    # the trees' variance (1) already covers residuals of 0.3: nothing added
    assert s[1] == 0.0
    # some tree variance: the root satisfies the calibration
    v2 = np.full(20, 0.02)
    s2 = calibrated_scatter(r[:, :1], v2[:, None])[0] ** 2
    z2 = (np.sum(r[:, 0] ** 2 / (v2 + s2)) + CALIBRATION_PRIOR) / (20 + CALIBRATION_PRIOR)
    assert z2 == pytest.approx(1.0, abs=1e-9) and 0 < s2 < np.mean(r[:, 0] ** 2)


def test_tree_laws_stay_within_the_training_laws_and_the_choice_is_held_out(world):
    _, surface, curves = world
    model = ContactGpModel(spread='trees').fit(curves, surface)
    theta = model.poke_params
    mean = model.predict_params(surface.features)
    lo, hi = theta.min(axis=0), theta.max(axis=0)
    assert np.all(mean >= lo - 1e-12) and np.all(mean <= hi + 1e-12)
    # a point's law is the trees' mean of training laws: at a training poke's own features
    # it is pulled towards that poke's law, closer than the mean of all laws
    own = model.predict_params(model._features)
    assert np.mean(np.abs(own - theta)) < np.mean(np.abs(theta.mean(axis=0) - theta))
    spread = model._gps
    assert set(spread.scores) == {str(mf) for mf in MAX_FEATURES}
    assert spread.state.max_features == min(MAX_FEATURES,
                                            key=lambda mf: spread.scores[str(mf)])
    # the std comes from the trees' disagreement plus the calibrated scatter
    _, sd = model.predict_params(surface.features, return_std=True)
    assert np.all(sd >= np.asarray(spread.state.scatter) - 1e-12)


def test_tree_laws_are_monotone_bake_as_predicted_and_round_trip(world, tmp_path):
    _, surface, curves = world
    model = ContactGpModel(spread='trees').fit(curves[:8], surface)
    baked = model.bake(surface, DEPTHS)
    assert np.all(np.diff(baked.forces, axis=1) >= 0.0) and np.all(baked.forces >= 0.0)
    rng = np.random.default_rng(4)
    idx = rng.integers(0, len(surface), 300)
    k = rng.integers(0, len(DEPTHS), 300)
    np.testing.assert_allclose(baked.forces[idx, k],
                               model.predict(surface.features[idx], DEPTHS[k]),
                               rtol=2e-5, atol=1e-6)
    path = save_response_model(model, tmp_path / 'trees.json')
    loaded = load_response_model(path)
    assert loaded.spread == 'trees' and loaded.version == model.version
    x, d = surface.features[::5], np.linspace(-0.005, 0.012, len(surface.features[::5]))
    np.testing.assert_array_equal(loaded.predict(x, d), model.predict(x, d))
    np.testing.assert_array_equal(loaded.predict_std(x, d), model.predict_std(x, d))
    data = json.loads(path.read_text())
    data['model']['processes']['trees']['max_features'] = 7
    bad = tmp_path / 'bad.json'
    bad.write_text(json.dumps(data))
    with pytest.raises(Exception, match='max_features'):
        load_response_model(bad)


def test_tree_laws_learn_online_as_in_a_batch_and_from_one_poke(world):
    _, surface, curves = world
    online = ContactGpModel(spread='trees').fit(curves[:1], surface)
    theta, sd = online.predict_params(surface.features[:3], return_std=True)
    np.testing.assert_allclose(theta, np.repeat(online.poke_params, 3, axis=0))
    np.testing.assert_allclose(sd[0], online.prior_scales[:3])
    for c in curves[1:6]:
        online.partial_fit(c)
    batch = ContactGpModel(spread='trees').fit(curves[:6], surface)
    x = surface.features[::7]
    np.testing.assert_allclose(online.predict(x, 0.004), batch.predict(x, 0.004), rtol=1e-9)
    with pytest.raises(InvalidInput, match='spread'):
        ContactGpModel(spread='forest')
    with pytest.raises(InvalidInput, match='scatter'):
        TreeSpread(np.zeros((2, 9)), np.zeros((2, 3)), TreeState(None, (0.1,)), None, (0.1,))


def test_tree_laws_over_a_large_surface_stay_bounded_in_memory(world):
    _, surface, curves = world
    model = ContactGpModel(spread='trees').fit(curves[:8], surface)
    features = np.tile(surface.features, (40000 // len(surface) + 1, 1))[:40000]
    tracemalloc.start()
    try:
        mean, cov = model.predict_param_dist(features)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    # every tree's parameters for all 40 000 points at once took over 200 MB
    assert peak < 60e6, peak
    k = len(surface)
    np.testing.assert_allclose(mean[k:2 * k], mean[:k])
    np.testing.assert_allclose(cov[:k], model.predict_param_dist(surface.features)[1])
