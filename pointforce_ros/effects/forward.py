"""Forward terms of accepted effects for the contact-wrench service (pure, no ROS).

The learner removes every accepted effect from the pokes before it learns (see
:mod:`pointforce_ros.effects.correct`), so a saved model's baked table is the clean,
quasi-static, frictionless elastic response of the object past its *true* surface. What the
service adds back at query time is decided per effect by what a planner's rigid body would
really meet:

* ``surface_offset`` (camera depth bias) and ``plastic_set``: the true surface differs from the
  camera's. The learner saves the corrected surface in the model and lists the effects in
  ``meta['surface_corrected']``; :func:`model_surface` applies an offset the file has not
  applied yet (a model written by other tools). The plastic set needs the poked spots, which
  only the learner knows.
* ``series_compliance``: the table or arm the object rests on (or the arm that presses) gives
  way by ``compliance * F`` along the approach, whatever body presses: the wrench at a
  commanded pose is the one at the pose moved back by that amount, solved for the *total*
  normal force (:func:`solve_retreat`). A model learned without the correction carries the
  compliance in every point's curve with that point's own force only, so it is too stiff
  wherever several points share the load (a wide body deflects the table by the sum).
* ``viscoelastic``: the table is the instantaneous elastic response. The service scales it by
  the fraction left after the pose has been held ``hold_time`` seconds after a fast approach,
  ``1 - sum g_i (1 - exp(-hold_time / tau_i))`` (:func:`hold_fraction`); ``hold_time = 0`` (the
  default) answers the instantaneous force, an upper bound, which is the safe side for force
  limits.
* ``ft_bias``, ``ft_drift``, ``time_offset`` belong to the measuring chain, ``hysteresis``
  leaves the loading branch the table holds, ``friction`` is tangential and path-dependent
  (the service answers normal contact): none has a forward term.
"""

from dataclasses import dataclass
from typing import Callable, Mapping, Tuple

import numpy as np

from pointforce_ros.effects.accepted import correct_surface, effects_from_dict
from pointforce_ros.effects.library import prony_terms
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Surface

SURFACE_EFFECTS = ('surface_offset', 'plastic_set')
"""Effects that move the surface (applied to the model's surface, not at query time)."""

NO_FORWARD_TERM = {
    'ft_bias': 'F/T sensor offset: part of the measuring chain',
    'ft_drift': 'F/T sensor drift: part of the measuring chain',
    'time_offset': 'pose/force stream offset: part of the measuring chain',
    'hysteresis': 'the model holds the loading branch; unloading needs the path',
    'friction': 'tangential and path-dependent; the service answers normal contact',
    'spatial_coupling': 'a model parameter: the model must be learned with this shape '
                        'constant (the learner\'s shape_constant), not a term added to answers',
}
"""Accepted effects the service does not add back, with the reason."""


@dataclass(frozen=True)
class ForwardTerms:
    """What the service applies to every answer of one model.

    Attributes:
        compliance: series compliance along the approach, m/N (0: none).
        force_scale: factor on the elastic wrench (viscoelastic hold fraction; 1: none).
        applied: names of the effects with a forward term in use.
        skipped: effect name -> why it has none (or why it is switched off).

    """

    compliance: float = 0.0
    force_scale: float = 1.0
    applied: Tuple[str, ...] = ()
    skipped: Tuple[Tuple[str, str], ...] = ()

    @classmethod
    def of(cls, effects: Mapping, *, series_compliance: bool = True,
           hold_time: float = 0.0) -> 'ForwardTerms':
        """Forward terms of stored ``effects`` (``ContactModel.effects``).

        Args:
            effects: ``{name: {param: value}}``.
            series_compliance: apply an accepted series compliance (False when it was the
                poking arm's own and the planner's robot is another one).
            hold_time: seconds the pose has been held after a fast approach (viscoelastic).

        Raises:
            InvalidInput: bad effects or a negative/non-finite ``hold_time``.

        """
        effects = effects_from_dict(effects)
        hold_time = float(hold_time)
        if not np.isfinite(hold_time) or hold_time < 0:
            raise InvalidInput(f'hold_time: must be a finite number >= 0 s, got {hold_time}')
        applied, skipped = [], []
        compliance, scale = 0.0, 1.0
        for name in effects:
            if name == 'series_compliance':
                if series_compliance:
                    compliance = float(effects[name]['compliance'])
                    applied.append(name)
                else:
                    skipped.append((name, 'switched off (series_compliance: false)'))
            elif name == 'viscoelastic':
                scale = hold_fraction(effects[name], hold_time)
                applied.append(name)
            elif name in SURFACE_EFFECTS:
                applied.append(name)
            else:
                skipped.append((name, NO_FORWARD_TERM[name]))
        return cls(compliance, scale, tuple(applied), tuple(skipped))

    @property
    def identity(self) -> bool:
        """Whether answers are the simulator's unchanged."""
        return self.compliance <= 0 and self.force_scale == 1.0


