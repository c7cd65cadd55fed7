"""Identification of (E, nu) and force from deformation: closed loop, cell fixtures, bad requests.

The closed-loop cases render the estimator's own model (exact answer known); the fixture cases
use static pushes of the cell's independent ground-truth FEM (neo-Hookean hexahedra) seen by its
depth camera (test/data/deformation/, ``make_deformation_fixtures.py``).
"""

import os

import numpy as np
import pytest

from pointforce_ros.deformation.bench import surface_samples
from pointforce_ros.deformation.fem import (CorotationalFem, load_columns,
                                            surface_point_load)
from pointforce_ros.deformation.force import (estimate_force, estimate_force_nelder_mead,
                                              ForceConfig, pull_reason)
from pointforce_ros.deformation.identify import (identify_elasticity, IdentifyConfig, Poke,
                                                 ReducedPoissonFamily)
from pointforce_ros.deformation.mesh import block_mesh, volume_mesh_from_surface
from pointforce_ros.deformation.observe import rest_offsets
from pointforce_ros.errors import InvalidInput

DATA = os.path.join(os.path.dirname(__file__), '..', 'data', 'deformation')
SIZE = (0.06, 0.05, 0.03)
CORNER = (0.47, -0.025)


@pytest.fixture(scope='module')
def mesh():
    return block_mesh(SIZE, 0.005, 5, grading=1.5, corner=CORNER)


def _sample_surface(mesh, u, count, noise, seed):
    """Seeded points on the displaced surface triangles (area-uniform) plus normal noise."""
    return surface_samples(mesh, u, count, noise, np.random.default_rng(seed))


def _push(fem, point, force, radius=0.004):
    nodes, w = surface_point_load(fem.mesh, point, radius)
    return fem.solve(load_columns(fem.mesh, nodes, w) @ np.asarray(force))


def test_reduced_poisson_family_matches_direct_solves(mesh):
    fem = CorotationalFem(mesh, 1.0, 0.35)
    nodes, w = surface_point_load(mesh, [0.5, 0.0, SIZE[2]], 0.004)
    loads = (load_columns(mesh, nodes, w) @ [0.2, 0.0, -1.0])[:, None]
    family = ReducedPoissonFamily(fem, loads, krylov=10)
    # measured: 0.0 at the reference, 4.7e-3 at nu = 0.49 (near-incompressible end)
    for nu, tol in ((0.05, 2e-3), (0.35, 1e-9), (0.45, 2e-3), (0.49, 1e-2)):
        fem.set_material(1.0, nu)
        direct = fem.solve_linear(loads)
        err = np.abs(family.displacements(nu) - direct).max() / np.abs(direct).max()
        assert err < tol, nu


def test_closed_loop_identification_and_force(mesh):
    truth = CorotationalFem(mesh, 3e4, 0.42)
    points = [[0.49, -0.008, SIZE[2]], [0.51, 0.01, SIZE[2]]]
    forces = [[0.05, 0.0, -0.6], [-0.1, 0.05, -0.8]]
    pokes = [Poke(p, f, _sample_surface(mesh, _push(truth, p, f), 6000, 5e-5, k))
             for k, (p, f) in enumerate(zip(points, forces))]
    fit, fem = identify_elasticity(mesh, pokes)
    assert fit.young == pytest.approx(3e4, rel=0.02)
    assert fit.poisson == pytest.approx(0.42, abs=0.02)
    assert fit.seconds < 30
    # a held-out push, camera only
    p, f = [0.5, -0.002, SIZE[2]], np.array([0.15, -0.1, -0.7])
    cloud = _sample_surface(mesh, _push(truth, p, f), 6000, 5e-5, 9)
    est = estimate_force(fem, p, cloud)
    np.testing.assert_allclose(est.force, f, atol=0.03 * np.linalg.norm(f))
    assert est.residual_rms < 2e-4
    assert np.all(est.uncertainty > 0) and est.magnitude_std < 0.05
    slow = estimate_force_nelder_mead(fem, p, cloud, ForceConfig(corotational=False),
                                      max_evaluations=400)
    np.testing.assert_allclose(slow.force, f, atol=0.05 * np.linalg.norm(f))


