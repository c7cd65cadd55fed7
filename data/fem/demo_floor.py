#!/usr/bin/env python3
"""How far the semi-empirical contact simulator can go on the demo's planner queries.

Answers the 9 queries of ``pointforce demo`` (sphere, paddle, cylinder at three poses each)
with the semi-empirical simulator on the demo's captured surface over a grid of shape
constants ``(c, L)``, twice: with the point model the demo learned (its last model) and with
the TRUE point response (the object's live FEM table, tip at the same place below the captured
surface), and scores each against the queries' FEM ground truth (``demo_queries_<object>.npz``).
The best true-response row is the floor of the simulator's ``(c, L)`` family on these queries
(a perfect point model, ``(c, L)`` chosen with the answers known); the best learned row is the
same with the demo's point model. Writes ``demo_floor_<object>.json`` beside this script.

Usage: python data/fem/demo_floor.py out/demo [--object lamb]   (after `pointforce demo`)
"""

import argparse
import json
from pathlib import Path

import numpy as np

from demo_floor_setup import load_demo_floor  # this folder
from pointforce_ros.contact.simulator import ContactSimulator

HERE = Path(__file__).resolve().parent
C_GRID = (0.0007, 0.001, 0.0015, 0.002, 0.003, 0.004, 0.006, 0.01)
L_GRID = (np.inf, 0.04, 0.02, 0.012, 0.008, 0.005)


def main():
    """Score the grid and write the JSON record."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('demo_out', help="the demo's --out folder (its cell/models are read)")
    parser.add_argument('--object', default='lamb')
    args = parser.parse_args()
    floor = load_demo_floor(args.demo_out, args.object)
    spec, queries, gt, model_path = floor.spec, floor.queries, floor.gt, floor.model_path
    sim = floor.served
    surface = sim.surface
    responses = {'learned': sim.response, 'true point': floor.true_response()}
    true = gt['force'][:, 2]
    peak = float(np.max(np.abs(true)))
    record = {'object': spec.name, 'model': str(model_path), 'served': [sim.c, sim.decay],
              'peak_true_N': peak, 'rows': []}
    for label, response in responses.items():
        for c in C_GRID:
            for decay in L_GRID:
                s = ContactSimulator(surface, response, c=c, decay=decay)
                pred = np.array([s.query(m, p, a, ctr).wrench.force[2]
                                 for _, m, p, a, ctr in queries])
                err = pred - true
                record['rows'].append(dict(
                    response=label, c_mm=1e3 * c, L_mm=None if np.isinf(decay) else 1e3 * decay,
                    rmse_N=float(np.sqrt(np.mean(err ** 2))),
                    rmse_pct=float(100 * np.sqrt(np.mean(err ** 2)) / peak),
                    below=int(np.sum(err < 0)), ratios=[float(r) for r in pred / true]))
    for label in responses:
        rows = sorted((r for r in record['rows'] if r['response'] == label),
                      key=lambda r: r['rmse_N'])
        record[f'best_{label.replace(" ", "_")}'] = rows[0]
        best = rows[0]
        print(f'{label:10s} best: c {best["c_mm"]:.1f} mm, L {best["L_mm"]} mm: RMSE '
              f'{best["rmse_N"]:.2f} N ({best["rmse_pct"]:.1f} % of {peak:.1f} N), '
              f'{best["below"]} of {len(true)} below; ratios '
              + ' '.join(f'{r:.2f}' for r in best['ratios']))
    out = HERE / f'demo_floor_{spec.name}.json'
    out.write_text(json.dumps(record, indent=1) + '\n')
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
