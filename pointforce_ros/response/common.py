"""Input checks and feature look-ups shared by the force-response models."""

from typing import Sequence, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.types import Surface

SCALE_FLOOR = np.array([1e-5, 1e-3, 1e-3, 1e-2])
"""Smallest standard deviation of the law parameters ``(d0 [m], log F, p, q)`` used to
standardise them (ours' processes and trees alike)."""
DEFAULT_MAX_SURFACE_DISTANCE = 0.01
"""Farthest a poked point may lie from its nearest surface point, metres."""


def check_curves(curves: Sequence[PokeCurve], surface: Surface) -> Tuple[PokeCurve, ...]:
    """Return ``curves`` as a tuple after checking types and unique ids.

    Raises:
        InvalidInput: no curves, an element that is not a ``PokeCurve``, duplicate poke ids, or
            ``surface`` not a ``Surface``.

    """
    if not isinstance(surface, Surface):
        raise InvalidInput(f'expected a Surface, got {type(surface).__name__}')
    curves = tuple(curves)
    if not curves:
        raise InvalidInput('fit: no poke curves given')
    for c in curves:
        if not isinstance(c, PokeCurve):
            raise InvalidInput(f'fit: expected PokeCurve items, got {type(c).__name__}')
    ids = [c.poke_id for c in curves]
    if len(set(ids)) != len(ids):
        raise InvalidInput('fit: duplicate poke ids in the training curves')
    return curves


def curve_features(curves: Sequence[PokeCurve], surface: Surface,
                   max_distance: float = DEFAULT_MAX_SURFACE_DISTANCE) -> np.ndarray:
    """(n, 9) features ``[p, rgb, n]`` of the surface point nearest to each poked point.

    Raises:
        InvalidInput: a poked point farther than ``max_distance`` metres from the surface.

    """
    if len(surface) == 0:
        raise InvalidInput('fit: the surface has no points')
    pts = np.stack([c.point for c in curves])
    sp = surface.points
    sp2 = (sp * sp).sum(1)[None, :]
    nearest = np.zeros(len(pts), dtype=np.int64)
    dist = np.zeros(len(pts))
    # (rows, N) distances, N up to ~1e5: pokes in blocks of at most ~16 MB
    block = max(1, 2_000_000 // max(len(sp), 1))
    for lo in range(0, len(pts), block):
        p = pts[lo:lo + block]
        d2 = (p * p).sum(1)[:, None] + sp2 - 2.0 * p @ sp.T
        near = np.argmin(d2, axis=1)
        nearest[lo:lo + block] = near
        dist[lo:lo + block] = np.sqrt(np.maximum(d2[np.arange(len(p)), near], 0.0))
    far = dist > max_distance
    if np.any(far):
        k = int(np.flatnonzero(far)[0])
        raise InvalidInput(f'fit: poke {curves[k].poke_id} lies {dist[k] * 1e3:.1f} mm from the '
                           f'nearest surface point (limit {max_distance * 1e3:.1f} mm): is the '
                           'surface in the same frame as the pokes?')
    return surface.features[nearest]


def check_query(features, d) -> Tuple[np.ndarray, np.ndarray]:
    """Validate a prediction query; ``d`` may be a scalar (broadcast) or (M,).

    Returns:
        features (M, 9) float64 and d (M,) float64.

    Raises:
        InvalidInput: wrong shapes or non-finite values.

    """
    features = np.asarray(features, dtype=float)
    if features.ndim == 1 and features.shape[0] == 9:
        features = features[None, :]
    if features.ndim != 2 or features.shape[1] != 9:
        raise InvalidInput(f'predict: features must be (M, 9) [p, rgb, n], got {features.shape}')
    d = np.asarray(d, dtype=float)
    if d.ndim == 0:
        d = np.full(len(features), float(d))
    if d.shape != (len(features),):
        raise InvalidInput(f'predict: d must be a scalar or ({len(features)},), got {d.shape}')
    if not (np.all(np.isfinite(features)) and np.all(np.isfinite(d))):
        raise InvalidInput('predict: non-finite features or displacements (NaN or inf)')
    return features, d


def check_depths(depths) -> np.ndarray:
    """Validate a bake grid: (K,) strictly increasing, K >= 2, finite.

    Raises:
        InvalidInput: otherwise.

    """
    depths = np.asarray(depths, dtype=float)
    if depths.ndim != 1 or len(depths) < 2 or not np.all(np.isfinite(depths)) \
            or np.any(np.diff(depths) <= 0):
        raise InvalidInput('bake: depths must be >= 2 finite, strictly increasing values (m)')
    return depths


def surface_scale(surface: Surface) -> float:
    """Size of the surface, metres: its bounding-box diagonal (at least 1 mm)."""
    if len(surface) == 0:
        return 1e-3
    ext = surface.points.max(axis=0) - surface.points.min(axis=0)
    return float(max(np.linalg.norm(ext), 1e-3))
