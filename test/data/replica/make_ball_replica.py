"""Write the coarse plate-on-ball replica the tests reload (``ball_replica/``).

The material is the one ``pointforce replica`` calibrated on ``ball_plate.npz`` (read from
``ball.replica.json`` beside this script, the full run's record); the body is re-meshed at
15 mm so that a test simulates it in seconds. The figures written with it are its held-out
errors on ``ball_plate.npz``: the static force error at the largest compression and over the
curve (one static simulation serves every held-out trial: they share the ball and the depth),
the force-time error of the fastest held-out trial, and the section at the largest
compression against the FEM's (``section_*``) and against the cell camera's view of the FEM's
(``camera_*``, ``ball_plate_camera.npz``, its depth bias removed on the rest frames).
Regenerate (about a minute)::

    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python test/data/replica/make_ball_replica.py
"""

import json
from pathlib import Path
import sys

from pointforce_ros.replica.build import PLATE_CONFIG
from pointforce_ros.replica.data import load_pokes
from pointforce_ros.replica.contour import read_camera_views
from pointforce_ros.replica.evaluate import held_out_figures, truth_section
from pointforce_ros.replica.mesh import ball_tet_mesh, read_vtk
from pointforce_ros.replica.replica import write_replica
from pointforce_ros.replica.scene import Material

HERE = Path(__file__).resolve().parent
H_COARSE = 0.015
"""Mesh edge length of the test replica, m."""


def main() -> int:
    """Write ``ball_replica/`` from ``ball.replica.json``."""
    desc = json.loads((HERE / 'ball.replica.json').read_text())
    material = Material(**desc['material'])
    data = load_pokes(HERE / 'ball_plate.npz')
    out = HERE / 'ball_replica'
    mesh = ball_tet_mesh(data.ball_radius, H_COARSE)
    # the figures of the mesh as the VTK holds it (9 digits): the ringing contact turns a
    # 1e-9 m node shift into a few percent of force, so the test must see the same nodes
    write_replica(out, mesh, material, PLATE_CONFIG)
    mesh = read_vtk(out / 'body.vtk', H_COARSE)
    figs = held_out_figures(mesh, material, PLATE_CONFIG, data,
                            section=truth_section(HERE / 'ball_plate.npz'),
                            camera=read_camera_views(HERE / 'ball_plate_camera.npz'))
    figs['data'] = 'test/data/replica/ball_plate.npz'
    write_replica(out, mesh, material, PLATE_CONFIG, figures=figs)
    print(json.dumps(figs, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
