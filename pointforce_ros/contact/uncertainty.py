"""An uncertainty with every contact answer: the wrench's standard deviation from its sources.

A contact query's wrench depends on the learned point response (the baked force table, which
carries the model's predictive standard deviation per surface point and depth) and on the
shape function's constant ``c`` and tail decay length ``L`` (identified from calibration
pushes, :mod:`pointforce_ros.contact.identify`). :func:`wrench_uncertainty` propagates both to
the wrench by linearisation, with a finite difference per source (four contact solves per
query, all through the public :class:`~pointforce_ros.contact.simulator.ContactSimulator`):

* **response**: the force table raised by one standard deviation wherever it is a contact
  force (above :data:`~pointforce_ros.response.baked.ONSET_FORCE`; the errors of a smooth
  process over a probe's footprint, a few centimetres, move together: full correlation is the
  conservative limit and what one extra solve can give; before each point's onset the table
  is not a contact force and is not raised);
* **shape**: ``(log c, 1 / L)`` moved by one standard deviation each (``1 / L`` so that the
  paper's ``g``, ``L = inf``, is the ordinary point ``1 / L = 0``); the two differences form the
  Jacobian ``J`` and the shape part of the covariance is ``J S J^T`` with ``S`` the 2x2
  covariance of ``(log c, 1 / L [1/m])`` (:func:`~pointforce_ros.contact.identify.
  calibrate_shape` gives it from the calibration pushes: the fit's covariance widened by the
  spread of ``c`` between the pushes);
* **relative**: an optional share of the wrench (model discrepancy not in the two above;
  :func:`~pointforce_ros.contact.identify.calibrate_shape` measures it on pushes the fit has
  not seen: a fit's own residual understates it, issue 17);
* **centre**: with the relative share, where the force acts. A pressure off by that share of
  itself is off in its distribution too: a linear gradient of the same relative size along
  each principal axis of the contact (the mode that leaves the total and moves the centre of
  pressure) shifts the centre by the share times the force's spread (the RMS distance of the
  contact force from its centre, per axis; ``pressure_spreads`` of
  :meth:`~pointforce_ros.contact.simulator.ContactSimulator.query_batch`), and turns the
  wrench by ``shift x F``. No new constant: a 60 mm paddle or a cylinder along a bone spreads
  its force over centimetres, and a 15 % share then moves it by millimetres, which the torque
  about a tool tip feels in full while the share of that (near zero) torque does not (the
  demo's torque components about the probe tips: 69 % inside their 90 % intervals without
  this part, 95 % with it, 8 stored lamb demo models, ``data/fem/demo_torque_coverage.py``;
  issue 17);
* **lateral**: an optional share of the normal force (along the approach) as the standard
  deviation of the force across the approach (isotropic in that plane): the contact model
  carries no friction or tangential stiffness, so a measured lateral force (a sloped surface,
  friction) is a discrepancy of that size. It acts where the contact force acts (the centre of
  pressure, ``r`` from the torque centre), so it carries a torque ``r x dF`` as well: with the
  torque centre at a wrist 10 cm above the contact, a lateral share of 3 % of a 10 N push is
  30 mN m of torque the other parts do not hold.

The parts are independent and add in variance. The perturbed simulators are built once
per model and kept (the first query on a new model or approach direction pays for their spatial
structures).
"""

import threading
from dataclasses import dataclass, field
from typing import Dict, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
from scipy.special import ndtri

from pointforce_ros.contact.simulator import check_neighbours, ContactSimulator
from pointforce_ros.errors import InvalidInput
from pointforce_ros.response.baked import BakedResponse, ONSET_FORCE
from pointforce_ros.types import Mesh, Pose

Z90 = 1.6448536269514722
"""Half-width of a two-sided 90 % normal interval in standard deviations."""

ContactModel = object
"""A :class:`pointforce_ros.model.files.ContactModel` (taken by its fields: ``surface``,
``response``, ``shape_constant``, ``shape_decay``, ``meta``; ``contact`` does not import the
``model`` wing, which imports it)."""

MODEL_FIELDS = ('surface', 'response', 'shape_constant', 'shape_decay', 'meta')


