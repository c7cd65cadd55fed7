#!/usr/bin/env python3
"""Figure 1's point-poke table with the height and the normal's z as a linear basis (a study).

The same draws and output as ``spread_variants.py`` (seed 0, 10 random training subsets per
size from the committed 30-poke fixtures, held-out pokes scored on their measured contact
samples; median and mean RMSE over the draws, ratio to ET's). On the dome the pokes' laws
follow the height and the normal's tilt (it thins towards its rim, session 19), which ET finds
by splitting on one coordinate; ours' processes see position through an isotropic RBF. Here
every process's linear basis also gets ``2.5 (z - z_c) / scale`` (``z``: base height, the
frame's centre and size) and, for ``znz``, ``n_z - 0.7``; the grid's basis weights (``tau``
0, 0.3, 3) let the marginal likelihood drop them. Not the product's default; session 28:

- ``z``: the height alone; ``znz``: the height and the normal's z on every process;
  ``znz_no_onset``: the same on the level, exponent and stiffening processes only (the onset
  keeps its ``rigid`` basis).

Usage: python data/figures/height_basis.py [--objects dome] [--sizes 5 10]
(about 25 s per object on one core; set OPENBLAS_NUM_THREADS=1).
"""

import numpy as np
from feature_variants import patched_prepare   # this script's folder is on sys.path
from spread_variants import OursWithin, print_table

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.response.ours import ContactGpModel


def height_basis(columns, skip=()):
    """Within the block, ``FeatureGp`` bases (but those in ``skip``) get ``columns`` added."""
    def change(process, features, parts, phi):
        if phi is not None and process.basis not in skip:
            f = np.asarray(features, dtype=float)
            extra = {'z': 2.5 * (f[:, 2] - process.frame.centre[2]) / process.frame.scale,
                     'nz': f[:, 8] - 0.7}
            phi = np.hstack([phi] + [extra[c][:, None] for c in columns])
        return parts, phi

    return patched_prepare(change)


def height_basis_model(columns, skip=()):
    """Ours fitted and queried with the extra basis columns."""
    return OursWithin(lambda: height_basis(tuple(columns), tuple(skip)))


VARIANTS = {
    'ours': ContactGpModel,
    'et': EtBaseline,
    'z': lambda: height_basis_model(('z',)),
    'znz': lambda: height_basis_model(('z', 'nz')),
    'znz_no_onset': lambda: height_basis_model(('z', 'nz'), skip=('rigid',)),
}


def main():
    """The height-basis table."""
    print_table(VARIANTS, __doc__.splitlines()[0])


if __name__ == '__main__':
    main()
