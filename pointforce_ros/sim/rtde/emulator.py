r"""Loopback UR controller emulator that the real ``ur_rtde`` 1.6.5 connects to.

Run it as its own process (the ur_rtde constructors hold the Python GIL through the handshake)::

    python -m pointforce_ros.sim.rtde.emulator --host 127.0.0.2 \
        --force-model pointforce_ros.sim.rtde.forces:HalfSpaceSpring \\
        --force-model-kwargs '{"z0": 0.0, "k": 2000.0}'

It prints one line ``rtde_emulator ready host=... rtde=30004 dashboard=29999 script=30003
control=30099 pid=...`` on stdout once every port listens (logs go to stderr), and shuts down
cleanly on SIGTERM or SIGINT. With ``--exit-with-parent`` it also shuts down when its stdin
reaches end-of-file: :func:`pointforce_ros.sim.rtde.process.start_emulator` keeps the write end
of that pipe, so the emulator follows its parent even when the parent is SIGKILLed (the kernel
closes the pipe) and no orphan holds the controller ports.

What it emulates
----------------
- **RTDE** (port 30004, protocol version 2, see :mod:`rtde_protocol`): any number of clients,
  each with its own output recipe streamed at its requested frequency (a divisor of 500 Hz),
  input recipes numbered 1, 2, ... in arrival order, ``IN_USE`` when a second client asks for
  registers another live client writes, ``NOT_FOUND`` for unknown variables.
- **Dashboard** (port 29999): welcome line, ``PolyscopeVersion``, ``get serial number``,
  ``is in remote control``, ``stop``, ``play``, ``pause``, ``unlock protective stop``,
  ``safetystatus``, ``safetymode``, ``robotmode``, ``programState``, ``running``, ``quit``.
- **Script server** (port 30003): a complete ``def name(): ... end`` program (ur_rtde's ~42 KB
  control script) starts "the program" (runtime_state PLAYING, output_int_register_0 = 1,
  F/T re-tared as a real controller does). URScript is NOT interpreted: the emulator plays the
  ur_rtde control script's register protocol (input_int_register_0 = command,
  output_int_register_0 = 1 ready / 2 done, real-time commands answer ready at once, async
  progress in output_int_register_2) and moves the TCP kinematically.
- **Motion**: moveL (sync and async; trapezoidal speed profile, straight line, orientation
  interpolated along the geodesic), stopL / stopJ (sync and async), speedL / speedStop,
  zeroFtSensor, moveUntilContact, start/read/stopContactDetection, triggerProtectiveStop,
  stopScript, plus the read-only queries (isSteady, getTCPOffset, getForwardKinematics, ...).
  Joint-space commands (moveJ, speedJ, servoJ, forceMode, ...) have no kinematic model here:
  they raise a "script error" that stops the program, so ur_rtde returns False (never a silent
  success).
- **Sensing** at 500 Hz: ``actual_TCP_pose`` (base, [x, y, z, rx, ry, rz]), ``actual_TCP_speed``,
  ``actual_TCP_force`` = force model wrench + sensor noise floor - tare (base-oriented; the
  reaction of the environment on the tool), ``ft_raw_wrench`` (untared), timestamp, robot and
  safety modes, status bits, runtime state and the output registers.
- **Safety**: a protective stop (injected, requested by ``triggerProtectiveStop`` or caused by
  ``|F| > --force-limit``) decelerates the TCP to rest within milliseconds, sets
  ``safety_status_bits`` bit 2 and ``safety_mode`` 3 and pauses the program.

Force model plug-in
-------------------
``--force-model module:factory`` with ``--force-model-kwargs JSON`` builds an object with
``wrench(tcp_pose6: np.ndarray, t: float) -> np.ndarray`` of shape (6,): the base-oriented
wrench ``[fx, fy, fz, tx, ty, tz]`` (N, N m) the environment applies to the tool when the TCP is
at ``tcp_pose6`` at controller time ``t`` (s). An optional ``set_params(**kwargs)`` method lets
the fault channel change parameters live. An optional ``tare(t)`` method means the model owns
the sensor offset: ``zeroFtSensor`` (and a program start) then call it and the emulator
subtracts nothing; without it the emulator subtracts the mean of the last 10 raw samples.
The built-in :class:`HalfSpaceSpring` is a flat elastic table top.

Fault-injection channel (TCP, port 30099 on the same address; one command per line, one JSON
reply line ``{"ok": true, ...}`` or ``{"ok": false, "error": "..."}``)
---------------------------------------------------------------------------------------------
===============================  =================================================================
``ping``                         liveness
``state``                        pose, twist, force, tare, modes, runtime state, clients, ticks
``protective_stop``              protective stop now (motion halts, program paused)
``unlock``                       clear the protective stop (the program stays paused; re-upload)
``program_stop``                 stop the control program (as the pendant's stop button)
``drop [refuse_s]``              close every RTDE / dashboard / script connection and refuse new
                                 ones for ``refuse_s`` seconds (default 0)
``stall force [seconds]``        keep streaming but freeze ``actual_TCP_force`` (0 = until unstall)
``stall stream [seconds]``       stop sending data packages (connections stay open)
``unstall``                      end both stalls
``model_params {json}``          ``force_model.set_params(**json)``
``model module:factory [json]``  replace the force model
``set_pose [x,y,z,rx,ry,rz]``    teleport the TCP (only while no motion is active)
===============================  =================================================================
:class:`EmulatorControl` is a small Python client for this channel.
"""

