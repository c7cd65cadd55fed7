"""The seed method's figures on the simulated cell (issue 4, "Figures to report").

Three figures, each on held-out data only, medians over random training subsets, seeded:

1. **Point-probe learning curves.** Held-out force RMSE against the number of training pokes
   (2, 3, 5, 10, 20) on each object for ours (:class:`~pointforce_ros.response.ours.
   ContactGpModel`), plain ET and the Auto-ET stand-in (:class:`~pointforce_ros.response.
   baseline.AutoEtBaseline`, small budget). Pool: 30 pokes of the ``realistic`` scenario on the
   FEM live path. RMSE: :func:`pointforce_ros.lab.evaluate.rmse`, ``contact`` region, i.e.
   every loading sample of every held-out poke from 0.5 mm before its (estimated) contact
   onset to its deepest point, against the measured (noisy, tared) normal force.
2. **Line and cylinder probes.** FEM full-solve trials at random orientations; force and torque
   RMSE (vector error, every step of every evaluated trial) of the baseline (the paper's
   simulator :class:`~pointforce_ros.lab.paper_contact.PaperContactSimulator` with the ET model and
   the default ``c``), ours (:class:`~pointforce_ros.contact.simulator.ContactSimulator` with our
   baked model and, for each scored trial, ``c`` identified from the object's *other* trials,
   leave one trial out) and the paper's "pure learning
   with the correct geometry" reference (Extra Trees on ``[p, rgb, n, d]`` of the probe's
   contact centre -> wrench, trained on the other trials of the same kind, leave one trial out).
3. **Shape constant.** ``c`` identified from the dent of a full nonlinear point poke
   (:func:`~pointforce_ros.contact.identify.identify_shape_constant`, dent depth at the tip =
   the poke depth, as the shape function says) and from the other probe trials
   (:func:`~pointforce_ros.contact.identify.identify_shape_constant_from_probes`), and the
   probe force RMSE of ours against ``c``.

4. **Next-poke suggestion.** Held-out RMSE against the number of pokes when each next poke is
   the pool location where ours is least certain (:func:`~pointforce_ros.response.suggest.
   suggest_pokes`) or a random one, both from the same 2 random pokes (:func:`~pointforce_ros.
   response.suggest.active_vs_random_curve`), and how many pokes the suggestion needs to
   match random choice's error at :data:`ACTIVE_MAX` pokes.

Ground truth is cached in ``data/figures/`` by ``make_figures_data.py`` there (the FEM is
minutes per trial); ``python -m pointforce_ros.lab.figures --out DIR`` then runs in minutes.
All public quantities are SI (metres, newtons, newton-metres), frame ``base``.
"""

import dataclasses
import hashlib
import json
import os
import time
from pathlib import Path
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from pointforce_ros import arguments
from pointforce_ros.paths import share_path
from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.pokes.curves import PokeCurve
from pointforce_ros.types import Mesh, Pose, Surface
from pointforce_ros.contact.identify import (best_capped_fit, choose_near, DECAY_GRID,
                                             decay_grid, dent_profile, identify_shape_constant,
                                             shape_fits_from_probes)
from pointforce_ros.contact.lcp import NEARS
from pointforce_ros.contact.simulator import ContactSimulator
from pointforce_ros.errors import NotConverged, PointforceError
from pointforce_ros.lab.baseline import AutoEtBaseline, EtBaseline
from pointforce_ros.lab.evaluate import draw_learning_rows, learning_curve
from pointforce_ros.response.scoring import CONTACT_MARGIN
from pointforce_ros.lab.paper_contact import PaperContactSimulator
from pointforce_ros.pokes.curves import extract_curve
from pointforce_ros.response.common import curve_features
from pointforce_ros.response.ours import ContactGpModel, product_model, ROBUST_Z
from pointforce_ros.response.shapefree import ShapeFreeGpModel
from pointforce_ros.lab.active import active_vs_random_curve
from pointforce_ros.sim.fem.live import LiveContact, POINT_PROBE
from pointforce_ros.sim.fem.probes import point_probe, pose_for_push
from pointforce_ros.sim.fem.solver import FemModel
from pointforce_ros.sim.generate import fem_cell_object, probe_trials, scan_object
from pointforce_ros.sim.objects import list_objects, load_object
from pointforce_ros.sim.scenario import load_scenario
from pointforce_ros.sim.session import simulate_campaign
from pointforce_ros.surface.equilibrium import build_equilibrium_surface, SurfaceConfig

OBJECTS = ('plush', 'vest', 'lamb', 'dome', 'thin_layer')
"""The five objects of the simulated cell, in report order."""

DATA_DIR = str(share_path('data', 'figures'))
"""Folder of the cached ground truth."""

SIZES = (2, 3, 5, 10, 20)
"""Training-set sizes of figure 1."""

DEFAULT_C = 0.004
"""Shape constant the project ships (``stiffness_learner`` parameter), metres."""

PROBE_TRAIN_POKES = 10
"""Point pokes the probe-trial models are trained on (as the paper: 10 locations)."""

FIXTURE_VERSION = 1


# ------------------------------------------------------------------------------- fixtures
def physics_hash(spec) -> str:
    """Short hash of the fields of an ``ObjectSpec`` that change its ground truth.

    Leaves out the live-cache grid, the validation mesh size, the description and the path:
    a new live grid does not change what a full solve answers.
    """
    core = dataclasses.replace(spec, live_grid=(0, 0), mesh_validation=0.0, description='',
                               source=None)
    return hashlib.sha1((repr(core) + str(FIXTURE_VERSION)).encode()).hexdigest()[:16]


def _scan_surface(spec, scenario, seed: int) -> Surface:

    _, scans = scan_object(spec, scenario, seed=seed)
    lo = np.array([spec.centre[0] - spec.size[0] / 2 - 0.005,
                   spec.centre[1] - spec.size[1] / 2 - 0.005, 0.004])
    hi = np.array([spec.centre[0] + spec.size[0] / 2 + 0.005,
                   spec.centre[1] + spec.size[1] / 2 + 0.005, spec.size[2] + 0.02])
    surface, _ = build_equilibrium_surface(scans, SurfaceConfig(roi_min=lo, roi_max=hi))
    return surface


def make_poke_fixture(name: str, out=DATA_DIR, count: int = 30, seed: int = 0,
                      scenario: str = 'realistic', say: Callable[[str], None] = print) -> Path:
    """Write ``pokes_<name>.npz``: the scanned surface and ``count`` poke curves (see module).

    Raises:
        DataError: the object's live cache is missing or stale.

    """
    started = time.monotonic()
    live = LiveContact.load(name, build=False)
    spec = live.spec
    scen = load_scenario(scenario)
    surface = _scan_surface(spec, scen, seed)
    say(f'[figures-data] {name}: surface {len(surface)} points, '
        f'{time.monotonic() - started:.0f} s')
    # the pokes aim at the scanned surface's points and normals, as the product's pokes do
    records = simulate_campaign(fem_cell_object(spec, live), scen, count=int(count), seed=seed,
                                force_limit=spec.force_cap, depth_limit=spec.max_depth,
                                surface=surface)
    curves = []
    for record in records:
        try:
            curves.append(extract_curve(record))
        except InvalidInput as exc:          # e.g. a poke on the dome's rim that made no contact
            say(f'[figures-data] {name}: skipped {record.poke_id}: {exc}')
    say(f'[figures-data] {name}: {len(curves)} curves, {time.monotonic() - started:.0f} s')
    arrays = curves_to_arrays(curves)
    arrays.update(surface_points=surface.points.astype(np.float32),
                  surface_normals=surface.normals.astype(np.float32),
                  surface_colors=surface.colors.astype(np.float32),
                  spec_hash=np.asarray(physics_hash(spec)), scenario=np.asarray(scenario),
                  seed=np.asarray(int(seed)), seconds=np.asarray(time.monotonic() - started))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f'pokes_{name}.npz'
    np.savez_compressed(path, **arrays)
    return path


def curves_to_arrays(curves: Sequence[PokeCurve]) -> Dict[str, np.ndarray]:
    """Pack curves into flat arrays (float32 samples, offsets) for an ``.npz``."""
    lengths = np.array([len(c) for c in curves], dtype=np.int64)
    return {'curve_ids': np.array([c.poke_id for c in curves]),
            'curve_offsets': np.concatenate([[0], np.cumsum(lengths)]),
            'curve_points': np.stack([c.point for c in curves]),
            'curve_normals': np.stack([c.normal for c in curves]),
            'curve_onsets': np.array([c.onset_d for c in curves]),
            'curve_d': np.concatenate([c.d for c in curves]).astype(np.float32),
            'curve_f': np.concatenate([c.f for c in curves]).astype(np.float32),
            'curve_t': np.concatenate([c.t for c in curves]).astype(np.float32)}


