"""Records in, contact model out: the pure entry point of learning, with no store and no files.

:func:`fit_contact_model` is what the ``stiffness_learner`` node would serve after it had read
``records`` from its poke store (ours, corrected by ``effects``, baked on ``surface``), for
callers that hold the records in memory (probe scoring, the lab, replicas).
"""

from typing import Dict, Optional, Sequence

import numpy as np

from pointforce_ros.errors import DataError
from pointforce_ros.model.files import ContactModel
from pointforce_ros.model.learner import OnlineLearner
from pointforce_ros.types import PokeRecord, Surface


def fit_contact_model(records: Sequence[PokeRecord], surface: Surface, *,
                      effects: Optional[Dict] = None, shape_constant: float = 0.004,
                      shape_decay: float = np.inf, **learner_kwargs) -> ContactModel:
    """Learn the contact model the nodes would serve from ``records``.

    Args:
        records: poke records in any order (learned in time order; only point pokes).
        surface: the equilibrium surface the model is baked on (``base``).
        effects: accepted effects ``{name: {param: value}}`` (``effects.json``).
        shape_constant: ``c`` of the shape function, metres.
        shape_decay: tail decay length of the shape function, metres (``inf``: none).
        **learner_kwargs: further :class:`OnlineLearner` options (``depths``,
            ``model_factory``, ``min_peak_force``).

    Raises:
        DataError: no poke could be learned from (the reasons of the first three).
        InvalidInput: malformed effects, shape constant or decay length.

    """
    learner = OnlineLearner(None, None, surface, shape_constant=shape_constant,
                            shape_decay=shape_decay, effects=effects or {}, **learner_kwargs)
    if learner.learn_records(records) is None:
        raise DataError('no poke could be learned from ('
                        + '; '.join(f'{k}: {v}' for k, v in list(learner.skipped.items())[:3])
                        + ')')
    return learner.contact_model()
