"""Validation cases of the FEM (Hertz, mesh refinement) shared by the tests and the fixtures.

Every function returns plain arrays in SI units; the heavy (fine-mesh) variants are cached in
``test/data/fem/`` by ``make_fem_cache.py`` and the tests run the coarse variants.
"""

import os
import time

import numpy as np

from pointforce_ros.sim.fem.mesh import graded_axis, structured_hex
from pointforce_ros.sim.fem.probes import point_probe, pose_for_push, sphere_probe
from pointforce_ros.sim.fem.solver import FemModel
from pointforce_ros.sim.fem.live import nonlinear_point_poke

HERTZ = dict(radius=0.01, young=1e5, poisson=0.45, size=0.3, fine=0.003, growth=1.5,
             h_max=0.05)
"""Hertz case: rigid sphere on a quarter block (symmetry planes x = 0, y = 0), bonded base.

``size`` is the quarter's edge (a 600 x 600 x 300 mm block); ``nu = 0.45`` as the objects.
"""

REFINE = dict(size=(0.06, 0.06, 0.04), young=1e5, poisson=0.45, depths=(0.002, 0.005))
"""Refinement case: point probe on a homogeneous block, centre poke."""


def hertz_force(depth, radius, young, poisson):
    """Hertz force (N) of a rigid sphere at ``depth`` (m) on a half-space, E* = E/(1-nu^2)."""
    e_star = young / (1.0 - poisson ** 2)
    return 4.0 / 3.0 * e_star * np.sqrt(radius) * np.asarray(depth) ** 1.5


def sneddon_sphere_force(depth, radius, young, poisson):
    """Force (N) of an exact rigid sphere (not Hertz's paraboloid) on a half-space.

    Sneddon (1965): ``d = a/2 ln((R+a)/(R-a))``, ``F = E*/2 ((a^2+R^2) ln((R+a)/(R-a)) - 2aR)``;
    0.3-0.5 % below Hertz at ``d / R = 0.03-0.05``. ``depth`` (K,) metres.
    """
    from scipy.optimize import brentq

    e_star = young / (1.0 - poisson ** 2)
    out = []
    for d in np.atleast_1d(np.asarray(depth, dtype=float)):
        a = brentq(lambda x: 0.5 * x * np.log((radius + x) / (radius - x)) - d,
                   1e-12 * radius, (1 - 1e-9) * radius)
        lg = np.log((radius + a) / (radius - a))
        out.append(0.5 * e_star * ((a * a + radius * radius) * lg - 2 * a * radius))
    return np.array(out)


def bonded_layer_factor(contact_radius, thickness, poisson):
    """Force factor of a layer of ``thickness`` bonded to a rigid base (Dimitriadis 2002).

    ``1 - 2 a0 chi / pi + 4 a0^2 chi^2 / pi^2 - 8 (a0^3 + 4 pi^2 b0 / 15) chi^3 / pi^3`` with
    ``chi = a / thickness`` (metres / metres) and the bonded-case ``a0``, ``b0`` of ``nu``.
    """
    nu = poisson
    a0 = -(1.2876 - 1.4678 * nu + 1.3442 * nu ** 2) / (1 - nu)
    b0 = (0.6387 - 1.0277 * nu + 1.5164 * nu ** 2) / (1 - nu)
    chi = np.asarray(contact_radius, dtype=float) / thickness
    return (1 - 2 * a0 * chi / np.pi + 4 * a0 ** 2 * chi ** 2 / np.pi ** 2
            - 8 / np.pi ** 3 * (a0 ** 3 + 4 * np.pi ** 2 * b0 / 15) * chi ** 3)


def tangential_factor(contact_radius, radius, poisson):
    """First-order force factor from the surface's in-plane motion, which Hertz neglects.

    A compressible body's surface moves inwards under the contact pressure, by
    ``u_r = -(1-2nu)(1+nu)/(E r) int_0^r p t dt`` (Johnson, Contact Mechanics, eq. 3.9), onto
    a part of the sphere that lies deeper; and the sphere's pressure acts along its own
    normal, with an outward in-plane part ``p r / R``. By reciprocity with the flat punch of
    the same contact radius, the two stiffen the contact by ``(1-2nu)/(1-nu) 3a/(4 pi R)``
    and ``(1-2nu)/(1-nu) a/(4 pi R)``: together ``1 + (1-2nu)/(1-nu) a/(pi R)`` (1.0-1.3 % at
    ``nu = 0.45``, 3-4 % at ``nu = 0.3`` for ``a / R = 0.17-0.22``; zero when incompressible).
    """
    a = np.asarray(contact_radius, dtype=float)
    return 1.0 + (1 - 2 * poisson) / (1 - poisson) * a / (np.pi * radius)