def arrays_to_curves(data: Mapping[str, np.ndarray]) -> List[PokeCurve]:
    """Inverse of :func:`curves_to_arrays` (samples back in float64).

    Raises:
        DataError: inconsistent offsets.

    """
    off = np.asarray(data['curve_offsets'])
    n = len(data['curve_ids'])
    if len(off) != n + 1 or off[-1] != len(data['curve_d']) or np.any(np.diff(off) < 2):
        raise DataError('poke fixture: curve offsets do not match the samples')
    out = []
    for k in range(n):
        s = slice(int(off[k]), int(off[k + 1]))
        normal = np.asarray(data['curve_normals'][k], dtype=np.float64)
        out.append(PokeCurve(poke_id=str(data['curve_ids'][k]),
                             point=np.asarray(data['curve_points'][k], dtype=np.float64),
                             normal=normal / np.linalg.norm(normal),
                             d=np.asarray(data['curve_d'][s], dtype=np.float64),
                             f=np.asarray(data['curve_f'][s], dtype=np.float64),
                             onset_d=float(data['curve_onsets'][k]),
                             t=np.asarray(data['curve_t'][s], dtype=np.float64)))
    return out


def point_dent(spec, depth: Optional[float] = None, h: Optional[float] = None) -> Dict:
    """Full nonlinear point poke at the object's centre; the displaced top surface.

    Returns:
        dict with ``points`` (P, 3) undeformed top nodes, ``normals`` (P, 3) their outward
        normals, ``displaced`` (P, 3) the nodes at ``depth``, ``poke_point`` (3,), ``depth``
        (m), ``force`` (3,) N on the probe; ``base``.

    Raises:
        NotConverged: the FE solve failed.

    """
    depth = float(depth or 0.5 * spec.max_depth)
    h = h or spec.mesh_live
    x, y = spec.centre
    mesh = spec.build_mesh(h, refine_at=(x, y), fine_radius=0.012, growth=1.4)
    model = FemModel(mesh, spec.gauss_young(mesh), spec.poisson, support=spec.support)
    q = np.asarray(spec.top_point(x, y), dtype=float)
    n = np.asarray(spec.top_normal(x, y), dtype=float)
    res = model.indent(point_probe(**POINT_PROBE), pose_for_push(q, -n), -n,
                       np.array([0.5 * depth, depth]), torque_centre=q)
    nodes = mesh.nodes[res.surface_index]
    return {'points': nodes, 'normals': np.asarray(spec.top_normal(nodes[:, 0], nodes[:, 1])),
            'displaced': res.surface[-1], 'poke_point': q, 'depth': depth,
            'force': res.force[-1]}


_TRIAL_KEYS = ('vertices', 'triangles', 'start_position', 'orientation', 'direction',
               'torque_centre', 'depths', 'force', 'torque')


def _trial_arrays(prefix: str, trials: Sequence[Optional[Mapping]]) -> Dict[str, np.ndarray]:
    """Trials as flat npz arrays ``<prefix>NN_<key>``, ``<prefix>_kinds``, ``<prefix>_seconds``.

    None (a skipped trial) keeps its index, with kind ``skipped``.
    """
    arrays = {f'{prefix}{i:02d}_{key}': np.asarray(trial[key])
              for i, trial in enumerate(trials) if trial is not None for key in _TRIAL_KEYS}
    arrays[f'{prefix}_kinds'] = np.array([t['kind'] if t is not None else 'skipped'
                                         for t in trials])
    arrays[f'{prefix}_seconds'] = np.array([t['seconds'] if t is not None else 0.0
                                           for t in trials])
    return arrays


def _arrays_trials(prefix: str, data: Mapping) -> List[Optional[Dict]]:
    """Inverse of :func:`_trial_arrays` (raw arrays, no Mesh)."""
    out = []
    for i, (kind, sec) in enumerate(zip(data.get(f'{prefix}_kinds', []),
                                        data.get(f'{prefix}_seconds', []))):
        if str(kind) == 'skipped':
            out.append(None)
            continue
        trial = {key: data[f'{prefix}{i:02d}_{key}'] for key in _TRIAL_KEYS}
        trial.update(kind=str(kind), seconds=float(sec))
        out.append(trial)
    return out


def read_partial(path: Path, settings: str, say: Callable[[str], None] = print
                 ) -> Dict[str, np.ndarray]:
    """Arrays of a partial probe fixture written with ``settings``, else ``{}``.

    Trials depend on the physics and the seed only (``settings``), so a rerun may ask for
    more or fewer of them. The stored settings themselves are not among the arrays returned.
    """
    if not Path(path).is_file():
        return {}
    with np.load(path, allow_pickle=False) as z:
        saved = {k: z[k] for k in z.files if k != 'settings'}
        stored = str(z['settings']) if 'settings' in z.files else ''
    if stored.split(' lines=')[0] != settings:
        say(f'[figures-data] {path} is for other settings: starting over')
        return {}
    say(f'[figures-data] resuming from {path}')
    return saved


def write_partial(path: Path, settings: str, arrays: Mapping[str, np.ndarray]) -> None:
    """Write a partial probe fixture atomically: ``arrays`` plus ``settings``.

    ``arrays`` as :func:`read_partial` returns them, without the settings.
    """
    path = Path(path)
    tmp = path.with_name(path.name.replace('.partial.npz', '.tmp.partial.npz'))
    np.savez_compressed(tmp, settings=np.asarray(settings), **arrays)
    os.replace(tmp, path)


def make_probe_fixture(name: str, out=DATA_DIR, lines: int = 3, cylinders: int = 2,
                       seed: int = 0, say: Callable[[str], None] = print) -> Path:
    """Write ``probes_<name>.npz``: line/cylinder trials and a point-poke dent (see module).

    Each solved trial (minutes) is kept in ``probes_<name>.partial.npz`` at once; a rerun with
    the same seed resumes from it (with more or fewer trials of a kind: the first ones are the
    same) and gives the same file as an uninterrupted run.

    Raises:
        NotConverged: the dent's full solve failed.

    """
    started = time.monotonic()
    spec = load_object(name)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    partial = out / f'probes_{name}.partial.npz'
    settings = f'{physics_hash(spec)} seed={seed}'
    saved = read_partial(partial, settings, say)

    def keep(**parts):
        saved.update(parts)
        write_partial(partial, settings, saved)

    if 'dent_depth' in saved:
        dent = {k[5:]: saved[k] for k in saved if k.startswith('dent_')}
    else:
        dent = point_dent(spec)
        keep(**{f'dent_{k}': np.asarray(v) for k, v in dent.items()})
    say(f'[figures-data] {name}: dent at {float(dent["depth"]) * 1e3:.1f} mm, '
        f'{time.monotonic() - started:.0f} s')
    trials = []
    for kind, count, kind_seed in (('line', lines, seed), ('cylinder', cylinders, seed + 1)):
        if not count:
            continue
        prefix = f'{kind}_trial'
        trials += probe_trials(
            spec, [kind], count, kind_seed, progress=say,
            done=_arrays_trials(prefix, saved)[:count],
            on_trial=lambda so_far, prefix=prefix: keep(**_trial_arrays(prefix, so_far)))
    arrays = _trial_arrays('trial', trials)
    arrays.update({f'dent_{k}': np.asarray(v) for k, v in dent.items()})
    arrays.update(spec_hash=np.asarray(physics_hash(spec)), seed=np.asarray(int(seed)),
                  seconds=np.asarray(time.monotonic() - started))
    path = out / f'probes_{name}.npz'
    np.savez_compressed(path, **arrays)
    if partial.is_file():
        partial.unlink()
    return path


def _check_hash(data, name: str, what: str, say) -> bool:

    ok = str(data['spec_hash']) == physics_hash(load_object(name))
    if not ok:
        say(f'[figures] WARNING {what} of {name} was made for other object physics (stale): '
            f'rerun data/figures/make_figures_data.py --object {name}')
    return ok


