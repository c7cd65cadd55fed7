"""Exception hierarchy of pointforce_ros.

Every error the package raises on purpose derives from :class:`PointforceError`, so a node can
catch one type, turn it into ``success=False`` with the message, and keep serving.
"""


class PointforceError(Exception):
    """Base class of every error raised on purpose by pointforce_ros."""


class InvalidInput(PointforceError, ValueError):
    """Input data is malformed: NaN, wrong shape, empty, degenerate, wrong message layout."""


class UnsafeCommand(PointforceError, ValueError):
    """A motion or poke request is outside the configured safety limits."""


class NotConverged(PointforceError, RuntimeError):
    """An iterative solver (FEM Newton, LCP, optimiser) did not reach its tolerance."""


class DataError(PointforceError, IOError):
    """Stored data (bag, poke store, model file) is missing, corrupt or of an unknown version."""


class DeviceFault(PointforceError, RuntimeError):
    """The robot or a sensor faulted: protective stop, lost connection, stalled F/T stream."""


class ModelNotReady(PointforceError, RuntimeError):
    """A query needs a fitted force-response model and none is available yet."""
