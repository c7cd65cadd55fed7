#!/usr/bin/env python3
"""Figure 1's point pokes against what the training pokes could tell at best (a study, issue 17).

The same draws as ``python -m pointforce_ros.lab.figures --learning-only --sizes 5 10`` (seed 0,
10 random training subsets per size of the committed 30-poke fixtures; every held-out poke
scored on its measured contact samples, median RMSE over the draws, newtons). Beside ours
(:class:`~pointforce_ros.response.ours.ContactGpModel`) and ET:

- ``floor``: each held-out poke's OWN law fitted to its own samples (in-sample: what the law
  family leaves, a lower bound for any model of that family);
- ``best_train``: an oracle that, for each held-out poke, picks the training poke whose fitted
  law fits it best (chosen with the answer known): what choosing among the laws the training
  pokes showed could reach;
- ``nearest``: the law of the training poke nearest in position (no oracle);
- ``mean_train``: the mean of the training pokes' curves (one curve for the whole object).

Session 28: at 10 pokes the law family leaves 0.04-0.11 N, far under both models, so the gap
lies in predicting a new site's law from the others; on the dome and thin_layer ET is within
10-20 % of ``best_train`` (it finds the matching training poke by normal or colour), so 0.9x ET
there asks for a prediction better than the best single training law.

Usage: python data/figures/figure1_oracles.py [--objects dome thin_layer] [--sizes 5 10]
(about 40 s per object on one core; set OPENBLAS_NUM_THREADS=1).
"""

import argparse
import time

import numpy as np

from pointforce_ros.lab.baseline import EtBaseline
from pointforce_ros.lab.figures import load_poke_fixture
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.response.scoring import CONTACT_MARGIN

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
COLUMNS = ('ours', 'et', 'floor', 'best_train', 'nearest', 'mean_train')


def draw_errors(train, test, surface):
    """``{column: residuals}`` of one draw's held-out samples (``test``: (curve, features))."""
    et = EtBaseline().fit(train, surface)
    ours = ContactGpModel().fit(train, surface)
    laws, where = ours.poke_params, ours.poke_points
    out = {k: [] for k in COLUMNS}
    for c, x in test:
        keep = c.d >= c.onset_d - CONTACT_MARGIN
        d, f = c.d[keep], c.f[keep]
        rows = np.repeat(x[None], len(d), axis=0)
        out['ours'].append(ours.predict(rows, d) - f)
        out['et'].append(et.predict(rows, d) - f)
        own, _ = ours.fit_curve(c, ours.law)
        out['floor'].append(ours.force_from_params(np.repeat(own[None], len(d), 0), d) - f)
        trained = [ours.force_from_params(np.repeat(t[None], len(d), 0), d) for t in laws]
        errs = [np.sqrt(np.mean((t - f) ** 2)) for t in trained]
        out['best_train'].append(trained[int(np.argmin(errs))] - f)
        out['nearest'].append(trained[int(np.argmin(np.linalg.norm(where - x[:3], axis=1)))]
                              - f)
        out['mean_train'].append(np.mean(trained, axis=0) - f)
    return {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in out.items()}


def main(argv=None):
    """Print one line per object and size: each column's median RMSE and its ratio to ET."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--sizes', nargs='+', type=int, default=[5, 10])
    args = parser.parse_args(argv)
    print('object pokes | ' + ' | '.join(COLUMNS))
    for name in args.objects:
        start = time.monotonic()
        surface, curves, _ = load_poke_fixture(name, say=lambda line: None)
        features = curve_features(curves, surface)
        rng = np.random.default_rng(0)              # the figure's draws: sizes in order
        for size in args.sizes:
            rows = []
            for _ in range(10):
                idx = rng.choice(len(curves), size=size, replace=False)
                mask = np.zeros(len(curves), bool)
                mask[idx] = True
                test = [(c, x) for c, x, m in zip(curves, features, mask) if not m]
                rows.append(draw_errors([curves[i] for i in idx], test, surface))
            med = {k: float(np.median([r[k] for r in rows])) for k in COLUMNS}
            print(f'{name} {size} | ' + ' | '.join(f'{med[k]:.3f} ({med[k] / med["et"]:.2f})'
                                                   for k in COLUMNS)
                  + f'   [{time.monotonic() - start:.0f} s]', flush=True)


if __name__ == '__main__':
    main()
