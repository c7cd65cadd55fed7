#!/usr/bin/env python3
"""Figure 1's point-poke table for two more readings of the surface features (a study).

The same draws and output as ``spread_variants.py`` (seed 0, 10 random training subsets per
size from the committed 30-poke fixtures, held-out pokes scored on their measured contact
samples; median and mean RMSE over the draws, ratio to ET's). Neither variant is the product's
default; the closing note of issue 17 (session 26) quotes this table. Variants:

- ``ours``: the default :class:`~pointforce_ros.response.ours.ContactGpModel`.
- ``height_x4`` / ``height_x10``: the processes' position kernel with the height (base z)
  weighed 4 or 10 times the horizontal coordinates (an anisotropic length scale). On the dome
  the pokes' laws follow the height (it thins towards its rim, session 19), which an isotropic
  kernel over an object 90 mm wide and 42 mm high barely separates.
- ``height_loo``: ``k`` = 1 or 4 per fit, the one whose chosen law has the lower
  leave-one-poke-out error (``law_scores``), as a product would have to choose it.
- ``fine_colour``: colour length scales 0.1 and 0.05 (RGB units) on the grid beside ``inf``
  and 0.3 for every fit (``relevance='auto'`` offers them only when leave-one-poke-out says
  so). thin_layer's two foams differ by 0.19 in RGB, where the grid's 0.3 keeps a correlation
  of 0.82 between them.

Usage: python data/figures/feature_variants.py [--objects dome thin_layer] [--sizes 5 10]
(about 20 s per object on one core; set OPENBLAS_NUM_THREADS=1).
"""

import contextlib

import numpy as np
from spread_variants import OursWithin, PickByLoo, print_table   # this folder is on sys.path

import pointforce_ros.response.gp as gp
from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.response.gp import GpGrid
from pointforce_ros.response.ours import ContactGpModel


@contextlib.contextmanager
def patched_prepare(change):
    """Within the block, ``FeatureGp._prepare`` returns ``change(gp, features, parts, phi)``."""
    original = gp.FeatureGp._prepare

    def prepare(self, features, groups=True, basis=True):
        parts, phi = original(self, features, groups, basis)
        return change(self, features, parts, phi)

    gp.FeatureGp._prepare = prepare
    try:
        yield
    finally:
        gp.FeatureGp._prepare = original


def height_weight(k):
    """Within the block, every ``FeatureGp`` scales the height of its RBF positions by ``k``."""
    def change(process, features, parts, phi):
        if parts is not None:
            pos, col, nor = parts
            parts = (pos * np.array([1.0, 1.0, k]), col, nor)
        return parts, phi

    return patched_prepare(change)


def height_weighted(k):
    """Ours fitted and queried with the height weighed ``k`` times in the position kernel."""
    return OursWithin(lambda: height_weight(float(k)))


def chosen_law_score(wrapper) -> float:
    """Leave-one-poke-out RMSE of the law (and mean mode) the wrapped model chose."""
    m = wrapper.model
    return m.law_scores.get(m.law, m.law_scores.get(f'{m.law}/{m.mean}', 0.0))


class HeightByLoo(PickByLoo):
    """Ours with the height weight of ``ks`` whose fit has the lowest leave-one-poke-out error."""

    def __init__(self, ks=(1.0, 4.0)):
        super().__init__([lambda k=k: height_weighted(k) for k in ks], chosen_law_score)


VARIANTS = {
    'ours': ContactGpModel,
    'et': EtBaseline,
    'height_x4': lambda: height_weighted(4.0),
    'height_x10': lambda: height_weighted(10.0),
    'height_loo': HeightByLoo,
    'fine_colour': lambda: ContactGpModel(grid=GpGrid(colour=(np.inf, 0.3, 0.1, 0.05))),
}


def main():
    """The feature variants' table."""
    print_table(VARIANTS, __doc__.splitlines()[0])


if __name__ == '__main__':
    main()