def hold_fraction(visco: Mapping, hold_time: float) -> float:
    """Force left after holding ``hold_time`` s: ``1 - sum g_i (1 - exp(-t / tau_i))``.

    ``visco`` holds the library's Prony series (``e1..eK``, ``tau1..tauK``) or one term
    (``g``, ``tau``); see :func:`~pointforce_ros.effects.library.prony_terms`.
    """
    g, tau = prony_terms(visco)
    return float(1.0 - np.sum(g * -np.expm1(-float(hold_time) / tau)))


def model_surface(model) -> Surface:
    """Return the surface the service should press against.

    That is ``model.surface`` with a surface offset applied unless
    ``model.meta['surface_corrected']`` says it already is. A ``plastic_set`` without the
    learner's correction cannot be applied (the poked spots are not in the file); the surface
    is then returned as stored.
    """
    effects = effects_from_dict(getattr(model, 'effects', {}) or {})
    done = set((getattr(model, 'meta', {}) or {}).get('surface_corrected', ()))
    todo = {k: v for k, v in effects.items() if k == 'surface_offset' and k not in done}
    return correct_surface(model.surface, todo) if todo else model.surface


def solve_retreat(normal_force: Callable[[np.ndarray, np.ndarray], np.ndarray],
                  compliance: float, n: int, tol: float = 1e-8,
                  max_iter: int = 40) -> Tuple[np.ndarray, int]:
    """Solve ``s = compliance * F_n(s)`` for the retreat ``s >= 0`` of ``n`` poses at once.

    ``F_n(s)`` (the push-back along the approach with the body moved back by ``s``) does not
    grow with ``s``, so ``g(s) = s - compliance F_n(s)`` rises and has one root in
    ``[0, compliance F_n(0)]``; it is found by the Illinois variant of regula falsi.

    Args:
        normal_force: ``normal_force(index (k,), shift (k,)) -> (k,)`` push-back force (N)
            of poses ``index`` moved back by ``shift`` metres.
        compliance: m/N, >= 0.
        n: number of poses.
        tol: metres; stop when every bracket or step is below it.
        max_iter: most evaluations after the first two.

    Returns:
        ``(shift (n,), evaluations)``.

    """
    everything = np.arange(n)
    f0 = np.maximum(normal_force(everything, np.zeros(n)), 0.0)
    lo = np.zeros(n)
    g_lo = -compliance * f0
    hi = compliance * f0
    active = np.flatnonzero(hi > tol)
    shift = np.zeros(n)
    if len(active) == 0 or compliance <= 0:
        return shift, 1
    g_hi = np.zeros(n)
    g_hi[active] = hi[active] - compliance * np.maximum(normal_force(active, hi[active]), 0.0)
    side = np.zeros(n, dtype=np.int8)
    evaluations = 2
    for _ in range(int(max_iter)):
        a = active
        width = g_hi[a] - g_lo[a]
        safe = np.where(width > 0, width, 1.0)
        s = np.where(width > 0, lo[a] - g_lo[a] * (hi[a] - lo[a]) / safe, 0.5 * (lo[a] + hi[a]))
        g = s - compliance * np.maximum(normal_force(a, s), 0.0)
        evaluations += 1
        shift[a] = s
        up = g > 0
        # Illinois: halve the kept end's value when the same end is replaced twice running
        hi[a[up]], g_hi[a[up]] = s[up], g[up]
        g_lo[a[up]] *= np.where(side[a[up]] == 1, 0.5, 1.0)
        side[a[up]] = 1
        dn = ~up
        lo[a[dn]], g_lo[a[dn]] = s[dn], g[dn]
        g_hi[a[dn]] *= np.where(side[a[dn]] == -1, 0.5, 1.0)
        side[a[dn]] = -1
        done = (np.abs(g) <= tol) | (hi[a] - lo[a] <= tol)
        active = a[~done]
        if len(active) == 0:
            break
    return shift, evaluations
