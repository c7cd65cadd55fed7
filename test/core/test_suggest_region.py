"""A planner's region of interest steers the learner's next-poke suggestions (issue 17)."""

import tracemalloc

import numpy as np
import pytest

from pointforce_ros.errors import InvalidInput
from pointforce_ros.model.learner import check_region, OnlineLearner, region_candidates
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.response.suggest import reference_depth
from pointforce_ros.sim.scenario import HalfSpaceContact, load_scenario
from pointforce_ros.sim.session import halfspace_object, simulate_campaign
from pointforce_ros.types import Surface

CONTACT = HalfSpaceContact(z0=0.04, k0=1.4e4, exponent=1.5, ripple=0.4, wavelength=0.06)
OBJECT = halfspace_object(CONTACT, region=((0.47, 0.53), (-0.03, 0.03)))
REGION = np.array([[0.515, 0.015, 0.04, 0.008]])   # a disc off the pokes' centre


def _surface():
    xs, ys = np.meshgrid(np.linspace(0.465, 0.535, 24), np.linspace(-0.035, 0.035, 24))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.04)])
    return Surface(points=points, normals=np.tile([0.0, 0.0, 1.0], (len(points), 1)))


def _poke_at(point, name):
    return simulate_campaign(OBJECT, load_scenario('clean'), points=[point],
                             normals=[[0.0, 0.0, 1.0]], force_limit=4.0, depth_limit=0.01,
                             speed=0.004, id_prefix=name)[0]


def _learner(tmp_path):
    store = PokeStore(tmp_path / 'pokes')
    for k, xy in enumerate([(0.49, -0.01), (0.50, 0.0), (0.485, 0.01)]):
        store.add(_poke_at([xy[0], xy[1], 0.04], f'poke-0{k}'))
    learner = OnlineLearner(tmp_path / 'pokes', tmp_path / 'models', _surface(),
                            shape_constant=0.004)
    learner.update()
    return store, learner


def test_region_rows_are_checked_and_a_zero_radius_is_no_region():
    assert check_region([0.0, 0.0, 0.0, 0.0]).shape == (0, 4)
    assert check_region([0.5, 0.0, 0.04, 0.01, 0.4, 0.0, 0.04, 0.0]).shape == (1, 4)
    with pytest.raises(InvalidInput):
        check_region([0.5, 0.0, 0.04])
    with pytest.raises(InvalidInput):
        check_region([0.5, 0.0, 0.04, -0.01])
    pts = _surface().points
    everything = np.arange(len(pts))
    np.testing.assert_array_equal(region_candidates(pts, everything, [0, 0, 0, 0]), everything)
    inside = region_candidates(pts, everything, REGION)
    gap = np.hypot(pts[inside, 0] - REGION[0, 0], pts[inside, 1] - REGION[0, 1])
    assert len(inside) > 0 and np.all(gap <= REGION[0, 3])


def test_suggestions_land_in_the_planners_region_and_lower_its_uncertainty(tmp_path):
    stds = {}
    for use_region in (False, True):
        store, learner = _learner(tmp_path / str(use_region))
        for k in range(3):
            idx, _ = learner.suggest(1, exclude_radius=0.004, edge_margin=0.004,
                                     region=REGION if use_region else None)
            point = learner.surface.points[idx[0]]
            if use_region:
                assert np.hypot(*(point[:2] - REGION[0, :2])) <= REGION[0, 3] + 1e-9
            store.add(_poke_at(point, f'poke-1{k}'))
            learner.update()
        inside = region_candidates(learner.surface.points, np.arange(len(learner.surface)),
                                   REGION)
        model = learner.model
        std = model.predict_std(learner.surface.features[inside], reference_depth(model))
        stds[use_region] = float(np.sqrt(np.mean(np.asarray(std) ** 2)))
    # without the region the most uncertain points are the surface's far corners
    assert stds[True] < 0.7 * stds[False]


def test_region_scores_rank_a_uniformly_uncertain_disc_from_its_middle():
    from pointforce_ros.model.learner import region_scores
    pts = _surface().points
    inside = region_candidates(pts, np.arange(len(pts)), REGION)
    score = region_scores(pts[inside], np.ones(len(inside)), 0.004)
    best = pts[inside[np.argmax(score)]]
    rim = np.max(np.hypot(pts[inside, 0] - REGION[0, 0], pts[inside, 1] - REGION[0, 1]))
    assert np.hypot(*(best[:2] - REGION[0, :2])) < 0.3 * rim
    # a point's own variance counts: a lone point scores its variance
    np.testing.assert_allclose(region_scores(pts[:1], np.array([2.0]), 0.004), [4.0])


def test_a_region_of_a_million_rows_is_refused_with_a_reason():
    rows = np.tile([0.5, 0.0, 0.04, 0.01], 1_000_000)
    with pytest.raises(InvalidInput, match='rows, at most'):
        check_region(rows)


def test_region_candidates_memory_stays_bounded_for_many_rows_and_points():
    rng = np.random.default_rng(11)
    pts = np.c_[rng.uniform(0.4, 0.6, (3000, 2)), np.full(3000, 0.04)]
    rows = np.c_[rng.uniform(0.4, 0.6, (3000, 2)), np.full(3000, 0.04),
                 rng.uniform(0.0005, 0.002, 3000)]
    everything = np.arange(len(pts))
    tracemalloc.start()
    try:
        inside = region_candidates(pts, everything, rows)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # the whole candidates x rows x 3 gap array would be 216 MB
    assert peak < 40e6
    expected = [i for i in everything
                if np.any(np.linalg.norm(pts[i, :2] - rows[:, :2], axis=1) <= rows[:, 3])]
    np.testing.assert_array_equal(inside, expected)
