"""Scenarios of the simulated cell: which effects are switched on, with which parameters and seeds.

A scenario file (``config/scenarios/<name>.yaml``) reads::

    name: realistic
    description: what it is for
    seed: 7                      # seeds the camera and F/T noise generators
    effects:                     # each effect at most once; see pointforce_ros.sim.disturbances
      - effect: camera_depth_bias
        bias: 0.002              # SI units
      - effect: ft_noise
        force_std: 0.03
        torque_std: 0.0015

:meth:`Scenario.force_model` wraps a clean contact function ``clean(tip (3,), axis (3,)) ->
(force (3,), torque (3,))`` into the stateful force model the RTDE controller emulator calls at
500 Hz; :meth:`Scenario.camera_kwargs` gives the depth camera its bias and noise.
"""

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, NamedTuple, Optional, Tuple

import numpy as np
import yaml

from pointforce_ros.sim.disturbances import (build_effect, DelayLine, Effect, Friction, Hysteresis,
                                             PlasticSet, SeriesCompliance, solve_series_compliance,
                                             TimeOffset, ViscoelasticRelaxation)
from pointforce_ros.sim.ft_sensor import FtSensor
from pointforce_ros.paths import share_dirs
from pointforce_ros.errors import InvalidInput, ModelNotReady, reading, TEXT_ENCODING
from pointforce_ros.rotations import rotvec_to_matrix

CleanFn = Callable[[np.ndarray, np.ndarray], Tuple[np.ndarray, np.ndarray]]

_TOP_KEYS = {'name', 'description', 'seed', 'effects'}


def scenario_dirs() -> List[Path]:
    """Return the folders searched for ``<name>.yaml``: ``$POINTFORCE_SCENARIOS``, then shipped."""
    dirs = [base / 'config' / 'scenarios' for base in share_dirs()]
    extra = os.environ.get('POINTFORCE_SCENARIOS')
    if extra:
        dirs.insert(0, Path(extra))
    return dirs


def list_scenarios() -> List[str]:
    """Return the names of the scenarios found in :func:`scenario_dirs`, sorted."""
    names = set()
    for folder in scenario_dirs():
        if folder.is_dir():
            names.update(p.stem for p in folder.glob('*.yaml'))
    return sorted(names)


class Sample(NamedTuple):
    """Ground truth of the last force-model call (for recording and tests).

    ``commanded_tip`` / ``actual_tip`` (3,) metres ``base``; ``axis`` (3,) push direction;
    ``set_depth`` plastic set under the tip, metres; ``clean``, ``contact``, ``reported`` (6,)
    wrenches: clean elastic response at the actual tip, after the material/contact effects, and
    as the F/T sensor reports it (delayed, noisy, tared); ``evaluations`` clean calls made.
    """

    t: float
    commanded_tip: np.ndarray
    actual_tip: np.ndarray
    axis: np.ndarray
    set_depth: float
    clean: np.ndarray
    contact: np.ndarray
    reported: np.ndarray
    evaluations: int


