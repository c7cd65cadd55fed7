"""Close the loop: candidate physical effects, their selection on held-out pokes, corrections.

* :mod:`.library`: the candidate effects (parameters, signatures) and their physics.
* :mod:`.data`: loading pokes (store, bag, CSV table) and the concatenated poke batch.
* :mod:`.model`: the structured base model and its extension by effects; fitting.
* :mod:`.diagnose`: :func:`diagnose` and the CLI entry :func:`run_diagnose`.
* :mod:`.correct`: storing accepted effects and correcting data / surfaces with them.
* :mod:`.forward`: the forward terms the contact service adds back at query time.
* :mod:`.probes`: probe trials scored through the contact service before and after the
  accepted effects; spatial coupling (the shape constant) and, on trials measured through the
  arm, series compliance tested on them.
* :mod:`.report`: Markdown + PNG report.
"""

from pointforce_ros.effects.correct import (apply_series_compliance, correct_curve,
                                            correct_record, correct_records, correct_surface,
                                            effects_from_dict, effects_to_dict,
                                            predict_measured, relaxed_fraction)
from pointforce_ros.effects.data import load_pokes, read_poke_table, write_poke_table
from pointforce_ros.effects.diagnose import diagnose, DiagnoseReport, run_diagnose
from pointforce_ros.effects.library import LIBRARY, PROBE_EFFECTS
from pointforce_ros.effects.probes import (fit_series_compliance, fit_spatial_coupling,
                                           load_probe_trials, ProbeTrial, score_probe_trials)

__all__ = ['apply_series_compliance', 'correct_curve', 'correct_record', 'correct_records',
           'correct_surface', 'diagnose', 'DiagnoseReport', 'effects_from_dict', 'effects_to_dict',
           'fit_series_compliance', 'fit_spatial_coupling', 'LIBRARY', 'load_pokes',
           'load_probe_trials', 'predict_measured', 'PROBE_EFFECTS', 'ProbeTrial',
           'read_poke_table', 'relaxed_fraction', 'run_diagnose', 'score_probe_trials',
           'write_poke_table']
