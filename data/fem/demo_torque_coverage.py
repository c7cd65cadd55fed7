#!/usr/bin/env python3
"""The demo's torque intervals with and without the centre-of-pressure part (a study).

``wrench_std`` carries, with the calibration's relative share, the torque of the centre of
pressure that share moves (:func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty`,
part ``'centre'``: the share times the contact force's spread, session 27). This replays
stored ``pointforce demo --out DIR`` runs: each run's last model and its stored uncertainty
sources, the 9 planner queries (torque about each probe's tip, as the demo asks), and counts
the true force and torque components inside the nominal 90 % intervals with the part
(``centre=True``, the service's) and without it.

Result (session 27, eight lamb runs of sessions 25-26, ``demo_torque_coverage.log``): torque
components inside 69 % -> 95 %, force components unchanged (93 %); per run 52-93 % -> 89-100
%. Before, a symmetric probe's torque about its tip was near zero and so was its share of it,
while the bone moved the true centre of pressure by millimetres (cylinder #2: 33-47 mN m).

Usage: python data/fem/demo_torque_coverage.py DEMO_OUT [DEMO_OUT ...]
"""

from pathlib import Path

import numpy as np

from demo_floor_setup import demo_runs_arguments  # this folder
from pointforce_ros.contact.uncertainty import wrench_uncertainty, Z90
from pointforce_ros.model.files import load_model


def main():
    """Print one line per run and part setting, and the pooled shares."""
    args, demo = demo_runs_arguments(__doc__.splitlines()[0])
    true = np.hstack([demo.gt['force'], demo.gt['torque']])
    pooled = {False: [], True: []}
    for out in args.demo_out:
        model = load_model(sorted((Path(out) / 'cell' / 'models').glob('model-v*.npz'))[-1])
        for centre in (False, True):
            pred, std = [], []
            for _, mesh, pose, approach, tip in demo.queries:
                u = wrench_uncertainty(model, mesh, [pose], approach, tip, centre=centre)
                pred.append(u.wrench[0])
                std.append(u.std[0])
            inside = np.abs(np.array(pred) - true) <= Z90 * np.array(std)
            pooled[centre].append(inside)
            print(f'{out} centre part {"on " if centre else "off"}: force components '
                  f'{inside[:, :3].mean():.0%}, torque components {inside[:, 3:].mean():.0%} '
                  f'(relative share {model.meta.get("relative_std", 0.0):.3f})', flush=True)
    for centre, runs in pooled.items():
        v = np.array(runs)
        print(f'centre part {"on " if centre else "off"}: {len(v)} runs, force components '
              f'{v[:, :, :3].mean():.1%}, torque components {v[:, :, 3:].mean():.1%}')


if __name__ == '__main__':
    main()
