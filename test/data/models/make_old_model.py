"""Regenerate ``contact_gp_independent.json``: a ContactGpModel saved before decorrelation.

The file is what the code at commit 92a3272 (the last one whose parameter processes were
always independent, in the parameters' own units) saved for the synthetic dome's first 7
pokes (the ``world`` of ``test/core/test_response_models.py``). Run it with that code first on
the path, for example::

    git worktree add /tmp/old 92a3272
    PYTHONPATH=/tmp/old python test/data/models/make_old_model.py
"""

from pathlib import Path

import numpy as np

from pointforce_ros.response.ours import ContactGpModel
from pointforce_ros.lab.model_store import save_response_model
from pointforce_ros.lab.synthetic_response import spread_indices, SyntheticObject


def world_curves(count: int = 7):
    """Return the test world's surface and its first ``count`` poke curves."""
    obj = SyntheticObject()
    surface = obj.surface(0.002)
    rng = np.random.default_rng(2024)
    idx = spread_indices(surface, 30, rng)
    curves = obj.curves(surface, idx, rng, rate=100.0, ft_noise=0.03, ft_bias=0.05)
    return surface, curves[:count]


def main() -> None:
    """Fit and write the model next to this script."""
    surface, curves = world_curves()
    model = ContactGpModel().fit(curves, surface)
    if 'decorrelate' in model.to_dict()['config']:
        raise SystemExit('this code already decorrelates: run it with the code of 92a3272')
    out = save_response_model(model, Path(__file__).with_name('contact_gp_independent.json'))
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