@dataclass(frozen=True)
class WrenchUncertainty:
    """Wrench of a contact query with its standard deviation (``base``).

    Attributes:
        wrench: (B, 6) ``[fx, fy, fz, tx, ty, tz]`` of the model's own simulator, N and N m.
        std: (B, 6) standard deviation of each component, N and N m.
        parts: source -> (B, 6) standard deviation from that source alone (``'response'``,
            ``'shape'``, ``'relative'``, ``'centre'``, ``'lateral'``); ``std**2`` is the sum
            of their squares.

    """

    wrench: np.ndarray
    std: np.ndarray
    parts: Mapping[str, np.ndarray] = field(default_factory=dict)

    def interval(self, level: float = 0.9) -> Tuple[np.ndarray, np.ndarray]:
        """Two-sided normal interval ``(low, high)`` (B, 6) at ``level`` (0.9: 1.645 sigma).

        Raises:
            InvalidInput: ``level`` outside (0, 1).

        """
        if not 0.0 < level < 1.0:
            raise InvalidInput(f'interval level must be in (0, 1), got {level}')
        z = float(ndtri(0.5 + level / 2))
        return self.wrench - z * self.std, self.wrench + z * self.std


class _Perturbed:
    """The model's simulator and its one-sigma response copy, built once per model."""

    def __init__(self, model: ContactModel, spacing: float, neighbours: Optional[str]):
        response = model.response
        law = getattr(model, 'shape_decay_law', None)   # None: the simulator's default
        near = getattr(model, 'shape_near', 'paper')
        self.nominal = ContactSimulator(model.surface, response, model.shape_constant,
                                        spacing=spacing, decay=model.shape_decay,
                                        decay_law=law, near=near, neighbours=neighbours)
        self.raised = None
        if response.std is not None:
            # raised where the table is a contact force only (above the onset force): the
            # spread before the onset (the process smoothing over it) would put every point
            # near the mesh in contact and add force no contact makes (+1.4 N on 6 N sphere
            # queries, where raising the depths > 0 gave +1.2 N, as scaling the table by its
            # 19 %; not measured again with this mask). Not at depths > 0: where camera bias
            # put the onset below the observed surface (d0 < 0) a shallow contact lies wholly
            # at d <= 0, and its response part was zero (the dome's first probe steps: 0.6 N
            # predicted, 0.9 N true, std 0.03 N)
            forces = response.forces + response.std * (response.forces > ONSET_FORCE)
            ratio = np.where(response.forces[:, -1] > 0,
                             forces[:, -1] / np.maximum(response.forces[:, -1], 1e-12), 1.0)
            raised = BakedResponse(depths=response.depths, forces=forces,
                                   slopes=response.slopes * ratio, std=None,
                                   version=response.version, meta=response.meta)
            self.raised = ContactSimulator(model.surface, raised, model.shape_constant,
                                           spacing=spacing, decay=model.shape_decay,
                                           decay_law=law, near=near, neighbours=neighbours)


_CACHE: Dict[int, Tuple[object, float, Optional[str], _Perturbed]] = {}
_LOCK = threading.Lock()


def _perturbed(model: ContactModel, spacing: float, neighbours: Optional[str]) -> _Perturbed:
    key = id(model)
    with _LOCK:
        hit = _CACHE.get(key)
        if hit is not None and hit[0] is model and hit[1:3] == (spacing, neighbours):
            return hit[3]
    built = _Perturbed(model, spacing, neighbours)
    with _LOCK:
        if len(_CACHE) >= 4:
            _CACHE.pop(next(iter(_CACHE)))
        _CACHE[key] = (model, spacing, neighbours, built)
    return built


def _check_cov(shape_cov) -> np.ndarray:
    cov = np.asarray(shape_cov, dtype=np.float64)
    if cov.shape != (2, 2) or not np.all(np.isfinite(cov)) or not np.allclose(cov, cov.T) \
            or np.any(np.diag(cov) < 0):
        raise InvalidInput('shape_cov: need a finite symmetric 2x2 covariance of (log c, 1/L '
                           f'[1/m]) with a non-negative diagonal, got {cov.tolist()}')
    return cov


SOURCE_KEYS = ('shape_cov', 'relative_std', 'lateral_std')
"""The uncertainty sources a model's ``meta`` may carry (:func:`uncertainty_sources`)."""


def _share(value, name: str) -> float:
    try:
        share = float(value)
    except (TypeError, ValueError):
        raise InvalidInput(f'{name}: must be a number, got {value!r}') from None
    if not (np.isfinite(share) and share >= 0):
        raise InvalidInput(f'{name}: must be a finite share >= 0, got {share}')
    return share


