"""A rigid probe pressed into the FEM, and the wide-contact comparison, on known answers."""

import numpy as np
import pytest

from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.deformation.mesh import block_mesh
from pointforce_ros.deformation.rigid_contact import RigidProbeContact
from pointforce_ros.deformation.wide_contacts import (anchor_curves, calibrate_young,
                                                      fem_trial_wrenches, modulus_field,
                                                      point_probe, POINT_PROBE, poke_forces,
                                                      scan_offset, trial_scores)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.sim.fem import live, probes
from pointforce_ros.sim.fem.probes import box_probe, pose_for_push
from pointforce_ros.types import Surface

L, H = 0.02, 0.01
E = 5e4


def _sliding_block():
    """Block on a frictionless table (bottom fixed in z only, two symmetry planes)."""
    mesh = block_mesh((L, L, H), 0.005, 3)
    fixed = np.zeros((mesh.n_nodes, 3), dtype=bool)
    fixed[mesh.fixed_nodes, 2] = True
    fixed[np.isclose(mesh.nodes[:, 0], 0), 0] = True
    fixed[np.isclose(mesh.nodes[:, 1], 0), 1] = True
    return CorotationalFem(mesh, E, 0.3, fixed_dofs=fixed)


def _plate_trial(depths):
    """A plate wider than the block pressed straight down: uniaxial stress, F = E A s / H."""
    start = pose_for_push([L / 2, L / 2, H + 0.001], [0.0, 0.0, -1.0])
    travel = np.clip(np.asarray(depths) - 0.001, 0.0, None)
    force = np.column_stack([np.zeros((len(depths), 2)), E * L * L * travel / H])
    return {'kind': 'cylinder', 'mesh': box_probe((0.05, 0.05, 0.01)),
            'start_position': start.position, 'orientation': start.orientation,
            'direction': np.array([0.0, 0.0, -1.0]), 'torque_centre': start.position,
            'depths': np.asarray(depths, dtype=float), 'force': force,
            'torque': np.zeros((len(depths), 3))}