def hertz_expected_ratio(depth, radius, young, poisson, thickness):
    """Closed-form FE / Hertz expected of the Hertz case: sphere x bonded block x in-plane.

    Combines :func:`sneddon_sphere_force` / :func:`hertz_force`, :func:`bonded_layer_factor`
    and :func:`tangential_factor` at the Hertz contact radius ``sqrt(R d)``; (K,) for depths
    (K,) metres.
    """
    depth = np.atleast_1d(np.asarray(depth, dtype=float))
    a = np.sqrt(radius * depth)
    return (sneddon_sphere_force(depth, radius, young, poisson)
            / hertz_force(depth, radius, young, poisson)
            * bonded_layer_factor(a, thickness, poisson) * tangential_factor(a, radius, poisson))


HERTZ_DEPTHS = (0.0003, 0.0005)
"""Depths of the Hertz check, metres (d / R = 0.03 and 0.05; contact radius 1.7-2.2 mm)."""

HERTZ_H_FINE = (0.0007, 0.0005, 0.00035)
"""Element sizes at the contact of the cached Hertz runs (convergence), metres; last finest."""


def hertz_case(h: float, depths=HERTZ_DEPTHS, nonlinear: bool = False,
               contact_order: int = 3, rings: int = 384, **over):
    """Sphere indentation of a quarter block meshed with ``h`` (m) at the contact.

    Returns:
        dict with ``depths`` (K,), ``force`` (K,) full-model vertical force (4 x quarter),
        ``hertz`` (K,), ``ratio`` (K,), ``elements``, ``seconds``.

    """
    p = dict(HERTZ, **over)
    size = p['size']
    xs = graded_axis(0.0, size, h, 0.0, p['fine'], p['growth'], p['h_max'])
    zs = graded_axis(0.0, size, h, size, 0.75 * p['fine'], p['growth'], p['h_max'])
    mesh = structured_hex(xs, xs, zs)
    fixed = np.zeros((mesh.n_nodes, 3), dtype=bool)
    fixed[mesh.nodes[:, 0] < 1e-12, 0] = True
    fixed[mesh.nodes[:, 1] < 1e-12, 1] = True
    t0 = time.time()
    model = FemModel(mesh, p['young'], p['poisson'], fixed=fixed, nonlinear=nonlinear,
                     contact_faces=mesh.top_faces(), contact_order=contact_order)
    probe = sphere_probe(p['radius'], rings=rings, segments=96)  # 384 rings: sag < 0.1 um
    res = model.indent(probe, pose_for_push([0.0, 0.0, size], [0, 0, -1]), [0, 0, -1],
                       np.asarray(depths, dtype=float))
    force = 4.0 * res.force[:, 2]
    hz = hertz_force(res.depths, p['radius'], p['young'], p['poisson'])
    return dict(depths=res.depths, force=force, hertz=hz, ratio=force / hz,
                elements=len(mesh.elements), seconds=time.time() - t0)


def refine_case(h: float, nonlinear: bool = True):
    """Point-probe centre poke of the homogeneous refinement block meshed with ``h`` (m).

    Returns:
        dict with ``depths``, ``force`` (K, 3), ``torque`` (K, 3) about the start point,
        ``table_force`` (K, 3), ``elements``, ``seconds``.

    """
    lx, ly, lz = REFINE['size']
    cx, cy = 0.5, 0.0
    xs = graded_axis(cx - lx / 2, cx + lx / 2, h, cx, 0.008, 1.4, 4 * h)
    ys = graded_axis(cy - ly / 2, cy + ly / 2, h, cy, 0.008, 1.4, 4 * h)
    zs = graded_axis(0.0, lz, h, lz, 0.008, 1.4, 4 * h)
    mesh = structured_hex(xs, ys, zs)
    t0 = time.time()
    model = FemModel(mesh, REFINE['young'], REFINE['poisson'], nonlinear=nonlinear)
    start = np.array([cx, cy, lz])
    res = model.indent(point_probe(0.002, 25.0, 0.03), pose_for_push(start, [0, 0, -1]),
                       [0, 0, -1], np.asarray(REFINE['depths']), torque_centre=start)
    return dict(depths=res.depths, force=res.force, torque=res.torque,
                table_force=res.table_force, elements=len(mesh.elements),
                seconds=time.time() - t0)


