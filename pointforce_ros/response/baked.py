"""Baked force response: per surface point, force against displacement as a table.

After each refit the learner *bakes* its model ``f = y(x, d)`` on the equilibrium surface: one
row of forces per surface point over a shared displacement grid. The contact solver then
interpolates instead of calling a regressor (DESIGN.md section 4).
"""

from dataclasses import dataclass, field
from typing import Mapping

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import as_array


ONSET_FORCE = 1e-3
"""Force (N) above which a baked row counts as in contact (well under F/T noise)."""

EXTRAPOLATION_KAPPA = 0.1
"""Growth of a force's standard deviation past the depth the pokes reached, per unit of that
depth and of the force (:func:`extrapolation_std`). Measured with the point model trained on
10 pokes cut at 3 mm on the five objects of the simulated cell, against the FEM truth of the
held-out pokes to 10 mm (``data/figures/extrapolation_std.py --cut 0.003 --fit``, record
``extrapolation_std_cut3.log``): the smallest value on a 0.05 grid that brings the coverage
past the learned depth (61 % with the model's own spread) to at least its coverage within it
(73 %): 84 % pooled. Chosen on four objects and scored on the fifth it is 0.05-0.10, and the
fifth's coverage past the depth goes 72 -> 81 % (plush), 58 -> 82 (vest), 48 -> 62 (lamb),
71 -> 94 (dome), 49 -> 51 (thin layer, whose substrate arrives abruptly)."""

EXTRAPOLATION_HORIZON = 2.0
"""Multiple of the depth the pokes reached past which a baked table grows no faster than its
tangent there (:meth:`BakedResponse.with_extrapolation`). A stiffening law fitted on shallow
pokes, continued to the end of the grid, gave absurd finite forces (1e26 N at 25 mm from pokes
to 1 mm); the seed paper continues its data along their slope from the deepest sample. Twice
the learned depth keeps every answer of the simulated cell's studies (probe trials press to
1.5 times pokes cut at 3 mm); ``data/figures/extrapolation_horizon.py`` measures the error past
it with and without the cap (record ``extrapolation_horizon.log``)."""


