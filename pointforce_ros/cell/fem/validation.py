"""Validation cases of the FEM (Hertz, mesh refinement) shared by the tests and the fixtures.

Every function returns plain arrays in SI units; the heavy (fine-mesh) variants are cached in
``test/data/fem/`` by ``make_fem_cache.py`` and the tests run the coarse variants.
"""

import os
import time

import numpy as np

from pointforce_ros.cell.fem.mesh import graded_axis, structured_hex
from pointforce_ros.cell.fem.probes import point_probe, pose_for_push, sphere_probe
from pointforce_ros.cell.fem.solver import FemModel

HERTZ = dict(radius=0.01, young=1e5, poisson=0.3, size=0.15, fine=0.003, growth=1.5,
             h_max=0.025)
"""Hertz case: rigid sphere on a quarter block (symmetry planes x = 0, y = 0), bonded base."""

REFINE = dict(size=(0.06, 0.06, 0.04), young=1e5, poisson=0.45, depths=(0.002, 0.005))
"""Refinement case: point probe on a homogeneous block, centre poke."""


def hertz_force(depth, radius, young, poisson):
    """Hertz force (N) of a rigid sphere at ``depth`` (m) on a half-space, E* = E/(1-nu^2)."""
    e_star = young / (1.0 - poisson ** 2)
    return 4.0 / 3.0 * e_star * np.sqrt(radius) * np.asarray(depth) ** 1.5


HERTZ_DEPTHS = (0.0003, 0.0005)
"""Depths of the Hertz check, metres (d / R = 0.03 and 0.05; contact radius 1.7-2.2 mm)."""

HERTZ_H_FINE = 0.00035
"""Element size at the contact of the cached fine Hertz run, metres."""


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


def make_fixtures(folder: str, progress=print):
    """Compute and write ``hertz_fine.npz`` and ``refine_fine.npz`` into ``folder``.

    The fine Hertz run is small-strain (linear) elasticity, which is what Hertz assumes; the
    neo-Hookean model's agreement with it at these depths is checked on the coarse mesh in
    the tests.
    """
    r = hertz_case(HERTZ_H_FINE, nonlinear=False)
    progress(f'hertz linear: ratio {np.round(r["ratio"], 4)} ({r["elements"]} elements, '
             f'{r["seconds"]:.0f} s)')
    out = {f'linear_{k}': np.asarray(v) for k, v in r.items()}
    np.savez_compressed(os.path.join(folder, 'hertz_fine.npz'), h=HERTZ_H_FINE, **out)
    r = refine_case(0.0015)
    progress(f'refine 1.5 mm: force {np.round(r["force"][:, 2], 4)} N ({r["elements"]} '
             f'elements, {r["seconds"]:.0f} s)')
    np.savez_compressed(os.path.join(folder, 'refine_fine.npz'), h=0.0015,
                        **{k: np.asarray(v) for k, v in r.items()})
