"""FEM validation against closed forms and invariants (coarse meshes; fine runs are fixtures).

Fixtures in test/data/fem/ come from ``python data/fem/make_fem_cache.py --validation``:

- ``hertz_fine.npz``: rigid sphere R = 10 mm, E = 100 kPa, nu = 0.45 (as the objects), quarter
  of a 600 x 600 x 300 mm block with a bonded base and symmetry planes, small-strain, depths 0.3
  and 0.5 mm (d / R = 0.03-0.05, contact radius 1.7-2.2 mm), at 0.7 / 0.5 / 0.35 mm elements at
  the contact; and nu = 0.3 at 0.35 mm. Measured FE / Hertz at 0.35 mm: 1.015 / 1.014 (nu 0.45),
  1.037 / 1.043 (nu 0.3). The closed-form terms Hertz neglects (exact sphere, bonded block,
  in-plane surface motion: ``validation.hertz_expected_ratio``) predict 1.013 / 1.016 and
  1.034 / 1.042: the FE is within 0.4 % of them.
- ``refine_fine.npz``: point probe (2 mm tip), homogeneous 60 x 60 x 40 mm block, neo-Hookean,
  depths 2 and 5 mm, at 3 / 1.5 / 1 / 0.75 mm elements near the probe.
"""

import os

import numpy as np
import pytest

from pointforce_ros.sim.fem import validation
from pointforce_ros.sim.fem.mesh import structured_hex
from pointforce_ros.sim.fem.probes import point_probe, pose_for_push, sphere_probe
from pointforce_ros.sim.fem.solver import FemModel
from pointforce_ros.sim.objects import load_object
from pointforce_ros.errors import NotConverged

DATA = os.path.join(os.path.dirname(__file__), '..', 'data', 'fem')


@pytest.fixture(scope='module')
def coarse_poke():
    """Point-probe poke of the refinement block at 3 mm elements (the coarse twin)."""
    return validation.refine_case(0.003)


def _hertz_expected(nu, depths, thickness=None):
    p = validation.HERTZ
    return validation.hertz_expected_ratio(depths, p['radius'], p['young'], nu,
                                           thickness or p['size'])


def test_closed_form_corrections_reduce_to_hertz_in_their_limits():
    p = validation.HERTZ
    r, e = p['radius'], p['young']
    d = np.array([1e-7, 1e-6])
    hz = validation.hertz_force(d, r, e, 0.3)
    np.testing.assert_allclose(validation.sneddon_sphere_force(d, r, e, 0.3), hz, rtol=1e-4)
    # Sneddon's sphere is softer than the paraboloid, by (a / R)^2 order
    d = np.array([3e-4, 5e-4])
    below = 1 - validation.sneddon_sphere_force(d, r, e, 0.3) / validation.hertz_force(
        d, r, e, 0.3)
    assert np.all(below > 0) and below[1] > below[0] and below[1] < 0.01
    assert validation.tangential_factor(0.002, r, 0.4999) == pytest.approx(1.0, abs=1e-4)
    assert validation.tangential_factor(0.002, r, 0.3) > validation.tangential_factor(
        0.002, r, 0.45) > 1.0
    assert validation.bonded_layer_factor(0.002, 1e3, 0.45) == pytest.approx(1.0, abs=1e-5)
    thin = validation.bonded_layer_factor(0.002, 0.02, 0.45)
    assert 1.05 < thin < 1.2  # Dimitriadis: +1.041 chi at nu = 0.45, chi = 0.1


