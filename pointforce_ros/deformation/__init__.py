"""Seed 001 (Petit/Ficuciello): an FEM model of the scanned object and force from deformation.

Pure core (numpy/scipy; no ROS, and never the simulated cell, whose FEM stays the independent
truth):

- :mod:`.mesh`: tetrahedral volume mesh closed down to the table from the equilibrium surface.
- :mod:`.fem`: static co-rotational linear tet FEM with a reusable factorisation.
- :mod:`.observe`: the point-to-plane comparison of a depth cloud with the model's surface (and
  the paper's two-way nearest-neighbour error for its baselines); the pushing camera's own rest
  frames as the residual's reference (:class:`.observe.RestFrames`).
- :mod:`.identify`: (E, nu) from pokes (force + cloud); closed-form E, 1-D search over nu.
- :mod:`.force`: the contact force from a cloud alone, with residual and covariance.
- :mod:`.bench`: timing of one force estimate and one identification against the paper's
  Nelder-Mead.
- :mod:`.rigid_contact`: a rigid probe mesh pressed into the FEM (frictionless LCP at face
  points): the force and torque of a wide contact.
- :mod:`.wide_contacts`: figure 2's line/cylinder trials, the calibrated FEM against the
  semi-empirical simulator (``python -m pointforce_ros.deformation.wide_contacts --out DIR``).
- :mod:`.poisson_study`: nu with and without side pushes on the homogeneous block.
- :mod:`.cell_check`: the estimator's side of the demo's camera-only force check, and a
  heterogeneous modulus field seeded by a point model's force map and refined by the
  identification's fit (:func:`.cell_check.refine_field`).
- :mod:`.fused`: the camera force's magnitude fused with the learner's point model at the
  probe's measured indentation (inverse variance, the FEM's direction): issue 18's
  heterogeneous objects, where a buried stiff part fools the FEM's magnitude.
"""