@dataclass(frozen=True)
class BakedResponse:
    """Force-versus-displacement table for every point of one equilibrium surface.

    Attributes:
        depths: (K,) strictly increasing displacement grid, metres (``d`` of the seed paper:
            positive = pushed in along ``-n``; may start below zero where camera bias makes
            force start early).
        forces: (N, K) normal force at each surface point and grid depth, newtons.
        slopes: (N,) extrapolation slope beyond ``depths[-1]``, N/m (the paper's slope
            extrapolation). Below ``depths[0]`` the force is held at ``forces[:, 0]``.
        std: (N, K) predictive standard deviation, newtons, or ``None`` when the model has none.
        version: model version the table was baked from.
        meta: JSON-serialisable description (model kind, effects, training pokes).

    Raises:
        InvalidInput: shapes that disagree, NaN, or a grid that is not strictly increasing.

    """

    depths: np.ndarray
    forces: np.ndarray
    slopes: np.ndarray
    std: np.ndarray = None
    version: int = 0
    meta: Mapping = field(default_factory=dict)

    def __post_init__(self):
        depths = as_array(self.depths, 'BakedResponse.depths', (None,))
        if len(depths) < 2 or np.any(np.diff(depths) <= 0):
            raise InvalidInput('BakedResponse.depths: need >= 2 strictly increasing values')
        forces = as_array(self.forces, 'BakedResponse.forces', (None, len(depths)))
        slopes = as_array(self.slopes, 'BakedResponse.slopes', (len(forces),))
        std = None if self.std is None else as_array(self.std, 'BakedResponse.std', forces.shape)
        object.__setattr__(self, 'depths', depths)
        object.__setattr__(self, 'forces', forces)
        object.__setattr__(self, 'slopes', slopes)
        object.__setattr__(self, 'std', std)
        object.__setattr__(self, 'meta', dict(self.meta))

    def with_extrapolation(self, learned_depth: float, kappa: float = EXTRAPOLATION_KAPPA,
                           horizon: float = EXTRAPOLATION_HORIZON) -> 'BakedResponse':
        """Return this table capped and with its ``std`` grown past the depth the pokes reached.

        ``learned_depth``: metres, the deepest nominal displacement the pokes reached (``D``).

        Within the pokes a model's spread says how far its curve may be off; past them the
        curve is its law continued, and the spread of its parameters (fitted where the data
        were) does not grow with the distance (the true forces 3 mm past pokes cut at 3 mm:
        31-42 % inside the lamb's and the vest's 90 % intervals, 79-85 % within the pokes).
        So :func:`extrapolation_std` is added in variance past ``D``. Past ``horizon * D``
        (the first grid depth at or beyond it, ``H``) each row grows no faster than its
        segment into ``H``: the force is the smaller of the law's and that tangent's
        continuation (a stiffening law is capped, a softening one kept), the extrapolation
        slope past the grid at most the tangent's, and the model's own ``std`` keeps its share
        of the force there. A table without ``std`` is only capped; a ``learned_depth`` that
        is not a positive number returns the table unchanged; ``kappa`` 0 adds no ``std``,
        ``horizon`` ``inf`` caps nothing. ``meta['learned_depth']``,
        ``meta['extrapolation_kappa']`` and ``meta['extrapolation_horizon']`` record it.
        """
        try:
            depth = float(learned_depth)
            horizon = float(horizon)
        except (TypeError, ValueError):
            return self
        if not np.isfinite(depth) or depth <= 0 or not horizon > 0:
            return self
        forces, slopes, std = tangent_cap(self.depths, self.forces, self.slopes, self.std,
                                          horizon * depth)
        if std is not None and kappa:
            extra = extrapolation_std(forces, self.depths[None, :], depth, kappa)
            std = np.sqrt(std ** 2 + extra ** 2)
        return BakedResponse(depths=self.depths, forces=forces, slopes=slopes, std=std,
                             version=self.version,
                             meta={**self.meta, 'learned_depth': depth,
                                   'extrapolation_kappa': float(kappa),
                                   'extrapolation_horizon': horizon})

    def __len__(self) -> int:
        """Return the number of surface points ``N``."""
        return len(self.forces)

    def onsets(self, threshold: float = ONSET_FORCE) -> np.ndarray:
        """(N,) displacement where each point's force first exceeds ``threshold``, metres.

        The contact onset of the table: where camera bias made force start before the
        observed surface it is negative. With ``k`` the first grid depth above the threshold,
        it is where the table's segment into ``k`` extrapolates to zero force (exactly where
        the interpolated force leaves zero when the row is zero before ``k``), kept within
        that segment; ``depths[0]`` for a row already above the threshold there, ``+inf`` for
        a row that never reaches it. Computed once per threshold.
        """
        cache = self.__dict__.setdefault('_onsets', {})
        if threshold not in cache:
            f = self.forces
            above = f > threshold
            k = np.argmax(above, axis=1)
            rows = np.arange(len(f))
            out = np.full(len(f), np.inf)
            hit = above[rows, k]
            first = hit & (k == 0)
            out[first] = self.depths[0]
            mid = hit & (k > 0)
            km, rm = k[mid], rows[mid]
            f0, f1 = f[rm, km - 1], f[rm, km]
            d0, d1 = self.depths[km - 1], self.depths[km]
            out[mid] = np.clip(d0 - f0 / (f1 - f0) * (d1 - d0), d0 - (d1 - d0), d1)
            out = np.maximum(out, self.depths[0])
            cache[threshold] = out
        return cache[threshold]

    def force(self, indices: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Interpolate ``y(x_i, d)`` for surface indices ``indices`` (M,) at depths ``d`` (M,).

        Linear in ``d`` inside the grid, held constant below it, extrapolated with ``slopes``
        above it. Vectorised: no Python loop over points.

        Returns:
            (M,) force in newtons.

        """
        indices = np.asarray(indices, dtype=np.int64)
        d = np.asarray(d, dtype=np.float64)
        grid = self.depths
        # ufuncs rather than np.clip / np.any: their wrappers cost more than the work on the
        # tens of points of one planner query
        k = np.minimum(np.maximum(np.searchsorted(grid, d, side='right') - 1, 0),
                       len(grid) - 2)
        lo, hi = grid[k], grid[k + 1]
        w = np.minimum(np.maximum((d - lo) / (hi - lo), 0.0), 1.0)
        f0 = self.forces[indices, k]
        f1 = self.forces[indices, k + 1]
        out = f0 + w * (f1 - f0)
        above = d > grid[-1]
        if above.any():
            out = np.where(above, self.forces[indices, -1]
                           + self.slopes[indices] * (d - grid[-1]), out)
        return out


def tangent_cap(depths, forces, slopes, std, at: float):
    """Return ``(forces, slopes, std)`` grown no faster than each row's tangent past ``at`` (m).

    ``H`` is the first grid depth at or beyond ``at`` (the second, if that is the first);
    past ``H`` a row's force is the smaller of its own and ``F(H) + s (d - H)``, ``s`` its
    segment's slope into ``H``, its slope past the grid the smaller of its own and ``s``, and
    its ``std`` scaled with the force it kept. Unchanged when ``at`` lies past the grid.
    """
    if not np.isfinite(at) or at >= depths[-1]:
        return forces, slopes, std
    j = max(int(np.searchsorted(depths, at)), 1)
    s = np.maximum((forces[:, j] - forces[:, j - 1]) / (depths[j] - depths[j - 1]), 0.0)
    line = forces[:, j, None] + s[:, None] * (depths[None, j + 1:] - depths[j])
    tail = forces[:, j + 1:]
    capped = np.minimum(tail, line)
    out = forces.copy()
    out[:, j + 1:] = capped
    if std is not None:
        std = std.copy()
        with np.errstate(divide='ignore', invalid='ignore'):
            share = np.where(tail > 0, capped / tail, 1.0)
        std[:, j + 1:] *= share
    return out, np.minimum(slopes, s), std


def extrapolation_std(force, depth, learned_depth, kappa: float) -> np.ndarray:
    """Return the standard deviation (N) of a force read past the depth the pokes reached.

    ``kappa |force| (depth - learned_depth) / learned_depth`` where ``depth`` lies past
    ``learned_depth`` (metres, > 0), zero before it: a point model fitted on pokes to ``D`` is
    a curve's continuation past ``D``, whose error grows with the distance in units of ``D``
    (``data/figures/extrapolation_std.py`` measures it). Arrays broadcast.
    """
    learned = np.asarray(learned_depth, dtype=float)
    past = np.maximum(np.asarray(depth, dtype=float) - learned, 0.0) / np.maximum(learned, 1e-9)
    return float(kappa) * np.abs(np.asarray(force, dtype=float)) * past
