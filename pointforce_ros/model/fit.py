"""Records in, contact model out: the pure entry point of learning, with no store and no files.

:func:`fit_contact_model` is what the ``stiffness_learner`` node would serve after it had read
``records`` from its poke store (ours, corrected by ``effects``, baked on ``surface``), for
callers that hold the records in memory (probe scoring, the lab, replicas).
"""

from dataclasses import replace
from typing import Dict, Optional, Sequence

import numpy as np

from pointforce_ros.errors import DataError
from pointforce_ros.model.files import ContactModel
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.pokes.table import surface_from_records
from pointforce_ros.types import PokeRecord, Surface


def fit_contact_model(records: Sequence[PokeRecord], surface: Optional[Surface], *,
                      effects: Optional[Dict] = None, shape_constant: float = 0.004,
                      shape_decay: float = np.inf, **learner_kwargs) -> ContactModel:
    """Learn the contact model the nodes would serve from ``records``.

    Args:
        records: poke records in any order (learned in time order; only point pokes).
        surface: the equilibrium surface the model is baked on (``base``); ``None``: the
            poked points themselves (:func:`~pointforce_ros.pokes.table.surface_from_records`,
            for a table from another rig that came without a cloud).
        effects: accepted effects ``{name: {param: value}}`` (``effects.json``).
        shape_constant: ``c`` of the shape function, metres.
        shape_decay: tail decay length of the shape function, metres (``inf``: none).
        **learner_kwargs: further :class:`OnlineLearner` options (``depths``,
            ``model_factory``, ``min_peak_force``, ``contact_snr``, ``min_peak_fraction``).
            A poke that cannot be used is skipped (its reason is in the model's
            ``meta['skipped']``), never stops the fit.

    Raises:
        DataError: no poke could be learned from (the reasons of the first three).
        InvalidInput: malformed effects, shape constant or decay length.

    """
    if surface is None:
        surface = surface_from_records([r for r in records if r.probe == 'point'] or records)
    learner = OnlineLearner(None, None, surface, shape_constant=shape_constant,
                            shape_decay=shape_decay, effects=effects or {}, **learner_kwargs)
    if learner.learn_records(records) is None:
        raise DataError('no poke could be learned from ('
                        + '; '.join(f'{k}: {v}' for k, v in list(learner.skipped.items())[:3])
                        + ')')
    model = learner.contact_model()
    if learner.skipped:
        meta = dict(model.meta)
        meta['skipped'] = dict(learner.skipped)
        model = replace(model, meta=meta)
    return model
