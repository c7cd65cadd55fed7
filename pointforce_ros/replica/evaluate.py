"""Lab script: both calibrators on measured pokes, held-out errors, simulations and wall time.

Usage::

    nice .venv/bin/python -m pointforce_ros.replica.evaluate data/figures/pokes_plush.npz \
        --h 0.01 --train 3 --held-out 3 --out out/replica_plush

Prints one JSON object (also written to ``OUT/evaluation.json``): per calibrator the material,
simulations, wall time, and the median held-out errors (at the largest compression, over the
curve, RMS in N); the mesh resolution; and how far the calibrated replica moves when the mesh
is refined (``resolution``: the force at the deepest point of the first held-out poke at
``h`` and ``h_fine``).
"""

import argparse
import json
from pathlib import Path
import sys
import time

import numpy as np

from pointforce_ros.replica.calibrate import (calibrate_paper, calibrate_scaling,
                                              damping_step, evaluate, force_at,
                                              simulate_loading, summary)
from pointforce_ros.replica.data import load_pokes, subset
from pointforce_ros.replica.mesh import heightfield_tet_mesh
from pointforce_ros.replica.scene import SceneConfig


def main(argv=None) -> int:
    """Run the evaluation; print and write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data')
    ap.add_argument('--h', type=float, default=0.01, help='mesh edge length, m')
    ap.add_argument('--h-fine', type=float, default=0.0075, help='refined mesh for the '
                    'resolution check, m (0: skip)')
    ap.add_argument('--train', type=int, default=3)
    ap.add_argument('--held-out', type=int, default=3)
    ap.add_argument('--damping', action='store_true', help='run the damping step too')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--out', default=None)
    args = ap.parse_args(argv)
    started = time.monotonic()
    data = load_pokes(args.data)
    train, held = data.split(0.5, seed=args.seed)
    train, held = subset(train[:args.train], 5), subset(held[:args.held_out], 5)
    config = SceneConfig()
    mesh = heightfield_tet_mesh(data.surface_points, args.h)
    result = {'data': args.data, 'h': args.h, 'nodes': len(mesh.nodes),
              'tets': len(mesh.tets), 'config': config.__dict__,
              'train': [p.poke_id for p in train], 'held_out': [p.poke_id for p in held]}
    for name, run in (('scaling', calibrate_scaling), ('paper', calibrate_paper)):
        calib = run(mesh, train, config)
        if args.damping:
            calib = damping_step(mesh, calib, train, held, config)
        errs = summary(evaluate(mesh, calib.final, held, config))
        result[name] = dict(calib.to_json(), held_out=errs)
        print(f'[evaluate] {name}: {errs}, {calib.simulations} simulations, '
              f'{calib.seconds:.0f} s', flush=True)
    if args.h_fine:
        best = result['scaling']['final']
        from pointforce_ros.replica.scene import Material
        mat = Material(**best)
        p = held[0]
        out = {}
        for h in (args.h, args.h_fine):
            m = heightfield_tet_mesh(data.surface_points, h)
            d, f = simulate_loading(m, mat, p, config)
            out[f'{h:g}'] = {'nodes': len(m.nodes),
                             'force_at_deepest_N': float(force_at(d, f, p.depth[-1:])[0]),
                             'measured_N': float(p.force[-1])}
        result['resolution'] = out
    result['seconds'] = time.monotonic() - started
    text = json.dumps(result, indent=1, default=float)
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        (Path(args.out) / 'evaluation.json').write_text(text)
    print(text)
    return 0


if __name__ == '__main__':
    np.set_printoptions(precision=4, suppress=True)
    sys.exit(main())
