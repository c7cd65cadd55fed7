#!/usr/bin/env python3
"""Regenerate ``side_foam_block_<k>.npz``: horizontal pushes into the foam block's side face.

Usage::

    nice -n 10 python test/data/deformation/make_side_pushes.py

Why: from frictionless pushes on the top, seen from above, Poisson's ratio is nearly
invisible (on a half-space the normal surface displacement under a normal load has the same
shape for every nu, only its scale ``(1 - nu^2) / E`` changes; measured on the block: the fit
residual moves 0.8 % over nu 0.02-0.47). A push into the side face, seen by the same camera
(0.25 m, 55 deg elevation, azimuth 200 deg: it looks at the -x face), compresses the material
near the top edge horizontally, and the top surface there rises with nu (not at all for
nu = 0): a vertical motion the camera sees, carried by nu.

Same scenario and file keys as ``make_deformation_fixtures.py``'s ``push_<object>_<k>.npz``
(``contact_point``, ``normal``, ``direction``, ``depths``, ``force`` on the object,
``cloud`` / ``cloud_start`` per stored depth, ``role`` = ``nu``); the cell's ground-truth FEM
(neo-Hookean, frictionless, 2 mm elements graded around the push) with the point probe along
``-normal``.
"""

import os
import sys
import time

for _var in ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.abspath(os.path.join(HERE, '..', '..', '..')))

import dataclasses  # noqa: E402

from make_deformation_fixtures import (boundary_triangles, CAMERA, render, say, spec_of,  # noqa
                                       VIEW)
from pointforce_ros.rotations import quaternion_to_matrix  # noqa: E402
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints  # noqa: E402
from pointforce_ros.sim.fem.live import POINT_PROBE  # noqa: E402
from pointforce_ros.sim.fem.probes import point_probe, pose_for_push  # noqa: E402
from pointforce_ros.sim.fem.solver import FemModel  # noqa: E402
from pointforce_ros.types import Mesh  # noqa: E402

DEPTHS = np.array([0.5, 1.0, 2.0, 3.0, 4.0, 5.0]) * 1e-3
STORED = np.array([3.0, 5.0]) * 1e-3
SIDE = [(0.000, 0.027), (-0.012, 0.025)]
"""(y, z) of the pushes on the -x face, metres (the block's top is at z = 0.040): at least
13 mm below the top edge, so that the estimator's probe-zone exclusion (a 12 mm cylinder about
the push axis) leaves the top surface in view."""


def make_side_push(name, spec, k, y, z, h=0.002, seed=40):
    """Solve one horizontal push into the -x face and render the stored depths."""
    t0 = time.time()
    x = spec.centre[0] - spec.size[0] / 2
    mesh = spec.build_mesh(h, refine_at=(x, y), growth=1.5)
    mesh = dataclasses.replace(mesh, top_nodes=np.arange(mesh.n_nodes))
    model = FemModel(mesh, spec.gauss_young(mesh), spec.poisson, support=spec.support)
    q = np.array([x, y, z])
    n = np.array([-1.0, 0.0, 0.0])
    d = -n
    probe = point_probe(**POINT_PROBE)
    res = model.indent(probe, pose_for_push(q, d), d, DEPTHS, torque_centre=q,
                       keep_solved=True, stop_force=3.0 * spec.force_cap)
    t_solve = time.time() - t0
    tris = boundary_triangles(mesh)
    target = np.array([spec.centre[0], spec.centre[1], 0.02])
    pose_cam = ring_viewpoints(target, count=1, azimuth0_deg=200.0, **VIEW)[0]
    cam = DepthCamera(seed=seed + k, **CAMERA)
    keep = [i for i, dep in enumerate(res.depths) if np.any(np.isclose(dep, STORED))]
    clouds, starts = [], [0]
    for i in keep:
        ppose = pose_for_push(q + res.depths[i] * d, d)
        rot = quaternion_to_matrix(ppose.orientation)
        occluder = Mesh(probe.vertices @ rot.T + ppose.position, probe.triangles)
        pts, _ = render(cam, pose_cam, res.surface[i], tris, occluder)
        clouds.append(pts)
        starts.append(starts[-1] + len(pts))
    path = os.path.join(HERE, f'side_{name}_{k}.npz')
    np.savez_compressed(
        path, xy=np.array([x, y]), tilt_deg=90.0, azimuth_deg=0.0, role='nu',
        contact_point=q, normal=n, direction=d, depths=res.depths[keep],
        force=-res.force[keep], probe_position=res.probe_position[keep],
        cloud=np.concatenate(clouds).astype(np.float32), cloud_start=np.array(starts),
        camera_pose=pose_cam, young=spec.young, poisson=spec.poisson,
        solve_seconds=t_solve, mesh_nodes=mesh.n_nodes, truth_h=h)
    f = -res.force[keep]
    say(f'{name} side push {k}: depths {np.round(res.depths[keep] * 1e3, 1)} mm, |F| '
        f'{np.round(np.linalg.norm(f, axis=1), 2)} N, {mesh.n_nodes} nodes, solve '
        f'{t_solve:.0f} s -> {path}')


def main():
    """Build the side pushes of the foam block."""
    spec = spec_of('foam_block')
    for k, (y, z) in enumerate(SIDE):
        make_side_push('foam_block', spec, k, y, z)


if __name__ == '__main__':
    main()
