"""Force-response models ``f = y(x, d)`` (seed 000, section III.B) and their common protocol.

``x = [p, rgb, n]`` is a row of :attr:`pointforce_ros.types.Surface.features` (position in
metres, colour in [0, 1], outward unit normal, all ``base``), ``d`` the nominal displacement along
``-n`` in metres (positive = pushed in) and ``f`` the normal force on the probe in newtons.

Every model in this package follows :class:`ForceResponseModel`:

- ``fit(curves, surface) -> self``: learn from loading curves
  (:class:`pointforce_ros.pokes.curves.PokeCurve`); each poke's features are taken from the
  nearest point of ``surface`` (raises ``InvalidInput`` when a poke lies farther than
  ``max_surface_distance`` from it: wrong frame or wrong surface). Bumps ``version``.
- ``partial_fit(curve, surface=None) -> self``: add one poke and refit (online learning).
- ``predict(features (M, 9), d (M,) or scalar) -> f (M,)``, newtons.
- ``predict_std(features, d) -> (M,)``: predictive standard deviation of the *mean* force
  curve (newtons), not of one noisy F/T sample.
- ``bake(surface, depths (K,)) -> BakedResponse``: forces (N, K), std (N, K) and extrapolation
  slopes (N,) on a whole surface, vectorised; what the contact solver interpolates.
- ``to_dict() -> dict`` (JSON-serialisable) and ``from_dict(dict)``: a loaded model predicts
  exactly as the saved one, without refitting. :mod:`pointforce_ros.lab.model_store` writes and
  reads these files atomically.
- ``version`` (int, +1 per fit), ``kind`` (str), ``poke_ids`` and ``poke_points`` (n, 3).

All of them raise ``ModelNotReady`` when asked to predict before a fit, and ``InvalidInput`` for
malformed queries (wrong shapes, NaN).

Implementations: :class:`~pointforce_ros.response.ours.ContactGpModel` (ours: a monotone
contact law per poke, parameters interpolated by a Gaussian process, with uncertainty) and the
seed paper's baselines :class:`~pointforce_ros.lab.baseline.EtBaseline` and
:class:`~pointforce_ros.lab.baseline.AutoEtBaseline`.
"""

from typing import Optional, Protocol, Sequence, runtime_checkable

import numpy as np


@runtime_checkable
class ForceResponseModel(Protocol):
    """Structural type of a force-response model (see the module docstring)."""

    kind: str
    version: int

    def fit(self, curves: Sequence, surface) -> 'ForceResponseModel':
        """Learn from loading curves on ``surface``."""

    def partial_fit(self, curve, surface=None) -> 'ForceResponseModel':
        """Add one curve and refit."""

    def predict(self, features: np.ndarray, d) -> np.ndarray:
        """Return the force (M,) in newtons."""

    def predict_std(self, features: np.ndarray, d) -> Optional[np.ndarray]:
        """Return the standard deviation (M,) in newtons."""

    def bake(self, surface, depths: np.ndarray):
        """Return a :class:`~pointforce_ros.response.baked.BakedResponse`."""

    def to_dict(self) -> dict:
        """Return the JSON-serialisable state."""
