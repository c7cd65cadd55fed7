"""The calibrated FEM as a second answer for wide contacts (issue 18's last figure).

On figure 2's line and cylinder probe trials (``data/figures/probes_<object>.npz``: FEM
full-solve ground truth of the cell) two models predict the wrench, both trained on the same
point pokes and never on the trial they are scored on:

- ``semi_empirical``: the project's contact simulator (:class:`~pointforce_ros.contact.
  simulator.ContactSimulator`, seed 000) with the point model :class:`~pointforce_ros.response.
  ours.ContactGpModel` fitted on ``n_train`` pokes and the shape function ``(c, decay)``
  identified from the object's *other* trials (leave one trial out), exactly as figure 2
  scores "ours" (``pointforce_ros.lab.figures.figure_probes``; restated here with product
  wings only: the house rule keeps ``deformation`` off ``lab`` and ``sim``).
- ``fem``: this wing's model of the scanned object (:func:`.mesh.volume_mesh_from_surface`,
  linear tetrahedra, bottom fixed) with Young's modulus calibrated on the *same* pokes
  (:func:`calibrate_young`: each poke is re-simulated with the cell's point probe by
  :class:`.rigid_contact.RigidProbeContact`, and ``E`` is the least-squares scale of force,
  which is exact because the model's force is proportional to ``E``); then each trial's probe
  is pressed into it (:class:`.rigid_contact.RigidProbeContact`). ``fem_field`` is the same
  with a heterogeneous ``E``: each poke's own modulus spread over the footprint by a Gaussian
  kernel in ``log E`` (the point model's local stiffness, seeding the FEM's field).

Both are scored against the trial's truth with figure 2's vector force RMSE (every step of
every trial) and, per step, the relative error of ``|F|``. Poisson's ratio is not observable
from normal point pokes (nor well from top-view clouds, see :mod:`.identify`), so it is set
(:data:`POISSON`); the report gives the FEM's sensitivity to it.

``python -m pointforce_ros.deformation.wide_contacts --out DIR`` writes ``wide_contacts.json``
and ``wide_contacts.png`` and prints the table. Units SI, frame ``base``.
"""

import argparse
from dataclasses import replace
import json
import os
import sys
import time
from pathlib import Path
from typing import Callable, Dict, List, Mapping, Optional, Sequence

import numpy as np

from pointforce_ros.contact.identify import (best_capped_fit, DECAY_GRID,
                                             shape_fits_from_probes)
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.deformation.fem import CorotationalFem
from pointforce_ros.deformation.mesh import TetMesh, volume_mesh_from_surface
from pointforce_ros.deformation.rigid_contact import RigidProbeContact
from pointforce_ros.errors import DataError, InvalidInput, PointforceError
from pointforce_ros.paths import share_path
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.types import Mesh, Pose, Surface

POISSON = 0.4
"""Poisson ratio of the FEM on every object (not identifiable from normal pokes), 1."""

DEFAULT_OBJECTS = ('foam_block', 'plush', 'vest', 'lamb')
"""Objects of the default run: the homogeneous block and three heterogeneous cell objects."""

FOAM_BLOCK = Path(__file__).resolve().parents[2] / 'test' / 'data' / 'deformation' / \
    'wide_foam_block.npz'
"""The homogeneous object's trials and pokes (made by the script beside it)."""

POKE_SAMPLES = 8
"""Depths of each poke curve the calibration re-simulates."""

FIELD_LENGTH = 0.015
"""Kernel length of the heterogeneous modulus field, metres."""

DEFAULT_C = 0.004
"""Shape constant figure 2 falls back to when none is identified, metres."""

FIGURES_DATA = share_path('data', 'figures')
"""Figure 2's fixtures (``pokes_<object>.npz``, ``probes_<object>.npz``)."""

POINT_PROBE = dict(tip_radius=0.002, half_angle_deg=25.0, length=0.03)
"""The cell's point probe (``pointforce_ros.sim.fem.live.POINT_PROBE``; the house rule keeps
the product wings off ``sim``, so the geometry is restated here, as ``replica`` does)."""