def uncertainty_sources(shape_cov=None, relative_std=0.0, lateral_std=0.0) -> dict:
    """Check the wrench's uncertainty sources; return them in the model-``meta`` form (JSON).

    Args:
        shape_cov: (2, 2) covariance of ``(log c, 1 / L [1/m])`` from the calibration pushes
            (:func:`~pointforce_ros.contact.identify.calibrate_shape`), or a flat list of its
            four entries; ``None`` or all zeros: none.
        relative_std: share of the wrench not explained by the model (>= 0).
        lateral_std: share of the normal force across the approach (>= 0).

    Returns:
        ``{'shape_cov': [[..], [..]], 'relative_std': .., 'lateral_std': ..}`` without the
        sources that are zero (what :func:`wrench_uncertainty` reads from ``model.meta``).

    Raises:
        InvalidInput: a malformed covariance or a share that is not finite and >= 0.

    """
    out = {}
    if shape_cov is not None:
        flat = np.asarray(shape_cov, dtype=np.float64).ravel()
        if flat.size not in (0, 4):
            raise InvalidInput(f'shape_cov: need the 4 entries of a 2x2 covariance of (log c, '
                               f'1/L [1/m]), got {flat.size}')
        if flat.size and np.any(flat != 0):
            out['shape_cov'] = _check_cov(flat.reshape(2, 2)).tolist()
    for name, value in (('relative_std', relative_std), ('lateral_std', lateral_std)):
        share = _share(value, name)
        if share > 0:
            out[name] = share
    return out


def lateral_share(simulator: ContactSimulator, pokes) -> float:
    """Return the RMS measured force across each push not predicted, over the RMS normal force.

    The ``lateral_std`` of a calibration: the contact model has no friction or tangential
    stiffness, so the force across the approach it misses at the calibration pushes is the
    share it will miss elsewhere (per component: two per push).

    Args:
        simulator: the calibrated simulator.
        pokes: ``(mesh, poses, approach, measured_force (n, 3))`` per push, or a mapping of
            them.

    """
    pokes = list(pokes.values()) if isinstance(pokes, Mapping) else list(pokes)
    across, normal = [], []
    for mesh, poses, approach, measured in pokes:
        a = np.asarray(approach, dtype=float)
        measured = np.asarray(measured, dtype=float)
        err = measured - simulator.query_batch(mesh, poses, a, np.zeros(3)).wrenches[:, :3]
        across.append(err - np.outer(err @ a, a))
        normal.append(measured @ a)
    across, normal = np.concatenate(across), np.concatenate(normal)
    return float(np.sqrt(np.sum(across ** 2) / (2 * len(normal)))
                 / np.sqrt(np.mean(normal ** 2)))


def _cross_matrices(v: np.ndarray) -> np.ndarray:
    """(B, 3, 3) ``[v]x`` of each row of ``v`` (B, 3): ``[v]x w = v x w``."""
    cross = np.zeros((len(v), 3, 3))
    cross[:, 0, 1], cross[:, 0, 2] = -v[:, 2], v[:, 1]
    cross[:, 1, 0], cross[:, 1, 2] = v[:, 2], -v[:, 0]
    cross[:, 2, 0], cross[:, 2, 1] = -v[:, 1], v[:, 0]
    return cross


def _lever(r: np.ndarray, a: np.ndarray) -> np.ndarray:
    """(B, 3) std of ``r x dF`` per unit std of ``dF`` (``dF`` isotropic across ``a``).

    ``Cov(r x dF) = [r]x (I - a a^T) [r]x^T`` per unit variance; its diagonal's square root.
    """
    cross = _cross_matrices(r)
    plane = np.eye(3) - np.outer(a, a)
    return np.sqrt(np.maximum(np.einsum('bij,jk,bik->bi', cross, plane, cross), 0.0))


def _centre_part(base: np.ndarray, spreads: np.ndarray, rel: float, approach) -> np.ndarray:
    """(B, 6) std of the torque of a centre of pressure moved by ``rel`` of the force's spread.

    The shift ``s`` across the approach has covariance ``rel**2 P M P`` (``M`` the (3, 3)
    second moment of the contact force about its centre, ``P`` the projector across
    ``approach``); the torque it carries is ``s x F``, covariance ``[F]x C [F]x^T``.
    """
    a = np.asarray(approach, dtype=np.float64)
    a = a / np.linalg.norm(a)
    plane = np.eye(3) - np.outer(a, a)
    cov = rel ** 2 * np.einsum('ij,bjk,kl->bil', plane, spreads, plane)
    f = base[:, :3]
    cross = _cross_matrices(f)
    out = np.zeros_like(base)
    out[:, 3:] = np.sqrt(np.maximum(np.einsum('bij,bjk,bik->bi', cross, cov, cross), 0.0))
    return out


