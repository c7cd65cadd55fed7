"""The model's effect terms: named physical effects the point model can carry, used live.

* :mod:`.library`: the candidate effects (parameters, signatures) and their physics.
* :mod:`.accepted`: the stored form of accepted effects (``ContactModel.effects``) and the
  surface they move.
* :mod:`.relaxation`: the Prony-series relaxation filters of the viscoelastic effect.
* :mod:`.correct`: correcting data with accepted effects (the learner corrects every poke before
  fitting) and predicting what the cell measures.
* :mod:`.forward`: the forward terms the contact service adds back at query time.

Finding which effects a data set holds is the diagnosis wing's job
(:mod:`pointforce_ros.diagnose`).

The package imports none of its modules: the contact service loads :mod:`.forward` (numpy and
the library only) and must not pay for the corrections' ``scipy.signal`` / ``scipy.optimize``
at every (re)start. Import names from their modules.
"""