def test_identification_reports_an_interval_that_covers_the_truth_and_widens_with_noise(mesh):
    truth = CorotationalFem(mesh, 3e4, 0.3)
    points = [[0.49, -0.008, SIZE[2]], [0.51, 0.01, SIZE[2]]]
    forces = [[0.05, 0.0, -0.6], [-0.1, 0.05, -0.8]]
    widths = []
    for noise in (1e-4, 6e-4):
        pokes = [Poke(p, f, _sample_surface(mesh, _push(truth, p, f), 4000, noise, 20 + k))
                 for k, (p, f) in enumerate(zip(points, forces))]
        fit, _ = identify_elasticity(mesh, pokes)
        lo, hi = fit.poisson_interval
        assert lo <= fit.poisson <= hi
        assert lo - 0.01 <= 0.3 <= hi + 0.01, (noise, fit.poisson_interval)
        e_lo, e_hi = fit.young_interval
        assert e_lo <= fit.young <= e_hi and e_lo < 3e4 * 1.02 and e_hi > 3e4 * 0.98
        widths.append(hi - lo)
    # six times the noise: a wider interval (a fixed-width report would not widen)
    assert widths[1] > 2 * widths[0], widths


def test_bad_requests_are_refused(mesh):
    fem = CorotationalFem(mesh, 3e4, 0.4)
    p = [0.5, 0.0, SIZE[2]]
    good = _sample_surface(mesh, _push(fem, p, [0, 0, -1.0]), 3000, 0.0, 1)
    with pytest.raises(InvalidInput, match='empty'):
        estimate_force(fem, p, np.zeros((0, 3)))
    with pytest.raises(InvalidInput, match='NaN'):
        estimate_force(fem, p, np.vstack([good, [np.nan, 0, 0]]))
    with pytest.raises(InvalidInput, match='not on it'):
        estimate_force(fem, [0.5, 0.0, SIZE[2] + 0.03], good)
    with pytest.raises(InvalidInput, match='only'):
        estimate_force(fem, p, good * [1, 1, 0])  # every point on the table
    with pytest.raises(InvalidInput):
        identify_elasticity(mesh, [])
    with pytest.raises(InvalidInput, match='zero force'):
        identify_elasticity(mesh, [Poke(p, [0, 0, 0], good)])
    with pytest.raises(InvalidInput):
        IdentifyConfig(poisson_bounds=(0.3, 0.6))
    with pytest.raises(InvalidInput):
        ForceConfig(load_radius=0.0)


def _fixture(name):
    with np.load(os.path.join(DATA, f'{name}.npz')) as data:
        return dict(data)


def _cloud(push, k):
    s = push['cloud_start']
    return push['cloud'][s[k]:s[k + 1]].astype(float)


def test_foam_block_identification_and_held_out_force_against_the_cell():
    rest = _fixture('rest_foam_block')
    mesh = volume_mesh_from_surface(rest['points'], rest['normals'], element_size=0.004,
                                    layers=8)
    offset = rest_offsets(mesh, rest['points'])
    pushes = [_fixture(f'push_foam_block_{k}') for k in range(6)]
    pokes = [Poke(d['contact_point'], d['force'][0], _cloud(d, 0))  # the 3 mm states
             for d in pushes if str(d['role']) == 'identify']
    fit, fem = identify_elasticity(mesh, pokes, rest_offset=offset)
    truth_e, truth_nu = float(pushes[0]['young']), float(pushes[0]['poisson'])
    # measured: E 53.9 kPa (+7.8 %), nu 0.227 (truth 50 kPa, 0.30): nu is weakly observable
    # from one top view, as the paper's figure 3 shows
    assert fit.young == pytest.approx(truth_e, rel=0.12)
    assert fit.poisson == pytest.approx(truth_nu, abs=0.1)
    errors = []
    for d in pushes:
        if str(d['role']) != 'heldout':
            continue
        for k in range(len(d['depths'])):
            est = estimate_force(fem, d['contact_point'], _cloud(d, k),
                                 ForceConfig(corotational=False), rest_offset=offset)
            errors.append(np.linalg.norm(est.force - d['force'][k]) / np.linalg.norm(
                d['force'][k]))
    # measured: median 6.5 %, worst 11.7 % (at 3 mm, 0.7 N)
    assert np.median(errors) < 0.1
    assert max(errors) < 0.15