def wrench_uncertainty(model: ContactModel, mesh: Mesh, poses: Union[Pose, Sequence[Pose]],
                       approach, torque_centre, *, shape_cov=None,
                       relative_std: Optional[float] = None, response: bool = True,
                       spacing: float = 0.003, lateral_std: Optional[float] = None,
                       centre: bool = True,
                       neighbours: Optional[str] = None) -> WrenchUncertainty:
    """Return the standard deviation of the wrench of ``mesh`` at ``poses`` (module docstring).

    Args:
        model: the contact model the service answers from; its baked response's ``std``
            (N, K) is the point model's spread (none: no response part).
        mesh: rigid mesh in its own frame.
        poses: one :class:`Pose` or ``B`` of them (or a (B, 7) array), ``base``.
        approach: (3,) unit push direction, ``base``.
        torque_centre: (3,) or (B, 3), metres, ``base``.
        shape_cov: (2, 2) covariance of ``(log c, 1 / L)`` (dimensionless, 1/m); ``None``:
            ``model.meta['shape_cov']`` if present, else no shape part.
        relative_std: share of the wrench added as an independent discrepancy (>= 0);
            ``None``: ``model.meta['relative_std']`` if present, else 0.
        response: include the response part.
        lateral_std: share of the normal force given to each force component across the
            approach (>= 0), with the torque it carries from the centre of pressure;
            ``None``: ``model.meta['lateral_std']`` if present, else 0.
        spacing: rigid-mesh sampling step of the simulator, metres (the service's).
        neighbours: the simulator's neighbour rule (the service's; ``None``: the default,
            :data:`~pointforce_ros.contact.simulator.NEIGHBOURS`).
        centre: with a relative share, also the torque of the centre of pressure it moves
            (module docstring; ``False`` leaves it out, for comparisons).

    Returns:
        :class:`WrenchUncertainty` with ``B`` rows (1 for a single pose).

    Raises:
        InvalidInput: a malformed covariance or share, or a query the simulator refuses.

    """
    if not all(hasattr(model, name) for name in MODEL_FIELDS):
        raise InvalidInput(f'wrench_uncertainty: expected a ContactModel, got '
                           f'{type(model).__name__}')
    if shape_cov is None:
        shape_cov = model.meta.get('shape_cov', np.zeros((2, 2)))
    cov = _check_cov(shape_cov)
    rel = float(model.meta.get('relative_std', 0.0) if relative_std is None else relative_std)
    if not (np.isfinite(rel) and rel >= 0):
        raise InvalidInput(f'relative_std: must be a finite share >= 0, got {rel}')
    lat = float(model.meta.get('lateral_std', 0.0) if lateral_std is None else lateral_std)
    if not (np.isfinite(lat) and lat >= 0):
        raise InvalidInput(f'lateral_std: must be a finite share >= 0, got {lat}')
    poses = [poses] if isinstance(poses, Pose) else poses
    sims = _perturbed(model, float(spacing),
                      None if neighbours is None else check_neighbours(neighbours))
    nominal = sims.nominal.query_batch(mesh, poses, approach, torque_centre,
                                       centre_of_pressure=lat > 0 or (rel > 0 and centre))
    base = nominal.wrenches
    parts = {}
    if response and sims.raised is not None:
        parts['response'] = np.abs(
            sims.raised.query_batch(mesh, poses, approach, torque_centre).wrenches - base)
    if np.any(np.diag(cov) > 0):
        c, decay = model.shape_constant, model.shape_decay
        inv = 0.0 if not np.isfinite(decay) else 1.0 / decay
        steps = np.sqrt(np.diag(cov))
        jac = np.zeros(base.shape + (2,))
        if steps[0] > 0:
            sim = sims.nominal.with_shape_constant(c * np.exp(steps[0]))
            jac[..., 0] = (sim.query_batch(mesh, poses, approach, torque_centre).wrenches
                           - base) / steps[0]
        if steps[1] > 0:
            sim = sims.nominal.with_shape_constant(c, 1.0 / (inv + steps[1]))
            jac[..., 1] = (sim.query_batch(mesh, poses, approach, torque_centre).wrenches
                           - base) / steps[1]
        var = np.einsum('bki,ij,bkj->bk', jac, cov, jac)
        parts['shape'] = np.sqrt(np.maximum(var, 0.0))
    if rel > 0:
        parts['relative'] = rel * np.abs(base)
        if centre:
            parts['centre'] = _centre_part(base, nominal.pressure_spreads, rel, approach)
    if lat > 0:
        a = np.asarray(approach, dtype=np.float64)
        a = a / np.linalg.norm(a)
        normal = np.abs(base[:, :3] @ a)                               # (B,)
        lateral = np.zeros_like(base)
        lateral[:, :3] = lat * normal[:, None] * np.sqrt(np.maximum(1.0 - a ** 2, 0.0))
        lateral[:, 3:] = lat * normal[:, None] * _lever(
            nominal.centres_of_pressure - nominal.torque_centres, a)
        parts['lateral'] = lateral
    total = np.zeros_like(base)
    for part in parts.values():
        total += part ** 2
    return WrenchUncertainty(wrench=base, std=np.sqrt(total), parts=parts)
