#!/usr/bin/env python3
"""Does coupling that depends on local properties lower the demo's floor?

Like ``demo_floor.py`` (the demo's captured surface, the TRUE point response below it, the 9
planner queries against their FEM truth), but the shape function's constant varies per contact
with the local point stiffness: ``c_i = c (k_i / k_ref) ** beta`` with ``k_i`` the true
point force at 3 mm at the contact's neighbours, ``k_ref`` the median over the surface, and
``G_ij = c_ij / (c_ij + r) exp(-r / L)``, ``c_ij = sqrt(c_i c_j)``; ``beta = 0`` is the
simulator's global family. Each family member's ``(c, L)`` (and so its score) is fitted on the
calibration pushes (sphere and rod, ``demo_calibration*_<object>.npz``) only; the queries are
scored held-out. Also prints the best grid row with the answers known (the floor).

Usage: python data/fem/demo_floor_local.py out/demo [--object lamb]
"""

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

from demo_floor_setup import lcp_force_z, load_demo_floor  # this folder
from pointforce_ros.bringup.demo import _calibration_pokes
from pointforce_ros.contact.lcp import bpp_dense
from pointforce_ros.contact.simulator import ContactSimulator

HERE = Path(__file__).resolve().parent
C_GRID = (0.001, 0.0015, 0.002, 0.003, 0.004, 0.006, 0.01)
L_GRID = (np.inf, 0.04, 0.02, 0.012, 0.008, 0.005)
BETAS = (-1.0, -0.5, -0.25, 0.0, 0.25, 0.5, 1.0)


def force_z(sim, mesh, pose, approach, centre, c, decay, scale):
    """Fz of one query with per-point constants ``c * scale`` (scale over surface points)."""
    pos, rot = pose.position[None], pose.rotation()[None]
    a = np.asarray(approach, dtype=float)
    run = sim._run(sim._samples(mesh), rot, pos, a, np.asarray(centre)[None], detail=True)
    if 'x' not in run:
        return 0.0
    q, nbr, d, nq = run['q'], run['nbr'], run['d'], run['nq']
    e = d - sim._onset[nbr].mean(axis=1)
    ci = c * scale[nbr].mean(axis=1)
    cij = np.sqrt(np.outer(ci, ci))
    r = np.linalg.norm(q[:, None] - q[None], axis=2)
    G = cij / (cij + r)
    if np.isfinite(decay):
        G *= np.exp(-r / decay)
    x, _ = bpp_dense(G, e, free=e >= 0.65 * e.max())
    return lcp_force_z(sim.response, nbr, d, x, nq, a)


def main():
    """Score the families and write the JSON record."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('demo_out')
    parser.add_argument('--object', default='lamb')
    parser.add_argument('--response', default='true', choices=('true', 'learned'))
    parser.add_argument('--property', default='stiffness', choices=('stiffness', 'stiffening'),
                        help='k_i: the point force at 3 mm, or its growth from 3 to 8 mm '
                        '(F(8 mm) / F(3 mm): a stiff layer below the surface)')
    args = parser.parse_args()
    floor = load_demo_floor(args.demo_out, args.object)
    spec, queries, gt, model_path = floor.spec, floor.queries, floor.gt, floor.model_path
    surface = floor.served.surface
    response = floor.response(args.response)
    sim = ContactSimulator(surface, response, c=0.002)
    every = np.arange(len(surface))
    k = np.asarray(response.force(every, np.full(len(surface), 0.003)))
    if args.property == 'stiffening':
        k = np.asarray(response.force(every, np.full(len(surface), 0.008))) / np.maximum(
            k, 1e-3)
    kref = float(np.median(k[k > 0]))
    kk = np.maximum(k, 0.05 * kref) / kref
    cal = _calibration_pokes(spec)
    cal_list = [(m, p, a, f) for m, p, a, f in cal.values()]
    true = gt['force'][:, 2]
    peak = float(np.max(np.abs(true)))
    rows = []
    for beta in BETAS:
        scale = kk ** beta
        for c, decay in itertools.product(C_GRID, L_GRID):
            calp = np.array([force_z(sim, m, p, a, p.position, c, decay, scale)
                             for m, ps, a, _ in cal_list for p in ps])
            calm = np.concatenate([f for *_, f in cal_list])
            cal_rel = float(np.sqrt(np.mean(((calp - calm) / calm) ** 2)))
            pred = np.array([force_z(sim, m, p, a, ctr, c, decay, scale)
                             for _, m, p, a, ctr in queries])
            err = pred - true
            rows.append(dict(beta=beta, c_mm=1e3 * c,
                             L_mm=None if np.isinf(decay) else 1e3 * decay,
                             cal_rel=cal_rel, rmse_pct=float(100 * np.sqrt(np.mean(err ** 2))
                                                             / peak),
                             below=int(np.sum(err < 0)), ratios=(pred / true).round(3).tolist()))
    print(f'{spec.name}, {args.response} response, {args.property}; k_ref {kref:.2f}; '
          f'k/k_ref 5-95 %: {np.percentile(kk, 5):.2f}-{np.percentile(kk, 95):.2f}')
    for beta in BETAS:
        mine = [r for r in rows if r['beta'] == beta]
        by_cal = min(mine, key=lambda r: r['cal_rel'])
        floor = min(mine, key=lambda r: r['rmse_pct'])
        for label, r in (('fit on calibration', by_cal), ('floor (answers known)', floor)):
            print(f'beta {beta:+.2f} {label:22s}: c {r["c_mm"]:.1f} mm L {r["L_mm"]} mm, '
                  f'calibration {100 * r["cal_rel"]:.1f} %, queries {r["rmse_pct"]:.1f} %, '
                  f'{r["below"]} below; ' + ' '.join(f'{v:.2f}' for v in r['ratios']))
    out = HERE / f'demo_floor_local_{spec.name}_{args.response}_{args.property}.json'
    out.write_text(json.dumps({'object': spec.name, 'model': str(model_path), 'k_ref': kref,
                               'rows': rows}, indent=1) + '\n')
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