def point_probe(tip_radius: float = 0.002, half_angle_deg: float = 25.0, length: float = 0.03,
                segments: int = 32) -> Mesh:
    """Tapered point probe: spherical tip at the origin, cone opening towards -z (push +z).

    Closed, convex, wound outward; the cell's probe geometry (see :data:`POINT_PROBE`).
    """
    alpha = np.radians(half_angle_deg)
    ang = np.linspace(0.0, np.pi / 2 - alpha, 10)[1:]
    ring_r = np.append(tip_radius * np.sin(ang), 0.0)
    ring_z = -(tip_radius - tip_radius * np.cos(ang))
    r_top = ring_r[-2] + (length + ring_z[-1]) * np.tan(alpha)
    ring_r = np.append(ring_r[:-1], r_top)
    ring_z = np.append(ring_z, -length)
    theta = 2 * np.pi * np.arange(segments) / segments
    verts = [np.zeros(3)]
    for r, z in zip(ring_r, ring_z):
        verts += [np.array([r * np.cos(t), r * np.sin(t), z]) for t in theta]
    verts.append(np.array([0.0, 0.0, -length]))
    verts = np.array(verts)
    ring = [1 + k * segments + np.arange(segments) for k in range(len(ring_r))]
    tris = [[0, ring[0][j], ring[0][(j + 1) % segments]] for j in range(segments)]
    for a, b in zip(ring[:-1], ring[1:]):
        for j in range(segments):
            k = (j + 1) % segments
            tris += [[a[j], b[j], b[k]], [a[j], b[k], a[k]]]
    tris += [[len(verts) - 1, ring[-1][(j + 1) % segments], ring[-1][j]]
             for j in range(segments)]
    tris = np.array(tris, dtype=np.int64)
    c = verts[tris]
    normal = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
    inward = np.einsum('ij,ij->i', normal, c.mean(axis=1) - verts.mean(axis=0)) < 0
    tris[inward] = tris[inward][:, [0, 2, 1]]
    return Mesh(verts, tris)


def trial_poses(trial: Mapping) -> List[Pose]:
    """Probe poses of every step of a trial: the start pose moved ``depths[k]`` along the push."""
    start = np.asarray(trial['start_position'], dtype=float)
    direction = np.asarray(trial['direction'], dtype=float)
    return [Pose(start + float(s) * direction, trial['orientation'])
            for s in np.asarray(trial['depths'], dtype=float)]


def bake_depths(curves: Sequence[PokeCurve]) -> np.ndarray:
    """Depths the point model is baked at for the simulator, metres (as figure 2)."""
    lo = min(0.0, min(c.onset_d for c in curves)) - 0.002
    return np.linspace(lo, 0.03, 121)


# ----------------------------------------------------------------------------- calibration
def poke_samples(curve: PokeCurve, count: int = POKE_SAMPLES):
    """``(travel (k,), force (k,))`` of a poke past its contact onset, ``count`` even depths.

    Travel is the probe's motion past the onset, metres; force the normal force, newtons.
    """
    d = np.asarray(curve.d, dtype=float) - float(curve.onset_d)
    f = np.asarray(curve.f, dtype=float)
    inside = d > 2e-4
    if int(inside.sum()) < 2:
        return np.zeros(0), np.zeros(0)
    d, f = d[inside], f[inside]
    order = np.argsort(d, kind='stable')
    d, f = d[order], f[order]
    targets = np.linspace(d[0], d[-1], int(count) + 1)[1:]
    idx = np.clip(np.searchsorted(d, targets), 0, len(d) - 1)
    return d[idx], f[idx]


def poke_forces(solver: RigidProbeContact, probe: Mesh, curve: PokeCurve, travel) -> np.ndarray:
    """(k,) normal force of the model under the point probe at each travel past contact, N.

    ``travel`` (k,) is counted from where the probe first touches the *model's* surface (the
    measured curve's travel is counted from its contact onset), metres.
    """
    n = np.asarray(curve.normal, dtype=float)
    start = _pose_for_push(np.asarray(curve.point, dtype=float) + 0.003 * n, -n)
    touch = solver.first_contact(probe, start, -n)  # the model's own surface sets the onset
    res = solver.press(probe, start, -n, np.asarray(travel, dtype=float) + touch)
    return res.force @ n