class CellForceModel:
    """Stateful force model: clean contact physics plus a scenario's effects, as the F/T reports.

    Implements the RTDE emulator's plug-in interface ``wrench(tcp_pose6, t) -> (6,)``. The TCP
    is the probe tip and the probe pushes along the TCP's +z axis. Per call: plastic set shifts
    the surface, series compliance moves the actual tip back along the axis (solved with all the
    force effects in the loop), viscoelastic relaxation, hysteresis and friction shape the
    wrench, the time offset delays it and the F/T sensor adds bias, drift and noise and subtracts
    its tare.

    Args:
        clean_fn: ``clean(tip (3,), axis (3,)) -> (force (3,), torque (3,))``: frictionless,
            quasi-static, elastic reaction of the object on the probe, base frame, N and N m.
        effects: effects of the ``geometry``, ``material``, ``contact`` and ``stream`` stages
            (camera effects are ignored here; pass F/T effects through ``ft_sensor``).
        ft_sensor: the sensor model; an ideal one (no noise, bias or drift) if None.

    Raises:
        InvalidInput: the same effect given twice.

    """

    def __init__(self, clean_fn: CleanFn, effects=(), *, ft_sensor: Optional[FtSensor] = None):
        self._clean = clean_fn
        by_type: Dict[type, Effect] = {}
        for eff in effects:
            if type(eff) in by_type:
                raise InvalidInput(f'effect {eff.name} given twice')
            by_type[type(eff)] = eff
        self.effects = tuple(effects)
        self._visco: Optional[ViscoelasticRelaxation] = by_type.get(ViscoelasticRelaxation)
        self._hyst: Optional[Hysteresis] = by_type.get(Hysteresis)
        self._fric: Optional[Friction] = by_type.get(Friction)
        series = by_type.get(SeriesCompliance)
        self._k_series = series.stiffness if series is not None else None
        plastic = by_type.get(PlasticSet)
        self.plastic = plastic.memory() if plastic is not None else None
        offset = by_type.get(TimeOffset)
        self._delay = DelayLine(offset.offset if offset is not None else 0.0)
        self.sensor = ft_sensor if ft_sensor is not None else FtSensor()
        self.last: Optional[Sample] = None
        self.reset()

    def reset(self) -> None:
        """Return to a fresh object at rest: no history, no plastic set, sensor offset zero."""
        self._t: Optional[float] = None
        self._states = (None, None, None)
        self._u = 0.0
        self._kc = 0.0
        self._delayed = np.zeros(6)
        self._rot = np.eye(3)
        self._delay.reset()
        if self.plastic is not None:
            self.plastic.reset()
        self.sensor.offset = np.zeros(6)
        self.sensor.tare_time = None
        self.last = None

    def reset_poke(self) -> None:
        """Mark the end of a poke: close the contact episode the plastic set is counting.

        The material histories (relaxation, hysteresis) are physical and carry on; they fade with
        time and motion on their own.
        """
        if self.plastic is not None:
            self.plastic.end_poke()
        self._u = 0.0

    def tare(self, t: Optional[float] = None) -> None:
        """Zero the F/T sensor at time ``t`` (default: the last call's time) on the current load.

        Raises:
            InvalidInput: non-finite time.

        """
        t = self._t if t is None else float(t)
        self.sensor.tare(self._delayed, 0.0 if t is None else t, self._rot)

    def _evaluate(self, tip_cmd, axis, set_depth, u, t):
        """Wrench pipeline for retraction ``u``; returns (contact, clean, states, tip)."""
        tip = tip_cmd - u * axis
        force, torque = self._clean(tip - set_depth * axis, axis)
        clean = np.concatenate([np.asarray(force, dtype=np.float64),
                                np.asarray(torque, dtype=np.float64)])
        s_visco, s_hyst, s_fric = self._states
        wrench = clean
        if self._visco is not None:
            wrench, s_visco = self._visco.step(s_visco, wrench, t)
        if self._hyst is not None:
            wrench, s_hyst = self._hyst.step(s_hyst, wrench, float(tip @ axis))
        if self._fric is not None:
            wrench, s_fric = self._fric.step(s_fric, wrench, tip, t)
        return wrench, clean, (s_visco, s_hyst, s_fric), tip

    def wrench(self, tcp_pose6, t: float) -> np.ndarray:
        """Return what the F/T reports for a TCP pose ``[x, y, z, rx, ry, rz]`` at time ``t``.

        Args:
            tcp_pose6: (6,) TCP (= probe tip) position in metres and rotation vector, ``base``.
            t: controller time, seconds, non-decreasing between calls.

        Returns:
            (6,) ``[fx, fy, fz, tx, ty, tz]`` base-oriented, N and N m, as ``actual_TCP_force``.

        Raises:
            InvalidInput: a pose that is not 6 finite numbers, or time going backwards.
            NotConverged: the series-compliance solve failed.

        """
        pose = np.asarray(tcp_pose6, dtype=np.float64)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            raise InvalidInput(f'tcp_pose6: need 6 finite numbers [x, y, z, rx, ry, rz], got '
                               f'{tcp_pose6!r}')
        t = float(t)
        if not np.isfinite(t) or (self._t is not None and t < self._t):
            raise InvalidInput(f'force model time must be finite and non-decreasing: got {t} '
                               f'after {self._t}')
        rot = rotvec_to_matrix(pose[3:])
        axis = rot[:, 2]
        tip_cmd = pose[:3]
        set_depth = (self.plastic.depth_offset(tip_cmd, axis) if self.plastic is not None
                     else 0.0)
        evaluations = 1
        if self._k_series is None:
            result = self._evaluate(tip_cmd, axis, set_depth, 0.0, t)
        else:
            box = []

            def push_back(u):
                box[:] = [self._evaluate(tip_cmd, axis, set_depth, u, t)]
                return -float(box[0][0][:3] @ axis)

            u, k_c, evaluations = solve_series_compliance(
                push_back, self._k_series, guess=self._u, contact_stiffness=self._kc)
            result = box[0]
            self._u, self._kc = u, k_c
        contact, clean, self._states, tip = result
        if self.plastic is not None:
            self.plastic.observe(-float(contact[:3] @ axis), tip)
        self._delayed = self._delay(t, contact)
        self._rot = rot
        self._t = t
        reported = self.sensor.read(self._delayed, t, rot)
        self.last = Sample(t, tip_cmd, tip, axis, set_depth, clean, contact, reported,
                           evaluations)
        return reported


