"""Held-out scores of a force-response model: residuals and RMSE over poke curves.

Error: root-mean-square of ``predict - f`` over the held-out samples in the ``contact`` region
(``d >= onset_d - 0.5 mm`` of the held-out curve, the default: the long force-free approach
would otherwise dilute the error) or over ``all`` loading samples. A model is never scored on a
poke it was trained on.
"""

from typing import Sequence, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.common import curve_features
from pointforce_ros.types import Surface

CONTACT_MARGIN = 0.0005
"""Samples from this far before the held-out curve's onset on count in the contact region, m."""


def heldout_errors(model, curves: Sequence[PokeCurve], surface: Surface,
                   region: str = 'contact') -> np.ndarray:
    """Concatenated residuals ``predict - f`` (newtons) of ``model`` on ``curves``.

    Raises:
        InvalidInput: unknown ``region``, or a curve the model was trained on.

    """
    if region not in ('contact', 'all'):
        raise InvalidInput(f"region must be 'contact' or 'all', got {region!r}")
    trained = set(getattr(model, 'poke_ids', []))
    leak = [c.poke_id for c in curves if c.poke_id in trained]
    if leak:
        raise InvalidInput(f'held-out evaluation on training pokes {leak[:3]}: refused')
    samples = []
    for c, x in zip(curves, curve_features(curves, surface)):
        keep = c.d >= c.onset_d - CONTACT_MARGIN if region == 'contact' else np.ones(len(c), bool)
        samples.append((x, c.d[keep], c.f[keep]))
    return sample_errors(model, samples)


def sample_errors(model, samples: Sequence[Tuple[np.ndarray, np.ndarray, np.ndarray]]
                  ) -> np.ndarray:
    """Residuals ``predict - f`` over ``(features (9,), d (K,), f (K,))`` per point, one query."""
    x = np.vstack([np.repeat(feat[None], len(d), axis=0) for feat, d, _ in samples])
    d = np.concatenate([d for _, d, _ in samples])
    f = np.concatenate([f for _, _, f in samples])
    return model.predict(x, d) - f


def rms(e: np.ndarray) -> float:
    """Root-mean-square of ``e`` (same unit)."""
    return float(np.sqrt(np.mean(e * e)))


def rmse(model, curves: Sequence[PokeCurve], surface: Surface, region: str = 'contact') -> float:
    """Held-out RMSE in newtons (see :func:`heldout_errors`)."""
    return rms(heldout_errors(model, curves, surface, region))