def mesh_shift_case(spec, x: float, y: float, shifts=(0.0, 0.001, 0.002), h=None):
    """Solve the live-path poke at (x, y) on meshes refined at points shifted along x.

    The physics is unchanged, only where the graded mesh is centred moves (by ``shifts``,
    metres), so the spread of the forces is the full solve's own discretisation noise at
    element size ``h`` (default ``spec.mesh_live``): the floor of any comparison with it.

    Returns:
        dict with ``depths`` (K,), ``force`` (S, K) normal force on the probe, N,
        ``shifts`` (S,), ``spread`` (K,) ``(max - min) / min`` over the shifts.

    """
    rows = []
    for dx in shifts:
        depths, f, n, _ = nonlinear_point_poke(spec, x, y, h=h, refine_at=(x + dx, y))
        rows.append(f @ n)
    force = np.array(rows)
    return dict(depths=depths, force=force, shifts=np.asarray(shifts, dtype=float),
                spread=(force.max(axis=0) - force.min(axis=0)) / force.min(axis=0))


REFINE_H = (0.003, 0.0015, 0.001, 0.00075)
"""Element sizes of the cached refinement runs, metres: the live caches' 3 mm, then 1.5 mm (the
validation size), 1 mm and 0.75 mm (75 min on this machine). The refinement checks are
1.5 -> 1 mm and 1 -> 0.75 mm; 3 mm is the coarse twin that the tests re-run."""


def make_hertz_fixture(folder: str, progress=print):
    """Compute and write ``hertz_fine.npz`` (small-strain runs, see the test module)."""
    out = {}
    p = HERTZ
    thick = p['size']
    runs = [(h, p['poisson']) for h in HERTZ_H_FINE] + [(HERTZ_H_FINE[-1], 0.3)]
    rows = []
    for h, nu in runs:
        r = hertz_case(h, nonlinear=False, poisson=nu)
        progress(f'hertz linear h {h * 1e3:.2f} mm nu {nu}: ratio {np.round(r["ratio"], 4)} '
                 f'({r["elements"]} elements, {r["seconds"]:.0f} s)')
        rows.append(r)
    k = len(HERTZ_H_FINE)
    out['h'] = np.array(HERTZ_H_FINE)
    out['poisson'] = p['poisson']
    out['depths'] = rows[0]['depths']
    out['force'] = np.array([r['force'] for r in rows[:k]])
    out['hertz'] = rows[0]['hertz']
    out['ratio'] = np.array([r['ratio'] for r in rows[:k]])
    out['expected'] = hertz_expected_ratio(out['depths'], p['radius'], p['young'],
                                           p['poisson'], thick)
    out['elements'] = np.array([r['elements'] for r in rows])
    out['seconds'] = np.array([r['seconds'] for r in rows])
    out['nu03_ratio'] = rows[-1]['ratio']
    out['nu03_expected'] = hertz_expected_ratio(out['depths'], p['radius'], p['young'], 0.3,
                                                thick)
    np.savez_compressed(os.path.join(folder, 'hertz_fine.npz'), **out)


def make_refine_fixture(folder: str, progress=print):
    """Compute and write ``refine_fine.npz``: the point poke at each of :data:`REFINE_H`."""
    rows = []
    for h in REFINE_H:
        r = refine_case(h)
        progress(f'refine {h * 1e3:.1f} mm: force {np.round(r["force"][:, 2], 4)} N '
                 f'({r["elements"]} elements, {r["seconds"]:.0f} s)')
        rows.append(r)
    np.savez_compressed(os.path.join(folder, 'refine_fine.npz'), h=np.array(REFINE_H),
                        **{k: np.array([r[k] for r in rows])
                           for k in ('depths', 'force', 'torque', 'table_force', 'elements',
                                     'seconds')})


def make_fixtures(folder: str, progress=print, parts=('hertz', 'refine')):
    """Compute and write ``hertz_fine.npz`` and/or ``refine_fine.npz`` into ``folder``.

    The Hertz runs are small-strain (linear) elasticity, which is what Hertz assumes; the
    neo-Hookean model's agreement with it at these depths is checked on the coarse mesh in
    the tests.
    """
    if 'hertz' in parts:
        make_hertz_fixture(folder, progress)
    if 'refine' in parts:
        make_refine_fixture(folder, progress)
