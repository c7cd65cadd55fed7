"""Ours with the laws spread by the processes and the trees in equal parts (``spread='mix'``)."""

import json

import numpy as np
import pytest

from pointforce_ros.errors import InvalidInput
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.response.ours import ContactGpModel, mixture, PRODUCT_SPREAD, product_model

DEPTHS = np.linspace(-0.008, 0.014, 45)


@pytest.fixture(scope='module')
def world():
    """Dome with a smooth stiffness field, a stiff inclusion, camera bias; 8 pokes."""
    obj = SyntheticObject()
    surface = obj.surface(0.003)
    rng = np.random.default_rng(2025)
    curves = obj.curves(surface, spread_indices(surface, 8, rng), rng, rate=100.0,
                        ft_noise=0.03, ft_bias=0.05)
    return surface, curves


def test_the_mixture_has_the_moments_of_an_equal_mixture_of_the_two_gaussians():
    rng = np.random.default_rng(3)
    m1, m2 = np.array([0.0, 1.0, 2.0]), np.array([1.0, -1.0, 2.5])
    a1, a2 = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
    c1, c2 = a1 @ a1.T + np.eye(3), a2 @ a2.T + 0.5 * np.eye(3)
    n = 400_000
    draws = np.vstack([rng.multivariate_normal(m1, c1, n), rng.multivariate_normal(m2, c2, n)])
    mean, cov = mixture(m1, c1, m2, c2)
    np.testing.assert_allclose(mean, draws.mean(axis=0), atol=0.01)
    np.testing.assert_allclose(cov, np.cov(draws.T), atol=0.03)
    # wider than the mean covariance by the means' disagreement, along it
    gap = m1 - m2
    assert gap @ cov @ gap > gap @ ((c1 + c2) / 2) @ gap + 0.2 * (gap @ gap) ** 2
    # batched as the model calls it: (M, P) means against (M, P, P) covariances
    bm, bc = mixture(np.stack([m1, m2]), np.stack([c1, c2]), np.stack([m2, m1]),
                     np.stack([c2, c1]))
    np.testing.assert_allclose(bm, [mean, mean])
    np.testing.assert_allclose(bc, [cov, cov])


def test_a_point_gets_the_mixture_of_the_processes_and_the_trees(world):
    surface, curves = world
    kw = dict(law='power', mean='median')      # the same law and mode for all three
    mix = ContactGpModel(spread='mix', **kw).fit(curves, surface)
    gp = ContactGpModel(spread='gp', **kw).fit(curves, surface)
    trees = ContactGpModel(spread='trees', **kw).fit(curves, surface)
    x = surface.features[::40]
    (m1, c1), (m2, c2) = gp.predict_param_dist(x), trees.predict_param_dist(x)
    mean, cov = mix.predict_param_dist(x)
    want_mean, want_cov = mixture(m1, c1, m2, c2)
    np.testing.assert_allclose(mean, want_mean, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(cov, want_cov, rtol=1e-9, atol=1e-15)
    # where the two spreads disagree most on log F the mixture is wider than their mean
    # variance there by the square of half the gap
    k = np.argmax(np.abs(m1[:, 1] - m2[:, 1]))
    assert cov[k, 1, 1] - (c1[k, 1, 1] + c2[k, 1, 1]) / 2 > 0.1 * (m1[k, 1] - m2[k, 1]) ** 2
    d = np.full(len(x), 0.004)
    np.testing.assert_allclose(mix.predict(x, d), mix.force_from_params(mean, d), rtol=1e-9)


def test_mixed_laws_are_monotone_bake_as_predicted_and_round_trip(world, tmp_path):
    surface, curves = world
    model = product_model().fit(curves, surface)
    assert model.spread == PRODUCT_SPREAD == 'mix'
    baked = model.bake(surface, DEPTHS)
    assert baked.meta['spread'] == 'mix'
    assert np.all(np.diff(baked.forces, axis=1) >= -1e-9)
    x, d = surface.features[::25], np.full(len(surface.features[::25]), 0.005)
    k = np.searchsorted(DEPTHS, 0.005)
    rows = np.arange(0, len(surface), 25)
    at_grid = model.predict(x, np.full(len(x), DEPTHS[k]))
    np.testing.assert_allclose(baked.forces[rows, k], at_grid, rtol=1e-4, atol=1e-6)
    again = ContactGpModel.from_dict(json.loads(json.dumps(model.to_dict())))
    np.testing.assert_array_equal(again.predict(x, d), model.predict(x, d))
    np.testing.assert_array_equal(again.predict_std(x, d), model.predict_std(x, d))
    broken = model.to_dict()
    del broken['processes']['trees']
    with pytest.raises(InvalidInput, match='malformed model data'):
        ContactGpModel.from_dict(broken)


def test_the_learner_learns_with_the_products_spread_online_as_in_a_batch(world):
    surface, curves = world
    learner = OnlineLearner(None, None, surface, shape_constant=0.004)
    batch = product_model().fit(curves[:5], surface)
    online = product_model()
    online.fit(curves[:1], surface)
    for c in curves[1:5]:
        online.partial_fit(c)
    x = surface.features[::30]
    d = np.full(len(x), 0.004)
    assert online.spread == 'mix' and learner.model_factory().spread == 'mix'
    np.testing.assert_allclose(online.predict(x, d), batch.predict(x, d), rtol=1e-9)