def test_plate_on_a_sliding_block_gives_uniaxial_stress():
    solver = RigidProbeContact(_sliding_block())
    trial = _plate_trial([0.0005, 0.0015, 0.002])
    start = pose_for_push(trial['start_position'], trial['direction'])
    assert solver.first_contact(trial['mesh'], start, trial['direction']) == pytest.approx(
        0.001, abs=1e-6)
    res = solver.press(trial['mesh'], start, trial['direction'], trial['depths'])
    # the contact compliance (1e-6 of G's diagonal) is the only departure from exactness
    np.testing.assert_allclose(res.force, trial['force'], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(res.torque, 0.0, atol=1e-8)
    assert res.contacts[0] == 0 and res.contacts[-1] > 0
    off = np.array([0.003, -0.002, 0.0])
    moved = solver.press(trial['mesh'], start, trial['direction'], trial['depths'],
                         torque_centre=trial['start_position'] + off)
    np.testing.assert_allclose(moved.torque, np.cross(-off, res.force), atol=1e-8)
    # the comparison scores the exact prediction at zero error
    scores = trial_scores(fem_trial_wrenches(solver, [trial]), [trial])
    assert scores['force_rmse'] < 1e-5
    assert scores['force_rmse_cylinder'] == pytest.approx(scores['force_rmse'])
    assert scores['force_rmse_line'] is None


def test_corotational_press_agrees_at_small_strain():
    solver = RigidProbeContact(_sliding_block())
    trial = _plate_trial([0.0012])
    start = pose_for_push(trial['start_position'], trial['direction'])
    lin = solver.press(trial['mesh'], start, trial['direction'], trial['depths'])
    cor = solver.press(trial['mesh'], start, trial['direction'], trial['depths'],
                       corotational=True)
    np.testing.assert_allclose(cor.force, lin.force, rtol=1e-3)


def test_trial_scores_of_a_known_error():
    f = np.array([[0.0, 0.0, 1.0], [0.0, 3.0, 4.0]])
    t = np.array([[0.0, 0.01, 0.0], [0.02, 0.0, 0.0]])
    trial = {'kind': 'line', 'force': f, 'torque': t}
    s = trial_scores([(1.1 * f, t)], [trial])
    assert s['magnitude_error'] == pytest.approx(0.1)
    assert s['bias'] == pytest.approx(0.1)
    assert s['force_rmse'] == pytest.approx(0.1 * np.sqrt((1 + 25) / 2))
    assert s['torque_rmse'] == 0.0
    assert s['per_trial'][0]['peak_force'] == pytest.approx(5.0)
    with pytest.raises(InvalidInput):
        trial_scores([(f[:1], t[:1])], [trial])


def test_calibration_recovers_the_modulus_that_made_the_pokes():
    mesh = block_mesh((0.04, 0.04, 0.02), 0.004, 4, corner=(-0.02, -0.02))
    solver = RigidProbeContact(CorotationalFem(mesh, 3e4, 0.4))
    probe = point_probe(**POINT_PROBE)
    curves = []
    for k, (x, y) in enumerate([(0.0, 0.0), (0.006, -0.004)]):
        travel = np.linspace(0.0, 0.004, 6)
        c = PokeCurve(poke_id=f'p{k}', point=np.array([x, y, 0.02]),
                      normal=np.array([0.0, 0.0, 1.0]), d=travel, f=np.zeros(6), onset_d=0.0,
                      t=travel / 0.002)
        f = np.concatenate([[0.0], poke_forces(solver, probe, c, travel[1:])])
        curves.append(PokeCurve(poke_id=c.poke_id, point=c.point, normal=c.normal, d=travel,
                                f=f, onset_d=0.0, t=c.t))
    solver.fem.set_material(1e4, 0.4)  # a wrong start: the fit must move it to 3e4
    cal = calibrate_young(solver, probe, curves, count=4)
    assert cal['young'] == pytest.approx(3e4, rel=1e-9)
    np.testing.assert_allclose(cal['per_poke'], 3e4, rtol=1e-9)
    assert cal['rms'] < 1e-9
    assert solver.fem.young == pytest.approx(3e4, rel=1e-9)
    rel = modulus_field(mesh, cal['points'], [2e4, 8e4])
    assert rel.shape == (len(mesh.tets),)
    assert np.exp(np.mean(np.log(rel))) == pytest.approx(1.0)
    assert rel.max() / rel.min() <= 4.0 + 1e-9


def test_scan_offset_and_anchoring_undo_a_camera_bias():
    bias = 0.002
    xy = np.stack(np.meshgrid(np.linspace(-0.01, 0.01, 9), np.linspace(-0.01, 0.01, 9)),
                  -1).reshape(-1, 2)
    surface = Surface(points=np.column_stack([xy, np.full(len(xy), 0.03 - bias)]),
                      normals=np.tile([0.0, 0.0, 1.0], (len(xy), 1)))
    d = np.linspace(0.0, 0.004, 5)
    truth = PokeCurve(poke_id='p', point=np.array([0.0, 0.0, 0.03]),
                      normal=np.array([0.0, 0.0, 1.0]), d=d, f=d * 1e3, onset_d=0.0, t=d)
    (seen,) = anchor_curves([truth], surface)
    assert seen.onset_d == pytest.approx(-bias)
    np.testing.assert_allclose(seen.d, d - bias, atol=1e-12)
    assert seen.point[2] == pytest.approx(0.03 - bias)
    assert scan_offset([seen]) == pytest.approx(bias)


def test_point_probe_is_the_cells():
    assert POINT_PROBE == live.POINT_PROBE
    ours, cell = point_probe(**POINT_PROBE), probes.point_probe(**live.POINT_PROBE)
    np.testing.assert_allclose(ours.vertices.min(axis=0), cell.vertices.min(axis=0), atol=2e-5)
    np.testing.assert_allclose(ours.vertices.max(axis=0), cell.vertices.max(axis=0), atol=2e-5)

    def volume(m):
        c = m.vertices[m.triangles]
        return abs(np.einsum('ij,ij->i', c[:, 0], np.cross(c[:, 1], c[:, 2])).sum()) / 6.0
    assert volume(ours) == pytest.approx(volume(cell), rel=0.02)
    c = ours.vertices[ours.triangles]
    outward = np.einsum('ij,ij->i', np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]),
                        c.mean(axis=1) - ours.vertices.mean(axis=0))
    assert np.all(outward > 0)
