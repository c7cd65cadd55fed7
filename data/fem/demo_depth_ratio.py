#!/usr/bin/env python3
"""The demo's learned point model against the FEM truth at its sites, by depth (session 34).

The demo prints one line at 3 mm (``point model against the FEM truth``): the mean force the
last served model gives within 6 mm of the calibration site, the rod site and each query site,
over the mean true point-probe force at the same tip positions
(:func:`~pointforce_ros.bringup.demo.point_model_check`). This prints the same ratios at 2, 3,
5, 7 and 9 mm, to tell an error of the response law's shape with depth (ratios that drift
with depth) from one of the spreading over position (ratios that hold at every depth).

Usage: python data/fem/demo_depth_ratio.py DEMO_OUT [--object lamb]   (about 20 s)
"""

import argparse

from demo_floor_setup import served_last_model  # this folder
from pointforce_ros.bringup.cell import _load_sim_object
from pointforce_ros.bringup.demo import point_model_check
from pointforce_ros.sim.fem.live import LiveContact

DEPTHS = (0.002, 0.003, 0.005, 0.007, 0.009)


def main() -> None:
    """Print the ratios of one demo run's last model, one line per depth."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('demo_out', help='a pointforce demo --out folder (out/demo)')
    parser.add_argument('--object', default='lamb')
    args = parser.parse_args()
    sim = served_last_model(args.demo_out)
    spec = _load_sim_object(args.object).spec
    live = LiveContact.load(spec.name, build=False)
    for depth in DEPTHS:
        ratios = point_model_check(spec, live, sim.surface, sim.response, depth=depth)
        print(f'{1e3 * depth:.0f} mm: '
              + ', '.join(f'{name} {value:.2f}' for name, value in ratios.items()), flush=True)


if __name__ == '__main__':
    main()
