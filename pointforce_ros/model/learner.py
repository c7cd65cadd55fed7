"""Online stiffness learning: poke store in, versioned baked contact models out.

:class:`OnlineLearner` is what the ``stiffness_learner`` node wraps (pure Python, no ROS). Each
call to :meth:`OnlineLearner.update` reads the pokes that landed in the store since the last call,
cuts their loading curves, refits the force-response model, bakes it on the equilibrium surface
and saves a :class:`~pointforce_ros.model.files.ContactModel` atomically. The model version is the
number of pokes in it, so a restarted learner that reloads the same store produces the same
model under the same version.

Before a poke joins the training set, the current model predicts it: that *prequential* error is
a genuine held-out figure, reported as ``validation_rmse``.

With accepted effects (``effects=``, what ``pointforce diagnose`` writes to ``effects.json``) every
poke is corrected before its curve is cut (:func:`~pointforce_ros.effects.correct.correct_record`;
the plastic set counts the earlier pokes at the spot over the whole store), the model is baked on
the corrected surface (surface offset, and the set where the object was poked), and the effects are
saved with the model so that the contact service adds their forward terms.
"""

import copy
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np
from scipy.spatial import cKDTree

from pointforce_ros.contact.lcp import check_decay, check_near
from pointforce_ros.contact.simulator import check_decay_law, DECAY_LAW
from pointforce_ros.contact.uncertainty import uncertainty_sources
from pointforce_ros.effects.accepted import correct_surface, effects_from_dict
from pointforce_ros.effects.correct import correct_record
from pointforce_ros.effects.library import count_earlier, PLASTIC_RADIUS
from pointforce_ros.errors import InvalidInput, ModelNotReady, PointforceError
from pointforce_ros.model.files import ContactModel, model_path, save_model
from pointforce_ros.pokes.curves import extract_curve, learned_depth, PokeCurve
from pointforce_ros.pokes.store import PokeStore
from pointforce_ros.response.ours import product_model
from pointforce_ros.response.suggest import (greedy_picks, reference_depth, suggest_pokes,
                                             Suggestion)
from pointforce_ros.types import Surface

DEFAULT_DEPTHS = np.linspace(-0.004, 0.025, 59)
MAX_POKE_FORCE = 1000.0
"""N: a poke whose F/T force exceeds this anywhere is not learned from (a broken or
mis-scaled sensor, a corrupt sample). No point-probe poke presses that hard (the poke server
caps its force limit far below; a UR e-series F/T sensor reads up to 50-160 N), and one such
poke would make the relative contact threshold refuse every later, real poke."""
MAX_REFITS_PER_UPDATE = 20
"""Most process refits one update makes: more new pokes than this (a restart over a large
store) are added in as many groups, each poke's law fitted on its own and the processes refit
once per group (a model with ``refit_processes``; the model learned is the same, the
prequential error of a group is that of the model before it)."""
MONOTONE_TOLERANCE = 1e-5
"""Share of a row's largest force a baked force may fall by from one depth to the next
(float32 rounding of the bake) before a monotone model's table counts as decreasing."""
RMSE_BATCH = 20_000
"""Most force samples :func:`curve_rmse` predicts in one call (bounded memory, few calls)."""
MAX_REGION_ROWS = 10_000
"""Most ``(x, y, z, radius)`` rows a planner's region may have: a suggestion compares every
candidate with every row (a larger region is refused, not left to exhaust memory)."""


@dataclass(frozen=True)
class LearnerStatus:
    """What the learner publishes after a refit.

    Attributes:
        version: model version (= pokes in the model).
        num_pokes: training pokes.
        training_rmse: N, model against its own training curves.
        validation_rmse: N, prequential: each poke predicted by the model before it was added
            (RMS over the pokes that had a predecessor model); NaN before the second poke.
        model_path: saved contact model.
        fit_seconds: refit + bake + save time of this update.
        skipped: poke id -> reason, for pokes that could not be used (no contact, ...).

    """

    version: int
    num_pokes: int
    training_rmse: float
    validation_rmse: float
    model_path: Optional[Path]
    fit_seconds: float
    skipped: Dict[str, str] = field(default_factory=dict)


