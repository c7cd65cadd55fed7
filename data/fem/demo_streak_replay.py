#!/usr/bin/env python3
"""Stored demo models with ``(c, L)`` from two pushes and from three (a study, session 31).

The demo's sphere and rod both press the lamb's red muscle beside the bone; the queries over
the bone (sphere and cylinder #1 and #2) came out low in nearly every run (7 of 9 below the
truth), and no decay or near-field law chosen from those two pushes fixed it
(``demo_floor_law.py``, ``demo_layer_replay.py``, ``demo_near_replay.py``). Session 22 made a
third push, the rod across the paler streak over the bone (``demo_calibration_streak_lamb.npz``,
``make_demo_calibration.py --probe streak``), and found it lifted everything on the models of
sessions 17-21. This replays the last model of each ``pointforce demo --out DIR`` run as the
contact service serves it (its decay law, the paper's near field), with ``(c, L)`` from

* ``2``: the sphere and the rod (the demo before session 31);
* ``3``: the sphere, the rod and the streak (the demo since);
* ``3near``: the same, with the near field chosen from the three by held-out error
  (:func:`~pointforce_ros.contact.identify.choose_near`, what three pushes allow elsewhere),

each through :func:`~pointforce_ros.contact.identify.calibrate_shape` with its uncertainty
sources, and scores the 9 planner queries through
:func:`~pointforce_ros.contact.uncertainty.wrench_uncertainty` (the service's answer and
``wrench_std``) against their FEM truth: the force vector's RMSE as a share of the largest true
force, how many ``Fz`` lie below the truth, how many true ``Fz`` lie inside the nominal 90 %
intervals and their mean width, and a summary per variant (both demo goals: under 8 % and at
most 6 of 9 on one side). The ``2`` row reproduces what the run's demo printed.

Usage: python data/fem/demo_streak_replay.py DEMO_OUT [DEMO_OUT ...] [--object lamb]
(about 25 s per run on one core)
"""


from demo_floor_setup import replay_arguments, replay_variants  # this folder
from pointforce_ros.bringup.demo import _calibration_pokes
from pointforce_ros.contact.lcp import NEARS


def main():
    """Print one line per run and variant, and a summary per variant."""
    args, demo, pushes, true, big = replay_arguments(__doc__.splitlines()[0])
    vectors = _calibration_pokes(demo.spec, vectors=True)
    three = pushes + [vectors['streak']]
    variants = (('2', pushes, None), ('3', three, None), ('3near', three, NEARS))
    replay_variants(args.demo_out, variants, demo.queries, true, big)


if __name__ == '__main__':
    main()