def calibrate_young(solver: RigidProbeContact, probe: Mesh, curves: Sequence[PokeCurve],
                    count: int = POKE_SAMPLES) -> Dict:
    """Young's modulus that makes the model's point pokes match the measured ones.

    The model is linear, so its force is ``E`` times its force at 1 Pa: ``E`` is the
    least-squares ratio over every sample, ``sum f_model,1 f / sum f_model,1^2``. The same
    ratio over one poke's samples is that poke's local modulus.

    Args:
        solver: contact solver on the model; its modulus (field) is rescaled to the fit.
        probe: the point probe mesh (tip at the origin, pushing along +z), metres.
        curves: measured pokes.
        count: depths re-simulated per poke.

    Returns:
        dict ``young`` (Pa, the mean element modulus after the fit), ``per_poke`` (list of
        Pa: each poke's own fit with the model's field shape, NaN where it has no samples),
        ``points`` ((n, 2) x-y of each poke, m), ``rms`` (N, residual over all samples).

    Raises:
        InvalidInput: no poke has force samples past its onset.

    """
    fem = solver.fem
    young0 = fem.young
    num = den = 0.0
    per, pts, rows = [], [], []
    for c in curves:
        travel, f = poke_samples(c, count)
        pts.append(np.asarray(c.point[:2], dtype=float))
        if len(travel) == 0:
            per.append(float('nan'))
            continue
        f_model = poke_forces(solver, probe, c, travel)
        num += float(f_model @ f)
        den += float(f_model @ f_model)
        per.append(young0 * float(f_model @ f) / max(float(f_model @ f_model), 1e-300))
        rows.append((f_model, f))
    if not den > 0:
        raise InvalidInput('calibrate_young: no poke has force samples past its onset')
    scale = num / den
    rms = float(np.sqrt(np.mean(np.concatenate([(scale * a - b) ** 2 for a, b in rows]))))
    fem.set_material(fem.element_young * scale, fem.poisson)  # same field: no refactorisation
    return {'young': float(fem.young), 'per_poke': per, 'points': np.array(pts), 'rms': rms}


