"""The shape function's near field: the paper's ``c / (c + r)`` or the flat ``(1 + r/c) e^(-r/c)``.

* the flat near field is 1 at the centre with no slope there (a dent spread by a skin), and its
  matrices stay positive definite with a fixed or a per-point tail;
* the stacked matrices and the compiled single-pose kernel use it (single = batch is checked in
  ``test_contact_single_pose.py``);
* :func:`choose_near` picks, by held-out error, the near field the pushes were made with, and
  :func:`calibrate_shape` identifies ``(c, L)`` under it;
* the model file, ``shape.json``, the learner and the contact service carry it.
"""

import numpy as np
import pytest

from pointforce_ros.contact import ContactSimulator, identify, shape_function
from pointforce_ros.contact.identify import calibrate_shape, choose_near
from pointforce_ros.contact.lcp import (check_near, NEARS, PointShapeStack, shape_matrix,
                                        varying_shape_function)
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.lab.synthetic_contact import grid_surface, power_response
from pointforce_ros.model.files import (_header, ContactModel, load_model, load_shape_near,
                                        save_model, save_shape, SHAPE)
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Pose

C = 0.004
DOWN = np.array([0.0, 0.0, -1.0])


def test_the_flat_near_field_is_flat_at_the_centre_and_positive_definite():
    r = np.array([0.0, 1e-5, C, 3 * C])
    g = shape_function(r, C, near='flat')
    np.testing.assert_allclose(g, (1 + r / C) * np.exp(-r / C), rtol=1e-14)
    assert g[0] == 1.0
    # no slope at r = 0 (the paper's falls as 1 - r / c): a flat-topped dent
    t = 1e-5 / C
    assert 1.0 - g[1] < t ** 2 and 1.0 - shape_function(1e-5, C) > 0.9 * t
    np.testing.assert_allclose(shape_function(r, C, 0.01, near='flat'),
                               g * np.exp(-r / 0.01), rtol=1e-14)
    rng = np.random.default_rng(8)
    q = np.column_stack([rng.uniform(-0.02, 0.02, (90, 2)), rng.normal(0, 1e-3, 90)])
    for decay in (np.inf, 0.008):
        assert np.linalg.eigvalsh(shape_matrix(q, C, decay, near='flat')).min() > 1e-9
    lengths = rng.uniform(0.001, 0.03, 90)
    r = np.linalg.norm(q[:, None] - q[None], axis=2)
    G = varying_shape_function(r, C, lengths[:, None], lengths[None], near='flat')
    np.testing.assert_allclose(np.diagonal(G), 1.0, rtol=1e-13)
    assert np.linalg.eigvalsh(G).min() > 1e-9
    with pytest.raises(InvalidInput, match='near'):
        check_near('gaussian')
    with pytest.raises(InvalidInput, match='near'):
        ContactSimulator(grid_surface(half=0.005, step=0.001),
                         power_response(1e4, 1.5, 121), C, near='bogus')


def test_the_point_stack_builds_the_flat_matrices():
    rng = np.random.default_rng(9)
    points = rng.uniform(-0.01, 0.01, (3, 25, 3)) * [1, 1, 0.05]
    lengths = rng.uniform(0.002, 0.02, (3, 25))
    for decays in (None, lengths):
        dense = PointShapeStack(points, C, 0.01, decays, near='flat').dense()
        for b in range(3):
            r = np.linalg.norm(points[b, :, None] - points[b, None], axis=2)
            want = (shape_matrix(points[b], C, 0.01, near='flat') if decays is None else
                    varying_shape_function(r, C, lengths[b, :, None], lengths[b, None], 'flat'))
            np.testing.assert_allclose(dense[b], want, rtol=1e-9, atol=1e-12)


def _pushes(truth, surface_half=0.04):
    """Three pushes with different probes, measured on ``truth`` (sphere, bar, wide paddle)."""
    out = []
    for mesh, lift, depths in ((icosphere(0.015, 3), 0.015, (0.002, 0.004)),
                               (box((0.05, 0.01, 0.01)), 0.0, (0.0015, 0.003)),
                               (box((0.03, 0.03, 0.01)), 0.0, (0.001, 0.002))):
        poses = [Pose(position=[0.0003, 0.0002, lift - d]) for d in depths]
        force = [truth.query(mesh, p, DOWN, p.position).wrench.force[2] for p in poses]
        out.append((mesh, poses, DOWN, np.array(force)))
    return out


@pytest.fixture(scope='module')
def patch():
    surface = grid_surface(half=0.035, step=0.003)
    return surface, power_response(3e4, 1.5, len(surface))


@pytest.mark.parametrize('made_with', NEARS)
def test_choose_near_finds_the_near_field_the_pushes_were_made_with(patch, made_with):
    surface, response = patch
    truth = ContactSimulator(surface, response, c=0.005, decay=0.016, near=made_with)
    pushes = _pushes(truth)
    start = ContactSimulator(surface, response, c=0.002)          # the paper's near field
    near, errors = choose_near(start, pushes, decays=(0.008, 0.016, 0.032))
    assert near == made_with
    other = next(n for n in NEARS if n != made_with)
    assert errors[other] > 2 * errors[made_with] + 0.005          # not a close call
    cal = calibrate_shape(start, pushes, decays=(0.008, 0.016, 0.032), nears=NEARS)
    assert cal.near == made_with and cal.near_errors == errors
    assert cal.fit.c == pytest.approx(0.005, rel=0.05) and cal.fit.decay == 0.016
    assert start.near == 'paper'                                   # the caller's is left alone
    # two pushes cannot choose (the held-out push would not refit L): the simulator's own
    assert choose_near(start, pushes[:2], decays=(0.016,)) == ('paper', {})
    assert calibrate_shape(start, pushes, decays=(0.008, 0.016, 0.032)).near == 'paper'


