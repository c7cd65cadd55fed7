"""Next-poke suggestions and the active-vs-random and learning-curve figures."""

import numpy as np
import pytest

from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.lab.evaluate import learning_curve, plot_learning_curve
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.lab.active import active_vs_random_curve, plot_active_vs_random
from pointforce_ros.response.suggest import (
                                             suggest_pokes)
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject

PNG = b'\x89PNG\r\n\x1a\n'


@pytest.fixture(scope='module')
def world():
    obj = SyntheticObject()
    surface = obj.surface(0.002)
    rng = np.random.default_rng(99)
    idx = spread_indices(surface, 20, rng)
    curves = obj.curves(surface, idx, rng, rate=100.0)
    return surface, curves


def _nearest(points, poked):
    return np.min(np.linalg.norm(points[:, None, :] - poked[None], axis=2), axis=1)


def test_suggestions_are_far_from_data_and_spread(world):
    surface, curves = world
    west = [c for c in curves if c.point[0] < -0.01]
    model = ContactGpModel().fit(west, surface)
    indices, std = suggest_pokes(model, surface, 3, exclude_radius=0.01)
    assert len(indices) == 3 and np.all(np.diff(std) <= 0)
    poked = np.stack([c.point for c in west])
    picked = surface.points[indices]
    typical = np.median(_nearest(surface.points, poked))
    assert np.all(_nearest(picked, poked) > typical)
    gaps = np.linalg.norm(picked[:, None] - picked[None], axis=2)[np.triu_indices(3, 1)]
    assert np.all(gaps > 0.01)
    # The first pick is the most uncertain point of the whole surface.
    all_std = model.predict_std(surface.features, model.reference_depth())
    assert std[0] == pytest.approx(all_std.max())


def test_suggestions_respect_candidates_and_radius(world):
    surface, curves = world
    model = ContactGpModel().fit(curves[:4], surface)
    cand = np.arange(0, len(surface), 13)
    indices, _ = suggest_pokes(model, surface, 5, exclude_radius=0.0, candidates=cand)
    assert len(indices) == 5 and set(indices) <= set(cand)
    one, _ = suggest_pokes(model, surface, 5, exclude_radius=0.2,
                           candidates=np.arange(len(surface)))
    assert len(one) == 0            # every point lies within 0.2 m of an earlier poke
    with pytest.raises(InvalidInput, match='count'):
        suggest_pokes(model, surface, 0, 0.01)
    with pytest.raises(InvalidInput, match='candidate'):
        suggest_pokes(model, surface, 1, 0.01, candidates=[len(surface)])
    with pytest.raises(ModelNotReady):
        suggest_pokes(ContactGpModel(), surface, 1, 0.01)


def test_active_vs_random_figure(world, tmp_path):
    surface, curves = world
    res = active_vs_random_curve(curves, surface, ContactGpModel, start=2, max_pokes=5,
                                 test_fraction=0.3, repeats=2, seed=3)
    assert res['sizes'] == [2, 3, 4, 5]
    for strategy in ('active', 'random'):
        e = np.array(res[strategy]['rmse'])
        assert e.shape == (2, 4) and np.all(np.isfinite(e)) and np.all(e > 0)
    # Both strategies start from the same pokes, so their first errors are identical.
    np.testing.assert_array_equal(np.array(res['active']['rmse'])[:, 0],
                                  np.array(res['random']['rmse'])[:, 0])
    plot_active_vs_random(res, tmp_path / 'avr.png')
    assert (tmp_path / 'avr.png').read_bytes()[:8] == PNG
    with pytest.raises(InvalidInput, match='candidates'):
        active_vs_random_curve(curves[:6], surface, ContactGpModel, max_pokes=5)


def test_learning_curve_table_and_plot(world, tmp_path):
    surface, curves = world
    rows = learning_curve(curves, surface, ContactGpModel, sizes=(2, 4, 40), repeats=2, seed=1)
    assert [r['size'] for r in rows] == [2, 4]          # 40 leaves nothing held out
    for r in rows:
        assert len(r['rmse']) == 2 and r['q25'] <= r['median'] <= r['q75']
    plot_learning_curve(rows, tmp_path / 'lc.png')
    assert (tmp_path / 'lc.png').read_bytes()[:8] == PNG
    with pytest.raises(InvalidInput, match='at least 2'):
        learning_curve(curves[:1], surface, ContactGpModel)
