#!/usr/bin/env python3
"""The product's point model, the processes and the trees in equal parts (a study, issue 17).

``ContactGpModel(spread='mix')`` (:data:`~pointforce_ros.response.ours.PRODUCT_SPREAD`): each
point's law parameters are the moment-matched mixture of the processes' and the trees'
Gaussians (:func:`~pointforce_ros.response.ours.mixture`), the law and the mean mode chosen on
the mixture's own leave-one-poke-out errors. Beside it the processes alone (``ours_gp``, the
default before session 47), the trees alone (``ours_trees``) and the seed's Extra Trees
(``et``). The parts and their data are those of ``tree_laws.py`` (held-out pokes only):

- ``--part figure1``: figure 1's draws (median RMSE over 10 draws, N, and the ratio to ET);
- ``--part steps``: the step tables of another generator (:mod:`pointforce_ros.lab.step_data`);
- ``--part coverage``: held-out samples inside ``+- Z90`` times each model's ``predict_std``;
- ``--part probes``: figure 2 (line and cylinder probe trials; ``(c, L)`` calibrated with the
  same point model on every poke, 10-poke point models), ``--objects``;
- ``--part synthetic``: the unit tests' synthetic dome (a smooth field).

Session 47 (record ``mix_spread.log``): see the record's header and ``docs/STATUS.md``.

Usage: python data/figures/mix_spread.py [--part figure1|steps|coverage|probes|synthetic]
[--objects ...] [--sizes 5 10] (set OPENBLAS_NUM_THREADS=1).
"""

import argparse

from tree_laws import coverage, figure1, probes, steps, synthetic, OBJECTS  # same folder
from nugget_floor import STEP_OBJECTS

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.response.ours import ContactGpModel, product_model

MODELS = {'et': EtBaseline, 'ours': product_model, 'ours_gp': ContactGpModel,
          'ours_trees': lambda: ContactGpModel(spread='trees')}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--part', choices=('figure1', 'steps', 'synthetic', 'coverage',
                                           'probes'), default='figure1')
    parser.add_argument('--objects', nargs='+')
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args = parser.parse_args(argv)
    print('object pokes | ' + ' | '.join(MODELS), flush=True)
    if args.part == 'figure1':
        figure1(args.objects or OBJECTS, args.sizes, MODELS)
    elif args.part == 'steps':
        steps(args.objects or STEP_OBJECTS, args.sizes, MODELS)
    elif args.part == 'coverage':
        coverage(args.objects or OBJECTS, args.sizes, MODELS)
    elif args.part == 'probes':
        probes(args.objects or OBJECTS, spreads=('mix',))
    else:
        synthetic(args.sizes, MODELS)


if __name__ == '__main__':
    main()
