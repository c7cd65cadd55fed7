"""Accepted effects as stored, and the surface they move (pure, no ROS; numpy only).

Accepted effects travel as a plain mapping ``{name: {param: value}}`` (SI values, the library's
parameter names, fixed settings included), which is what ``ContactModel.effects`` of
:mod:`pointforce_ros.model.files` stores: :func:`effects_to_dict` / :func:`effects_from_dict`.
:func:`correct_surface` moves the camera surface onto the true one (surface offset, plastic set
where the object was poked).

The contact service needs exactly this (:mod:`pointforce_ros.effects.forward`) and nothing of
the data corrections (:mod:`pointforce_ros.effects.correct`, which load ``scipy.signal`` and
``scipy.optimize`` through the relaxation filters and the poke curves): keep it that light.
"""

from typing import Dict, Mapping

import numpy as np

from pointforce_ros.effects.library import (check_params, LIBRARY, PLASTIC_RADIUS, plastic_depth,
                                            PROBE_EFFECTS)
from pointforce_ros.errors import InvalidInput
from pointforce_ros.types import Surface

Effects = Mapping[str, Mapping[str, float]]


def effects_to_dict(effects) -> Dict[str, Dict[str, float]]:
    """Return accepted effects as a JSON-ready ``{name: {param: value}}`` mapping.

    Args:
        effects: a :class:`~pointforce_ros.diagnose.run.DiagnoseReport`, a sequence of
            :class:`~pointforce_ros.diagnose.run.AcceptedEffect`, or a mapping.

    Raises:
        InvalidInput: unknown effects or bad parameters.

    """
    if hasattr(effects, 'accepted') and not isinstance(effects, Mapping):
        effects = effects.accepted
    if not isinstance(effects, Mapping):
        effects = {e.name: e.params for e in effects}
    return effects_from_dict(effects)


def effects_from_dict(data) -> Dict[str, Dict[str, float]]:
    """Validate a stored ``{name: {param: value}}`` mapping (library order, floats).

    Raises:
        InvalidInput: not a mapping, unknown effect names, missing/unknown or non-finite
            parameters.

    """
    if data is None:
        return {}
    if not isinstance(data, Mapping):
        raise InvalidInput(f'effects: expected a mapping name -> parameters, got '
                           f'{type(data).__name__}')
    known = list(LIBRARY) + list(PROBE_EFFECTS)
    unknown = [name for name in data if name not in known]
    if unknown:
        raise InvalidInput(f'effects: unknown effect(s) {unknown}; known: {", ".join(known)}')
    return {name: check_params(name, data[name]) for name in known if name in data}


def correct_surface(surface: Surface, effects: Effects, *, poke_points=None,
                    poke_counts=None) -> Surface:
    """Move the observed surface onto the true one.

    ``surface_offset`` moves every point by ``+offset`` along its normal; ``plastic_set`` sinks
    the points within the radius of each poked spot by ``set(count)`` (when ``poke_points``
    (K, 3) and ``poke_counts`` (K,) are given; the deepest spot wins where they overlap).

    Raises:
        InvalidInput: bad effects, or poke arrays of different lengths.

    """
    effects = effects_from_dict(effects)
    points = np.array(surface.points)
    normals = surface.normals
    if 'surface_offset' in effects:
        points += effects['surface_offset']['offset'] * normals
    if 'plastic_set' in effects and poke_points is not None:
        spots = np.asarray(poke_points, dtype=np.float64).reshape(-1, 3)
        counts = np.asarray(poke_counts if poke_counts is not None else np.ones(len(spots)))
        if counts.shape != (len(spots),):
            raise InvalidInput('correct_surface: poke_points and poke_counts differ in length')
        ps = effects['plastic_set']
        depth = plastic_depth(counts, ps['max_set'], ps['n0'])
        rel = points[:, None, :] - spots[None, :, :]
        along = np.einsum('ijk,ik->ij', rel, normals)
        across = rel - along[:, :, None] * normals[:, None, :]
        near = np.einsum('ijk,ijk->ij', across, across) <= ps.get('radius', PLASTIC_RADIUS) ** 2
        sink = np.max(np.where(near, depth[None, :], 0.0), axis=1) if len(spots) else 0.0
        points = points - sink[:, None] * normals if len(spots) else points
    return Surface(points=points, normals=normals, colors=surface.colors, frame=surface.frame)
