#!/usr/bin/env python3
"""Figure 1's point-poke table on thin_layer and the dome for settings ours already has (a study).

The same draws and output as ``spread_variants.py`` (seed 0, 10 random training subsets per
size from the committed 30-poke fixtures, held-out pokes scored on their measured contact
samples; median and mean RMSE over the draws, ratio to ET's). thin_layer's two foams differ in
the captured green channel (0.62-0.67 against 0.78-0.82) and ET on colour alone reaches
0.169 N at 10 pokes (session 18); ours scores 0.249 N there. Variants (session 28, none kept):

- ``median``, ``stiffening``: ``mean='median'``, ``law='stiffening'``;
- ``relevance_auto``: finer colour and normal length scales where leave-one-poke-out says;
- ``colour_all``: a colour basis on every process, with ``relevance='auto'``;
  ``colour_all_independent``: the same without decorrelation;
- ``curve_mean_green``: the kernel mean of the training pokes' own curves over the green
  channel alone (length 0.05; a diagnostic, as ``spread_variants.py``'s ``curve_mean_*``).

Usage: python data/figures/colour_variants.py [--objects thin_layer dome] [--sizes 5 10]
(about 30 s per object on one core; set OPENBLAS_NUM_THREADS=1).
"""

import sys

from spread_variants import CurveMean, print_table   # this script's folder is on sys.path

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.response.ours import ContactGpModel

COLOUR = ('colour',) * 4

VARIANTS = {
    'ours': ContactGpModel,
    'et': EtBaseline,
    'median': lambda: ContactGpModel(mean='median'),
    'stiffening': lambda: ContactGpModel(law='stiffening'),
    'relevance_auto': lambda: ContactGpModel(relevance='auto'),
    'colour_all': lambda: ContactGpModel(bases=COLOUR, relevance='auto'),
    'colour_all_independent': lambda: ContactGpModel(decorrelate=False, bases=COLOUR,
                                                     relevance='auto'),
    'curve_mean_green': lambda: CurveMean(4, 0.05),
}


def main():
    """The table, thin_layer and the dome by default."""
    argv = sys.argv[1:] or ['--objects', 'thin_layer', 'dome']
    print_table(VARIANTS, __doc__.splitlines()[0], argv)


if __name__ == '__main__':
    main()
