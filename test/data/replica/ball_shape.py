"""Lab script: the engine ball's force-depth shape against the FEM truth, and its section.

Not a test. One push per JSON entry on the plate-on-ball replica at mesh ``H`` (m), printing the
ratio of the engine's force to the FEM's at 15 depths from 2 to 30 mm, the curve error after
matching the force at 30 mm and after a least-squares scale, and (``"section": 1``) the section at
30 mm against the FEM's (:func:`pointforce_ros.replica.contour.ball_section_error`). Entry keys:
``E`` (Pa, default 71.5e3), ``nu`` (0.3), ``damping`` (0.003), ``cfg`` (overrides of
``PLATE_CONFIG``; ``{"friction": 0.0}`` for the frictionless pushes quoted), ``section``. The
exploration that chose ``PLATE_CONFIG`` ran this; e.g. (``ball_h75_dt2.log``)::

    OPENBLAS_NUM_THREADS=1 nice -n 10 .venv/bin/python test/data/replica/ball_shape.py 0.0075 \\
        '[{"nu": 0.4, "E": 57476, "cfg": {"time_step": 0.002}, "section": 1}]'
"""

from dataclasses import replace
import json
from pathlib import Path
import sys
import time

import numpy as np

from pointforce_ros.replica.build import replica_body
from pointforce_ros.replica.calibrate import simulate_loading
from pointforce_ros.replica.contour import ball_section_error
from pointforce_ros.replica.data import load_pokes
from pointforce_ros.replica.evaluate import truth_section
from pointforce_ros.replica.scene import Material

DATA = Path(__file__).resolve().with_name('ball_plate.npz')


def main(argv) -> int:
    """Run the pushes of ``argv[2]`` (JSON list) on a ``argv[1]`` m mesh; print the figures."""
    data = load_pokes(DATA)
    _, held = data.split()
    compression, section = truth_section(DATA)
    with np.load(DATA) as z:
        fem_depth, fem_force = z['fem_depth'], z['fem_force']
    mesh, config = replica_body(data, float(argv[1]))
    depths = np.linspace(0.002, 0.030, 15)
    truth = np.interp(depths, fem_depth, fem_force)
    for run in json.loads(argv[2]):
        cfg = replace(config, **run.get('cfg', {}))
        material = Material.from_young(run.get('E', 7.15e4), run.get('nu', 0.3),
                                       run.get('damping', 0.003))
        started = time.monotonic()
        d, f = simulate_loading(mesh, material, held[0], cfg)
        order = np.argsort(d)
        sim = np.interp(depths, d[order], f[order])
        k_max, k_ls = truth[-1] / sim[-1], float(sim @ truth) / float(sim @ sim)

        def curve(k):
            return 100 * np.sqrt(np.mean((k * sim - truth) ** 2)) / truth.max()
        print(json.dumps(run), f'{time.monotonic() - started:.0f}s ratio',
              (sim / truth).round(3).tolist(),
              f'| k@max {k_max:.3f} curve {curve(k_max):.2f}% | LS k {k_ls:.3f} at30 '
              f'{100 * abs(k_ls * sim[-1] / truth[-1] - 1):.2f}% curve {curve(k_ls):.2f}%',
              flush=True)
        if run.get('section'):
            errors = ball_section_error(mesh, material, cfg, compression, section)
            print('  section', {k: round(v, 4) for k, v in errors.items()}, flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv))
