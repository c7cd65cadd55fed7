#!/usr/bin/env python3
"""Figure 2 under each neighbour rule of the contact simulator (a study, session 44).

Step 2 of the contact simulator averages a rigid sample's three nearest surface points: with
equal weights (the paper, ``neighbours='equal'``) or with weights that vanish where a point
leaves the three (``'smooth'``, :func:`~pointforce_ros.contact.single_pose.neighbour_weights`),
which takes most of the steps out of a sideways sweep (``answer_smoothness.py
--neighbours``). This scores figure 2's line and cylinder trials of each object under both
(:func:`~pointforce_ros.lab.figures.figure_probes`, ``(c, L)`` identified under the same rule,
the paper's simulator on one draw), as ``nugget_floor.py --part figure2`` does for ours.

Session 44 (record ``neighbour_rule.log``), ours' force RMSE equal -> smooth: plush 0.629 ->
0.596 N, vest 1.490 -> 1.435, lamb 0.814 -> 0.806, the dome 0.336 -> 0.320, thin_layer 1.314 ->
1.426 N (6.4 -> 6.9 % of the peak): better on four objects, worse on one, the five sum to 4.58
N under both. Both goals of figure 2 hold under both rules. With the demo's replays
(``data/fem/demo_neighbour_replay.py``: 8.53 -> 8.67 % of the largest true force) the rule
is not chosen by accuracy; equal stays the default, smooth is the contact service's option.

Usage: python data/figures/neighbour_rule.py [--objects ...] (3-6 min per object and rule on
one core; set OPENBLAS_NUM_THREADS=1).
"""

import argparse

from nugget_floor import figure2_line  # this folder
from pointforce_ros.contact import simulator as simulator_module
from pointforce_ros.contact.simulator import NEIGHBOUR_RULES
from pointforce_ros.lab.figures import load_poke_fixture, load_probe_fixture

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')


def main(argv=None):
    """Print one line per object and rule."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    args = parser.parse_args(argv)
    for name in args.objects:
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        trials, dent, _ = load_probe_fixture(name, say=lambda line: None)
        for rule in NEIGHBOUR_RULES:
            before = simulator_module.NEIGHBOURS
            simulator_module.NEIGHBOURS = rule   # every simulator the figure builds
            try:
                figure2_line(f'{name} {rule}', surface, curves, trials, dent)
            finally:
                simulator_module.NEIGHBOURS = before


if __name__ == '__main__':
    main()