def test_calibrate_shape_reuses_the_held_out_refits_choose_near_made(patch, monkeypatch):
    surface, response = patch
    pushes = _pushes(ContactSimulator(surface, response, c=0.005, decay=0.016, near='flat'))
    start = ContactSimulator(surface, response, c=0.002)
    decays = (0.008, 0.016, 0.032)
    chosen = calibrate_shape(start.with_shape_constant(start.c, near='flat'), pushes,
                             decays=decays)
    fits = []
    original = identify.identify_shape_constant_from_probes

    def counted(sim, pokes, c_bounds=(1e-4, 0.1), decays=None):
        fits.append(len(pokes) if decays is not None and len(decays) > 1 else 0)
        return original(sim, pokes, c_bounds, decays)

    monkeypatch.setattr(identify, 'identify_shape_constant_from_probes', counted)
    cal = calibrate_shape(start, pushes, decays=decays, nears=NEARS)
    assert cal.near == 'flat'
    # the same held-out numbers as a calibration told the near field ...
    np.testing.assert_allclose(cal.held_out, chosen.held_out, rtol=1e-12)
    assert cal.held_out_decays == chosen.held_out_decays
    assert cal.relative_std == pytest.approx(chosen.relative_std, rel=1e-12)
    # ... from one refit over the decay lengths per push and near field, and the joint fit
    n = len(pushes)
    assert sorted(f for f in fits if f) == [n - 1] * (len(NEARS) * n) + [n]


def test_the_share_after_a_choice_predicts_each_push_under_the_near_field_chosen_without_it(
        patch):
    """With four pushes the held-out share is nested: the chosen near field's own held-out
    errors are the smallest offered, so they understate what the choice meets on a new push."""
    surface, response = patch
    made = {near: _pushes(ContactSimulator(surface, response, c=0.005, decay=0.016, near=near))
            for near in NEARS}
    pushes = [made['flat'][0], made['paper'][1], made['flat'][2], made['paper'][0]]
    start = ContactSimulator(surface, response, c=0.002)
    decays = (0.016,)                   # one decay length: the choice still flips, 3x faster
    cal = calibrate_shape(start, pushes, decays=decays, nears=NEARS)
    assert cal.near == 'flat'
    inner = []
    for i, push in enumerate(pushes):
        others = pushes[:i] + pushes[i + 1:]
        near, _ = choose_near(start, others, decays=decays)
        inner.append(near)
        sim = start.with_shape_constant(start.c, near=near)
        fit = identify.identify_shape_constant_from_probes(sim, others, decays=decays)
        error = identify._relative_error(sim.with_shape_constant(fit.c, fit.decay), push)
        np.testing.assert_allclose(cal.held_out[i], (fit.c, error), rtol=1e-9)
        assert cal.held_out_decays[i] == fit.decay
    assert 'paper' in inner             # the choice flips without some push: a real test
    errors = np.array([e for _, e in cal.held_out])
    share = np.sqrt(np.mean(errors ** 2)) * identify.small_sample_factor(len(errors))
    assert cal.relative_std == pytest.approx(max(share, cal.in_sample_std), rel=1e-12)
    assert cal.relative_std > cal.near_errors['flat'] * identify.small_sample_factor(4)


def test_models_shape_files_the_learner_and_the_service_keep_the_near_field(tmp_path, patch):
    surface, response = patch
    flat = ContactModel(surface=surface, response=response, shape_constant=0.005, version=3,
                        shape_decay=0.016, shape_near='flat')
    path = save_model(flat, tmp_path)
    assert load_model(path).shape_near == 'flat'
    plain = ContactModel(surface=surface, response=response, shape_constant=0.005, version=4,
                         shape_decay=0.016)
    assert 'shape_near' not in _header(plain)         # as in every file from before the field
    assert load_model(save_model(plain, tmp_path / 'paper')).shape_near == 'paper'
    with pytest.raises(InvalidInput, match='shape_near'):
        ContactModel(surface=surface, response=response, shape_constant=0.005, shape_near='x')
    # the service answers with the model's near field
    mesh, pose = box((0.03, 0.03, 0.01)), Pose(position=[0.0, 0.0, -0.002])
    server = WrenchServer()
    server.load(path)
    served = server.simulator().query(mesh, pose, DOWN, pose.position).wrench.force[2]
    want = ContactSimulator(surface, response, 0.005, decay=0.016, near='flat').query(
        mesh, pose, DOWN, pose.position).wrench.force[2]
    other = ContactSimulator(surface, response, 0.005, decay=0.016).query(
        mesh, pose, DOWN, pose.position).wrench.force[2]
    assert served == pytest.approx(want, rel=1e-9) and abs(want - other) > 0.05 * abs(want)
    # shape.json
    assert load_shape_near(tmp_path / 'none') == 'paper'
    save_shape(tmp_path, 0.005, 0.016, near='flat')
    assert load_shape_near(tmp_path) == 'flat'
    (tmp_path / SHAPE).write_text('{"shape_constant": 0.005, "shape_near": "round"}')
    with pytest.raises(DataError, match='near'):
        load_shape_near(tmp_path)
    with pytest.raises(InvalidInput, match='near'):
        save_shape(tmp_path, 0.005, near='round')