def test_hertz_fine_fixture_within_3_percent_and_explained():
    """Finest mesh (0.35 mm at the contact): FE / Hertz within 3 %, FE / closed form within 1 %.

    What is left over Hertz is physics Hertz neglects, checked against closed forms: the exact
    sphere (Sneddon, -0.3 to -0.5 %), the bonded 300 mm block (Dimitriadis et al. 2002,
    +0.6 to +0.8 %) and the in-plane motion of a compressible surface under a curved probe
    (+1.0 to +1.3 % at nu 0.45, +3.2 to +4.0 % at nu 0.3).
    """
    data = np.load(os.path.join(DATA, 'hertz_fine.npz'))
    depths, ratio = data['depths'], data['ratio']
    assert float(data['poisson']) == validation.HERTZ['poisson']
    np.testing.assert_allclose(depths, validation.HERTZ_DEPTHS)
    assert np.all(np.abs(ratio[-1] - 1) < 0.03), ratio[-1]
    expected = _hertz_expected(float(data['poisson']), depths)
    gap = ratio / expected - 1  # (H, K): discretisation and contact-integration error
    assert np.all(np.abs(gap[-1]) < 0.01), gap
    # converging: the finest mesh is closer to the closed form than the coarsest
    assert np.abs(gap[-1]).max() < np.abs(gap[0]).max(), gap
    # nu = 0.3 on the same mesh: the larger in-plane term is predicted to 0.5 %
    measured = data['nu03_ratio'] / ratio[-1]
    predicted = _hertz_expected(0.3, depths) / expected
    assert np.all(predicted > 1.015)
    np.testing.assert_allclose(measured, predicted, rtol=0.005)


def test_hertz_coarse_run_and_neo_hookean_agree_at_small_depth():
    fine = np.load(os.path.join(DATA, 'hertz_fine.npz'))
    # a smaller, coarser block: 1 mm elements, 60 mm quarter block (+3.5 % from the
    # bonded base at this contact radius)
    kw = dict(depths=(0.0005,), size=0.06, h_max=0.012, rings=128)
    linear = validation.hertz_case(0.001, **kw)
    ratio = linear['ratio'][0] / _hertz_expected(validation.HERTZ['poisson'], [0.0005], 0.06)[0]
    # against the closed form of this block: discretisation makes it stiffer, by a few %
    assert 0.995 < ratio < 1.08, ratio
    assert ratio >= fine['ratio'][-1, -1] / fine['expected'][-1] - 0.005
    # at d / R = 0.05 the large-deformation model agrees with small-strain elasticity
    nonlinear = validation.hertz_case(0.001, nonlinear=True, **kw)
    assert nonlinear['force'][0] == pytest.approx(linear['force'][0], rel=0.02)


def test_mesh_refinement_of_the_point_poke(coarse_poke):
    """Refining the point poke's mesh: 1 -> 0.75 mm changes the force by +4.6 % at 2 mm depth
    and +2.1 % at 5 mm (under the 5 % target); 1.5 -> 1 mm by +4.4 % and +6.4 %.

    The fixture holds 3 / 1.5 / 1 / 0.75 mm runs (3 -> 1.5 mm: +11.5 % / +13.3 %); the coarse
    3 mm run is repeated here, so a fixture that no longer matches the solver fails. At 5 mm
    the changes shrink with h; at 2 mm they stall near 4.5 %: the 2 mm-radius tip under a
    25 degree cone is resolved by one or two elements there. The coarser mesh is always the
    stiffer.
    """
    fine = np.load(os.path.join(DATA, 'refine_fine.npz'))
    np.testing.assert_allclose(fine['h'], validation.REFINE_H)
    fz = fine['force'][:, :, 2]  # (H, K)
    np.testing.assert_allclose(coarse_poke['depths'], fine['depths'][0])
    np.testing.assert_allclose(coarse_poke['force'][:, 2], fz[0], rtol=5e-3)
    change = fz[:-1] / fz[1:] - 1  # (H - 1, K): each refinement, at depths 2 and 5 mm
    assert np.all(change > 0), change
    assert np.all(change[-1] < 0.05), change      # 1 -> 0.75 mm: the target
    assert change[1, 0] < 0.05 and change[1, 1] < 0.07, change   # 1.5 -> 1 mm
    assert np.all(change[0] > 1.5 * change[1]), change
    assert change[-1, 1] < 0.5 * change[1, 1], change  # at 5 mm the changes shrink


def test_symmetric_poke_has_no_torque_and_table_balances_the_probe(coarse_poke):
    f = coarse_poke['force']
    size = 0.06
    assert np.all(np.abs(coarse_poke['torque']) < 1e-3 * np.abs(f[:, 2:3]) * size)
    # the tip sits on a node: the discrete solution may lean by a fraction of a percent
    assert np.all(np.abs(f[:, :2]) < 1e-2 * np.abs(f[:, 2:3]))
    np.testing.assert_allclose(coarse_poke['table_force'], f, atol=1e-6 * np.abs(f).max())


