#!/usr/bin/env python3
"""The demo's poke-learn-calibrate-query chain offline: where the pokes land, what it costs.

Replays ``pointforce demo`` without ROS, on the surface a demo run captured
(``<demo_out>/cell/surface.npz``): the first poke at the calibration site, then each next poke
from :meth:`OnlineLearner.suggest` (with the planner's region of interest, ``--region``, or
over the whole surface), each simulated against the object's live FEM table under the
``realistic`` scenario (:func:`~pointforce_ros.sim.session.simulate_campaign`), learned by the
:class:`OnlineLearner`; then the point model against the truth at the calibration and query
sites (:func:`~pointforce_ros.bringup.demo.point_model_check`), ``(c, L)`` from the two
calibration pushes (:func:`~pointforce_ros.contact.identify.calibrate_shape`) and the 9
planner queries answered by the simulator against their FEM truth (held out: never fitted).
Runs under machine load where the live demo's emulator stalls; no interval coverage (that
needs the contact service).

Usage: python data/fem/demo_floor_pokes.py out/demo [--object lamb] [--seeds 0 1 2] [--pokes 8]
"""

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from demo_floor_setup import load_demo_queries  # this folder
from pointforce_ros.bringup.demo import (_calibration_pokes, CALIBRATION_OFFSET, CALIBRATIONS,
                                         planner_region, point_model_check)
from pointforce_ros.contact.identify import calibrate_shape, decay_grid
from pointforce_ros.model.files import load_surface
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.model.serving import WrenchServer
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.sim.generate import fem_cell_object
from pointforce_ros.sim.scenario import load_scenario
from pointforce_ros.sim.session import simulate_campaign

HERE = Path(__file__).resolve().parent


def run(spec, live, surface, queries, gt, region: bool, seed: int, pokes: int = 8,
        calibration_region: bool = True, footprint: bool = False) -> dict:
    """One replay; returns the point-model ratios, (c, L) and the query scores.

    ``calibration_region``: the region holds the calibration pushes' sites beside the query
    tips (as the demo does); ``False``: the query tips only. ``footprint``: the region is the
    pushes' contact footprints, else 12 mm discs round their tips (the demo).
    """
    obj = fem_cell_object(spec, live)
    scenario = load_scenario('realistic')
    rows = None
    if region:
        calibration = [(None, push(spec)[0], pose, None, None)
                       for _, push in CALIBRATIONS.values()
                       for pose in push(spec)[1][-1:]] if calibration_region else []
        rows = planner_region(queries + calibration,
                              surface=surface if footprint else None)
    site = np.asarray(spec.centre, dtype=float) + CALIBRATION_OFFSET
    gap = np.linalg.norm(surface.points[:, :2] - site, axis=1)
    index = int(np.argmin(np.where(surface.normals[:, 2] > 0.7, gap, np.inf)))
    with tempfile.TemporaryDirectory() as tmp:
        store = PokeStore(Path(tmp) / 'pokes')
        learner = OnlineLearner(Path(tmp) / 'pokes', Path(tmp) / 'models', surface,
                                shape_constant=0.004)
        where = []
        for k in range(pokes):
            if k > 0:
                index = int(learner.suggest(1, exclude_radius=0.01, max_tilt_deg=35.0,
                                            region=rows)[0][0])
            where.append(surface.points[index].tolist())
            record = simulate_campaign(obj, scenario, points=[surface.points[index]],
                                       normals=[surface.normals[index]], surface=surface,
                                       force_limit=float(spec.force_cap),
                                       depth_limit=float(spec.max_depth), speed=0.004,
                                       standoff=0.006, seed=1000 * seed + k,
                                       id_prefix=f'poke-{k:02d}-')[0]
            store.add(record)
            learner.update()
        ratios = point_model_check(spec, live, surface, learner.contact_model().response)
        server = WrenchServer()
        server.load(learner.current_model_path())
        sim = server.simulator()
        vectors = _calibration_pokes(spec, vectors=True)
        cal = calibrate_shape(sim, [vectors['sphere'], vectors['rod']],
                              decays=decay_grid(sim.surface))
        fitted = sim.with_shape_constant(cal.fit.c, cal.fit.decay)
        pred = np.array([fitted.query(m, p, a, ctr).wrench.force[2]
                         for _, m, p, a, ctr in queries])
    true = gt['force'][:, 2]
    err = pred - true
    return {'region': region, 'calibration_region': region and calibration_region,
            'footprint': region and footprint,
            'seed': seed, 'pokes': where, 'ratios': ratios,
            'c_mm': 1e3 * cal.fit.c, 'L_mm': 1e3 * cal.fit.decay,
            'rmse_pct': float(100 * np.sqrt(np.mean(err ** 2)) / np.max(np.abs(true))),
            'below': int(np.sum(err < 0)), 'pred_over_true': (pred / true).round(3).tolist()}


def main():
    """Replay with and without the region for each seed; write the JSON record."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('demo_out', help="a demo's --out folder (its cell/surface.npz)")
    parser.add_argument('--object', default='lamb')
    parser.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    parser.add_argument('--modes', nargs='+', default=['none', 'all'],
                        choices=('none', 'all', 'queries', 'footprint'),
                        help='none: suggestions over the whole surface; all: 12 mm discs round '
                        'the query and calibration tips (the demo); queries: round the query '
                        'tips only; footprint: the query and calibration contact footprints')
    parser.add_argument('--tag', default='', help='suffix of the JSON record')
    parser.add_argument('--pokes', type=int, default=8, help='pokes per replay (the demo: 8)')
    args = parser.parse_args()
    demo = load_demo_queries(args.object)
    spec, live, queries, gt = demo.spec, demo.live, demo.queries, demo.gt
    surface = load_surface(Path(args.demo_out) / 'cell' / 'surface.npz')
    runs = []
    for seed in args.seeds:
        for mode in args.modes:
            r = run(spec, live, surface, queries, gt, mode != 'none', seed, args.pokes,
                    calibration_region=mode in ('all', 'footprint'),
                    footprint=mode == 'footprint')
            runs.append(r)
            print(f'seed {seed} region {mode:7s} {args.pokes} pokes: point model '
                  + ', '.join(f'{k} {v:.2f}' for k, v in r['ratios'].items())
                  + f'; c {r["c_mm"]:.2f} mm L {r["L_mm"]:.0f} mm; queries RMSE '
                  f'{r["rmse_pct"]:.1f} %, {r["below"]} of 9 below', flush=True)
    out = HERE / f'demo_floor_pokes_{spec.name}{args.tag}.json'
    out.write_text(json.dumps({'object': spec.name, 'surface': args.demo_out, 'runs': runs},
                              indent=1) + '\n')
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
