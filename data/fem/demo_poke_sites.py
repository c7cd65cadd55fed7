#!/usr/bin/env python3
"""Where a demo's pokes landed against its sites, and the point model there (session 35).

The demo's point model reads 0.95-1.09 of the FEM truth at its query sites from run to run
(the ``point model against the FEM truth`` line), and the runs' poke sites differ with the
captured surface and the suggestions' near-ties. This prints, per ``pointforce demo --out
DIR`` run, for each site of :func:`~pointforce_ros.bringup.demo.demo_sites`: the distance
from the site to the nearest poke (``cell/pokes/index.json``), how many pokes landed within
the region's 12 mm (:data:`~pointforce_ros.bringup.demo.REGION_RADIUS`), and the last served
model's ratio to the truth at 3 mm
(:func:`~pointforce_ros.bringup.demo.point_model_check`). With ``DIR:LOG`` (the run's printed
output) it adds the run's calibrated summary (force RMSE as a share of the largest true force,
``Fz`` below / above the truth; :func:`demo_runs.read_run`) and the ratio of each planner
query's predicted to true ``Fz``.

Usage: python data/fem/demo_poke_sites.py DEMO_OUT[:LOG] [...] [--object lamb]
(about 20 s per run)
"""

import argparse
import json
import re
from pathlib import Path

import numpy as np

from demo_floor_setup import served_last_model  # this folder
from demo_runs import read_run  # this folder
from pointforce_ros.bringup.cell import _load_sim_object
from pointforce_ros.bringup.demo import demo_sites, point_model_check, REGION_RADIUS
from pointforce_ros.sim.fem.live import LiveContact

QUERY_ROW = re.compile(r'\[demo\] (?P<name>(?:sphere|paddle|cylinder)[^#]*#\d)\s+'
                       r'(?P<pred>[0-9.]+)\s+[0-9.]+\.\.[0-9.]+\s+(?P<true>[0-9.]+)')


def query_ratios(log: str) -> dict:
    """``{query: predicted / true Fz}`` from the last calibrated query table of a demo log."""
    text = Path(log).read_text(errors='replace')
    table = text[text.rfind('query            pred Fz'):]
    out = {}
    for m in QUERY_ROW.finditer(table):
        out.setdefault(m['name'].strip(), float(m['pred']) / float(m['true']))
    return out


def poke_distances(demo_out: str, spec) -> dict:
    """``{site: (nearest poke distance in mm, pokes within the region's radius)}``."""
    index = json.loads((Path(demo_out) / 'cell' / 'pokes' / 'index.json').read_text())
    points = np.array([p['point'] for p in index['pokes']], dtype=float)
    out = {}
    for name, site in demo_sites(spec).items():
        gap = np.linalg.norm(points[:, :2] - np.asarray(site), axis=1)
        out[name] = (1e3 * float(gap.min()), int(np.sum(gap < REGION_RADIUS)))
    return out


def main() -> None:
    """Print one block per run."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('runs', nargs='+', help='DEMO_OUT or DEMO_OUT:LOG')
    parser.add_argument('--object', default='lamb')
    args = parser.parse_args()
    spec = _load_sim_object(args.object).spec
    live = LiveContact.load(spec.name, build=False)
    for run in args.runs:
        demo_out, _, log = run.partition(':')
        sim = served_last_model(demo_out)
        ratios = point_model_check(spec, live, sim.surface, sim.response)
        gaps = poke_distances(demo_out, spec)
        head = demo_out
        if log:
            summary = read_run(log)
            head += (f': {summary["pct"]:.1f} % of the largest true force, '
                     f'{summary["below"]} below / {summary["above"]} above')
        print(head)
        for name, (gap, count) in gaps.items():
            print(f'  {name:<14} nearest poke {gap:5.1f} mm, {count} within '
                  f'{1e3 * REGION_RADIUS:.0f} mm, point model / truth at 3 mm '
                  f'{ratios.get(name, float("nan")):.2f}')
        if log:
            print('  predicted / true Fz: ' + ', '.join(
                f'{name} {value:.2f}' for name, value in query_ratios(log).items()), flush=True)


if __name__ == '__main__':
    main()