def curve_rmse(model, curves: Sequence[PokeCurve], surface: Surface,
               tree: Optional[cKDTree] = None) -> float:
    """RMS of ``model`` against the force samples of ``curves`` (N); NaN for no curves.

    ``tree``: a ``cKDTree`` of ``surface.points`` to reuse (built here when ``None``).
    """
    if not curves:
        return float('nan')
    tree = cKDTree(surface.points) if tree is None else tree
    _, nearest = tree.query(np.array([c.point for c in curves]))
    sq, count, start = 0.0, 0, 0
    while start < len(curves):     # a few predictions of at most RMSE_BATCH samples each
        stop, size = start + 1, len(curves[start].d)
        while stop < len(curves) and size + len(curves[stop].d) <= RMSE_BATCH:
            size += len(curves[stop].d)
            stop += 1
        batch = curves[start:stop]
        feats = np.repeat(surface.features[nearest[start:stop]], [len(c.d) for c in batch],
                          axis=0)
        err = model.predict(feats, np.concatenate([c.d for c in batch])) \
            - np.concatenate([c.f for c in batch])
        sq, count, start = sq + float(np.sum(err ** 2)), count + len(err), stop
    return float(np.sqrt(sq / count))


class OnlineLearner:
    """Refit-as-pokes-arrive learner over a :class:`PokeStore`.

    Args:
        store_dir: the poke store the poke server writes (``None``: records come only through
            :meth:`learn_records`).
        model_dir: where versioned contact models are saved (``None``: nothing is saved;
            :meth:`contact_model` returns the model in memory).
        surface: equilibrium surface the model is baked on.
        shape_constant: ``c`` of the shape function, metres.
        shape_decay: decay length of the shape function's tail, metres (``inf``: the paper's
            ``g``).
        shape_decay_law: how the decay length applies (``'fixed'`` or ``'penetration'``,
            :class:`~pointforce_ros.contact.simulator.ContactSimulator`), stored in each
            model; ``None``: the simulator's default.
        shape_near: the shape function's near field (``'paper'`` or ``'flat'``,
            :data:`~pointforce_ros.contact.lcp.NEARS`), stored in each model.
        depths: (K,) bake grid, metres.
        model_factory: makes an empty force-response model (default: ours as the product
            uses it, :func:`~pointforce_ros.response.ours.product_model`).
        corrections: optional callable ``records -> records`` applied before curve extraction
            instead of the built-in correction by ``effects``.
        effects: accepted effects ``{name: {param: value}}`` (``pointforce diagnose``'s
            ``effects.json``): removed from every poke, applied to the baked surface and
            stored in each saved model. Its ``spatial_coupling`` (``c`` fitted on probe
            trials) replaces ``shape_constant``.
        min_peak_force: N; a poke whose force never exceeded this made no real contact (the
            point was off the object or the surface is wrong) and is not learned from.
            ``None`` (the default): the threshold is relative to the data, the larger of
            ``contact_snr`` times the poke's own noise and ``min_peak_fraction`` times the
            largest peak force learned so far (a soft region's small forces are learned
            from; step data has no fixed force scale).
        contact_snr: noise sigmas a poke's peak must exceed (relative threshold).
        min_peak_fraction: share of the largest peak learned so far a poke's peak must
            exceed (relative threshold).
        progress: optional callable that takes a line of progress text (an update of many
            pokes reports each group of them).

    Raises:
        InvalidInput: a non-positive shape constant or decay length, or malformed effects.

    """

    def __init__(self, store_dir, model_dir, surface: Surface, *, shape_constant: float,
                 depths: np.ndarray = DEFAULT_DEPTHS,
                 model_factory: Callable[[], object] = product_model,
                 corrections: Optional[Callable] = None, effects: Optional[dict] = None,
                 min_peak_force: Optional[float] = None, shape_decay: float = np.inf,
                 contact_snr: float = 5.0, min_peak_fraction: float = 0.02,
                 shape_decay_law: Optional[str] = None, shape_near: str = 'paper',
                 progress: Optional[Callable[[str], None]] = None):
        """Open the store; nothing is fitted until :meth:`update`."""
        if not (np.isfinite(shape_constant) and shape_constant > 0):
            raise InvalidInput(f'shape_constant: must be > 0 m, got {shape_constant}')
        self.shape_decay = check_decay(shape_decay, 'shape_decay')
        self.shape_decay_law = check_decay_law(
            DECAY_LAW if shape_decay_law is None else shape_decay_law, 'shape_decay_law')
        self.shape_near = check_near(shape_near, 'shape_near')
        self.store = None if store_dir is None else PokeStore(store_dir)
        self.model_dir = None if model_dir is None else Path(model_dir)
        self.surface = surface
        self.shape_constant = float(shape_constant)
        self.depths = np.asarray(depths, dtype=np.float64)
        self.model_factory = model_factory
        self.corrections = corrections
        self.effects = effects_from_dict(effects)
        coupling = self.effects.get('spatial_coupling')
        if coupling is not None:
            # c identified by diagnose on probe trials replaces the one given
            self.shape_constant = float(coupling['shape_constant'])
        # every poke read (time, point, normal, peak normal force): plastic-set counts
        self._spots: List[tuple] = []
        self.min_peak_force = None if min_peak_force is None else float(min_peak_force)
        if not (contact_snr >= 0 and 0 <= min_peak_fraction < 1):
            raise InvalidInput(f'contact_snr must be >= 0 and min_peak_fraction in [0, 1), got '
                               f'{contact_snr} and {min_peak_fraction}')
        self.contact_snr = float(contact_snr)
        self.min_peak_fraction = float(min_peak_fraction)
        self._failed_points: List[np.ndarray] = []
        self.model = None
        self.curves: List[PokeCurve] = []
        self.uncertainty: dict = {}   # wrench uncertainty sources stored in each model's meta
        self.skipped: Dict[str, str] = {}
        self._c_updates = 0   # models saved for a new shape constant (versions stay increasing)
        self._prequential: List[np.ndarray] = []
        self.status: Optional[LearnerStatus] = None
        self._lock = threading.RLock()  # update() mutates the model that suggest() reads
        # one update at a time; it holds _lock per group of pokes, so suggest() is answered
        # between groups rather than after a long update
        self._updating = threading.Lock()
        self.progress = progress
        self._tree = cKDTree(surface.points)   # poked point -> surface point, for the errors
        self._checked: Optional[ContactModel] = None   # the model _add baked and checked

    def _new_curves(self) -> List[PokeCurve]:
        if self.store is None:
            return []
        self.store.refresh()
        seen = {c.poke_id for c in self.curves} | set(self.skipped)
        for name, reason in self.store.quarantine_reasons.items():   # set aside on open
            if name not in seen and name.startswith('poke-'):
                self.skipped[name] = f'quarantined: {reason}'
        fresh = []
        for poke_id in self.store.ids():
            if poke_id in seen:
                continue
            try:
                curve = self._curve(self.store.get(poke_id))
            except Exception as exc:  # noqa: BLE001 - one bad poke must not block the rest
                self.skipped[poke_id] = (str(exc) if isinstance(exc, PointforceError) else
                                         f'cannot be learned from ({type(exc).__name__}: '
                                         f'{exc})')
                continue
            if curve is not None:
                fresh.append(curve)
        return fresh

    def _curve(self, record) -> Optional[PokeCurve]:
        """Cut the loading curve of one (corrected) poke record; ``None`` with the reason noted.

        Raises:
            PointforceError: the record cannot be cut into a curve.

        """
        poke_id = record.poke_id
        if record.outcome.startswith('aborted'):
            self.skipped[poke_id] = f'not learned from: {record.outcome}'
            return None
        largest = float(np.max(np.abs(record.wrench[:, :3]))) if len(record) else 0.0
        if largest > MAX_POKE_FORCE:
            self.skipped[poke_id] = (f'implausible force: {largest:.4g} N in a sample, over '
                                     f'{MAX_POKE_FORCE:g} N (a broken or mis-scaled F/T '
                                     'sensor); not learned from')
            return None
        peak = float(np.max(record.normal_force())) if len(record) else 0.0
        if self.min_peak_force is not None and peak < self.min_peak_force:
            self._failed_points.append(record.point.copy())
            self.skipped[poke_id] = (f'no contact: peak force {peak:.3f} N < '
                                     f'{self.min_peak_force:g} N ({record.outcome}); '
                                     'the point is off the object or the surface is wrong')
            return None
        count = self._remember(record, peak)
        if self.corrections is not None:
            record = self.corrections([record])[0]
        elif self.effects:
            record = correct_record(record, self.effects, count)
        try:
            curve = extract_curve(record)
        except PointforceError as exc:
            if 'no contact' in str(exc):
                self._failed_points.append(record.point.copy())
            raise
        if self.min_peak_force is None:
            threshold = self.contact_threshold(curve)
            if curve.meta['peak_force'] < threshold:
                self._failed_points.append(record.point.copy())
                self.skipped[poke_id] = (
                    f'no contact: peak force {curve.meta["peak_force"]:.3f} N < {threshold:.3f}'
                    f' N (max of {self.contact_snr:g} x its noise '
                    f'{curve.meta["noise_std"]:.3f} N and {self.min_peak_fraction:g} x the '
                    f'largest peak learned, {self._largest_peak():.3f} N; {record.outcome})')
                return None
        return curve

    def _largest_peak(self) -> float:
        return max((float(c.meta.get('peak_force', 0.0)) for c in self.curves), default=0.0)

    def contact_threshold(self, curve: PokeCurve) -> float:
        """Peak force (N) ``curve`` must exceed to count as a contact (relative threshold).

        The larger of ``contact_snr`` times the curve's own noise and ``min_peak_fraction``
        times the largest peak force learned so far.
        """
        return max(self.contact_snr * float(curve.meta.get('noise_std', 0.0)),
                   self.min_peak_fraction * self._largest_peak())

    def learn_records(self, records: Sequence) -> Optional[LearnerStatus]:
        """Learn from ``records`` (point pokes, in time order) as if they had landed in the store.

        Returns the new status, or ``None`` when none of them could be learned from (see
        ``skipped`` for why).
        """
        fresh = []
        with self._updating:
            with self._lock:
                for record in sorted(records, key=lambda r: float(r.t[0]) if len(r) else 0.0):
                    if record.probe != 'point':
                        continue
                    try:
                        curve = self._curve(record)
                    except Exception as exc:  # noqa: BLE001 - one bad poke must not block
                        self.skipped[record.poke_id] = (
                            str(exc) if isinstance(exc, PointforceError) else
                            f'cannot be learned from ({type(exc).__name__}: {exc})')
                        continue
                    if curve is not None:
                        fresh.append(curve)
            return self._fit(fresh)

    def _remember(self, record, peak: float) -> int:
        """Note a poke's spot; return how many earlier pokes pressed there (plastic set)."""
        self._spots.append((float(record.t_controller[0]) if len(record) else 0.0,
                            record.point.copy(), record.normal.copy(), peak))
        if 'plastic_set' not in self.effects:
            return 0
        # the new poke's own count only (all counts per poke read made a restart cubic in
        # the pokes): the spots before it in time order, as :meth:`_spot_counts` orders them
        t, point, normal, _ = self._spots[-1]
        before = [s for s in self._spots[:-1] if s[0] <= t]
        if not before:
            return 0
        radius = self.effects.get('plastic_set', {}).get('radius', PLASTIC_RADIUS)
        counts = count_earlier(np.array([s[1] for s in before] + [point]),
                               np.array([s[2] for s in before] + [normal]),
                               np.array([s[3] for s in before] + [peak]), radius,
                               start=len(before))
        return int(counts[0])

    def _spot_counts(self):
        """Earlier pokes within the plastic radius of every remembered poke, in time order."""
        order = np.argsort([s[0] for s in self._spots], kind='stable')
        radius = self.effects.get('plastic_set', {}).get('radius', PLASTIC_RADIUS)
        counts = count_earlier(np.array([self._spots[i][1] for i in order]),
                               np.array([self._spots[i][2] for i in order]),
                               np.array([self._spots[i][3] for i in order]), radius)
        return counts, order

    def model_surface(self) -> Surface:
        """Surface the model is baked on: the observed one moved by the surface effects."""
        if not any(k in self.effects for k in ('surface_offset', 'plastic_set')):
            return self.surface
        points = counts = None
        if 'plastic_set' in self.effects and self._spots:
            counts, order = self._spot_counts()
            points = np.array([self._spots[i][1] for i in order])
            counts = counts + 1  # the set after each poke, itself included
        return correct_surface(self.surface, self.effects, poke_points=points,
                               poke_counts=counts)

    def update(self) -> Optional[LearnerStatus]:
        """Fit the pokes that arrived since the last call; return the new status or ``None``."""
        with self._updating:
            with self._lock:
                fresh = self._new_curves()
            return self._fit(fresh)

    def _fit(self, fresh: List[PokeCurve]) -> Optional[LearnerStatus]:
        """Add ``fresh`` to the model; save and return the new status, or ``None``.

        A poke that cannot be added, or whose model is not sane (:func:`check_served`), is
        skipped with the reason and the model stays as it was without it. The model is
        locked per group of pokes (a suggestion waits for one group, not the whole update).
        """
        if not fresh:
            return None
        start = time.perf_counter()
        grouped = hasattr(self.model_factory(), 'refit_processes')
        size = -(-len(fresh) // MAX_REFITS_PER_UPDATE) if grouped else 1
        groups = [fresh[i:i + size] for i in range(0, len(fresh), size)]
        # one sanity check of the model the whole update gives (a bake of the surface each);
        # only when it fails, again group by group with a check each, to find the poke
        before = self._state() if len(groups) > 1 else None
        added = self._add_groups(groups, start, len(fresh), check=before is None)
        if before is not None and added:
            with self._lock:
                try:
                    self._checked = check_served(self.contact_model(), self.model)
                except Exception:  # noqa: BLE001 - found again, per group, below
                    self._restore(before)
                    added = self._add_groups(groups, start, len(fresh), check=True)
        if not added:
            return None
        with self._lock:
            return self._save(start, self._checked)

    def _add_groups(self, groups, start: float, total: int, check: bool) -> int:
        """Add each group (:meth:`_add`) under the model lock, with progress; return how many."""
        added = 0
        for k, group in enumerate(groups):
            with self._lock:
                added += self._add(group, check)
            if len(groups[0]) > 1 and self.progress is not None:
                self.progress(f'learned {k * len(groups[0]) + len(group)} of {total} new pokes '
                              f'({added} added, {time.perf_counter() - start:.1f} s)')
        return added

    def _state(self) -> tuple:
        """Return what :meth:`_restore` puts back: the model (a copy), how far each list went."""
        return (copy.deepcopy(self.model, {id(self.surface): self.surface}),
                len(self.curves), len(self._prequential), self._checked, dict(self.skipped))

    def _restore(self, state: tuple) -> None:
        self.model, self.curves, self._prequential, self._checked, self.skipped = (
            state[0], self.curves[:state[1]], self._prequential[:state[2]], state[3],
            dict(state[4]))

    def _add(self, group: List[PokeCurve], check: bool = True) -> int:
        """Add ``group`` with one process refit; on failure split it (bad pokes skipped).

        ``check``: refuse a model that is not sane (:func:`check_served`) after the group.
        Returns how many pokes were added.
        """
        before = self._state()
        added = []
        try:
            for curve in group:
                if self.model is not None:
                    self._prequential.append(np.array([curve_rmse(
                        self.model, [curve], self.surface, self._tree)]))
                if self.model is None:
                    self.model = self.model_factory().fit([curve], self.surface)
                elif len(group) > 1:
                    self.model.partial_fit(curve, self.surface, refit=False)
                else:
                    self.model.partial_fit(curve, self.surface)
                added.append(curve)
                self.curves.append(curve)
            if len(group) > 1:
                self.model.refit_processes()
            self._checked = check_served(self.contact_model(), self.model) if check else None
            return len(added)
        except Exception as exc:  # noqa: BLE001 - the model is kept as it was before the group
            self._restore(before)
            if len(group) == 1:
                self._skip(group[0], exc)
                return 0
        half = len(group) // 2
        return self._add(group[:half], check) + self._add(group[half:], check)

    def _skip(self, curve: PokeCurve, exc: Exception) -> None:
        """Note why ``curve`` was not learned from."""
        self.skipped[curve.poke_id] = (
            str(exc) if isinstance(exc, PointforceError) else
            f'cannot be learned from ({type(exc).__name__}: {exc})')

    def set_shape_constant(self, c: float, decay: Optional[float] = None,
                           decay_law: Optional[str] = None,
                           near: Optional[str] = None) -> Optional[LearnerStatus]:
        """Use shape constant ``c`` (m) from now on; save a new model version if there is one.

        ``decay`` (m, or ``inf`` for the paper's ``g``) replaces the tail's decay length too
        unless it is ``None``, ``decay_law`` the law it applies by and ``near`` the near
        field (:data:`~pointforce_ros.contact.lcp.NEARS`).

        For a ``c`` identified from data (``identify_shape_constant_from_probe`` or a dent):
        the response is unchanged, the saved model's simulator uses the new ``c``.

        Raises:
            InvalidInput: ``c`` not finite and positive, ``decay`` not positive.

        """
        if not (np.isfinite(c) and c > 0):
            raise InvalidInput(f'shape_constant: must be > 0 m, got {c}')
        decay = None if decay is None else check_decay(decay, 'shape_decay')
        law = None if decay_law is None else check_decay_law(decay_law, 'shape_decay_law')
        near = None if near is None else check_near(near, 'shape_near')
        with self._lock:
            self.shape_constant = float(c)
            if decay is not None:
                self.shape_decay = decay
            if law is not None:
                self.shape_decay_law = law
            if near is not None:
                self.shape_near = near
            self._checked = None   # baked before the change: _save bakes again
            if self.model is None:
                return None
            self._c_updates += 1
            return self._save(time.perf_counter())

    def set_uncertainty(self, sources: Optional[dict]) -> Optional[LearnerStatus]:
        """Store the wrench's uncertainty sources in every model from now on.

        ``sources`` (``shape_cov``, ``relative_std``, ``lateral_std``, as
        :func:`~pointforce_ros.contact.uncertainty.uncertainty_sources` takes them) come from
        the calibration that identified ``(c, L)``; the contact service turns them and the
        response's own spread into a standard deviation of each wrench. Saves a new model
        version if there is a model and the sources changed.

        Raises:
            InvalidInput: malformed sources.

        """
        checked = uncertainty_sources(**dict(sources or {}))
        with self._lock:
            if checked == self.uncertainty:
                return None
            self.uncertainty = checked
            self._checked = None   # baked before the change: _save bakes again
            if self.model is None:
                return None
            self._c_updates += 1
            return self._save(time.perf_counter())

    def contact_model(self) -> ContactModel:
        """Return the current model baked on the model surface, as it would be saved.

        Raises:
            ModelNotReady: before the first fit.

        """
        with self._lock:
            if self.model is None:
                raise ModelNotReady('no model yet: no poke has been learned from')
            corrected = [k for k in ('surface_offset', 'plastic_set') if k in self.effects]
            # the deepest the pokes pressed: past it an answer is extrapolated, its std grows
            # (BakedResponse.with_extrapolation) and the service says so (depth_note)
            learned = learned_depth(self.curves)
            return ContactModel(surface=self.model_surface(),
                                response=self.model.bake(self.surface, self.depths)
                                .with_extrapolation(learned),
                                shape_constant=self.shape_constant,
                                version=len(self.curves) + self._c_updates,
                                shape_decay=self.shape_decay, effects=self.effects,
                                shape_decay_law=self.shape_decay_law,
                                shape_near=self.shape_near,
                                meta={'kind': getattr(self.model, 'kind', 'unknown'),
                                      'pokes': [c.poke_id for c in self.curves],
                                      'learned_depth': learned,
                                      'surface_corrected': corrected,
                                      **self.uncertainty})

    def _save(self, start: float, contact: Optional[ContactModel] = None) -> LearnerStatus:
        contact = self.contact_model() if contact is None else contact
        version = contact.version
        path = None if self.model_dir is None else save_model(contact, self.model_dir)
        pre = np.concatenate(self._prequential) if self._prequential else np.zeros(0)
        self.status = LearnerStatus(
            version=version, num_pokes=len(self.curves),
            training_rmse=curve_rmse(self.model, self.curves, self.surface, self._tree),
            validation_rmse=float(np.sqrt(np.mean(pre ** 2))) if len(pre) else float('nan'),
            model_path=path, fit_seconds=time.perf_counter() - start,
            skipped=dict(self.skipped))
        return self.status

    def processed(self, poke_id: str) -> bool:
        """Whether ``poke_id`` has been learned from or skipped (see ``skipped`` for why)."""
        with self._lock:
            return poke_id in self.skipped or any(c.poke_id == poke_id for c in self.curves)

    def current_model_path(self) -> Optional[Path]:
        """Path of the newest saved model, or ``None`` before the first fit."""
        if self.status is None or self.model_dir is None:
            return None
        return model_path(self.model_dir, self.status.version)

    def suggest(self, count: int = 1, exclude_radius: float = 0.01,
                max_tilt_deg: float = 35.0, up=(0.0, 0.0, 1.0), edge_margin: float = 0.008,
                region: Optional[np.ndarray] = None, region_length: float = 0.006):
        """Next poke locations where the model is least certain.

        Only points whose normal is within ``max_tilt_deg`` of ``up``, that lie at least
        ``edge_margin`` (m, measured across ``up``) from any steeper point and half of it from the
        rim of the cloud (points whose neighbours within ``edge_margin`` lie on one side), and are
        not near a poke that found no contact, are candidates: the probe pushes along ``-n``,
        and at an edge the camera's point may not be on the object.

        ``region`` is where a planner will ask for wrenches: (M, 4) rows ``(x, y, z, radius)``,
        metres, ``base``; a row is the disc of ``radius`` around ``(x, y, z)`` measured across
        ``up`` (rows with radius 0 are ignored). Candidates are then those inside the region
        (:func:`region_candidates`), ranked by the model's variance in the region around them
        (:func:`region_scores`, smoothed over ``region_length``, m) rather than by their own:
        the most uncertain point of a disc is its rim, the poke that lowers the disc's
        uncertainty most is nearer its middle. When no candidate lies inside, the whole
        surface is used as without a region.

        Returns:
            (indices (count,), std (count,) in N) into ``surface``.

        Raises:
            ModelNotReady: before the first fit.
            InvalidInput: ``count`` outside 1..50, a malformed ``region``.

        """
        if self.model is None:
            raise ModelNotReady('no model yet: poke at least once before asking for suggestions')
        if not 1 <= int(count) <= 50:
            raise InvalidInput(f'count: must be 1..50, got {count}')
        up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
        flat = self.surface.normals @ up >= np.cos(np.radians(max_tilt_deg))
        candidates = np.flatnonzero(flat)
        across = self.surface.points - np.outer(self.surface.points @ up, up)
        if edge_margin > 0 and np.any(~flat) and len(candidates):
            dist, _ = cKDTree(across[~flat]).query(across[candidates])
            candidates = candidates[dist >= edge_margin]
        if edge_margin > 0 and len(candidates):
            rim = np.flatnonzero(_on_rim(across, np.arange(len(across)), edge_margin))
            if len(rim):
                dist, _ = cKDTree(across[rim]).query(across[candidates])
                candidates = candidates[dist >= edge_margin / 2]
        failed = [p for p in self._failed_points]
        if failed and len(candidates):
            dist, _ = cKDTree(np.array(failed)).query(self.surface.points[candidates])
            candidates = candidates[dist >= max(exclude_radius, edge_margin)]
        if len(candidates) == 0:
            raise InvalidInput(f'no surface point has a normal within {max_tilt_deg} degrees of '
                               f'{up.tolist()} and {edge_margin} m from steeper points')
        inside = (np.zeros(0, dtype=np.int64) if region is None else
                  region_candidates(self.surface.points, candidates, region, up))
        with self._lock:
            if len(inside) == 0:
                return suggest_pokes(self.model, self.surface, int(count),
                                     exclude_radius=exclude_radius, candidates=candidates)
            depth = reference_depth(self.model)
            std = np.asarray(self.model.predict_std(self.surface.features[inside], depth),
                             dtype=float)
            done = np.asarray(getattr(self.model, 'poke_points', np.zeros((0, 3))), float)
            picked = _pick(self.surface.points[inside], inside, std,
                           region_scores(self.surface.points[inside], std, region_length, up),
                           done, int(count), exclude_radius)
            if len(picked.indices) == 0:   # the region is poked out: the whole surface
                return suggest_pokes(self.model, self.surface, int(count),
                                     exclude_radius=exclude_radius, candidates=candidates)
            return picked


def check_served(contact: ContactModel, model) -> ContactModel:
    """Return ``contact`` if its baked table is physically sane, else raise with the reason.

    Sane: finite forces, standard deviations and slopes (the table itself refuses NaN and
    inf), no negative force or slope and, for a ``model`` whose law is ``monotone``, no force
    that falls with depth (beyond :data:`MONOTONE_TOLERANCE` of the row's largest force).

    Raises:
        InvalidInput: the first property the table breaks.

    """
    table = contact.response
    forces = table.forces
    if np.any(forces < 0) or np.any(table.slopes < 0):
        raise InvalidInput(f'model refused: a negative force ({forces.min():.4g} N) or slope '
                           f'({table.slopes.min():.4g} N/m) in the baked table')
    if getattr(model, 'monotone', False) and forces.shape[1] > 1:
        fall = -np.diff(forces, axis=1)
        allowed = MONOTONE_TOLERANCE * forces.max(axis=1, keepdims=True) + 1e-12
        if np.any(fall > allowed):
            i, k = np.unravel_index(int(np.argmax(fall - allowed)), fall.shape)
            raise InvalidInput(f'model refused: the force at surface point {i} falls by '
                               f'{fall[i, k]:.4g} N between depths {table.depths[k]:.4g} and '
                               f'{table.depths[k + 1]:.4g} m (the law is monotone)')
    return contact


def check_region(region) -> np.ndarray:
    """Return a planner's region of interest as (M, 4) ``(x, y, z, radius)`` rows, metres.

    Accepts (M, 4) or a flat sequence of 4 M numbers (a ROS double array); rows with radius 0
    are dropped, so ``[0, 0, 0, 0]`` (the parameter's default) is no region.

    Raises:
        InvalidInput: a length that is not a multiple of 4, non-finite values, a negative
            radius or more than ``MAX_REGION_ROWS`` rows.

    """
    arr = np.asarray(region, dtype=np.float64)
    if arr.size % 4 or (arr.ndim == 2 and arr.shape[1] != 4) or arr.ndim > 2:
        raise InvalidInput(f'region: (x, y, z, radius) rows in metres, got {arr.size} numbers '
                           f'in shape {arr.shape}')
    arr = arr.reshape(-1, 4)
    if len(arr) > MAX_REGION_ROWS:
        raise InvalidInput(f'region: {len(arr)} (x, y, z, radius) rows, at most '
                           f'{MAX_REGION_ROWS}; merge the discs into fewer, larger ones')
    if not np.all(np.isfinite(arr)) or np.any(arr[:, 3] < 0):
        raise InvalidInput('region: every value must be finite and every radius >= 0 m')
    return arr[arr[:, 3] > 0]


def region_candidates(points: np.ndarray, candidates: np.ndarray, region,
                      up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Return the ``candidates`` (surface indices) inside a planner's region of interest.

    ``region``: see :func:`check_region`; a point is inside when its distance across ``up``
    to some row's centre is at most that row's radius. An empty region keeps every candidate.
    """
    rows = check_region(region)
    candidates = np.asarray(candidates, dtype=np.int64)
    if len(rows) == 0:
        return candidates
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    inside = np.zeros(len(candidates), dtype=bool)
    block = max(1, 250_000 // len(rows))   # a gap array of at most ~6 MB per block
    for start in range(0, len(candidates), block):
        gap = points[candidates[start:start + block]][:, None, :] - rows[None, :, :3]
        gap -= (gap @ up)[..., None] * up
        inside[start:start + block] = np.any(np.linalg.norm(gap, axis=2) <= rows[None, :, 3],
                                             axis=1)
    return candidates[inside]


def region_scores(points: np.ndarray, std: np.ndarray, length: float,
                  up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Return the model's variance in the region around each of its points, N^2.

    ``points`` (K, 3) are the region's surface points and ``std`` (K,) the model's force std
    there; the score of point ``i`` is ``sum_j std_j^2 exp(-r_ij^2 / (2 length^2))``, ``r``
    measured across ``up``: the variance a poke at ``i`` would take away if it informed its
    neighbours over ``length`` (a squared-exponential proxy of the variance reduction).
    """
    if not length > 0:
        raise InvalidInput(f'region_length: must be > 0 m, got {length}')
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    flat = points - np.outer(points @ up, up)
    tree = cKDTree(flat)
    pairs = tree.sparse_distance_matrix(tree, 4.0 * length, output_type='coo_matrix')
    other = pairs.row != pairs.col    # each point counts itself once, below
    row, col = pairs.row[other], pairs.col[other]
    weight = np.exp(-pairs.data[other] ** 2 / (2.0 * length ** 2))
    var = np.asarray(std, dtype=float) ** 2
    return var + np.bincount(row, weights=weight * var[col], minlength=len(var))


def _pick(points: np.ndarray, indices: np.ndarray, std: np.ndarray, score: np.ndarray,
          done: np.ndarray, count: int, exclude_radius: float) -> Suggestion:
    """Greedy picks by ``score`` at least ``exclude_radius`` from each other and earlier pokes."""
    allowed = np.ones(len(indices), dtype=bool)
    if exclude_radius > 0:
        for p in done:
            allowed &= np.linalg.norm(points - p, axis=1) > exclude_radius
    return greedy_picks(points, indices, score, std, allowed, count, exclude_radius)


def _on_rim(points: np.ndarray, indices: np.ndarray, radius: float) -> np.ndarray:
    """Whether each of ``points[indices]`` is on the rim of the cloud (one-sided neighbours).

    A point is on the rim when the mean offset of its neighbours within ``radius`` is longer
    than a fifth of ``radius``: an interior point's neighbours surround it (mean offset near
    0), an edge point's lie in a half disc (centroid 0.42 r, about 0.3 r on a coarse grid).
    """
    from scipy.spatial import cKDTree
    tree = cKDTree(points)
    rim = np.zeros(len(indices), dtype=bool)
    for k, neighbours in enumerate(tree.query_ball_point(points[indices], radius)):
        offsets = points[neighbours] - points[indices[k]]
        rim[k] = np.linalg.norm(offsets.mean(axis=0)) > radius / 5
    return rim