def modulus_field(mesh: TetMesh, points, moduli, length: float = FIELD_LENGTH) -> np.ndarray:
    """(M,) relative element modulus: the pokes' ``log E`` smoothed by a Gaussian kernel in x-y.

    Args:
        mesh: the volume mesh.
        points: (n, 2) x-y of the pokes, metres.
        moduli: (n,) each poke's modulus, Pa (NaN ignored).
        length: kernel length, metres.

    Returns:
        (M,) moduli divided by their geometric mean (the overall scale is calibrated after).

    Raises:
        InvalidInput: no finite positive modulus.

    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    e = np.asarray(moduli, dtype=float)
    ok = np.isfinite(e) & (e > 0)
    if not ok.any():
        raise InvalidInput('modulus_field: no finite positive poke modulus')
    centroid = mesh.nodes[mesh.tets].mean(axis=1)[:, :2]
    d2 = ((centroid[:, None, :] - pts[ok][None]) ** 2).sum(-1)
    w = np.exp(-0.5 * d2 / length ** 2) + 1e-12
    loge = (w @ np.log(e[ok])) / w.sum(axis=1)
    return np.exp(loge - loge.mean())


# ----------------------------------------------------------------------------- comparison
def _pose_for_push(position, direction) -> Pose:
    """Pose whose +z axis is ``direction`` at ``position`` (as the cell's probes are posed)."""
    z = np.asarray(direction, dtype=float)
    z = z / np.linalg.norm(z)
    ref = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = ref - z * (ref @ z)
    x /= np.linalg.norm(x)
    return Pose.from_matrix(np.block([[np.stack([x, np.cross(z, x), z], 1),
                                       np.asarray(position, float)[:, None]],
                                      [np.zeros((1, 3)), np.ones((1, 1))]]))


def fem_trial_wrenches(solver: RigidProbeContact, trials: Sequence[Mapping]) -> List[tuple]:
    """One ``(force (K, 3), torque (K, 3))`` per trial: its probe pressed into the model."""
    out = []
    for t in trials:
        start = Pose(np.asarray(t['start_position'], float), np.asarray(t['orientation'], float))
        res = solver.press(t['mesh'], start, t['direction'], t['depths'],
                           torque_centre=t['torque_centre'])
        out.append((res.force, res.torque))
    return out


def trial_scores(pred: Sequence[tuple], trials: Sequence[Mapping]) -> Dict:
    """Force/torque RMSE and ``|F|`` errors of predictions against the trials' truth.

    Args:
        pred: one ``(force (K, 3), torque (K, 3))`` per trial.
        trials: dicts with ``force`` (K, 3), ``torque`` (K, 3), ``kind``.

    Returns:
        dict with ``force_rmse`` (N: RMS of the error vector over every step, figure 2's
        measure), ``torque_rmse`` (N m), ``magnitude_error`` (median over steps of
        ``| |F_pred| - |F_true| | / |F_true|``), ``bias`` (median signed relative error of
        ``|F|``), ``per_trial`` (the same per trial) and ``force_rmse_<kind>``.

    Raises:
        InvalidInput: a prediction whose shape does not match its trial.

    """
    if len(pred) != len(trials):
        raise InvalidInput(f'trial_scores: {len(pred)} predictions for {len(trials)} trials')
    rows = []
    for (pf, pt), t in zip(pred, trials):
        tf, tt = np.asarray(t['force'], float), np.asarray(t['torque'], float)
        pf, pt = np.asarray(pf, float), np.asarray(pt, float)
        if pf.shape != tf.shape or pt.shape != tt.shape:
            raise InvalidInput(f'trial_scores: prediction {pf.shape} vs truth {tf.shape}')
        mag_t = np.linalg.norm(tf, axis=1)
        rel = (np.linalg.norm(pf, axis=1) - mag_t) / np.maximum(mag_t, 1e-9)
        rows.append(dict(kind=str(t['kind']), ef=pf - tf, et=pt - tt, rel=rel, peak=mag_t.max()))

    def summary(sel):
        ef = np.vstack([r['ef'] for r in sel])
        et = np.vstack([r['et'] for r in sel])
        rel = np.concatenate([r['rel'] for r in sel])
        return {'force_rmse': float(np.sqrt(np.mean(np.sum(ef ** 2, axis=1)))),
                'torque_rmse': float(np.sqrt(np.mean(np.sum(et ** 2, axis=1)))),
                'magnitude_error': float(np.median(np.abs(rel))),
                'bias': float(np.median(rel))}

    out = summary(rows)
    for kind in ('line', 'cylinder'):
        sel = [r for r in rows if r['kind'] == kind]
        out[f'force_rmse_{kind}'] = summary(sel)['force_rmse'] if sel else None
    out['per_trial'] = [dict(kind=r['kind'], peak_force=float(r['peak']), **summary([r]))
                        for r in rows]
    return out


def semi_empirical_shapes(curves, surface: Surface, trials, say=print) -> List[tuple]:
    """Figure 2's leave-one-trial-out ``(c, decay)`` per trial (point model on every poke)."""
    depths = bake_depths(curves)
    calibration = ContactSimulator(
        surface, ContactGpModel().fit(list(curves), surface).bake(surface, depths), DEFAULT_C)
    shapes = []
    for j in range(len(trials)):
        others = [(t['mesh'], trial_poses(t), t['direction'], t['force'])
                  for i, t in enumerate(trials) if i != j]
        try:
            fits = shape_fits_from_probes(calibration, others, c_bounds=(1e-4, 0.1),
                                          decays=DECAY_GRID)
        except PointforceError as exc:
            say(f'[wide]   c for trial {j} not identified ({exc}); default')
            fits = []
        best = best_capped_fit(fits, surface)      # the tail within DECAY_CAP thicknesses
        shapes.append((float(best.c), float(best.decay)) if best else (DEFAULT_C, np.inf))
    return shapes


def semi_empirical_wrenches(curves, surface: Surface, trials, shapes) -> List[tuple]:
    """Figure 2's "ours": point model on ``curves``, each trial with its own ``(c, decay)``."""
    model = ContactGpModel().fit(list(curves), surface)
    sim = ContactSimulator(surface, model.bake(surface, bake_depths(curves)), DEFAULT_C)
    out = []
    for (c, decay), t in zip(shapes, trials):
        w = sim.with_shape_constant(c, decay).query_batch(
            t['mesh'], trial_poses(t), t['direction'], t['torque_centre']).wrenches
        out.append((w[:, :3], w[:, 3:]))
    return out


# ----------------------------------------------------------------------------- data
def _npz(path: Path) -> Dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def _curves(data: Mapping) -> List[PokeCurve]:
    """Poke curves of a figure fixture (``curve_*`` arrays, as ``lab.figures`` packs them)."""
    off = np.asarray(data['curve_offsets'])
    out = []
    for k in range(len(data['curve_ids'])):
        s = slice(int(off[k]), int(off[k + 1]))
        normal = np.asarray(data['curve_normals'][k], dtype=float)
        out.append(PokeCurve(poke_id=str(data['curve_ids'][k]),
                             point=np.asarray(data['curve_points'][k], dtype=float),
                             normal=normal / np.linalg.norm(normal),
                             d=np.asarray(data['curve_d'][s], dtype=float),
                             f=np.asarray(data['curve_f'][s], dtype=float),
                             onset_d=float(data['curve_onsets'][k]),
                             t=np.asarray(data['curve_t'][s], dtype=float)))
    return out


def _surface(data: Mapping) -> Surface:
    nrm = np.asarray(data['surface_normals'], dtype=float)
    return Surface(points=np.asarray(data['surface_points'], dtype=float),
                   normals=nrm / np.linalg.norm(nrm, axis=1, keepdims=True),
                   colors=np.clip(np.asarray(data['surface_colors'], dtype=float), 0.0, 1.0))


def _trials(data: Mapping) -> List[Dict]:
    trials = []
    for i, kind in enumerate(data['trial_kinds']):
        if str(kind) == 'skipped':
            continue
        t = {k: data[f'trial{i:02d}_{k}'] for k in (
            'vertices', 'triangles', 'start_position', 'orientation', 'direction',
            'torque_centre', 'depths', 'force', 'torque')}
        t['kind'] = str(kind)
        t['mesh'] = Mesh(t.pop('vertices'), t.pop('triangles'))
        trials.append(t)
    return trials


def load_object_data(name: str, foam_block=FOAM_BLOCK, figures=FIGURES_DATA):
    """``(surface, curves, trials)`` of an object: figure 2's fixtures, or the foam block's.

    Raises:
        DataError: the fixture is missing (the message says how to make it).

    """
    if name == 'foam_block':
        path = Path(foam_block)
        if not path.is_file():
            raise DataError(f'no {path}: make it with python '
                            f'test/data/deformation/make_wide_contact_fixtures.py')
        data = _npz(path)
        surface = _surface(data)
        return surface, anchor_curves(_curves(data), surface), _trials(data)
    pokes, probes = Path(figures) / f'pokes_{name}.npz', Path(figures) / f'probes_{name}.npz'
    for path in (pokes, probes):
        if not path.is_file():
            raise DataError(f'no {path}: make it with python data/figures/make_figures_data.py '
                            f'--object {name}')
    data = _npz(pokes)
    return _surface(data), _curves(data), _trials(_npz(probes))


def anchor_curves(curves: Sequence[PokeCurve], surface: Surface, radius: float = 0.003
                  ) -> List[PokeCurve]:
    """Re-express noise-free pokes (onset 0 at the true surface) from the scanned surface.

    A recorded campaign measures each poke from the *scanned* surface point, so a camera
    bias appears as a non-zero onset; full-solve pokes start on the true surface. This moves
    each curve's point to the scan (mean height of upward scan points within ``radius`` in
    x-y, along the normal line) and shifts ``d`` and ``onset_d`` by the gap, as
    :func:`~pointforce_ros.pokes.curves.extract_curve` would have seen them.
    """
    up = surface.normals[:, 2] > 0.5
    pts = surface.points[up]
    out = []
    for c in curves:
        near = np.linalg.norm(pts[:, :2] - c.point[:2], axis=1) <= radius
        if not near.any():
            out.append(c)
            continue
        gap = float(c.point[2] - pts[near, 2].mean()) * float(c.normal[2])
        point = np.asarray(c.point, dtype=float) - gap * np.asarray(c.normal, dtype=float)
        out.append(replace(c, point=point, d=np.asarray(c.d) - gap,
                           onset_d=float(c.onset_d) - gap))
    return out


def scan_offset(curves: Sequence[PokeCurve]) -> float:
    """How far the true surface lies above the scanned one along the normal, metres.

    A poke's contact onset ``onset_d`` is where, along ``-normal`` from the scanned point,
    the probe met the object; a camera depth bias shows as the same negative onset on every
    poke (the cell's ``realistic`` scenario: 2 mm, onsets -1.7 to -2.5 mm). The median over
    the pokes, negated, is the correction. The point model absorbs it per poke; the FEM's
    geometry needs it, or every wide contact starts millimetres late.
    """
    return float(-np.median([c.onset_d for c in curves])) if len(curves) else 0.0


def object_model(surface: Surface, element_size: float, poisson: float = POISSON,
                 offset: float = 0.0) -> RigidProbeContact:
    """Build the FEM of a scanned surface at 1 Pa, wrapped in a contact solver.

    ``offset`` (metres, :func:`scan_offset`) moves the scanned points out along their
    normals before meshing.
    """
    points = surface.points + float(offset) * surface.normals
    mesh = volume_mesh_from_surface(points, surface.normals,
                                    element_size=element_size, layers=8, grading=1.5)
    return RigidProbeContact(CorotationalFem(mesh, 1.0, poisson))


def compare_object(name: str, draws: int = 3, n_train: int = 10, element_size: float = 0.003,
                   seed: int = 0, field: bool = True, foam_block=FOAM_BLOCK,
                   say: Callable[[str], None] = print) -> Dict:
    """Both models on one object's trials, median over ``draws`` random training sets.

    Returns:
        dict with ``scores`` ({method: trial_scores medians}), ``draws`` (per draw),
        ``young`` (calibrated E per draw, Pa), ``mesh`` (nodes, tets, element size),
        ``trials`` (kinds and peak forces), ``seconds`` (per method, per draw).

    """
    t0 = time.monotonic()
    surface, curves, trials = load_object_data(name, foam_block)
    if len(curves) < n_train:
        raise InvalidInput(f'{name}: {len(curves)} pokes, need n_train = {n_train}')
    probe = point_probe(**POINT_PROBE)
    offset = scan_offset(curves)
    solver = object_model(surface, element_size, offset=offset)
    mesh = solver.fem.mesh
    say(f'[wide] {name}: {len(trials)} trials, {len(curves)} pokes; mesh {mesh.n_nodes} nodes,'
        f' {len(mesh.tets)} tets, scan raised {1e3 * offset:.2f} mm '
        f'({time.monotonic() - t0:.0f} s)')
    shapes = semi_empirical_shapes(curves, surface, trials, say)
    rng = np.random.default_rng([int(seed), 2])  # figure 2's draws
    per_draw, youngs = [], []
    secs = {'semi_empirical': [], 'fem': [], 'fem_field': []}
    for rep in range(int(draws)):
        pick = rng.choice(len(curves), size=n_train, replace=False)
        train = [curves[i] for i in pick]
        scores = {}
        t1 = time.monotonic()
        scores['semi_empirical'] = trial_scores(
            semi_empirical_wrenches(train, surface, trials, shapes), trials)
        secs['semi_empirical'].append(time.monotonic() - t1)
        t1 = time.monotonic()
        solver.fem.set_material(1.0, POISSON)
        cal = calibrate_young(solver, probe, train)
        scores['fem'] = trial_scores(fem_trial_wrenches(solver, trials), trials)
        secs['fem'].append(time.monotonic() - t1)
        entry = {'young': cal['young'], 'poke_rms': cal['rms'],
                 'per_poke_young': cal['per_poke']}
        if field:
            t1 = time.monotonic()
            rel = modulus_field(mesh, cal['points'], cal['per_poke'])
            solver.fem.set_material(rel, POISSON)
            cal_f = calibrate_young(solver, probe, train)
            scores['fem_field'] = trial_scores(fem_trial_wrenches(solver, trials), trials)
            secs['fem_field'].append(time.monotonic() - t1)
            entry.update(field_scale=cal_f['young'], field_poke_rms=cal_f['rms'],
                         field_range=[float(rel.min() * cal_f['young']),
                                      float(rel.max() * cal_f['young'])])
        youngs.append(entry)
        per_draw.append(scores)
        say(f'[wide]   draw {rep + 1}/{draws}: force RMSE ' + ', '.join(
            f'{m} {s["force_rmse"]:.3f} N' for m, s in scores.items())
            + f'; E {cal["young"] / 1e3:.1f} kPa')
    methods = list(per_draw[0])
    keys = ('force_rmse', 'torque_rmse', 'magnitude_error', 'bias', 'force_rmse_line',
            'force_rmse_cylinder')
    med = {m: {k: (float(np.median([d[m][k] for d in per_draw]))
                   if per_draw[0][m][k] is not None else None) for k in keys}
           for m in methods}
    peak = float(max(np.linalg.norm(t['force'], axis=1).max() for t in trials))
    return {'object': name, 'scores': med, 'peak_force': peak, 'draws': per_draw,
            'calibration': youngs, 'shapes': [list(s) for s in shapes],
            'mesh': {'nodes': int(mesh.n_nodes), 'tets': int(len(mesh.tets)),
                     'element_size': float(element_size)},
            'trials': [{'kind': t['kind'], 'steps': int(len(t['depths'])),
                        'peak_force': float(np.linalg.norm(t['force'], axis=1).max())}
                       for t in trials],
            'seconds': {k: float(np.median(v)) for k, v in secs.items() if v},
            'scan_offset': offset, 'total_seconds': time.monotonic() - t0, 'poisson': POISSON,
            'n_train': n_train}


# ----------------------------------------------------------------------------- report
def table(results: Sequence[Mapping]) -> str:
    """Markdown table of the medians: force RMSE (all, line, cylinder), |F| error, torque."""
    head = ('| object | model | force RMSE N | line | cylinder | median abs |F| err | '
            'median |F| bias | torque RMSE mN m |')
    lines = [head, '|' + ' --- |' * 8]

    def fmt(v, scale=1.0, pct=False):
        if v is None:
            return '-'
        return f'{100 * v:.1f} %' if pct else f'{scale * v:.3f}'
    for r in results:
        for m, s in r['scores'].items():
            lines.append(f'| {r["object"]} | {m} | {fmt(s["force_rmse"])} | '
                         f'{fmt(s["force_rmse_line"])} | {fmt(s["force_rmse_cylinder"])} | '
                         f'{fmt(s["magnitude_error"], pct=True)} | {fmt(s["bias"], pct=True)} |'
                         f' {fmt(s["torque_rmse"], 1e3)} |')
    return '\n'.join(lines)


def plot(results: Sequence[Mapping], path) -> None:
    """Bar charts of the force RMSE over the peak force, per object and model: all, line, cyl."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    order = ['semi_empirical', 'fem', 'fem_field']
    methods = sorted({m for r in results for m in r['scores']}, key=order.index)
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    width = 0.8 / max(len(methods), 1)
    x = np.arange(len(results))
    for ax, key, title in zip(axes, ('force_rmse', 'force_rmse_line', 'force_rmse_cylinder'),
                              ('all trials', 'line trials', 'cylinder trials')):
        for k, m in enumerate(methods):
            v = [(r['scores'][m][key] or np.nan) / r['peak_force'] if m in r['scores']
                 else np.nan for r in results]
            ax.bar(x + (k - (len(methods) - 1) / 2) * width, v, width, label=m)
        ax.set_xticks(x, [r['object'] for r in results])
        ax.set_title(title)
    axes[0].set_ylabel('force RMSE / peak force')
    axes[0].legend()
    fig.suptitle('Held-out line and cylinder probe trials: calibrated FEM vs semi-empirical')
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def run(out_dir, objects: Sequence[str] = DEFAULT_OBJECTS, draws: int = 3,
        element_size: float = 0.003, seed: int = 0, field: bool = True,
        foam_block=FOAM_BLOCK, say: Callable[[str], None] = print) -> Dict:
    """Compare on every object; write ``wide_contacts.json`` and ``.png``; return the result."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    results, skipped = [], {}
    for name in objects:
        try:
            results.append(compare_object(name, draws=draws, element_size=element_size,
                                          seed=seed, field=field, foam_block=foam_block,
                                          say=say))
        except DataError as exc:
            skipped[name] = str(exc)
            say(f'[wide] {name} skipped: {exc}')
    result = {'objects': results, 'skipped': skipped, 'table': table(results),
              'settings': {'draws': draws, 'element_size': element_size, 'seed': seed,
                           'poisson': POISSON}}
    tmp = out / 'wide_contacts.json.tmp'
    tmp.write_text(json.dumps(_jsonable(result), indent=1))
    os.replace(tmp, out / 'wide_contacts.json')
    if results:
        plot(results, out / 'wide_contacts.png')
    return result


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Command line: ``python -m pointforce_ros.deformation.wide_contacts --out DIR``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--out', required=True, help='output folder')
    ap.add_argument('--object', action='append', help='object (repeatable); default '
                    + ', '.join(DEFAULT_OBJECTS))
    ap.add_argument('--draws', type=int, default=3, help='random training sets (default 3)')
    ap.add_argument('--element-size', type=float, default=0.003, help='FEM x-y element, m')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--no-field', action='store_true', help='skip the heterogeneous-E FEM')
    args = ap.parse_args(argv)
    result = run(args.out, args.object or DEFAULT_OBJECTS, args.draws, args.element_size,
                 args.seed, not args.no_field)
    print(result['table'])
    for name, why in result['skipped'].items():
        print(f'skipped {name}: {why}')
    return 0 if result['objects'] else 1


if __name__ == '__main__':
    sys.exit(main())