@dataclass(frozen=True)
class Scenario:
    """A named set of effects with their parameters and a seed.

    Attributes:
        name: scenario name.
        description: one line on what it is for.
        seed: base seed of the camera and F/T noise generators.
        effects: the switched-on effects, each at most once.
        source: the file it was read from, if any.

    Raises:
        InvalidInput: an effect given twice or a non-integer seed.

    """

    name: str
    description: str = ''
    seed: int = 0
    effects: Tuple[Effect, ...] = ()
    source: Optional[str] = None

    def __post_init__(self):
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
            raise InvalidInput(f'scenario {self.name}: seed must be an integer, got '
                               f'{self.seed!r}')
        names = [eff.name for eff in self.effects]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise InvalidInput(f'scenario {self.name}: effect(s) {dupes} listed more than once')
        object.__setattr__(self, 'effects', tuple(self.effects))
        object.__setattr__(self, 'seed', int(self.seed))

    def effect(self, name: str) -> Optional[Effect]:
        """Return the effect called ``name``, or None when it is off."""
        return next((eff for eff in self.effects if eff.name == name), None)

    def _child_seed(self, *key: int) -> int:
        return int(np.random.SeedSequence([self.seed, *key]).generate_state(1)[0])

    def camera_kwargs(self, index: int = 0) -> dict:
        """Keyword arguments for ``DepthCamera`` (bias, noise, seed of camera ``index``)."""
        kwargs = {'depth_bias': 0.0, 'noise_a': 0.0, 'noise_b': 0.0}
        for eff in self.effects:
            if eff.stage == 'camera':
                kwargs.update(eff.camera_kwargs())
        kwargs['seed'] = self._child_seed(1, int(index))
        return kwargs

    def ft_sensor(self) -> FtSensor:
        """Return a fresh F/T sensor with this scenario's noise, bias and drift."""
        kwargs = {}
        for eff in self.effects:
            if eff.stage == 'ft':
                kwargs.update(eff.ft_kwargs())
        return FtSensor(seed=self._child_seed(2), **kwargs)

    def force_model(self, clean_fn: CleanFn, *, ft_sensor: Optional[FtSensor] = None
                    ) -> CellForceModel:
        """Wrap ``clean_fn`` into a fresh stateful :class:`CellForceModel` for this scenario.

        Args:
            clean_fn: ``clean(tip (3,), axis (3,)) -> (force (3,), torque (3,))``, base frame.
            ft_sensor: overrides the scenario's sensor (e.g. ``FtSensor()`` for an ideal one).

        """
        physical = [eff for eff in self.effects if eff.stage not in ('camera', 'ft')]
        return CellForceModel(clean_fn, physical,
                              ft_sensor=ft_sensor if ft_sensor is not None else self.ft_sensor())

    def to_dict(self) -> dict:
        """Return the YAML-ready mapping of this scenario."""
        return {'name': self.name, 'description': self.description, 'seed': self.seed,
                'effects': [{'effect': eff.name, **eff.params()} for eff in self.effects]}


def scenario_from_dict(data, source: Optional[str] = None) -> Scenario:
    """Build a :class:`Scenario` from its YAML mapping.

    Raises:
        InvalidInput: not a mapping, unknown top-level keys, bad effects or seed.

    """
    where = f' in {source}' if source else ''
    if not isinstance(data, dict):
        raise InvalidInput(f'scenario{where}: expected a mapping, got {type(data).__name__}')
    unknown = set(data) - _TOP_KEYS
    if unknown:
        raise InvalidInput(f'scenario{where}: unknown key(s) {sorted(unknown)}; expected '
                           f'{sorted(_TOP_KEYS)}')
    if not data.get('name'):
        raise InvalidInput(f'scenario{where}: needs a "name"')
    effects = data.get('effects') or []
    if not isinstance(effects, list):
        raise InvalidInput(f'scenario{where}: "effects" must be a list of mappings')
    return Scenario(name=str(data['name']), description=str(data.get('description', '')),
                    seed=data.get('seed', 0), effects=tuple(build_effect(e) for e in effects),
                    source=source)


