"""Wrench uncertainty: closed forms for the response part, Monte Carlo for the shape part."""

from dataclasses import replace

import numpy as np
import pytest

from pointforce_ros.contact.identify import shape_fit_covariance, ShapeFit
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.contact.uncertainty import wrench_uncertainty, Z90
from pointforce_ros.errors import InvalidInput
from pointforce_ros.lab.synthetic_contact import patch_contact_model
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.shapes import box, icosphere
from pointforce_ros.types import Pose

DOWN = np.array([0.0, 0.0, -1.0])


def _with_std(model, share, decay=np.inf):
    r = model.response
    baked = BakedResponse(depths=r.depths, forces=r.forces, slopes=r.slopes,
                          std=share * r.forces, version=r.version)
    return replace(model, response=baked, shape_decay=decay)


def _queries():
    sphere = icosphere(0.01, 3)
    paddle = box([0.04, 0.006, 0.02])
    at = np.array([0.505, 0.004, 0.04])
    return [(sphere, [Pose(position=at + [0, 0, 0.01 - 0.003]),
                      Pose(position=at + [-0.01, 0.005, 0.01 - 0.002])], at),
            (paddle, [Pose(position=at + [0, 0, -0.002])], at)]


def test_response_part_is_the_share_of_the_wrench_for_a_uniform_relative_spread():
    # forces f_i = y(d~_i); raising y by 10 % everywhere leaves the displacements (the LCP is
    # geometric) and raises every force by 10 %: the response std is 10 % of each component
    model = _with_std(patch_contact_model(), 0.1)
    for mesh, poses, centre in _queries():
        out = wrench_uncertainty(model, mesh, poses, DOWN, centre)
        assert out.wrench.shape == (len(poses), 6) and np.all(out.wrench[:, 2] > 0.2)
        np.testing.assert_allclose(out.parts['response'], 0.1 * np.abs(out.wrench),
                                   rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(out.std, out.parts['response'], rtol=1e-12)
        low, high = out.interval(0.9)
        np.testing.assert_allclose(high - out.wrench, Z90 * out.std, rtol=1e-9)
        # the nominal wrench is the model's own simulator's
        sim = ContactSimulator(model.surface, model.response, model.shape_constant)
        np.testing.assert_allclose(out.wrench, sim.query_batch(mesh, poses, DOWN,
                                                               centre).wrenches, atol=1e-12)


def test_shape_part_matches_monte_carlo_over_c_and_decay():
    model = _with_std(patch_contact_model(), 0.0, decay=0.02)
    cov = np.array([[0.02 ** 2, 0.3 * 0.02 * 4.0], [0.3 * 0.02 * 4.0, 4.0 ** 2]])
    rng = np.random.default_rng(12)
    draws = rng.multivariate_normal([np.log(model.shape_constant), 1.0 / 0.02], cov, 300)
    sim = ContactSimulator(model.surface, model.response, model.shape_constant, decay=0.02)
    mesh, poses, centre = _queries()[1]
    out = wrench_uncertainty(model, mesh, poses, DOWN, centre, shape_cov=cov, response=False)
    samples = np.array([sim.with_shape_constant(np.exp(a), 1.0 / b).query_batch(
        mesh, poses, DOWN, centre).wrenches[0] for a, b in draws])
    mc = samples.std(axis=0)
    assert mc[2] > 0.01 * abs(out.wrench[0, 2])          # the shape matters for a paddle
    np.testing.assert_allclose(out.parts['shape'][0, 2], mc[2], rtol=0.2)
    assert set(out.parts) == {'shape'}


def test_relative_part_and_bad_input():
    model = patch_contact_model()                   # no std in the table: no response part
    mesh, poses, centre = _queries()[0]
    out = wrench_uncertainty(model, mesh, poses, DOWN, centre, relative_std=0.05)
    assert set(out.parts) == {'relative', 'centre'}
    np.testing.assert_allclose(out.std[:, :3], 0.05 * np.abs(out.wrench[:, :3]))
    np.testing.assert_allclose(out.std ** 2, out.parts['relative'] ** 2
                               + out.parts['centre'] ** 2, rtol=1e-12)
    alone = wrench_uncertainty(model, mesh, poses, DOWN, centre, relative_std=0.05,
                               centre=False)
    assert set(alone.parts) == {'relative'}
    np.testing.assert_allclose(alone.std, 0.05 * np.abs(alone.wrench))
    with pytest.raises(InvalidInput, match='shape_cov'):
        wrench_uncertainty(model, mesh, poses, DOWN, centre, shape_cov=[[1.0, 2.0], [0.0, 1]])
    with pytest.raises(InvalidInput, match='relative_std'):
        wrench_uncertainty(model, mesh, poses, DOWN, centre, relative_std=-0.1)
    with pytest.raises(InvalidInput, match='level'):
        out.interval(1.5)
    with pytest.raises(InvalidInput, match='lateral_std'):
        wrench_uncertainty(model, mesh, poses, DOWN, centre, lateral_std=np.nan)


def test_lateral_part_spreads_across_the_approach_only():
    model = patch_contact_model()
    mesh, poses, centre = _queries()[0]
    out = wrench_uncertainty(model, mesh, poses, DOWN, centre, lateral_std=0.1)
    fz = np.abs(out.wrench[:, 2])
    np.testing.assert_allclose(out.std[:, 0], 0.1 * fz)
    np.testing.assert_allclose(out.std[:, 1], 0.1 * fz)
    np.testing.assert_allclose(out.std[:, 2], 0.0)
    # about z (the approach) the lateral force turns only with the in-plane lever
    cop = ContactSimulator(model.surface, model.response, model.shape_constant).query_batch(
        mesh, poses, DOWN, centre, centre_of_pressure=True).centres_of_pressure
    r = cop - centre
    np.testing.assert_allclose(out.std[:, 5], 0.1 * fz * np.hypot(r[:, 0], r[:, 1]),
                               rtol=1e-9)
    # an oblique approach: the component along x shrinks by sqrt(1 - a_x^2)
    a = np.array([0.6, 0.0, -0.8])
    oblique = wrench_uncertainty(model, mesh, poses[:1], a, centre, lateral_std=0.1)
    f_n = abs(oblique.wrench[0, :3] @ a)
    np.testing.assert_allclose(oblique.std[0, :3], 0.1 * f_n * np.sqrt(1 - a ** 2))


def test_the_lateral_force_carries_its_torque_from_the_centre_of_pressure():
    # a planner asking about its wrist, 10 cm above the contact: a lateral discrepancy dF
    # there turns the wrist by r x dF. Monte Carlo of dF (isotropic across the approach, std
    # 0.1 F_n per axis) applied at the centre of pressure against the part's torque std.
    model = patch_contact_model()
    mesh, poses, tip = _queries()[0]
    wrist = tip + np.array([0.0, 0.0, 0.1])
    near = wrench_uncertainty(model, mesh, poses, DOWN, tip, lateral_std=0.1)
    far = wrench_uncertainty(model, mesh, poses, DOWN, wrist, lateral_std=0.1)
    np.testing.assert_allclose(far.wrench[:, :3], near.wrench[:, :3])
    cop = ContactSimulator(model.surface, model.response, model.shape_constant).query_batch(
        mesh, poses, DOWN, wrist, centre_of_pressure=True).centres_of_pressure
    rng = np.random.default_rng(5)
    for i, f_n in enumerate(np.abs(far.wrench[:, 2])):
        d_f = np.zeros((20000, 3))
        d_f[:, :2] = rng.normal(scale=0.1 * f_n, size=(20000, 2))
        d_t = np.cross(cop[i] - wrist, d_f)
        np.testing.assert_allclose(far.std[i, 3:], d_t.std(axis=0), rtol=0.03, atol=1e-9)
        # the 10 cm lever dominates: about 0.1 F_n x 0.1 m on each axis across the approach
        assert far.std[i, 3] > 5 * near.std[i, 3] and far.std[i, 4] > 5 * near.std[i, 4]


def test_the_centre_of_pressure_is_where_the_force_acts():
    # every contact force along the surface normal: on the patch the torque about any centre
    # is (centre of pressure - centre) x force, and the centre of pressure lies under the probe
    model = patch_contact_model()
    sim = ContactSimulator(model.surface, model.response, model.shape_constant)
    for mesh, poses, centre in _queries():
        out = sim.query_batch(mesh, poses, DOWN, centre, centre_of_pressure=True)
        r = out.centres_of_pressure - centre
        lever = np.cross(r, out.wrenches[:, :3])
        np.testing.assert_allclose(out.wrenches[:, 3:5], lever[:, :2],
                                   atol=0.02 * np.abs(lever[:, :2]).max() + 1e-9)
        for pose, cop, spread in zip(poses, out.centres_of_pressure, out.pressure_spreads):
            assert np.linalg.norm(cop[:2] - np.asarray(pose.position)[:2]) < 0.02
            # the spread is the contacts' force-weighted second moment about that centre
            one = sim.query(mesh, pose, DOWN, centre)
            arm = one.rigid_points_in_contact - cop
            w = one.contact_forces / one.contact_forces.sum()
            np.testing.assert_allclose(spread, np.einsum('k,ki,kj->ij', w, arm, arm),
                                       rtol=1e-6, atol=1e-12)
            assert np.all(np.linalg.eigvalsh(spread) > -1e-15)
        plain = sim.query_batch(mesh, poses, DOWN, centre)
        assert plain.centres_of_pressure is None and plain.pressure_spreads is None
    # no contact: the centre of pressure is the torque centre (no lever)
    mesh, poses, centre = _queries()[0]
    lifted = [Pose(position=np.asarray(p.position) + [0, 0, 0.05]) for p in poses]
    out = sim.query_batch(mesh, lifted, DOWN, centre, centre_of_pressure=True)
    assert np.all(out.wrenches == 0.0)
    np.testing.assert_allclose(out.centres_of_pressure, np.broadcast_to(centre, (2, 3)))
    assert np.all(out.pressure_spreads == 0.0)


def test_a_relative_discrepancy_moves_the_centre_of_pressure_by_its_share_of_the_spread():
    # A pressure off by a share rel of itself is off in where it acts, too: each contact's force
    # f_k times 1 + g . (q_k - cop), a linear gradient of that relative size along each
    # principal axis of the contact (g ~ N(0, rel^2 M^+), M the force's second moment across
    # the approach), keeps the total and turns the torque. Monte Carlo over such gradients,
    # applied to the contacts' own forces, normals and positions, against the part.
    model = patch_contact_model()
    sim = ContactSimulator(model.surface, model.response, model.shape_constant)
    rng = np.random.default_rng(17)
    plane = np.eye(3) - np.outer(DOWN, DOWN)
    for mesh, poses, centre in _queries():
        out = wrench_uncertainty(model, mesh, poses, DOWN, centre, relative_std=0.1)
        np.testing.assert_allclose(out.parts['centre'][:, :3], 0.0)
        for i, pose in enumerate(poses):
            one = sim.query(mesh, pose, DOWN, centre)
            f, q, n = one.contact_forces, one.rigid_points_in_contact, one.contact_normals
            cop = (f @ q) / f.sum()
            arm = (q - cop) @ plane
            spread = np.einsum('k,ki,kj->ij', f / f.sum(), arm, arm)
            g = rng.multivariate_normal(np.zeros(3), 0.1 ** 2 * np.linalg.pinv(spread), 4000)
            df = f[None, :] * (g @ arm.T)                               # (draws, K)
            torque = np.einsum('dk,kj->dj', df, np.cross(q - centre, n))
            mc = torque.std(axis=0)
            assert np.all(mc[:2] > 1e-5)                       # mN m: a real part, not noise
            np.testing.assert_allclose(out.parts['centre'][i, 3:5], mc[:2], rtol=0.08)
            assert out.parts['centre'][i, 5] <= 0.1 * mc[:2].max() + 1e-9


def test_shape_covariance_shrinks_with_more_informative_pushes():
    model = patch_contact_model()
    sim = ContactSimulator(model.surface, model.response, model.shape_constant, decay=0.02)
    queries = _queries()
    pokes = []
    for mesh, poses, centre in queries:
        measured = -sim.query_batch(mesh, poses, DOWN, centre).wrenches[:, :3] @ DOWN
        pokes.append((mesh, poses, DOWN, measured * (1 + 0.02 * np.arange(len(poses)))))
    fit = ShapeFit(c=model.shape_constant, u0=np.nan, rmse=0.0, n_points=3, method='probe',
                   decay=0.02)
    both = shape_fit_covariance(sim, pokes, fit)
    sphere_only = shape_fit_covariance(sim, pokes[:1], fit)
    assert both.shape == (2, 2) and np.all(np.linalg.eigvalsh(both) > 0)
    # adding the paddle (a wide contact) pins 1/L down
    assert both[1, 1] < sphere_only[1, 1]
    with pytest.raises(InvalidInput):
        shape_fit_covariance(sim, [], fit)


def test_response_part_reaches_contacts_before_the_observed_surface():
    # camera bias: the table's force starts 1 mm before the observed surface (onset d0 < 0);
    # a sphere 0.5 mm short of the surface touches only at d <= 0 and still gets the spread
    model = _with_std(patch_contact_model(), 0.1)
    r = model.response
    early = BakedResponse(depths=r.depths - 0.001, forces=r.forces, slopes=r.slopes,
                          std=r.std, version=r.version)
    assert np.all(early.onsets() < -0.0009)
    model = replace(model, response=early)
    sphere, _, centre = _queries()[0]
    poses = [Pose(position=centre + [0, 0, 0.01 + 0.0005])]
    out = wrench_uncertainty(model, sphere, poses, DOWN, centre)
    assert out.wrench[0, 2] > 0.01                       # in contact, wholly at d <= 0
    np.testing.assert_allclose(out.parts['response'], 0.1 * np.abs(out.wrench),
                               rtol=1e-6, atol=1e-9)


def test_past_the_horizon_a_stiffening_row_follows_its_tangent_and_a_softening_one_its_law():
    # rows: F = a s^3 (stiffening: a pokes-to-1-mm law run to 25 mm is absurd), F = a s^0.5
    # (softening), and a row still out of contact; grid 0.5 mm to 25 mm, pokes to 2 mm
    depths = np.linspace(0.0, 0.025, 51)
    forces = np.stack([1e9 * depths ** 3, 30.0 * np.sqrt(depths), np.zeros_like(depths)])
    slopes = np.array([3e9 * 0.025 ** 2, 15.0 / np.sqrt(0.025), 0.0])
    table = BakedResponse(depths, forces, slopes, std=0.2 * forces)
    capped = table.with_extrapolation(0.002, kappa=0.1)      # horizon 2: H = 4 mm on the grid
    assert capped.meta['extrapolation_horizon'] == 2.0
    k = int(np.flatnonzero(np.isclose(depths, 0.004))[0])
    tangent = (forces[0, k] - forces[0, k - 1]) / (depths[k] - depths[k - 1])
    want = forces[0, k] + tangent * (depths[k:] - depths[k])
    np.testing.assert_allclose(capped.forces[0, k:], want, rtol=1e-12)
    np.testing.assert_array_equal(capped.forces[0, :k + 1], forces[0, :k + 1])
    assert capped.slopes[0] == pytest.approx(tangent, rel=1e-12)
    assert capped.forces[0, -1] < 0.1 * forces[0, -1]
    # continued past the grid along the tangent too, not the law's slope
    far = capped.force(np.array([0]), np.array([0.035]))[0]
    assert far == pytest.approx(want[-1] + tangent * 0.010, rel=1e-12)
    np.testing.assert_array_equal(capped.forces[1:], forces[1:])
    np.testing.assert_array_equal(capped.slopes[1:], slopes[1:])
    # the model's own std keeps its 20 % share of the force it kept; kappa's term is added
    past = depths > 0.002
    own = 0.2 * capped.forces
    extra = 0.1 * capped.forces * (depths - 0.002) / 0.002
    np.testing.assert_allclose(capped.std[:, past], np.hypot(own, extra)[:, past], rtol=1e-9)
    assert np.all(np.diff(capped.forces, axis=1) >= 0.0)
    # a horizon past the grid caps nothing
    same = table.with_extrapolation(0.002, kappa=0.1, horizon=20.0)
    np.testing.assert_array_equal(same.forces, forces)


def test_the_response_std_grows_past_the_learned_depth():
    # the table: sqrt(std^2 + (kappa F (d - D) / D)^2) past D, the model's own std before it
    model = _with_std(patch_contact_model(), 0.02)
    r = model.response
    grown = r.with_extrapolation(0.004, kappa=0.1, horizon=np.inf)
    past = r.depths > 0.004
    assert past.any() and (~past).any()
    want = np.sqrt(r.std ** 2 + (0.1 * r.forces * (r.depths - 0.004) / 0.004) ** 2)
    np.testing.assert_allclose(grown.std[:, past], want[:, past], rtol=1e-12)
    np.testing.assert_array_equal(grown.std[:, ~past], r.std[:, ~past])
    np.testing.assert_array_equal(grown.forces, r.forces)
    assert grown.meta['learned_depth'] == 0.004 and grown.meta['extrapolation_kappa'] == 0.1
    # the default horizon (twice the learned depth) leaves the table to there as it was
    capped = r.with_extrapolation(0.004, kappa=0.1)
    within = r.depths <= 0.008
    np.testing.assert_array_equal(capped.forces[:, within], r.forces[:, within])
    np.testing.assert_allclose(capped.std[:, within], grown.std[:, within], rtol=1e-12)
    # nothing to grow: no std, no depth, kappa 0
    for same in (BakedResponse(r.depths, r.forces, r.slopes).with_extrapolation(0.004),
                 r.with_extrapolation(None),
                 r.with_extrapolation(float('nan')), r.with_extrapolation(0.0),
                 r.with_extrapolation(0.004, kappa=0.0, horizon=np.inf)):
        assert same.std is None or np.array_equal(same.std, r.std)
    # the wrench: queries pressing 2-3 mm keep their response part when the pokes reached
    # 10 mm and get a wider one when they reached 1 mm, wider still at a larger kappa
    mesh, poses, centre = _queries()[0]
    parts = [wrench_uncertainty(replace(model, response=r.with_extrapolation(depth, kappa)),
                                mesh, poses, DOWN, centre).parts['response'][:, 2]
             for depth, kappa in ((0.010, 0.1), (0.001, 0.1), (0.001, 0.3))]
    own = wrench_uncertainty(model, mesh, poses, DOWN, centre).parts['response'][:, 2]
    np.testing.assert_allclose(parts[0], own, rtol=1e-12)
    assert np.all(parts[1] > 1.5 * own) and np.all(parts[2] > 1.5 * parts[1])


def test_the_spread_is_taken_under_the_services_neighbour_rule():
    model = patch_contact_model(spacing=0.003)
    sphere = icosphere(0.012, 2)
    poses = [Pose(position=[0.5003 + 0.0004 * i, 0.0011, 0.04 + 0.012 - 0.003]) for i in range(4)]
    down, centre = [0.0, 0.0, -1.0], [0.5, 0.0, 0.05]
    answers = {}
    for rule in ('equal', 'smooth'):
        u = wrench_uncertainty(model, sphere, poses, down, centre, relative_std=0.1,
                               neighbours=rule)
        sim = ContactSimulator(model.surface, model.response, model.shape_constant,
                               neighbours=rule)
        np.testing.assert_allclose(u.wrench, sim.query_batch(sphere, poses, down,
                                                             centre).wrenches, rtol=1e-12)
        answers[rule] = u
    # the two rules answer differently (the spread follows the answer it is of)
    assert np.all(np.abs(answers['smooth'].wrench[:, 2] - answers['equal'].wrench[:, 2])
                  > 1e-4 * answers['equal'].wrench[:, 2])
    with pytest.raises(InvalidInput, match="neighbours: must be one of"):
        wrench_uncertainty(model, sphere, poses, down, centre, neighbours='cubic')