def test_force_grows_monotonically_with_depth():
    spec = load_object('plush')
    mesh = spec.build_mesh(0.004, refine_at=(0.5, 0.0), growth=1.5)
    model = FemModel(mesh, spec.gauss_young(mesh), spec.poisson)
    q, n = spec.top_point(0.5, 0.0), spec.top_normal(0.5, 0.0)
    depths = np.array([0.5, 1.0, 2.0, 3.0, 4.0]) * 1e-3
    res = model.indent(point_probe(0.002, 25.0), pose_for_push(q, -n), -n, depths)
    fn = res.force @ n
    assert fn[0] > 0
    assert np.all(np.diff(fn) > 0)
    # and it is convex-ish: stiffness (slope) grows with depth, as for any indenter
    assert np.all(np.diff(np.diff(fn) / np.diff(depths)) > 0)
    tol = np.maximum(model.penetration_tol, model.penetration_rel * depths)
    assert np.all(res.max_penetration <= 5 * tol)  # Uzawa stops within 5x when it stagnates


def test_stiff_inclusion_is_felt():
    """Lamb: a poke over the bone is measurably stiffer than one over plain muscle."""
    spec = load_object('lamb')
    bone = spec.regions[-1].params['centre']
    out = []
    for x, y in ((bone[0], bone[1]), (0.47, -0.02)):
        mesh = spec.build_mesh(0.004, refine_at=(x, y), growth=1.5)
        model = FemModel(mesh, spec.gauss_young(mesh), spec.poisson)
        q, n = spec.top_point(x, y), spec.top_normal(x, y)
        res = model.indent(point_probe(0.002, 25.0), pose_for_push(q, -n), -n, [0.004])
        out.append(float(res.force[-1] @ n))
    assert out[0] > 1.2 * out[1], out


def test_failure_raises_not_converged_naming_the_step():
    mesh = structured_hex(np.linspace(0, 0.02, 5), np.linspace(0, 0.02, 5),
                          np.linspace(0, 0.01, 3))
    model = FemModel(mesh, 1e5, 0.45)
    model.max_iter = 1
    with pytest.raises(NotConverged, match='step 0'):
        model.indent(sphere_probe(0.005), pose_for_push([0.01, 0.01, 0.01], [0, 0, -1]),
                     [0, 0, -1], [0.003], max_bisections=1)


def test_sliding_support_balances_and_is_softer_than_bonded():
    mesh = structured_hex(np.linspace(0.48, 0.52, 9), np.linspace(-0.02, 0.02, 9),
                          np.linspace(0, 0.01, 3))
    forces = []
    for support in ('fixed', 'sliding'):
        model = FemModel(mesh, 1e5, 0.45, support=support, nonlinear=False)
        res = model.indent(sphere_probe(0.01), pose_for_push([0.5, 0.0, 0.01], [0, 0, -1]),
                           [0, 0, -1], [0.0005])
        np.testing.assert_allclose(res.table_force, res.force, atol=1e-6)
        forces.append(res.force[-1, 2])
    assert forces[1] < forces[0]


def test_mesh_shift_case_solves_the_live_path_poke_on_shifted_meshes():
    from pointforce_ros.sim.fem.live import nonlinear_point_poke

    spec = load_object('plush')
    x, y = 0.49, 0.005
    r = validation.mesh_shift_case(spec, x, y, shifts=(0.0, 0.0025), h=0.005)
    depths, f, n, _ = nonlinear_point_poke(spec, x, y, h=0.005)
    np.testing.assert_allclose(r['depths'], depths)
    # no shift: the live path's own poke. The same solve run twice agrees to about 1e-9, not
    # bit for bit (a fresh clone once saw 1.1e-9; the cause is not traced, threaded linear
    # algebra is the likely one), while a mesh shifted by part of an element moves it by
    # percent.
    np.testing.assert_allclose(r['force'][0], f @ n, rtol=1e-7)
    # a shifted mesh answers the same physics, differently discretised
    assert np.all(r['force'][1] > 0) and not np.allclose(r['force'][1], r['force'][0])
    np.testing.assert_allclose(r['spread'], np.ptp(r['force'], axis=0) / r['force'].min(axis=0))
