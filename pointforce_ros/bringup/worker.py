"""CPU-heavy jobs of a process that hosts ROS nodes, run in a fresh process of their own.

The demo hosts the cell's nodes in its own process (:mod:`~pointforce_ros.bringup.launcher`):
their executor threads wake for every F/T and TCP sample (250 and 500 Hz), and each wake takes
the interpreter lock from whatever else the process computes. The demo's fit of ``(c, L)``
from three pushes took 49 s alone on the 2-core machine, 68 s beside the running cell in a
process of its own, and about 280 s in the demo's main thread (session 32). Such a job runs
here in a spawned process (never forked: a fork copies the nodes' threads' locks mid-use);
where no process can be started it runs in the caller's, and says so.

Nothing here imports rclpy: the spawned process imports this module and the core only.
"""

import concurrent.futures
import multiprocessing
from typing import Callable, Dict, Optional, Sequence

from pointforce_ros.contact.identify import (calibrate_shape, decay_grid,
                                             identify_shape_constant_from_probe)
from pointforce_ros.errors import PointforceError
from pointforce_ros.model.serving import WrenchServer


def in_fresh_process(fn: Callable, *args):
    """Return ``fn(*args)`` computed in a spawned process (``fn`` and ``args`` picklable).

    An exception ``fn`` raises is raised here. Where no process can be started or it dies
    (out of memory, killed), ``fn`` runs in this process after a printed note.
    """
    try:
        context = multiprocessing.get_context('spawn')
        with concurrent.futures.ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
            return pool.submit(fn, *args).result()
    except (OSError, concurrent.futures.process.BrokenProcessPool) as exc:
        print(f'[worker] no process of its own for {getattr(fn, "__name__", fn)} ({exc}): '
              'computing it here')
    return fn(*args)


def shape_calibration(model_path: str, sphere: Optional[tuple],
                      pushes: Sequence[tuple]) -> Dict[str, object]:
    """``c`` from ``sphere`` alone and ``(c, L)`` from ``pushes``, on the model at ``model_path``.

    The contact simulator is the one the contact service builds from that file
    (:class:`~pointforce_ros.model.serving.WrenchServer`); the pushes are
    ``(mesh, poses, approach, measured)`` as
    :func:`~pointforce_ros.contact.identify.calibrate_shape` takes them (``pushes`` with two
    or more, else no joint fit). Returns ``{'c_only': ShapeFit or None, 'calibration':
    ShapeCalibration or None, 'errors': {name: message}}`` with ``'sphere'`` and/or
    ``'pushes'`` in ``errors`` where that fit failed (:class:`PointforceError`).
    """
    server = WrenchServer()
    server.load(model_path)
    simulator = server.simulator()
    out = {'c_only': None, 'calibration': None, 'errors': {}}
    if sphere is not None:
        try:
            out['c_only'] = identify_shape_constant_from_probe(simulator, *sphere)
        except PointforceError as exc:
            out['errors']['sphere'] = str(exc)
    if len(pushes) >= 2:
        try:
            out['calibration'] = calibrate_shape(simulator, list(pushes),
                                                 decays=decay_grid(simulator.surface))
        except PointforceError as exc:
            out['errors']['pushes'] = str(exc)
    return out
