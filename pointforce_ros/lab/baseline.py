"""The seed paper's force-response learner, as written (seed 000, sections III.B and IV.C.1).

- :class:`EtBaseline`: scikit-learn ``ExtraTreesRegressor`` (default hyperparameters) on rows
  ``[p, rgb, n, d] -> f`` pooled from every sample of every training curve.
- :class:`AutoEtBaseline`: stands in for auto-sklearn's *Auto-ET* (the paper's choice, 30 s
  budget): a time-boxed random search over the Extra-Trees hyperparameters with cross-validation
  grouped by poke (no poke is in both the training and the validation fold), then a refit of
  the best configuration on all rows. The default configuration is always evaluated first.
- Slope extrapolation (section IV.C.1, "we simply extrapolate the training data following the
  estimated force-displacement slope"): trees are constant outside the trained depths, so above
  the deepest trained displacement ``d_top`` the force continues linearly with the slope of the
  model's own prediction over ``[d_top - slope_window, d_top]`` (least squares through
  ``slope_points`` predictions; clipped at zero: a falling slope is a tree artefact, not
  physics).

Rows: the paper does not say how densely the 250 Hz curves were used. Extra Trees grown to
single-sample leaves need ~2 nodes per row and tree, so rows per poke are capped by uniform
subsampling in time (``max_rows_per_poke``, default 250; ``None`` = every sample).
"""

import base64
import io
import time
from typing import List, Mapping, Optional, Sequence

import joblib
import numpy as np
from sklearn.ensemble import ExtraTreesRegressor
from sklearn.model_selection import GroupKFold

from pointforce_ros.errors import InvalidInput, ModelNotReady
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.response.baked import BakedResponse
from pointforce_ros.response.common import (check_curves, check_depths, check_query,
                                            curve_features, DEFAULT_MAX_SURFACE_DISTANCE)
from pointforce_ros.types import Surface

KIND_ET = 'pointforce.response.et_baseline'
KIND_AUTO = 'pointforce.response.auto_et_baseline'
FORMAT = 1


