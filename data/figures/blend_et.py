#!/usr/bin/env python3
"""Would averaging ours with Extra Trees reach figure 1's goal (at most 0.9x ET)? No.

Figure 1's protocol (:func:`~pointforce_ros.lab.evaluate.learning_curve`, sizes 5 and 10, the
same 10 seeded draws per size as the figure, held-out pokes' measured contact samples) with
three more models beside ours (:class:`~pointforce_ros.response.ours.ContactGpModel`) and ET
(:class:`~pointforce_ros.lab.baseline.EtBaseline`):

* ``blend``: the mean of ours and ET; ``blend70``: 0.3 ours + 0.7 ET (two models whose errors
  are partly independent average to less than either);
* ``resid``: ours plus an ET fitted to ours' residual on the training rows (depth held at the
  deepest trained one past it).

Prints each model's median RMSE (N) and its ratio to ET. Session 31
(``blend_et.log``): the blends reach 0.93-1.25 (``blend``) and 0.94-1.12 (``blend70``) of ET,
never 0.9 on every object and size; ``resid`` stays at ours' (ours fits its own training pokes,
so their residual says nothing about the spreading between pokes). Not a product model.

Usage: OPENBLAS_NUM_THREADS=1 python data/figures/blend_et.py [plush vest lamb dome thin_layer]
(about 40 s per object on one core)
"""

import sys
import time

import numpy as np

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.evaluate import learning_curve
from pointforce_ros.lab.figures import load_poke_fixture, OBJECTS
from pointforce_ros.response.ours import ContactGpModel


class Blend:
    """``w`` ours + ``1 - w`` ET."""

    def __init__(self, w: float = 0.5):
        self.w = w

    def fit(self, curves, surface):
        """Fit both on ``curves``; returns ``self``."""
        self.ours = ContactGpModel().fit(curves, surface)
        self.et = EtBaseline().fit(curves, surface)
        return self

    def predict(self, features, d):
        """Return the weighted force (N)."""
        return self.w * self.ours.predict(features, d) + (1 - self.w) * self.et.predict(features,
                                                                                        d)


class Residual:
    """Ours plus Extra Trees on ours' training residual."""

    def fit(self, curves, surface):
        """Fit ours, then the trees on ``f - ours(x, d)`` of the training rows; returns self."""
        self.ours = ContactGpModel().fit(curves, surface)
        et = EtBaseline()
        x, y, _, _ = et.rows(curves, surface)
        self.trees = et._make({}).fit(x, y - self.ours.predict(x[:, :9], x[:, 9]))
        self.top = float(x[:, 9].max())
        return self

    def predict(self, features, d):
        """Return ours' force plus the trees' residual (N)."""
        d = np.broadcast_to(np.asarray(d, dtype=float), (len(features),))
        rows = np.hstack([features, np.minimum(d, self.top)[:, None]])
        return self.ours.predict(features, d) + self.trees.predict(rows)


def main():
    """Print one line per object."""
    for name in sys.argv[1:] or OBJECTS:
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        start = time.time()
        rows = learning_curve(curves, surface, {'ours': ContactGpModel, 'et': EtBaseline,
                                                'blend': Blend, 'blend70': lambda: Blend(0.3),
                                                'resid': Residual},
                              sizes=(5, 10), repeats=10, seed=0)
        et = {r['size']: r['median'] for r in rows if r['model'] == 'et'}
        print(name, ' '.join(f"{r['model']}@{r['size']} {r['median']:.3f} "
                             f"({r['median'] / et[r['size']]:.2f})" for r in rows),
              f'[{time.time() - start:.0f} s]', flush=True)


if __name__ == '__main__':
    main()
