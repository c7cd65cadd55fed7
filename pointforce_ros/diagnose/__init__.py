"""Close the loop: residuals of held-out pokes -> the physical effect behind them.

* :mod:`.batch`: the concatenated poke batch the effect models evaluate in one pass.
* :mod:`.model`: the structured base model and its extension by effects; fitting.
* :mod:`.run`: :func:`diagnose` and the CLI entry :func:`run_diagnose`.
* :mod:`.probes`: probe trials scored through the contact service before and after the
  accepted effects; spatial coupling (the shape constant) and, on trials measured through the
  arm, series compliance tested on them.
* :mod:`.report`: Markdown + PNG report.
"""

from pointforce_ros.diagnose.probes import (fit_series_compliance, fit_spatial_coupling,
                                            score_probe_trials)
from pointforce_ros.diagnose.run import diagnose, DiagnoseReport, run_diagnose

__all__ = ['diagnose', 'DiagnoseReport', 'fit_series_compliance', 'fit_spatial_coupling',
           'run_diagnose', 'score_probe_trials']
