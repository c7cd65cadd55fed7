"""Render the plate-on-ball truth with the cell's depth camera: the section the camera sees.

The truth of ``make_ball_plate.py`` (the cell's neo-Hookean FEM, frictionless plate and table)
is solved again to its largest compression (30 mm; on the 12-element mesh, the data file's
coarse one, F(30 mm) within 0.2 % of the 16-element truth: 5 minutes against 20 on a loaded
machine; the log gives the two sections' gap) and its whole deformed surface (the upper
hemisphere and its mirror image) is rendered by the cell's simulated depth camera
(:class:`pointforce_ros.sim.camera.DepthCamera` through
:func:`pointforce_ros.bringup.camera_check.render_view`, the renderer of the camera-check
views), with the ``realistic`` scenario's bias (2 mm, reads too far) and range noise
(0.2 mm + 0.004 z^2), each camera seeded by the scenario. The plate (150 x 150 x 20 mm) and
the table occlude, as on a cell.

Viewpoints: two cameras of the cell's ring (:func:`pointforce_ros.sim.camera.ring_viewpoints`,
0.35 m, on the -x and +x sides: they look across the section plane y = 0) at ``ELEVATION``
degrees: a side camera, as seed 002's. The cell's scanning elevation (55 degrees) sees almost
none of the loaded ball under the plate (``hidden_at_55deg`` counts its section points).
Each camera takes ``FRAMES`` frames of the rest ball (before the plate touches) and of the
loaded ball (the plate held at 30 mm).

Writes ``<data stem>_camera.npz`` beside the data file: per camera its pose (4, 4) ``base <-
optical``, and the rest and loaded points within ``KEEP`` of the section plane (the camera's
cloud cropped to the section's slab; ``base``, metres), flattened with offsets; the
scenario's nominal bias and noise; the rendered FEM's own section (``rendered_section_xz``).
The replica's evaluation extracts the section from these
points (:func:`pointforce_ros.replica.contour.camera_section`). It also checks that the
solved surface's plane y = 0 is the data file's ``section_xz`` (the same truth).

Regenerate (about 2 minutes of CPU per ball)::

    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python test/data/replica/make_ball_camera.py \
        test/data/replica/ball_plate.npz
    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python test/data/replica/make_ball_camera.py \
        test/data/replica/ball_core.npz
"""

import argparse
from pathlib import Path
import sys
import time

import numpy as np

from pointforce_ros.bringup.camera_check import render_view
from pointforce_ros.replica.contour import section_error
from pointforce_ros.sim.camera import DepthCamera, ring_viewpoints
from pointforce_ros.sim.scenario import load_scenario
from pointforce_ros.types import Mesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_ball_plate import indent_ball, MAX_COMPRESSION, RADIUS  # noqa: E402

SCENARIO = 'realistic'
"""The cell's scenario whose camera bias and noise the views carry."""
ELEVATION = 10.0
"""Camera elevation above the table plane, degrees (a side camera under the plate's edge)."""
DISTANCE = 0.35
"""Camera distance to the ball's deformed centre, m (the cell's default)."""
FRAMES = 4
"""Frames per state and camera (as the camera check stacks them)."""
KEEP = 0.012
"""Half-width of the slab about y = 0 kept of each cloud, m."""