def test_clouds_that_do_not_see_the_push_identify_no_modulus():
    """Audit 39: the rest scan given as the pushed cloud "identified" E 0.87 MPa (truth 50 kPa)
    with a compliance 1.5 standard errors wide of zero; the same push's real cloud is 0.12."""
    rest = _fixture('rest_foam_block')
    mesh = volume_mesh_from_surface(rest['points'], rest['normals'], element_size=0.006,
                                    layers=4)
    offset = rest_offsets(mesh, rest['points'])
    push = _fixture('push_foam_block_0')
    fit, _ = identify_elasticity(mesh, [Poke(push['contact_point'], push['force'][0],
                                             _cloud(push, 0))], rest_offset=offset)
    assert fit.young == pytest.approx(float(push['young']), rel=0.2)
    assert fit.young_std < 0.3 * fit.young
    for force in (push['force'][0], 1e6 * push['force'][0]):   # E 0.87 MPa, 0.87 TPa before
        with pytest.raises(InvalidInput, match='do not resolve a displacement'):
            identify_elasticity(mesh, [Poke(push['contact_point'], force, rest['points'])],
                                rest_offset=offset)


def test_identification_with_a_given_modulus_field_recovers_its_scale_and_local_moduli(mesh):
    # a block twice as stiff on its +x half: a uniform fit reads the two pokes' own moduli
    # apart (local_young), and the true field shape gives back the true scale
    centroid = mesh.nodes[mesh.tets].mean(axis=1)
    field = np.where(centroid[:, 0] > 0.5, 2.0, 1.0)
    field /= field.mean()
    truth = CorotationalFem(mesh, 4e4 * field, 0.35)
    points = [[0.485, 0.0, SIZE[2]], [0.515, 0.0, SIZE[2]]]
    forces = [[0.0, 0.0, -0.6], [0.0, 0.0, -0.9]]
    pokes = [Poke(p, f, _sample_surface(mesh, _push(truth, p, f), 5000, 3e-5, 40 + k))
             for k, (p, f) in enumerate(zip(points, forces))]
    uniform, _ = identify_elasticity(mesh, pokes, IdentifyConfig(poisson_bounds=(0.34, 0.36)))
    soft, stiff = uniform.local_young
    assert stiff > 1.4 * soft, uniform.local_young
    fit, fem = identify_elasticity(mesh, pokes, IdentifyConfig(poisson_bounds=(0.34, 0.36)),
                                   young_field=field)
    assert fit.young == pytest.approx(4e4, rel=0.05)
    np.testing.assert_allclose(fem.element_young / fem.young, field, rtol=1e-9)
    # E's std at the fitted nu is smaller than the interval over every nu it could be
    assert 0 < fit.young_std / fit.young < fit.young_relative_std
    with pytest.raises(InvalidInput, match='positive'):
        identify_elasticity(mesh, pokes, young_field=-field)


def test_a_cloud_that_bulges_out_at_the_contact_is_a_pull_not_a_push(mesh):
    fem = CorotationalFem(mesh, 3e4, 0.35)
    p = [0.5, 0.0, SIZE[2]]
    press = _sample_surface(mesh, _push(fem, p, [0.1, 0.0, -0.8]), 6000, 5e-5, 3)
    est = estimate_force(fem, p, press)
    assert pull_reason(fem, p, est) is None
    # the same surface pulled out by 0.8 N (a cloud of another state, a wrong contact point)
    bulge = _sample_surface(mesh, _push(fem, p, [0.1, 0.0, 0.8]), 6000, 5e-5, 4)
    est = estimate_force(fem, p, bulge)
    assert est.force[2] > 0.5   # the estimate explains the cloud: an outward force
    reason = pull_reason(fem, p, est)
    assert reason is not None and 'outward' in reason
