"""A calibrated PyBullet replica of a poked object (seed 002, Kao et al.; issue 19).

``mesh`` (tet volume mesh, VTK), ``scene`` (PyBullet DIRECT scene, force through the pusher's
prismatic joint), ``data`` (measured pokes), ``calibrate`` (the paper's MLP calibrator and our
scaling calibrator, damping step), ``replica`` (writer and :func:`load_replica`), ``cli``.
"""