class EtBaseline:
    """Extra Trees on ``[p, rgb, n, d]`` with the paper's slope extrapolation.

    Args:
        params: ``ExtraTreesRegressor`` keyword arguments (default: scikit-learn defaults).
        random_state: seed of the trees.
        max_rows_per_poke: cap on rows taken from each curve (uniform in time), or ``None``.
        slope_window: depth window below ``d_top`` for the extrapolation slope, metres.
        slope_points: predictions in that window.
        n_jobs: threads for scikit-learn.
        max_surface_distance: farthest a poke may lie from the surface, metres.

    """

    kind = KIND_ET

    def __init__(self, params: Optional[Mapping] = None, random_state: int = 0,
                 max_rows_per_poke: Optional[int] = 250, slope_window: float = 0.0015,
                 slope_points: int = 6, n_jobs: int = 1,
                 max_surface_distance: float = DEFAULT_MAX_SURFACE_DISTANCE):
        if max_rows_per_poke is not None and max_rows_per_poke < 2:
            raise InvalidInput('EtBaseline: max_rows_per_poke must be >= 2 or None')
        if not (slope_window > 0 and slope_points >= 2):
            raise InvalidInput('EtBaseline: slope_window must be > 0 and slope_points >= 2')
        self.params = dict(params or {})
        self.random_state = int(random_state)
        self.max_rows_per_poke = max_rows_per_poke
        self.slope_window = float(slope_window)
        self.slope_points = int(slope_points)
        self.n_jobs = int(n_jobs)
        self.max_surface_distance = float(max_surface_distance)
        self.version = 0
        self.estimator: Optional[ExtraTreesRegressor] = None
        self.d_top: Optional[float] = None
        self._ids: List[str] = []
        self._points = np.zeros((0, 3))
        self._curves: List[PokeCurve] = []
        self._surface: Optional[Surface] = None
        self.fit_seconds = 0.0

    @property
    def poke_ids(self) -> List[str]:
        """Ids of the training pokes."""
        return list(self._ids)

    @property
    def poke_points(self) -> np.ndarray:
        """(n, 3) surface positions of the training pokes, metres."""
        return self._points.copy()

    def rows(self, curves: Sequence[PokeCurve], surface: Surface):
        """Training rows: X (R, 10) ``[p, rgb, n, d]``, y (R,) force, groups (R,) poke index."""
        feats = curve_features(curves, surface, self.max_surface_distance)
        xs, ys, gs = [], [], []
        for k, (c, x) in enumerate(zip(curves, feats)):
            take = np.arange(len(c))
            if self.max_rows_per_poke is not None and len(c) > self.max_rows_per_poke:
                take = np.unique(np.round(np.linspace(0, len(c) - 1,
                                                      self.max_rows_per_poke)).astype(int))
            xs.append(np.hstack([np.repeat(x[None], len(take), axis=0), c.d[take, None]]))
            ys.append(c.f[take])
            gs.append(np.full(len(take), k))
        return np.vstack(xs), np.concatenate(ys), np.concatenate(gs), feats

    def _make(self, params: Mapping) -> ExtraTreesRegressor:
        return ExtraTreesRegressor(random_state=self.random_state, n_jobs=self.n_jobs,
                                   **dict(params))

    def fit(self, curves: Sequence[PokeCurve], surface: Surface) -> 'EtBaseline':
        """Fit on all rows of ``curves``; returns ``self``.

        Raises:
            InvalidInput: no curves, duplicate ids, pokes off the surface.

        """
        start = time.perf_counter()
        curves = check_curves(curves, surface)
        x, y, groups, feats = self.rows(curves, surface)
        params = self._choose_params(x, y, groups)
        self.estimator = self._make(params).fit(x, y)
        self.d_top = float(x[:, 9].max())
        self._ids = [c.poke_id for c in curves]
        self._points = feats[:, :3].copy()
        self._curves = list(curves)
        self._surface = surface
        self.version += 1
        self.fit_seconds = time.perf_counter() - start
        return self

    def _choose_params(self, x, y, groups) -> Mapping:
        return self.params

    def partial_fit(self, curve: PokeCurve, surface: Optional[Surface] = None) -> 'EtBaseline':
        """Add one poke and refit from scratch (trees have no incremental update).

        Raises:
            InvalidInput: duplicate id, or no surface known.

        """
        surface = surface if surface is not None else self._surface
        if surface is None:
            raise InvalidInput('partial_fit: pass the surface (the model has not seen one)')
        if curve.poke_id in self._ids:
            raise InvalidInput(f'partial_fit: poke {curve.poke_id} is already in the model')
        if not self._curves and self._ids:
            raise InvalidInput('partial_fit: a loaded baseline keeps no training curves; refit '
                               'it with fit()')
        return self.fit(self._curves + [curve], surface)

    # ---------------------------------------------------------------------------- prediction
    def _require(self) -> None:
        if self.estimator is None:
            raise ModelNotReady(f'{type(self).__name__}: no pokes yet; fit the model first')

    def _raw(self, features: np.ndarray, d: np.ndarray) -> np.ndarray:
        return self.estimator.predict(np.hstack([features, d[:, None]]))

    def slope(self, features: np.ndarray) -> np.ndarray:
        """(M,) extrapolation slope at ``features``, N/m (>= 0)."""
        self._require()
        features, _ = check_query(features, 0.0)
        depths = np.linspace(self.d_top - self.slope_window, self.d_top, self.slope_points)
        m = len(features)
        rep = np.repeat(features, len(depths), axis=0)
        f = self._raw(rep, np.tile(depths, m)).reshape(m, len(depths))
        dc = depths - depths.mean()
        return np.maximum((f - f.mean(axis=1, keepdims=True)) @ dc / (dc @ dc), 0.0)

    def predict(self, features: np.ndarray, d) -> np.ndarray:
        """Force (M,), newtons; linear extrapolation above the trained depth range.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        self._require()
        features, d = check_query(features, d)
        out = self._raw(features, np.minimum(d, self.d_top))
        above = d > self.d_top
        if np.any(above):
            out[above] += self.slope(features[above]) * (d[above] - self.d_top)
        return out

    def predict_std(self, features: np.ndarray, d) -> np.ndarray:
        """Spread (M,) of the individual trees' predictions, newtons (within the trained range).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: malformed query.

        """
        self._require()
        features, d = check_query(features, d)
        rows = np.hstack([features, np.minimum(d, self.d_top)[:, None]])
        s1 = np.zeros(len(rows))
        s2 = np.zeros(len(rows))
        for tree in self.estimator.estimators_:
            p = tree.predict(rows)
            s1 += p
            s2 += p * p
        n = len(self.estimator.estimators_)
        return np.sqrt(np.maximum(s2 / n - (s1 / n) ** 2, 0.0))

    def bake(self, surface: Surface, depths, chunk: int = 4096) -> BakedResponse:
        """Tabulate the model on every surface point (std is not computed: ``None``).

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: bad grid or surface.

        """
        self._require()
        if not isinstance(surface, Surface):
            raise InvalidInput(f'bake: expected a Surface, got {type(surface).__name__}')
        depths = check_depths(depths)
        feats = surface.features
        n, k = len(feats), len(depths)
        forces = np.empty((n, k))
        slopes = np.empty(n)
        inside = depths <= self.d_top
        for lo in range(0, n, chunk):
            fx = feats[lo:lo + chunk]
            m = len(fx)
            slopes[lo:lo + m] = self.slope(fx)
            grid = np.minimum(depths, self.d_top)
            cols = np.unique(np.append(grid[inside], self.d_top))
            vals = self._raw(np.repeat(fx, len(cols), axis=0), np.tile(cols, m)
                             ).reshape(m, len(cols))
            at = np.searchsorted(cols, grid)
            block = vals[:, at]
            block += slopes[lo:lo + m, None] * np.maximum(depths - self.d_top, 0.0)[None, :]
            forces[lo:lo + m] = block
        return BakedResponse(depths=depths, forces=forces, slopes=slopes, std=None,
                             version=self.version,
                             meta={'model': self.kind, 'n_pokes': len(self._ids),
                                   'poke_ids': list(self._ids), 'd_top': self.d_top})

    # ------------------------------------------------------------------------ serialisation
    def _config(self) -> dict:
        return {'params': self.params, 'random_state': self.random_state,
                'max_rows_per_poke': self.max_rows_per_poke, 'slope_window': self.slope_window,
                'slope_points': self.slope_points, 'n_jobs': self.n_jobs,
                'max_surface_distance': self.max_surface_distance}

    def to_dict(self) -> dict:
        """JSON-serialisable state; the fitted trees travel as base64 of a joblib dump."""
        blob = None
        if self.estimator is not None:
            buf = io.BytesIO()
            joblib.dump(self.estimator, buf, compress=3)
            blob = base64.b64encode(buf.getvalue()).decode('ascii')
        return {'kind': self.kind, 'format': FORMAT, 'version': int(self.version),
                'config': self._config(), 'd_top': self.d_top, 'poke_ids': list(self._ids),
                'poke_points': self._points.tolist(), 'estimator_joblib_b64': blob,
                'extra': self._extra()}

    def _extra(self) -> dict:
        return {}

    @classmethod
    def from_dict(cls, data: Mapping) -> 'EtBaseline':
        """Rebuild a model saved by :meth:`to_dict` (the trees are loaded, not refitted).

        Only load files you trust: the trees are a joblib (pickle) payload.

        Raises:
            InvalidInput: wrong kind/format or malformed data.

        """
        if data.get('kind') != cls.kind or data.get('format') != FORMAT:
            raise InvalidInput(f'{cls.__name__}.from_dict: not a {cls.kind} v{FORMAT} model '
                               f'(kind={data.get("kind")!r}, format={data.get("format")!r})')
        try:
            model = cls(**data['config'])
            model.version = int(data['version'])
            model.d_top = None if data['d_top'] is None else float(data['d_top'])
            model._ids = list(data['poke_ids'])
            model._points = np.array(data['poke_points'], dtype=float).reshape(-1, 3)
            if data['estimator_joblib_b64'] is not None:
                raw = base64.b64decode(data['estimator_joblib_b64'])
                model.estimator = joblib.load(io.BytesIO(raw))
            model._load_extra(data.get('extra', {}))
        except (KeyError, TypeError, ValueError) as exc:
            raise InvalidInput(f'{cls.__name__}.from_dict: malformed model data: {exc}') from exc
        return model

    def _load_extra(self, extra: Mapping) -> None:
        pass


class AutoEtBaseline(EtBaseline):
    """Time-boxed random search over Extra-Trees hyperparameters (stand-in for Auto-ET).

    Args:
        budget_s: wall-clock budget of the search, seconds (the paper gave Auto-ET 30 s). The
            default configuration is always scored; then random ones until the budget is
            spent; then the winner is refitted on all rows.
        folds: grouped cross-validation folds (at most the number of pokes).
        search_seed: seed of the random configurations.
        others: as :class:`EtBaseline`.

    Search space (after auto-sklearn's ``extra_trees`` regressor): ``n_estimators`` in
    {50, 100, 200}, ``max_features`` in [0.1, 1], ``min_samples_split`` in 2..20,
    ``min_samples_leaf`` in 1..20, ``bootstrap`` in {False, True} (auto-sklearn's
    ``friedman_mse`` criterion is the same as ``squared_error`` in scikit-learn >= 1.9).

    """

    kind = KIND_AUTO

    def __init__(self, budget_s: float = 10.0, folds: int = 5, search_seed: int = 0,
                 **kwargs):
        super().__init__(**kwargs)
        if not (np.isfinite(budget_s) and budget_s > 0):
            raise InvalidInput(f'AutoEtBaseline: budget_s must be > 0 s, got {budget_s}')
        if folds < 2:
            raise InvalidInput(f'AutoEtBaseline: folds must be >= 2, got {folds}')
        self.budget_s = float(budget_s)
        self.folds = int(folds)
        self.search_seed = int(search_seed)
        self.search_log: List[dict] = []
        self.best_params: dict = {}

    def _sample(self, rng: np.random.Generator) -> dict:
        return {'n_estimators': int(rng.choice([50, 100, 200])),
                'max_features': float(rng.uniform(0.1, 1.0)),
                'min_samples_split': int(rng.integers(2, 21)),
                'min_samples_leaf': int(rng.integers(1, 21)),
                'bootstrap': bool(rng.integers(0, 2))}

    def _choose_params(self, x, y, groups) -> Mapping:
        start = time.perf_counter()
        self.search_log = []
        n_groups = len(np.unique(groups))
        if n_groups < 2:
            self.best_params = dict(self.params)
            return self.best_params
        splitter = GroupKFold(n_splits=min(self.folds, n_groups))
        rng = np.random.default_rng(self.search_seed)
        best, best_score = dict(self.params), np.inf
        candidate = dict(self.params)
        while True:
            sse, count = 0.0, 0
            for tr, va in splitter.split(x, y, groups):
                est = self._make(candidate).fit(x[tr], y[tr])
                sse += float(((est.predict(x[va]) - y[va]) ** 2).sum())
                count += len(va)
            score = float(np.sqrt(sse / count))
            self.search_log.append({'params': candidate, 'cv_rmse': score,
                                    't': time.perf_counter() - start})
            if score < best_score:
                best, best_score = candidate, score
            if time.perf_counter() - start >= self.budget_s:
                break
            candidate = self._sample(rng)
        self.best_params = dict(best)
        return self.best_params

    def _config(self) -> dict:
        cfg = super()._config()
        cfg.update(budget_s=self.budget_s, folds=self.folds, search_seed=self.search_seed)
        return cfg

    def _extra(self) -> dict:
        return {'best_params': self.best_params, 'search_log': self.search_log}

    def _load_extra(self, extra: Mapping) -> None:
        self.best_params = dict(extra.get('best_params', {}))
        self.search_log = list(extra.get('search_log', []))

    def summary(self) -> str:
        """One line describing the search result (for logs and reports)."""
        return (f'{len(self.search_log)} configurations in {self.budget_s:g} s; best '
                f'{self.best_params}')