def box_mesh(lo, hi) -> Mesh:
    """Return the closed triangle mesh of the axis-aligned box ``lo``-``hi`` (3,) each, metres."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    corners = np.array([[x, y, z] for z in (lo[2], hi[2]) for y in (lo[1], hi[1])
                        for x in (lo[0], hi[0])])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return Mesh(corners, np.array(tris))


def deformed_ball(core_young: float, core_radius: float, n: int = 16, steps: int = 30):
    """Solve the FEM (as ``make_ball_plate.relaxed_curve``) and return the full ball.

    Returns:
        ``(rest (V, 3), loaded (V, 3), triangles (T, 3), section (S, 2))``: the whole
        ball's surface at rest and at ``MAX_COMPRESSION`` (table frame, metres, outward
        triangles), and its loaded outline in y = 0 (``make_ball_plate``'s ``section_xz``).

    """
    mesh, res = indent_ball(n, n // 2, steps, core_young, core_radius)
    quads = mesh.boundary_faces
    upper = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    tris = np.concatenate([upper, upper[:, ::-1] + mesh.n_nodes])  # mirror: reversed winding
    mirror = np.array([1.0, 1.0, -1.0])

    def whole(nodes, mid):
        return np.concatenate([nodes, nodes * mirror]) + [0.0, 0.0, mid]

    loaded_nodes = res.surface[-1]
    rest = whole(mesh.nodes, RADIUS)
    loaded = whole(loaded_nodes, RADIUS - MAX_COMPRESSION / 2)
    on_plane = (np.abs(mesh.nodes[:, 1]) < 1e-9) & (
        np.abs(np.linalg.norm(mesh.nodes, axis=1) - RADIUS) < 1e-9)
    up = loaded_nodes[on_plane][:, [0, 2]]
    mid = RADIUS - MAX_COMPRESSION / 2
    section = np.concatenate([up, up[up[:, 1] > 1e-9] * [1.0, -1.0]]) + [0.0, mid]
    return rest, loaded, tris, section


def main(argv=None) -> int:
    """Solve, render and write ``<data>_camera.npz``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data', help='ball_plate.npz or ball_core.npz (make_ball_plate.py)')
    ap.add_argument('--n', type=int, default=12,
                    help='elements across the FEM mesh (the data file: 16)')
    ap.add_argument('--out', default=None, help='output file (default: beside the data)')
    args = ap.parse_args(argv)
    data = Path(args.data)
    with np.load(data, allow_pickle=False) as z:
        core_young = float(z['core_young']) if 'core_young' in z.files else 0.0
        core_radius = float(z['core_radius']) if 'core_radius' in z.files else 0.0
        section_xz = np.asarray(z['section_xz'], float)
    started = time.monotonic()
    rest, loaded, tris, section = deformed_ball(core_young, core_radius, args.n)
    gap = section_error(section_xz, section, (0.0, RADIUS - MAX_COMPRESSION / 2))
    print(f'FEM n={args.n} in {time.monotonic() - started:.0f} s; its section against the '
          f"data file's section_xz: RMS radial gap {gap['rms_m'] * 1e3:.3f} mm "
          f"({gap['error_pct']:.3f} % of the width), largest {gap['max_m'] * 1e3:.3f} mm",
          flush=True)
    scenario = load_scenario(SCENARIO)
    target = [0.0, 0.0, RADIUS - MAX_COMPRESSION / 2]
    plate_z = 2 * RADIUS - MAX_COMPRESSION
    plate = box_mesh([-0.075, -0.075, plate_z], [0.075, 0.075, plate_z + 0.02])
    table = box_mesh([-0.2, -0.2, -0.02], [0.2, 0.2, 0.0])
    both = Mesh(np.concatenate([plate.vertices, table.vertices]),
                np.concatenate([plate.triangles, table.triangles + len(plate.vertices)]))
    rest_occ = Mesh(table.vertices, table.triangles)
    out = {'pose': [], 'rest': [], 'loaded': []}
    hidden = 0
    for i, pose in enumerate(ring_viewpoints(target, DISTANCE, count=2,
                                             elevation_deg=ELEVATION)):
        camera = DepthCamera(**scenario.camera_kwargs(i))
        rest_pts = np.concatenate([render_view(camera, pose, rest, tris, rest_occ)[0]
                                   for _ in range(FRAMES)])
        loaded_pts = np.concatenate([render_view(camera, pose, loaded, tris, both)[0]
                                     for _ in range(FRAMES)])
        out['pose'].append(pose)
        out['rest'].append(rest_pts[np.abs(rest_pts[:, 1]) < KEEP])
        out['loaded'].append(loaded_pts[np.abs(loaded_pts[:, 1]) < KEEP])
        print(f'camera {i}: {len(out["rest"][-1])} rest, {len(out["loaded"][-1])} loaded '
              f'points within {KEEP * 1e3:g} mm of y = 0 ({FRAMES} frames)')
    for pose in ring_viewpoints(target, DISTANCE, count=2, elevation_deg=55.0):
        pts = render_view(DepthCamera(), pose, loaded, tris, both)[0]
        hidden += int(np.count_nonzero(np.abs(pts[:, 1]) < 0.003))
    print(f'the cell scan elevation (55 deg) sees {hidden} loaded points within 3 mm of y = 0')
    kw = scenario.camera_kwargs(0)
    dest = Path(args.out) if args.out else data.with_name(f'{data.stem}_camera.npz')
    np.savez_compressed(
        dest, pose=np.array(out['pose']),
        rest_points=np.concatenate(out['rest']).astype(np.float32),
        rest_offsets=np.cumsum([0] + [len(p) for p in out['rest']]),
        loaded_points=np.concatenate(out['loaded']).astype(np.float32),
        loaded_offsets=np.cumsum([0] + [len(p) for p in out['loaded']]),
        rendered_section_xz=section, rendered_n=args.n,
        compression=MAX_COMPRESSION, radius=RADIUS, frames=FRAMES, elevation_deg=ELEVATION,
        scenario=SCENARIO, depth_bias=kw['depth_bias'], noise_a=kw['noise_a'],
        noise_b=kw['noise_b'], hidden_at_55deg=hidden)
    print(f'wrote {dest} ({dest.stat().st_size / 1e3:.0f} kB)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