import argparse
import json
import logging
import os
import signal
import sys
import threading

import numpy as np

from pointforce_ros.sim.rtde.constants import CONTROL_PORT, DASHBOARD_PORT, RTDE_PORT, SCRIPT_PORT
from pointforce_ros.sim.rtde.controller import Controller
from pointforce_ros.sim.rtde.forces import load_force_model
from pointforce_ros.sim.rtde.server import Emulator


def _parse_args(argv):
    parser = argparse.ArgumentParser(
        prog='rtde_emulator',
        description='Loopback UR controller emulator for the real ur_rtde (see module doc).')
    parser.add_argument('--host', default='127.0.0.2',
                        help='loopback address to listen on (default 127.0.0.2)')
    parser.add_argument('--rtde-port', type=int, default=RTDE_PORT)
    parser.add_argument('--dashboard-port', type=int, default=DASHBOARD_PORT)
    parser.add_argument('--script-port', type=int, default=SCRIPT_PORT)
    parser.add_argument('--control-port', type=int, default=CONTROL_PORT,
                        help='fault-injection channel port (default 30099)')
    parser.add_argument('--force-model', default='pointforce_ros.sim.rtde.forces:HalfSpaceSpring',
                        help='force model factory as module:attribute')
    parser.add_argument('--force-model-kwargs', default='{}',
                        help='JSON object of keyword arguments for the factory')
    parser.add_argument('--initial-pose', default='[0.3, 0.0, 0.3, 3.14159265, 0.0, 0.0]',
                        help='JSON [x, y, z, rx, ry, rz] of the TCP at start (m, rad, base)')
    parser.add_argument('--ft-noise-floor', type=float, default=0.005,
                        help='std of the F/T sensor noise added to every model, N '
                             '(torques get 0.02 m times this); a real sensor is never '
                             'bitwise constant and the driver relies on it to spot a frozen '
                             'sensor')
    parser.add_argument('--force-limit', type=float, default=150.0,
                        help='|F| above this (N) triggers a protective stop')
    parser.add_argument('--contact-threshold', type=float, default=1.0,
                        help='push-back force (N) that tool_contact reports as contact')
    parser.add_argument('--seed', type=int, default=0, help='seed of the sensor noise floor')
    parser.add_argument('--log-level', default='WARNING')
    parser.add_argument('--exit-with-parent', action='store_true',
                        help='shut down when stdin reaches end-of-file (the parent holds the '
                             'write end of a pipe; it closes when the parent dies, even by '
                             'SIGKILL)')
    return parser.parse_args(argv)


def _stop_at_end_of_stdin(stop: threading.Event) -> None:
    """Set ``stop`` once stdin reaches end-of-file (or fails): the parent has gone."""
    try:
        while sys.stdin.buffer.read(4096):
            pass
    except (OSError, ValueError):
        pass
    logging.getLogger(__name__).warning('stdin closed: the parent process has gone, stopping')
    stop.set()


def main(argv=None) -> int:
    """Run the emulator until SIGTERM or SIGINT."""
    args = _parse_args(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(stream=sys.stderr, level=args.log_level.upper(),
                        format='%(asctime)s rtde_emulator %(levelname)s %(message)s')
    try:
        kwargs = json.loads(args.force_model_kwargs)
        model = load_force_model(args.force_model, kwargs)
        pose = np.asarray(json.loads(args.initial_pose), dtype=float).reshape(6)
    except (ValueError, TypeError) as exc:
        print(f'rtde_emulator: {exc}', file=sys.stderr)
        return 2
    controller = Controller(model, pose, noise_floor=args.ft_noise_floor,
                            force_limit=args.force_limit,
                            contact_threshold=args.contact_threshold, seed=args.seed)
    emulator = Emulator(args.host, controller, rtde_port=args.rtde_port,
                        dashboard_port=args.dashboard_port, script_port=args.script_port,
                        control_port=args.control_port)
    try:
        emulator.start()
    except OSError as exc:
        print(f'rtde_emulator: cannot listen on {args.host}: {exc}', file=sys.stderr)
        return 3
    stop = threading.Event()

    def on_signal(signum, frame):
        stop.set()
    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    if args.exit_with_parent:
        threading.Thread(target=_stop_at_end_of_stdin, args=(stop,), daemon=True,
                         name='parent-watch').start()
    ports = emulator.ports
    print(f'rtde_emulator ready host={args.host} rtde={ports["rtde"]} '
          f'dashboard={ports["dashboard"]} script={ports["script"]} '
          f'control={ports["control"]} pid={os.getpid()}', flush=True)
    while not stop.wait(0.2):
        pass
    emulator.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