def load_scenario(name_or_path) -> Scenario:
    """Load a scenario by name (``config/scenarios/<name>.yaml``) or by path to a YAML file.

    Raises:
        InvalidInput: unknown name (the message lists the known ones) or invalid content.
        DataError: the file cannot be read or is not valid YAML.

    """
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith(('.yaml', '.yml')) or os.sep in text):
        found = [d / f'{text}.yaml' for d in scenario_dirs() if (d / f'{text}.yaml').is_file()]
        if not found:
            raise InvalidInput(f'unknown scenario {text!r}; known: {", ".join(list_scenarios())}')
        path = found[0]
    with reading(path, 'scenario file (YAML)'):
        with open(path, encoding=TEXT_ENCODING) as stream:
            data = yaml.safe_load(stream)
    return scenario_from_dict(data, source=str(path))


@dataclass(frozen=True)
class HalfSpaceContact:
    """Analytic clean contact: a flat elastic top at height ``z0`` (normal +z of ``base``).

    The push-back is ``k d**exponent`` along +z for a tip ``d = z0 - tip_z`` below the top, with
    ``k = k0 * (1 + ripple * sin(2 pi x / wavelength) * sin(2 pi y / wavelength))`` so that the
    stiffness varies over the surface; no torque. ``exponent`` 1.5 is Hertz-like, 1.0 a spring.
    A stand-in for the FEM live path in tests and demos; units N, m.
    """

    z0: float = 0.04
    k0: float = 1.4e4
    exponent: float = 1.5
    ripple: float = 0.0
    wavelength: float = 0.05

    def __call__(self, tip: np.ndarray, axis: np.ndarray):
        """Return ``(force (3,), torque (3,))`` on a probe tip at ``tip`` (3,), metres."""
        depth = self.z0 - float(tip[2])
        if depth <= 0.0:
            return np.zeros(3), np.zeros(3)
        k = self.k0
        if self.ripple:
            w = 2.0 * np.pi / self.wavelength
            k = k * (1.0 + self.ripple * np.sin(w * tip[0]) * np.sin(w * tip[1]))
        return np.array([0.0, 0.0, k * depth ** self.exponent]), np.zeros(3)


def make_force_model(scenario: str = 'clean', object_name: Optional[str] = 'plush',
                     halfspace: Optional[dict] = None) -> CellForceModel:
    """Build the emulator's force model: clean contact physics + a scenario's effects.

    Spec string for the emulator: ``pointforce_ros.sim.scenario:make_force_model`` with JSON
    keyword arguments, e.g. ``{"scenario": "realistic", "object_name": "plush"}``.

    Args:
        scenario: scenario name or path.
        object_name: object of ``config/objects`` whose precomputed FEM live contact
            (``LiveContact.load(name).point_probe_wrench``) is the clean physics.
        halfspace: keyword arguments of :class:`HalfSpaceContact`; when given it replaces the
            FEM object (no precomputed data needed).

    Raises:
        InvalidInput: unknown scenario or bad half-space parameters.
        ModelNotReady: the FEM live path is not available.
        DataError: the object's live cache is missing or stale (the message says how to build
            it).

    """
    spec = load_scenario(scenario)
    if halfspace is not None:
        try:
            clean = HalfSpaceContact(**halfspace)
        except TypeError as exc:
            raise InvalidInput(f'make_force_model: bad halfspace parameters: {exc}')
        return spec.force_model(clean)
    live_cls = None
    for module_name in ('pointforce_ros.sim.fem', 'pointforce_ros.sim.fem.live'):
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue
        live_cls = getattr(module, 'LiveContact', None)
        if live_cls is not None:
            break
    if live_cls is None:
        raise ModelNotReady('FEM live contact path (LiveContact) is not available; pass '
                            'halfspace={...} for an analytic object')
    # never build a missing or stale cache here (minutes of FEM inside the emulator's start):
    # fail with the command that builds it
    live = live_cls.load(object_name, build=False)
    return spec.force_model(live.point_probe_wrench)
