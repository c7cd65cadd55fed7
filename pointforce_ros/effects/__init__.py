"""The model's effect terms: named physical effects the point model can carry, used live.

* :mod:`.library`: the candidate effects (parameters, signatures) and their physics.
* :mod:`.correct`: storing accepted effects and correcting data / surfaces with them (the
  learner corrects every poke before fitting).
* :mod:`.forward`: the forward terms the contact service adds back at query time.

Finding which effects a data set holds is the diagnosis wing's job
(:mod:`pointforce_ros.diagnose`).
"""

from pointforce_ros.effects.correct import (apply_series_compliance, correct_curve,
                                            correct_record, correct_records, correct_surface,
                                            effects_from_dict, effects_to_dict,
                                            predict_measured, relaxed_fraction)
from pointforce_ros.effects.library import LIBRARY, PROBE_EFFECTS

__all__ = ['apply_series_compliance', 'correct_curve', 'correct_record', 'correct_records',
           'correct_surface', 'effects_from_dict', 'effects_to_dict', 'LIBRARY',
           'predict_measured', 'PROBE_EFFECTS', 'relaxed_fraction']