def _read_fixture(data_dir, name: str, part: str) -> Dict[str, np.ndarray]:
    """Arrays of ``<part>_<name>.npz`` (DataError naming the command that makes it)."""
    path = Path(data_dir) / f'{part}_{name}.npz'
    if not path.is_file():
        what = 'poke' if part == 'pokes' else 'probe'
        raise DataError(f'no {what} fixture {path}: make it with python '
                        f'data/figures/make_figures_data.py --object {name} --part {part}')
    with np.load(path, allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def load_poke_fixture(name: str, data_dir=DATA_DIR, say: Callable[[str], None] = print
                      ) -> Tuple[Surface, List[PokeCurve], bool]:
    """Read ``pokes_<name>.npz``: ``(surface, curves, fresh)``.

    ``fresh`` is False when the file was made for other object physics (a warning is printed).

    Raises:
        DataError: the file is missing (the message says how to make it) or inconsistent.

    """
    data = _read_fixture(data_dir, name, 'pokes')
    surface = Surface(points=data['surface_points'].astype(np.float64),
                      normals=_unit(data['surface_normals']),
                      colors=np.clip(data['surface_colors'].astype(np.float64), 0.0, 1.0))
    return surface, arrays_to_curves(data), _check_hash(data, name, 'poke fixture', say)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def load_probe_fixture(name: str, data_dir=DATA_DIR, say: Callable[[str], None] = print
                       ) -> Tuple[List[Dict], Dict, bool]:
    """Read ``probes_<name>.npz``: ``(trials, dent, fresh)``.

    Each trial is a dict with ``kind``, ``mesh`` (:class:`Mesh`), ``start_position`` (3,),
    ``orientation`` (4,), ``direction`` (3,), ``torque_centre`` (3,), ``depths`` (K,) m,
    ``force`` (K, 3) N and ``torque`` (K, 3) N m (FEM ground truth, ``base``).

    Raises:
        DataError: the file is missing (the message says how to make it).

    """
    data = _read_fixture(data_dir, name, 'probes')
    cap = 1.5 * load_object(name).force_cap
    trials = []
    for i, kind in enumerate(data['trial_kinds']):
        t = {key: data[f'trial{i:02d}_{key}'] for key in (
            'vertices', 'triangles', 'start_position', 'orientation', 'direction',
            'torque_centre', 'depths', 'force', 'torque')}
        t['kind'] = str(kind)
        t['mesh'] = Mesh(t.pop('vertices'), t.pop('triangles'))
        first = float(-(t['force'][0] @ t['direction']))
        if first > cap:
            # made before the generator checked clearance on dense samples: the probe
            # started inside the object (a cylinder's side on a dome's apex)
            say(f'[figures] {name}: trial {i} ({kind}) left out: it began inside the object '
                f'({first:.1f} N at its first step, {1e3 * t["depths"][0]:.1f} mm)')
            continue
        trials.append(t)
    dent = {k[5:]: data[k] for k in data if k.startswith('dent_')}
    return trials, dent, _check_hash(data, name, 'probe fixture', say)


def trial_poses(trial: Mapping) -> List[Pose]:
    """Probe poses of every step of a trial: the start pose moved ``depths[k]`` along the push."""
    start = np.asarray(trial['start_position'], dtype=float)
    direction = np.asarray(trial['direction'], dtype=float)
    return [Pose(start + float(s) * direction, trial['orientation'])
            for s in np.asarray(trial['depths'], dtype=float)]


# ------------------------------------------------------------------ figure 1: learning curves
ISSUE17_RATIO = 0.9
"""Issue 17's figure-1 goal: ours at most this times the baseline at 5 and at 10 pokes."""


def learning_goals(rows: Sequence[Mapping]) -> Dict:
    """Judge figure 1's goals from :func:`~pointforce_ros.lab.evaluate.learning_curve` rows.

    The baseline at each size is the better (lower median) of ``et`` and ``auto_et``.
    Goals: ours <= 0.5 x baseline at 5 and at 10 pokes (the seed paper's claim); ours at 3
    pokes <= baseline at 10; ours <= :data:`ISSUE17_RATIO` x baseline at 5 and at 10 pokes
    (issue 17).

    Returns:
        ``{'half_at_5': bool, 'half_at_10': bool, 'three_vs_ten': bool, 'ratio_5': float,
        'ratio_10': float, 'ours_3': float, 'baseline_10': float, 'issue17_at_5': bool,
        'issue17_at_10': bool}`` (``None`` where a size is missing).

    Raises:
        InvalidInput: no ``ours`` rows or no baseline rows.

    """
    med = {(r['model'], int(r['size'])): float(r['median']) for r in rows}
    if not any(m == 'ours' for m, _ in med):
        raise InvalidInput('learning_goals: no rows of model "ours"')
    bases = [m for m in ('et', 'auto_et') if any(k == m for k, _ in med)]
    if not bases:
        raise InvalidInput('learning_goals: no baseline rows (et or auto_et)')

    def base(size):
        vals = [med[(m, size)] for m in bases if (m, size) in med]
        return min(vals) if vals else None

    out = {}
    for size in (5, 10):
        ours, b = med.get(('ours', size)), base(size)
        ratio = None if ours is None or b is None else ours / b
        out[f'ratio_{size}'] = ratio
        out[f'half_at_{size}'] = None if ratio is None else bool(ratio <= 0.5)
        out[f'issue17_at_{size}'] = None if ratio is None else bool(ratio <= ISSUE17_RATIO)
    out['ours_3'] = med.get(('ours', 3))
    out['baseline_10'] = base(10)
    out['three_vs_ten'] = (None if out['ours_3'] is None or out['baseline_10'] is None
                           else bool(out['ours_3'] <= out['baseline_10']))
    return out


class CappedAtTraining:
    """A force model whose predictions are capped at the largest force its training pokes saw.

    A diagnostic of figure 1, not a product model. Pokes stop at the cell's force cap, so no
    held-out sample lies above it, and ET, an average of training rows, never predicts above
    the largest training force either: a stiff guess costs it at most the distance to the cap.
    A contact law keeps rising past the cap, as the true force does (figure 1b), so the same
    stiff guess costs it more on the measured samples. Scoring ``ours`` capped like ET shows how
    much of the measured gap is that censoring. A planner needs the force past the cap, so the
    product model is not capped.
    """

    def __init__(self, model):
        self.model = model
        self.cap = np.inf

    @property
    def poke_ids(self) -> List[str]:
        """Ids of the training pokes of the wrapped model."""
        return self.model.poke_ids

    def fit(self, curves: Sequence[PokeCurve], surface: Surface) -> 'CappedAtTraining':
        """Fit the wrapped model and note the largest training force; returns ``self``."""
        self.model.fit(curves, surface)
        self.cap = float(max(np.max(c.f) for c in curves))
        return self

    def predict(self, features: np.ndarray, d) -> np.ndarray:
        """Return the wrapped model's force, at most the largest training force (N)."""
        return np.minimum(self.model.predict(features, d), self.cap)


def figure_learning(curves: Sequence[PokeCurve], surface: Surface, sizes=SIZES,
                    repeats: int = 10, seed: int = 0, auto_budget: float = 1.0,
                    truth: Optional[Mapping] = None) -> List[Dict]:
    """Figure 1 rows for one object (same subsets for every model).

    Models: ours (the product's point model, :func:`~pointforce_ros.response.ours.
    product_model`), its processes alone (``ours_gp``), ours as it was before issue 17
    (``ours_before``: power law, force at the parameters' mean), ours capped at its training
    pokes' largest force (a diagnostic, see :class:`CappedAtTraining`), ours with independent
    parameter processes (before decorrelation), ours with the outlier screen, ours with its
    laws spread by Extra Trees (``ours_trees``), its shape-free candidate, ET and Auto-ET.
    ``truth`` (:func:`full_depth_truth`) adds each model's score against the true forces, also
    past the force cap.
    """
    factories = {'ours': product_model,
                 # the processes alone (the product's spread mixes them with the trees)
                 'ours_gp': ContactGpModel,
                 # before issue 17: one power law, force at the parameters' predictive mean
                 'ours_before': lambda: ContactGpModel(law='power', mean='median'),
                 'ours_capped': lambda: CappedAtTraining(product_model()),
                 'ours_independent': lambda: ContactGpModel(decorrelate=False),
                 # the optional outlier screen (ours.py, module docstring point 8)
                 'ours_screened': lambda: ContactGpModel(robust_z=ROBUST_Z),
                 # the laws spread by Extra Trees instead of the processes (response/trees.py)
                 'ours_trees': lambda: ContactGpModel(spread='trees'),
                 'ours_shape_free': ShapeFreeGpModel, 'et': EtBaseline,
                 'auto_et': lambda: AutoEtBaseline(budget_s=auto_budget)}
    sizes = [s for s in sizes if s < len(curves)]
    return learning_curve(curves, surface, factories, sizes=sizes, repeats=repeats, seed=seed,
                          truth=truth)


def full_depth_truth(name: str, curves: Sequence[PokeCurve], step: float = 0.00025) -> Dict:
    """Return the true normal force at each poked point, also past where the poke stopped.

    A poke stops at the object's force cap, so a held-out curve holds no sample above it,
    and a regressor that never predicts more than the largest force it was trained on is
    never caught out there; a planner's query is not capped. Here the object's own FEM live
    path gives the force at the poke's point from 0.5 mm before its detected onset to the
    cell's depth limit (which, like the pokes, counts from the captured surface), every
    ``step``, in the poke's own depth coordinate (the captured surface point; the true
    surface lies ``b`` above it along the normal, so the FEM depth is ``d + b``). Depths
    without a finite FEM force are left out.

    Returns:
        ``{poke_id: (d (K,), f (K,))}``, metres and newtons.

    Raises:
        DataError: the object's live cache is missing or stale.

    """
    live = LiveContact.load(name, build=False)
    spec = live.spec
    out = {}
    for c in curves:
        x, y = float(c.point[0]), float(c.point[1])
        bias = float((spec.top_height(x, y) - c.point[2]) * c.normal[2])
        d = np.arange(c.onset_d - CONTACT_MARGIN, spec.max_depth + 0.5 * step, step)
        f = np.array([live.normal_force(x, y, v + bias) if v + bias > 0 else 0.0 for v in d])
        ok = np.isfinite(f)
        out[c.poke_id] = (d[ok], f[ok])
    return out


# ---------------------------------------------------------------- figure 2: probe trials
def truth_floor(name: str, curves: Sequence[PokeCurve], stride: int = 5) -> float:
    """Held-out RMSE (N) of the *true* physics that knows only the camera's mean bias.

    Every curve is predicted by the object's own FEM live path at its poked point, at depth
    ``d + bias`` (``bias``: the mean over ``curves`` of the true surface's height above the
    poked point, along its normal): a model that knew the stiffness field exactly and the
    camera's mean bias, but not the camera noise left at each poked point (which shifts each
    poke's onset at random). No model learned from other pokes can beat it. Scored like figure
    1 (contact region), on every ``stride``-th sample.

    Raises:
        DataError: the object's live cache is missing or stale.

    """
    live = LiveContact.load(name, build=False)
    pts = np.array([c.point for c in curves])
    normal_z = np.array([c.normal[2] for c in curves])
    bias = float(np.mean((live.spec.top_height(pts[:, 0], pts[:, 1]) - pts[:, 2]) * normal_z))
    err = []
    for c in curves:
        idx = np.flatnonzero(c.d >= c.onset_d - CONTACT_MARGIN)[::max(1, int(stride))]
        x, y = float(c.point[0]), float(c.point[1])
        f = np.array([live.normal_force(x, y, d + bias) if d + bias > 0 else 0.0
                      for d in c.d[idx]])
        err.append(f - c.f[idx])
    err = np.concatenate(err)
    return float(np.sqrt(np.mean(err * err)))


def own_law_rmse(curves: Sequence[PokeCurve]) -> float:
    """RMSE (N) of each curve against its *own* contact-law fit: the law's noise floor."""
    model = ContactGpModel()
    err = []
    for c in curves:
        keep = c.d >= c.onset_d - CONTACT_MARGIN
        params = np.repeat(model.fit_curve(c)[0][None], int(keep.sum()), axis=0)
        err.append(model.force_from_params(params, c.d[keep]) - c.f[keep])
    err = np.concatenate(err)
    return float(np.sqrt(np.mean(err * err)))


def spread_budget(curves: Sequence[PokeCurve], surface: Surface, size: int = 10,
                  repeats: int = 10, seed: int = 0) -> Dict:
    """Where ours' held-out error comes from: the law's shape spread over the object, or not.

    Over ``repeats`` random training subsets of ``size`` pokes, each held-out poke is predicted
    twice by the same fitted :class:`~pointforce_ros.response.ours.ContactGpModel`:

    - ``ours``: every parameter ``(d0, log F, p)`` predicted at the poke's location;
    - ``own_shape``: the onset ``d0`` predicted, but ``(log F, p)`` taken from the held-out
      poke's *own* fit: what ours would score if it spread the curve's shape over the object
      perfectly (it still has to place the onset, like every model).

    The gap between them is the error of spreading a handful of pokes' stiffness over the
    surface; ``own_shape`` above the true-physics floor is the onset (camera noise) and the
    law's misfit. Where the law's fitted onset trades against its exponent (a stiffening
    curve fitted with an early onset and a large exponent), the own shape at another onset is
    no oracle: on lamb it scores worse than ours.

    Returns:
        ``{'size', 'ours', 'own_shape'}``: medians over the subsets of the held-out RMSE, N.

    Raises:
        InvalidInput: ``size`` leaves no held-out poke, or ``repeats < 1``.

    """
    curves = list(curves)
    if not 1 <= size < len(curves) or repeats < 1:
        raise InvalidInput(f'spread_budget: need 1 <= size < {len(curves)} pokes and '
                           f'repeats >= 1, got size {size}, repeats {repeats}')
    own = {}
    rng = np.random.default_rng(seed)
    scores = {'ours': [], 'own_shape': []}
    for _ in range(repeats):
        pick = set(rng.choice(len(curves), size=size, replace=False).tolist())
        model = ContactGpModel().fit([curves[i] for i in sorted(pick)], surface)
        test = [c for i, c in enumerate(curves) if i not in pick]
        predicted = model.predict_params(curve_features(test, surface))
        err = {k: [] for k in scores}
        for c, theta in zip(test, predicted):
            keep = c.d >= c.onset_d - CONTACT_MARGIN
            if (model.law, c.poke_id) not in own:     # the poke's own fit of the chosen law
                own[(model.law, c.poke_id)] = model.fit_curve(c, model.law)[0]
            mixed = np.concatenate([theta[:1], own[(model.law, c.poke_id)][1:]])
            for key, params in (('ours', theta), ('own_shape', mixed)):
                rows = np.repeat(params[None], int(keep.sum()), axis=0)
                err[key].append(model.force_from_params(rows, c.d[keep]) - c.f[keep])
        for key, e in err.items():
            e = np.concatenate(e)
            scores[key].append(float(np.sqrt(np.mean(e * e))))
    return {'size': int(size), **{k: float(np.median(v)) for k, v in scores.items()}}


def half_goal_reachable(goals: Mapping, truth: Optional[float]) -> Optional[bool]:
    """Return whether half the 10-poke baseline lies above the true-physics floor.

    If not, no model can reach the "half" goal: the floor is the error of the object's own
    physics. ``None`` when either number is missing.
    """
    base = goals.get('baseline_10')
    if base is None or truth is None:
        return None
    return bool(0.5 * base > truth)


def wrench_rmse(pred_force, pred_torque, true_force, true_torque) -> Tuple[float, float]:
    """RMS of the force (N) and torque (N m) error vectors over all rows ((R, 3) each)."""
    ef = np.asarray(pred_force, float) - np.asarray(true_force, float)
    et = np.asarray(pred_torque, float) - np.asarray(true_torque, float)
    return (float(np.sqrt(np.mean(np.sum(ef * ef, axis=1)))),
            float(np.sqrt(np.mean(np.sum(et * et, axis=1)))))


def contact_centre_rows(trial: Mapping, surface: Surface) -> np.ndarray:
    """(K, 10) ``[p, rgb, n, d]`` of a trial's steps for the pure-learning reference.

    ``x`` is the surface point nearest to the probe's push line through its start position (in
    the plane normal to the push), ``d`` the probe travel past that point along the push, m.
    """
    a = np.asarray(trial['direction'], float)
    start = np.asarray(trial['start_position'], float)
    rel = surface.points - start
    along = rel @ a
    lateral = np.linalg.norm(rel - along[:, None] * a, axis=1)
    k = int(np.argmin(lateral))
    d = np.asarray(trial['depths'], float) - along[k]
    x = np.repeat(surface.features[k][None], len(d), axis=0)
    return np.column_stack([x, d])


def pure_learning(trials: Sequence[Mapping], surface: Surface, seed: int = 0
                  ) -> List[Optional[Tuple[np.ndarray, np.ndarray]]]:
    """Leave-one-trial-out Extra Trees on probe data of the same kind (the paper's reference).

    Returns:
        One ``(force (K, 3), torque (K, 3))`` per trial, or ``None`` when no other trial of
        its kind exists.

    """
    from sklearn.ensemble import ExtraTreesRegressor

    rows = [contact_centre_rows(t, surface) for t in trials]
    out = []
    for i, t in enumerate(trials):
        others = [j for j, u in enumerate(trials) if j != i and u['kind'] == t['kind']]
        if not others:
            out.append(None)
            continue
        x = np.vstack([rows[j] for j in others])
        y = np.vstack([np.hstack([trials[j]['force'], trials[j]['torque']]) for j in others])
        model = ExtraTreesRegressor(random_state=seed, n_jobs=1).fit(x, y)
        pred = model.predict(rows[i])
        out.append((pred[:, :3], pred[:, 3:]))
    return out


def bake_depths(curves: Sequence[PokeCurve]) -> np.ndarray:
    """Return the bake grid of the figures: from 2 mm before the earliest onset to 30 mm."""
    lo = min(0.0, min(c.onset_d for c in curves)) - 0.002
    return np.linspace(lo, 0.03, 121)


def _simulate_ours(sim, trials) -> List[Tuple[np.ndarray, np.ndarray]]:
    out = []
    for t in trials:
        batch = sim.query_batch(t['mesh'], trial_poses(t), t['direction'], t['torque_centre'])
        out.append((batch.wrenches[:, :3], batch.wrenches[:, 3:]))
    return out


def _simulate_paper(sim, fallback, trials) -> Tuple[List[Tuple[np.ndarray, np.ndarray]], int]:
    """Paper simulator per pose; where its LCP scheme fails (singular ``G``), ``fallback``."""
    out, failed = [], 0
    for t in trials:
        f, m = [], []
        for pose in trial_poses(t):
            try:
                w = sim.query(t['mesh'], pose, t['direction'], t['torque_centre']).wrench
            except NotConverged:
                failed += 1
                w = fallback.query(t['mesh'], pose, t['direction'], t['torque_centre']).wrench
            f.append(w.force)
            m.append(w.torque)
        out.append((np.array(f), np.array(m)))
    return out, failed


def _score(preds, trials, pick) -> Tuple[float, float]:
    pf = np.vstack([preds[i][0] for i in pick])
    pt = np.vstack([preds[i][1] for i in pick])
    tf = np.vstack([trials[i]['force'] for i in pick])
    tt = np.vstack([trials[i]['torque'] for i in pick])
    return wrench_rmse(pf, pt, tf, tt)


def identify_c_dent(dent: Mapping, r_min: float = 0.003):
    """Shape constant from the dent of a point poke (``ShapeFit``), or the error text.

    ``g(r) = c / (c + r)`` is the displacement at ``r`` per unit displacement at the poke, so
    the dent is fitted with its depth at the poke fixed to the poke depth (``dent['depth']``
    when given). With a free depth the FEM dents (which fall off faster than ``1 / r`` on a
    finite object on a table) drive ``c`` to its lower bound.
    """
    surf = Surface(points=dent['points'], normals=_unit(dent['normals']))
    r, u = dent_profile(surf, dent['displaced'], dent['poke_point'])
    try:
        u0 = float(dent['depth']) if 'depth' in dent else None
        return identify_shape_constant(r, u, u0=u0, r_min=r_min, c_bounds=(1e-4, 0.5))
    except PointforceError as exc:
        return str(exc)


def figure_probes(curves: Sequence[PokeCurve], surface: Surface, trials: Sequence[Mapping],
                  dent: Optional[Mapping] = None, repeats: int = 10, seed: int = 0,
                  n_train: int = PROBE_TRAIN_POKES, c_grid: Optional[Sequence[float]] = None,
                  paper_draws: int = 3, say: Callable[[str], None] = print,
                  nears: Sequence[str] = NEARS,
                  point_model: Callable[[], object] = product_model) -> Dict:
    """Figures 2 and 3 for one object (see the module docstring).

    Every trial is scored, each with ``c`` identified from the object's *other* trials
    (leave one trial out, :func:`~pointforce_ros.contact.identify.
    identify_shape_constant_from_probes`) with the point model trained on every poke of
    ``curves``: ``c`` is one constant of the object, so no step sees the trial it scores.
    (One calibration trial was not enough: where the point model is wrong under that probe,
    ``c`` absorbs the error; plush's first line trial alone asked for 40 mm against 2 mm from
    the others. Identified with a 10-poke model it also scattered 4x between draws.) Point
    models are trained on ``n_train`` pokes drawn at
    random from ``curves``, ``repeats`` times; the RMSEs are medians over those draws. The
    paper's simulator (dense ``G`` inverted per round, seconds per query) runs on the first
    ``paper_draws`` draws only; where its LCP scheme fails (singular ``G``: duplicate contact
    points) that query is answered by our simulator with the same ET model (counted in
    ``failed_paper_queries``; ``et_our_sim`` is that combination on every query).

    ``ours`` identifies ``c`` together with the decay length of the shape function's tail
    (:data:`~pointforce_ros.contact.identify.DECAY_GRID`, no longer than
    :data:`~pointforce_ros.contact.identify.DECAY_CAP` times the object's thickness:
    :func:`~pointforce_ros.contact.identify.decay_grid`); ``ours_no_decay`` is ``c`` alone,
    the paper's ``g`` (the error before that effect was added). The near field of ``ours``
    (``nears``, :data:`~pointforce_ros.contact.lcp.NEARS`) is chosen per trial by the other
    trials, each predicted from the rest (:func:`~pointforce_ros.contact.identify.
    choose_near`); ``('paper',)`` keeps the seed's ``c / (c + r)``. ``point_model`` makes ours'
    point model, for each draw and for the calibration of ``(c, L)`` on every poke (default:
    the product's, :func:`~pointforce_ros.response.ours.product_model`).

    Returns:
        dict with ``c`` (``dent``, ``probe``: median of ``per_trial``, the leave-one-out
        values, ``with_decay``: the leave-one-out ``(c, decay, near field)``, ``default``),
        ``rmse`` ({method: {force,
        torque, force_line, force_cylinder}} medians), ``peak_force`` (N), ``c_curve``
        ({c: [force RMSE per draw]}), ``failed_paper_queries``, ``eval_trials``.

    Raises:
        InvalidInput: fewer than 2 trials or fewer than ``n_train + 1`` curves.

    """
    trials = list(trials)
    if len(trials) < 2:
        raise InvalidInput('figure_probes: need >= 2 trials (the others identify c)')
    if len(curves) < n_train:
        raise InvalidInput(f'figure_probes: need >= {n_train} curves, got {len(curves)}')
    c_grid = np.asarray(c_grid if c_grid is not None else
                        np.geomspace(2.5e-4, 0.064, 9), dtype=float)
    evaluate = list(range(len(trials)))
    kinds = {k: [i for i in evaluate if trials[i]['kind'] == k] for k in ('line', 'cylinder')}
    rng = np.random.default_rng([int(seed), 2])
    depths = bake_depths(curves)
    c_dent = identify_c_dent(dent) if dent is not None else 'no dent data'
    reference = pure_learning(trials, surface, seed)
    ref_pick = [i for i in evaluate if reference[i] is not None]
    per = {m: {'force': [], 'torque': [], 'force_line': [], 'force_cylinder': []}
           for m in ('baseline', 'et_our_sim', 'ours', 'ours_no_decay', 'ours_default_c')}
    paper_repeats = min(int(repeats), int(paper_draws))
    c_curve, failed = {float(c): [] for c in c_grid}, 0
    calibration = ContactSimulator(
        surface, point_model().fit(list(curves), surface).bake(surface, depths), DEFAULT_C)
    c_trial, shape_trial = [], []
    for j in evaluate:
        others = [(t['mesh'], trial_poses(t), t['direction'], t['force'])
                  for i, t in enumerate(trials) if i != j]
        try:  # one scan gives both: c alone (the paper's g, decay inf) and the best pair
            fits = shape_fits_from_probes(calibration, others, c_bounds=(1e-4, 0.1),
                                          decays=DECAY_GRID)
        except PointforceError as exc:
            say(f'[figures]   c for trial {j} not identified ({exc}); using {DEFAULT_C} m')
            fits = []
        paper = [f.c for f in fits if np.isinf(f.decay)]
        if fits and not paper:
            say(f'[figures]   c alone for trial {j} not identified; using {DEFAULT_C} m')
        c_trial.append(float(paper[0]) if paper else DEFAULT_C)
        # the near field the other trials predict each other best with, then (c, L) under it
        near, _ = choose_near(calibration, others, decay_grid(surface), nears=nears)
        if near != calibration.near:
            try:
                fits = shape_fits_from_probes(calibration.with_shape_constant(
                    calibration.c, near=near), others, c_bounds=(1e-4, 0.1), decays=DECAY_GRID)
            except PointforceError as exc:
                say(f'[figures]   (c, L) for trial {j} not identified under the {near} near '
                    f'field ({exc}); the paper\'s')
                near = calibration.near
        best = best_capped_fit(fits, surface)      # the tail within DECAY_CAP thicknesses
        shape_trial.append((float(best.c), float(best.decay), near) if best
                           else (DEFAULT_C, np.inf, calibration.near))
    say('[figures]   c from the other trials [mm]: '
        + ', '.join(f'{1e3 * c:.2f}' for c in c_trial) + '; with the tail\'s decay length '
        '(and near field): '
        + ', '.join(f'{1e3 * c:.2f} / {1e3 * L:.0f} ({n})' for c, L, n in shape_trial))
    for rep in range(int(repeats)):
        pick = rng.choice(len(curves), size=n_train, replace=False)
        train = [curves[i] for i in pick]
        ours = point_model().fit(train, surface)
        sim = ContactSimulator(surface, ours.bake(surface, depths), DEFAULT_C)
        et = EtBaseline().fit(train, surface)
        et_sim = ContactSimulator(surface, et.bake(surface, depths), DEFAULT_C)
        preds = {'ours': [_simulate_ours(sim.with_shape_constant(c, decay, near=n), [t])[0]
                          for (c, decay, n), t in zip(shape_trial, trials)],
                 'ours_no_decay': [_simulate_ours(sim.with_shape_constant(c), [t])[0]
                                   for c, t in zip(c_trial, trials)],
                 'ours_default_c': _simulate_ours(sim, trials),
                 'et_our_sim': _simulate_ours(et_sim, trials)}
        if rep < paper_repeats:
            preds['baseline'], bad = _simulate_paper(
                PaperContactSimulator(surface, et.predict, DEFAULT_C), et_sim, trials)
            failed += bad
        for name, pr in preds.items():
            f, m = _score(pr, trials, evaluate)
            per[name]['force'].append(f)
            per[name]['torque'].append(m)
            for kind, idx in kinds.items():
                if idx:
                    per[name][f'force_{kind}'].append(_score(pr, trials, idx)[0])
        for c in c_grid:
            c_curve[float(c)].append(_score(_simulate_ours(sim.with_shape_constant(c), trials),
                                            trials, evaluate)[0])
        say(f'[figures]   draw {rep + 1}/{repeats}: force RMSE '
            f'ours {per["ours"]["force"][-1]:.3f} N, our sim + ET '
            f'{per["et_our_sim"]["force"][-1]:.3f} N'
            + (f', paper sim + ET {per["baseline"]["force"][-1]:.3f} N' if 'baseline' in preds
               else ''))
    rmse = {name: {k: (float(np.median(v)) if v else None) for k, v in vals.items()}
            for name, vals in per.items() if vals['force']}
    if ref_pick:
        f, m = _score(reference, trials, ref_pick)
        rmse['pure_learning'] = {'force': f, 'torque': m, 'trials': len(ref_pick)}
        for kind, idx in kinds.items():
            sel = [i for i in idx if reference[i] is not None]
            rmse['pure_learning'][f'force_{kind}'] = _score(reference, trials, sel)[0] \
                if sel else None
    peak = float(max(np.linalg.norm(trials[i]['force'], axis=1).max() for i in evaluate))
    return {'c': {'dent': c_dent.c if not isinstance(c_dent, str) else None,
                  'dent_note': c_dent if isinstance(c_dent, str) else
                  f'rmse {c_dent.rmse * 1e3:.3f} mm over {c_dent.n_points} nodes',
                  'probe': float(np.median(c_trial)), 'per_trial': c_trial,
                  'with_decay': [list(v) for v in shape_trial],
                  'default': DEFAULT_C},
            'rmse': rmse, 'peak_force': peak, 'c_curve': c_curve,
            'failed_paper_queries': int(failed),
            'paper_queries': int(paper_repeats * sum(len(t['depths']) for t in trials)),
            'eval_trials': len(evaluate),
            'eval_kinds': {k: len(v) for k, v in kinds.items()}}


def probe_goals(result: Mapping) -> Dict:
    """Figure 2 goals: ours <= 0.7 x baseline force RMSE, and ours < 10 % of the peak force."""
    ours = result['rmse']['ours']['force']
    base = result['rmse']['baseline']['force']
    ratio = ours / base if base else float('inf')
    frac = ours / result['peak_force']
    return {'ratio': ratio, 'ratio_met': bool(ratio <= 0.7), 'peak_fraction': frac,
            'peak_met': bool(frac < 0.10)}


# ------------------------------------------------------------- figure 4: next-poke suggestion
ACTIVE_MAX = 12
"""Pokes the active-vs-random comparison grows to (of the pool's 70 % candidates)."""


def pokes_to_match(result: Mapping) -> Dict:
    """Fewest pokes at which each strategy's median RMSE reaches random's at the last size.

    Returns:
        ``{'target': N, 'active': pokes or None, 'random': pokes, 'saved': random - active}``
        (``None``: active never reaches it).

    """
    sizes = list(result['sizes'])
    target = float(result['random']['median'][-1])

    def first(strategy):
        med = result[strategy]['median']
        hit = [n for n, e in zip(sizes, med) if e <= target * (1 + 1e-9)]
        return hit[0] if hit else None

    active, random = first('active'), first('random')
    return {'target': target, 'active': active, 'random': random,
            'saved': None if active is None else random - active}


def figure_active(curves: Sequence[PokeCurve], surface: Surface, repeats: int = 10,
                  seed: int = 0, max_pokes: int = ACTIVE_MAX) -> Dict:
    """Figure 4 for one object: :func:`active_vs_random_curve` with ours, and the savings."""
    res = active_vs_random_curve(list(curves), surface, ContactGpModel, start=2,
                                 max_pokes=max_pokes, repeats=repeats, seed=seed)
    res['match'] = pokes_to_match(res)
    return res


# ---------------------------------------------------------------------------- plots, table
def _pyplot():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def plot_learning(per_object: Mapping[str, Sequence[Mapping]], path) -> None:
    """Figure 1 PNG: one panel per object, median RMSE with the inter-quartile band."""
    plt = _pyplot()
    names = list(per_object)
    fig, axes = plt.subplots(1, max(len(names), 1), figsize=(3.4 * max(len(names), 1), 3.2),
                             dpi=110, squeeze=False)

    for ax, name in zip(axes[0], names):
        draw_learning_rows(ax, per_object[name])
        ax.set_xscale('log')
        ax.set_xticks(list(SIZES))
        ax.set_xticklabels([str(s) for s in SIZES])
        ax.set_xticks([], minor=True)  # a log axis labels its minor ticks over so short a range
        ax.set_title(name)
        ax.set_xlabel('training pokes')
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel('held-out RMSE [N]')
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


METHOD_LABELS = {'baseline': 'baseline (paper sim + ET, c = 4 mm)',
                 'et_our_sim': 'our sim + ET, c = 4 mm',
                 'ours_default_c': 'ours, c = 4 mm',
                 'ours_no_decay': 'ours (identified c, paper\'s g)',
                 'ours': 'ours (identified c and tail decay)',
                 'pure_learning': 'pure learning (LOO trials)'}


def plot_active(per_object: Mapping[str, Mapping], path) -> None:
    """Figure 4 PNG: one panel per object, active and random medians with quartile bands."""
    plt = _pyplot()
    names = list(per_object)
    fig, axes = plt.subplots(1, max(len(names), 1), figsize=(3.4 * max(len(names), 1), 3.2),
                             dpi=110, squeeze=False)
    for ax, name in zip(axes[0], names):
        res = per_object[name]
        for strategy in ('active', 'random'):
            r = res[strategy]
            ax.plot(res['sizes'], r['median'], marker='o', ms=3, label=strategy)
            ax.fill_between(res['sizes'], r['q25'], r['q75'], alpha=0.2)
        ax.axhline(res['match']['target'], color='grey', lw=0.8, ls=':')
        ax.set_title(name)
        ax.set_xlabel('pokes')
        ax.grid(True, alpha=0.3)
    axes[0][0].set_ylabel('held-out RMSE [N]')
    axes[0][0].legend(fontsize=8)
    fig.suptitle('next poke: least certain location (active) vs random, ours')
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_probes(per_object: Mapping[str, Mapping], path) -> None:
    """Figure 2 PNG: force and torque RMSE per object and method (grouped bars)."""
    plt = _pyplot()
    names = list(per_object)
    methods = [m for m in METHOD_LABELS if any(m in per_object[n]['rmse'] for n in names)]
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6), dpi=110)
    width = 0.8 / max(len(methods), 1)
    panels = ((axes[0], 'force', 'N', 1.0), (axes[1], 'torque', 'mN m', 1e3))
    for ax, key, unit, scale in panels:
        for j, m in enumerate(methods):
            vals = [scale * (per_object[n]['rmse'].get(m, {}).get(key) or np.nan)
                    for n in names]
            ax.bar(np.arange(len(names)) + (j - (len(methods) - 1) / 2) * width, vals, width,
                   label=METHOD_LABELS[m])
        ax.set_xticks(np.arange(len(names)))
        ax.set_xticklabels(names)
        ax.set_ylabel(f'{key} RMSE [{unit}]')
        ax.grid(True, axis='y', alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle('line + cylinder probes, held-out trials (median over training draws)')
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def plot_shape_constant(per_object: Mapping[str, Mapping], path) -> None:
    """Figure 3 PNG: ours' probe force RMSE against ``c``, identified values marked."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.6, 3.8), dpi=110)
    for name, res in per_object.items():
        cs = sorted(res['c_curve'])
        med = [float(np.median(res['c_curve'][c])) for c in cs]
        line, = ax.plot(np.array(cs) * 1e3, med, marker='.', label=name)
        cp = res['c']['probe']
        if cp:
            ax.axvline(cp * 1e3, color=line.get_color(), ls='--', lw=0.8)
        if res['c']['dent']:
            ax.axvline(res['c']['dent'] * 1e3, color=line.get_color(), ls=':', lw=0.8)
    ax.axvline(DEFAULT_C * 1e3, color='k', lw=0.6, alpha=0.5)
    ax.set_xscale('log')
    ax.set_xlabel('shape constant c [mm]\n(dashed: from other trials, median; dotted: from the '
                  'dent; grey: 4 mm)')
    ax.set_yscale('log')  # vest's small-c errors (tens of N) would flatten every other curve
    ax.set_ylabel('ours: probe force RMSE [N]')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def _fmt(v, digits=3) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return '-'
    if isinstance(v, bool):
        return 'met' if v else 'NOT met'
    return f'{v:.{digits}f}'


def _learning_table(learning: Mapping, key: str, extra: Optional[Tuple[str, Mapping]] = None
                    ) -> List[str]:
    """Markdown rows of figure 1: per object and model, ``key`` at each of :data:`SIZES`.

    ``extra``: ``(title, {object: value})``, a column after the object's name.
    """
    head = ['object'] + ([extra[0]] if extra else []) + ['model'] + [str(s) for s in SIZES]
    lines = ['| ' + ' | '.join(head) + ' |', '| ' + ' | '.join('---' for _ in head) + ' |']
    for name, rows in learning.items():
        first = [name] + ([_fmt(extra[1].get(name), 2)] if extra else [])
        for model in dict.fromkeys(r['model'] for r in rows if key in r):
            value = {r['size']: r[key] for r in rows if r['model'] == model}
            lines.append('| ' + ' | '.join(first + [model] + [_fmt(value.get(s))
                                                              for s in SIZES]) + ' |')
    return lines


def markdown_report(result: Mapping) -> str:
    """Markdown tables of figures 1-3 and the goals (the body of ``figures.md``)."""
    lines = ['# Seed-method figures on the simulated cell', '',
             f"Objects: {', '.join(result['objects']) or 'none'}; repeats "
             f"{result['repeats']}; seed {result['seed']}; run time "
             f"{result['seconds']:.0f} s.", '']
    if result.get('skipped'):
        lines += ['Skipped: ' + '; '.join(f'{k}: {v}' for k, v in result['skipped'].items()),
                  '']
    lines += ['## 1. Point probe: held-out force RMSE [N] vs training pokes', '',
              'RMSE over every loading sample of every held-out poke from 0.5 mm before its '
              'estimated contact onset to its deepest point, against the measured (tared, '
              'noisy) normal force; median over random training subsets of the 30-poke pool '
              '(realistic scenario, FEM live path).', '',
              *_learning_table(result['learning'], 'median'),
              '', '`ours_capped` (a diagnostic, not the product model): ours with its '
              'predictions capped at the largest force its training pokes saw. No held-out '
              'sample lies above the force cap and ET never predicts above its largest training '
              'force, so on this table a stiff guess costs ET at most the distance to the cap; '
              'the gap between `ours` and `ours_capped` is that censoring.']
    if any('truth_median' in r for rows in result['learning'].values() for r in rows):
        lines += ['', '### 1b. The same subsets, against the true force [N]', '',
                  'Held-out poke points scored against the object\'s FEM force from 0.5 mm '
                  'before the poke\'s onset to the cell\'s depth limit, also past the force cap '
                  'where the poke stopped (`full_depth_truth`; where the FEM converged there): '
                  'what a planner\'s deep query meets. `past cap`: share of those samples above '
                  'the force cap. The goals are judged on the measured table above.', '',
                  *_learning_table(result['learning'], 'truth_median',
                                   ('past cap', result.get('past_cap', {})))]
    lines += ['', '| object | ours/base @5 | goal <= 0.5 | goal <= 0.9 (#17) | ours/base @10 | '
              'goal <= 0.5 | goal <= 0.9 (#17) | ours@3 vs base@10 [N] | goal |',
              '| --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for name, g in result['learning_goals'].items():
        lines.append(f"| {name} | {_fmt(g['ratio_5'], 2)} | {_fmt(g['half_at_5'])} | "
                     f"{_fmt(g.get('issue17_at_5'))} | "
                     f"{_fmt(g['ratio_10'], 2)} | {_fmt(g['half_at_10'])} | "
                     f"{_fmt(g.get('issue17_at_10'))} | "
                     f"{_fmt(g['ours_3'])} vs {_fmt(g['baseline_10'])} | "
                     f"{_fmt(g['three_vs_ten'])} |")
    lines += ['', '(baseline = the better of ET and Auto-ET at that size)', '']
    if result.get('error_budget'):
        lines += ['### Floors [N] (same held-out protocol, all 30 pokes)', '',
                  '`true physics`: the object\'s own FEM force at every held-out sample, knowing '
                  'the camera\'s mean bias but not its noise at each poked point (that noise '
                  'moves each poke\'s contact onset at random). No model learned from other '
                  'pokes can go below it. `own law`: each curve against its own contact-law fit '
                  '(the F/T noise floor).', '',
                  '`ours, own shape @10`: ours with the held-out poke\'s own `(log F, p)` and '
                  'the predicted onset (spreading the stiffness over the object made perfect); '
                  '`ours @10` on the same subsets. Where a poke\'s law trades its fitted onset '
                  'against its exponent (lamb\'s stiffening curves), its own shape at another '
                  'onset is no oracle and can score worse than ours. '
                  '`half reachable`: half the 10-poke baseline '
                  'lies above the true-physics floor.', '',
                  '| object | true physics | own law | ours, own shape @10 | ours @10 | '
                  'half reachable |', '| --- | --- | --- | --- | --- | --- |']
        for name, b in result['error_budget'].items():
            spread = b.get('spread') or {}
            reach = {None: '-', True: 'yes', False: 'no'}[b.get('half_reachable')]
            lines.append(f"| {name} | {_fmt(b.get('truth'))} | {_fmt(b['own_law'])} | "
                         f"{_fmt(spread.get('own_shape'))} | {_fmt(spread.get('ours'))} | "
                         f"{reach} |")
        lines.append('')
    lines += [
              '## 2. Line and cylinder probes: wrench RMSE on held-out trials', '',
              'RMS of the force / torque error vector over every step of every evaluated trial '
              '(each scored with c identified from the other trials); point models trained on '
              f'{PROBE_TRAIN_POKES} pokes, median over the training draws.', '',
              '| object | method | force [N] | torque [mN m] | line force [N] | '
              'cylinder force [N] |', '| --- | --- | --- | --- | --- | --- |']
    for name, res in result['probes'].items():
        for m in METHOD_LABELS:
            r = res['rmse'].get(m)
            if r is None:
                continue
            torque = None if r.get('torque') is None else 1e3 * r['torque']
            lines.append(f"| {name} | {METHOD_LABELS[m]} | {_fmt(r['force'])} | "
                         f"{_fmt(torque, 2)} | {_fmt(r.get('force_line'))} | "
                         f"{_fmt(r.get('force_cylinder'))} |")
    lines += ['', '| object | eval trials (line/cyl) | peak force [N] | ours/baseline | '
              'goal <= 0.7 | ours/peak | goal < 10 % | failed paper queries |',
              '| --- | --- | --- | --- | --- | --- | --- | --- |']
    for name, res in result['probes'].items():
        g = result['probe_goals'][name]
        lines.append(f"| {name} | {res['eval_kinds']['line']}/{res['eval_kinds']['cylinder']}"
                     f" | {res['peak_force']:.2f} | {g['ratio']:.2f} | {_fmt(g['ratio_met'])} | "
                     f"{100 * g['peak_fraction']:.1f} % | {_fmt(g['peak_met'])} | "
                     f"{res['failed_paper_queries']}/{res['paper_queries']} |")
    lines += ['', '## 3. Shape constant c', '',
              '| object | c from dent [mm] | c from the other trials, all-poke model, per '
              'trial [mm] | c / decay length identified together, per trial [mm] | '
              'ours force RMSE at 4 mm / identified c / c and decay [N] | best c on the grid '
              '[mm] |',
              '| --- | --- | --- | --- | --- | --- |']
    for name, res in result['probes'].items():
        c = res['c']
        cs = sorted(res['c_curve'])
        med = [float(np.median(res['c_curve'][k])) for k in cs]
        best = cs[int(np.argmin(med))]
        dent = _fmt(None if c['dent'] is None else 1e3 * c['dent'], 2)
        probe = ', '.join(f'{1e3 * v:.2f}' for v in c['per_trial'])
        pairs = ', '.join(f'{1e3 * v:.2f} / ' + (f'{1e3 * L:.0f}' if np.isfinite(L) else 'inf')
                          + (f' {rest[0]}' if rest and rest[0] != 'paper' else '')
                          for v, L, *rest in c.get('with_decay', []))
        no_decay = res['rmse'].get('ours_no_decay', {}).get('force')
        lines.append(f"| {name} | {dent} | {probe} | {pairs or '-'} | "
                     f"{_fmt(res['rmse']['ours_default_c']['force'])} / {_fmt(no_decay)} / "
                     f"{_fmt(res['rmse']['ours']['force'])} | {1e3 * best:.2f} |")
    lines.append('')
    if result.get('active'):
        sizes = next(iter(result['active'].values()))['sizes']
        show = [n for n in (2, 3, 5, 8, 10, ACTIVE_MAX) if n in sizes]
        lines += ['## 4. Next poke: least certain location vs random (ours)', '',
                  'Held-out RMSE [N], median over the repeats (30 % of the pool held out per '
                  'repeat; both strategies start from the same 2 random pokes and choose among '
                  'the remaining pool locations). `pokes to match`: fewest pokes whose median '
                  f'reaches random choice\'s median at {ACTIVE_MAX} pokes.', '',
                  '| object | strategy | ' + ' | '.join(str(n) for n in show)
                  + ' | pokes to match |', '| --- | --- | ' + ' | '.join('---' for _ in show)
                  + ' | --- |']
        for name, res in result['active'].items():
            for strategy in ('active', 'random'):
                med = dict(zip(res['sizes'], res[strategy]['median']))
                lines.append(f'| {name} | {strategy} | '
                             + ' | '.join(_fmt(med.get(n)) for n in show)
                             + f" | {res['match'][strategy] or '-'} |")
        lines.append('')
    return '\n'.join(lines) + '\n'


# ---------------------------------------------------------------------------------- driver
def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def run_figures(out_dir, objects: Sequence[str] = OBJECTS, quick: bool = False,
                repeats: Optional[int] = None, seed: int = 0, auto_budget: float = 1.0,
                data_dir=DATA_DIR, say: Callable[[str], None] = print,
                learning_only: bool = False, sizes: Sequence[int] = SIZES) -> Dict:
    """Compute figures 1-3 from the cached fixtures; write PNGs, ``figures.md``, JSON.

    Args:
        out_dir: output folder (created).
        objects: object names; ``quick`` keeps the first two.
        quick: 2 objects, 3 training subsets, Auto-ET budget 0.3 s.
        repeats: training subsets per size (default 10, quick 3).
        seed: seed of the subset draws.
        auto_budget: Auto-ET search budget per fit, seconds.
        data_dir: folder of ``pokes_<object>.npz`` and ``probes_<object>.npz``.
        learning_only: figure 1 and its error budget only (no next-poke or probe figures).
        sizes: figure 1's training-set sizes (the subsets are drawn size by size in this
            order, so the same sizes and seed give the same subsets).

    Returns:
        dict with ``learning`` ({object: rows}), ``learning_goals``, ``probes`` ({object:
        figure_probes result}), ``probe_goals``, ``skipped`` ({object: reason}), ``files``,
        ``seconds``; the same is written to ``figures.json``.

    Raises:
        InvalidInput: an unknown object name or ``repeats < 1``.

    """
    started = time.monotonic()
    objects = list(objects)[:2] if quick else list(objects)
    unknown = [o for o in objects if o not in list_objects()]
    if unknown:
        raise InvalidInput(f'run_figures: unknown object(s) {unknown}; known: {list_objects()}')
    repeats = int(repeats or (3 if quick else 10))
    if repeats < 1:
        raise InvalidInput('run_figures: repeats must be >= 1')
    if quick:
        auto_budget = min(auto_budget, 0.3)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = {'objects': [], 'repeats': repeats, 'seed': int(seed), 'auto_budget': auto_budget,
              'learning': {}, 'learning_goals': {}, 'past_cap': {}, 'error_budget': {},
              'active': {},
              'probes': {},
              'probe_goals': {},
              'skipped': {}, 'stale': [], 'files': []}
    for k, name in enumerate(objects):
        say(f'[figures] {k + 1}/{len(objects)} {name}: loading fixtures')
        try:
            surface, curves, fresh = load_poke_fixture(name, data_dir, say)
        except DataError as exc:
            result['skipped'][name] = str(exc)
            say(f'[figures]   skipped: {exc}')
            continue
        if not fresh:
            result['stale'].append(f'pokes_{name}')
        result['objects'].append(name)
        t0 = time.monotonic()
        try:
            truth = full_depth_truth(name, curves)
            cap = load_object(name).force_cap
            forces = np.concatenate([f for _, f in truth.values()])
            result['past_cap'][name] = float(np.mean(forces > cap))
        except DataError as exc:
            truth = None
            say(f'[figures]   no full-depth truth: {exc}')
        rows = figure_learning(curves, surface, sizes=sizes, repeats=repeats, seed=seed,
                               auto_budget=auto_budget, truth=truth)
        result['learning'][name] = [{k2: r[k2] for k2 in ('model', 'size', 'median', 'q25',
                                                          'q75', 'fit_s', 'truth_median')
                                     if k2 in r} for r in rows]
        result['learning_goals'][name] = learning_goals(rows)
        budget = {'own_law': own_law_rmse(curves)}
        try:
            budget['truth'] = truth_floor(name, curves)
        except DataError as exc:
            say(f'[figures]   no truth floor: {exc}')
        if 10 < len(curves):
            budget['spread'] = spread_budget(curves, surface, 10, repeats, seed)
        budget['half_reachable'] = half_goal_reachable(result['learning_goals'][name],
                                                       budget.get('truth'))
        result['error_budget'][name] = budget
        line = ', '.join(f"{r['model']}@{r['size']} {r['median']:.3f}" for r in rows
                         if r['size'] in (3, 5, 10))
        say(f'[figures]   learning curves ({time.monotonic() - t0:.0f} s): {line} N')
        if learning_only:
            continue
        t0 = time.monotonic()
        active = figure_active(curves, surface, repeats=repeats, seed=seed)
        result['active'][name] = active
        m = active['match']
        say(f"[figures]   next poke ({time.monotonic() - t0:.0f} s): random reaches "
            f"{m['target']:.3f} N at {m['random']} pokes, active at {m['active']}")
        try:
            trials, dent, fresh = load_probe_fixture(name, data_dir, say)
        except DataError as exc:
            result['skipped'][f'{name} probes'] = str(exc)
            say(f'[figures]   probe figures skipped: {exc}')
            continue
        if not fresh:
            result['stale'].append(f'probes_{name}')
        t0 = time.monotonic()
        res = figure_probes(curves, surface, trials, dent, repeats=repeats, seed=seed, say=say)
        result['probes'][name] = res
        result['probe_goals'][name] = probe_goals(res)
        say(f"[figures]   probes ({time.monotonic() - t0:.0f} s): force RMSE ours "
            f"{res['rmse']['ours']['force']:.3f} N, baseline "
            f"{res['rmse']['baseline']['force']:.3f} N, peak {res['peak_force']:.2f} N")
    result['seconds'] = time.monotonic() - started
    if result['learning']:
        plot_learning(result['learning'], out / 'fig1_learning_curves.png')
        result['files'].append('fig1_learning_curves.png')
    if result['active']:
        plot_active(result['active'], out / 'fig4_active_vs_random.png')
        result['files'].append('fig4_active_vs_random.png')
    if result['probes']:
        plot_probes(result['probes'], out / 'fig2_probe_rmse.png')
        plot_shape_constant(result['probes'], out / 'fig3_shape_constant.png')
        result['files'] += ['fig2_probe_rmse.png', 'fig3_shape_constant.png']
    (out / 'figures.md').write_text(markdown_report(result))
    result['files'].append('figures.md')
    (out / 'figures.json').write_text(json.dumps(_jsonable(result), indent=1))
    result['files'].append('figures.json')
    say(f"[figures] done in {result['seconds']:.0f} s -> {out} ({', '.join(result['files'])})")
    return result


def main(argv=None) -> int:
    """``python -m pointforce_ros.lab.figures --out DIR [--quick] [--objects a b]``."""
    import argparse

    parser = argparse.ArgumentParser(description='seed-method figures on the simulated cell')
    parser.add_argument('--out', default='out/figures', help='output directory')
    parser.add_argument('--objects', nargs='+', default=list(OBJECTS))
    parser.add_argument('--quick', action='store_true', help='2 objects, 3 subsets')
    parser.add_argument('--repeats', type=arguments.positive_int, default=None)
    parser.add_argument('--seed', type=arguments.seed, default=0)
    parser.add_argument('--auto-budget', type=arguments.positive_float, default=1.0,
                        help='Auto-ET budget, s')
    parser.add_argument('--data', default=DATA_DIR, help='folder of the cached fixtures')
    parser.add_argument('--learning-only', action='store_true',
                        help='figure 1 (learning curves) and its error budget only')
    parser.add_argument('--sizes', type=arguments.positive_int, nargs='+', default=list(SIZES),
                        help='figure 1 training-set sizes')
    args = parser.parse_args(argv)
    try:
        run_figures(args.out, args.objects, quick=args.quick, repeats=args.repeats,
                    seed=args.seed, auto_budget=args.auto_budget, data_dir=args.data,
                    learning_only=args.learning_only, sizes=tuple(args.sizes))
    except InvalidInput as exc:
        print(f'[figures] error: {exc}')
        return 2
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
