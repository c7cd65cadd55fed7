"""BLAS threading for small dense problems (the response models, the contact solver).

Its own module, light to import: the contact service's serving path uses it and loads no
fitting code (``test/core/test_service_imports.py``).
"""

import contextlib

from threadpoolctl import ThreadpoolController

_CONTROLLER = []
"""``[controller]`` once BLAS was looked at: ``None`` where a limit has nothing to do."""

_PROCESS_LIMIT = []


def single_threaded_blas():
    """Context manager: BLAS on one thread inside (and the previous setting restored after).

    The models multiply small matrices (tens of pokes) against long ones (surface points);
    OpenBLAS's threads cost more than they save there (measured: a 40 000-point bake takes
    2x the CPU time with threads on a busy 2-core machine) and starve a concurrent ROS
    executor; the contact simulator's LCP stacks are many small matrices (a multi-threaded
    OpenBLAS was 30x slower on a loaded machine: 5.2 s against 0.16 s for 78 problems of
    size 109). Where every BLAS already runs one thread when first asked
    (``OPENBLAS_NUM_THREADS=1``, or :func:`limit_blas_for_process`; read once) the context
    is a no-op: a limit costs about 45 us, a twentieth of a single contact query. Falls back
    to a no-op when threadpoolctl cannot see the BLAS.
    """
    try:
        if not _CONTROLLER:
            controller = ThreadpoolController()
            single = all(lib['num_threads'] == 1 for lib in controller.info()
                         if lib['user_api'] == 'blas')
            _CONTROLLER.append(None if single else controller)
        if _CONTROLLER[0] is None:
            return contextlib.nullcontext()
        return _CONTROLLER[0].limit(limits=1, user_api='blas')
    except Exception:  # noqa: BLE001 - threading is an optimisation, never a failure
        return contextlib.nullcontext()


def limit_blas_for_process() -> None:
    """Run BLAS on one thread in this whole process from now on.

    For a process that solves small problems one after another (the contact service): the
    per-call limit of :func:`single_threaded_blas` then costs nothing.
    """
    try:
        _PROCESS_LIMIT.append(ThreadpoolController().limit(limits=1, user_api='blas'))
    except Exception:  # noqa: BLE001 - threading is an optimisation, never a failure
        return
    _CONTROLLER[:] = [None]
