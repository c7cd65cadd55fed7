"""A calibrated PyBullet replica of a poked object (seed 002, Kao et al.; issue 19).

``mesh`` (tet volume mesh, VTK), ``scene`` (PyBullet DIRECT scene, force through the pusher's
prismatic joint), ``data`` (measured pokes), ``calibrate`` (the paper's MLP calibrator and our
scaling calibrator, damping step), ``replica`` (writer and :func:`load_replica`), ``cli``.

``from pointforce_ros.replica import load_replica`` works; PyBullet is loaded only then (the
``pointforce`` command imports ``replica.cli`` without it).
"""

__all__ = ['load_replica', 'LoadedReplica']


def __getattr__(name):
    """Load :func:`load_replica` and :class:`LoadedReplica` on first use (PEP 562)."""
    if name in __all__:
        from pointforce_ros.replica import replica  # loads pybullet: only when asked for
        return getattr(replica, name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
