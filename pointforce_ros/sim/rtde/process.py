"""Start the RTDE controller emulator as its own process and wait until it is ready.

The ur_rtde interface constructors hold the GIL through their handshake, so the emulator never
runs in the process that connects to it. Used by ``pointforce cell``, the demo, the benchmarks
and the test fixtures. The emulator exits with the process that started it, also when that
process is SIGKILLed (it watches a stdin pipe whose write end only the parent holds). Ports are
fixed by ur_rtde (30004, 29999, 30003), so concurrent emulators
use distinct loopback addresses; :func:`loopback_hosts` yields candidates.
"""

import itertools
import json
import os
import selectors
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator, List, Optional, Sequence

from pointforce_ros.sim.rtde.client import EmulatorControl
from pointforce_ros.errors import DeviceFault

ADDRESS_IN_USE = 3  # the emulator's exit code when its address is taken
REPO_ROOT = Path(__file__).resolve().parents[3]
"""The folder holding the pointforce_ros package (a source checkout or site-packages)."""


def loopback_hosts(seed: Optional[int] = None) -> Iterator[str]:
    """Endless distinct loopback addresses ``127.<64 + seed % 128>.<n // 250>.<2 + n % 250>``.

    ``seed`` defaults to this process id, so two processes rarely pick the same addresses.
    """
    second = 64 + (os.getpid() if seed is None else int(seed)) % 128
    for n in itertools.count():
        yield f'127.{second}.{(n // 250) % 256}.{2 + n % 250}'


class EmulatorProcess:
    """A running emulator: its address, fault channel, process and log file."""

    def __init__(self, host: str, process: subprocess.Popen, log_path: Path):
        """Wrap a started process (see :func:`start_emulator`)."""
        self.host = host
        self.process = process
        self.log_path = Path(log_path)
        self.control = EmulatorControl(host)

    def log(self) -> str:
        """Return what the emulator wrote to stderr so far."""
        return self.log_path.read_text(errors='replace') if self.log_path.exists() else ''

    def alive(self) -> bool:
        """Whether the process still runs."""
        return self.process.poll() is None

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 5 s."""
        if self.process.stdin is not None and not self.process.stdin.closed:
            try:
                self.process.stdin.close()   # the emulator's parent watch ends it too
            except OSError:
                pass
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5.0)
        if self.process.stdout is not None:
            self.process.stdout.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def _wait_ready(process: subprocess.Popen, deadline: float) -> str:
    """Read the emulator's stdout until its readiness line; 'ready', 'ended' or 'timeout'."""
    sel = selectors.DefaultSelector()
    sel.register(process.stdout, selectors.EVENT_READ)
    try:
        while time.monotonic() < deadline:
            if not sel.select(timeout=max(0.0, min(0.2, deadline - time.monotonic()))):
                if process.poll() is not None:
                    return 'ended'
                continue
            line = process.stdout.readline()
            if not line:
                return 'ended'      # end-of-file: it is exiting
            if line.startswith('rtde_emulator ready'):
                return 'ready'
        return 'timeout'
    finally:
        sel.close()


def _ready_or_exit_code(process: subprocess.Popen, timeout: float):
    """Wait for ``process``: (True, None) once ready, else (False, its exit code or None).

    Its stdout ends as it exits, a moment before its exit status is there: a process that
    ended by itself is waited for (up to 5 s) so it is not read as a readiness time-out
    (session 37: a bad argument once was).
    """
    state = _wait_ready(process, time.monotonic() + timeout)
    if state == 'ready':
        return True, None
    if state == 'ended':
        try:
            return False, process.wait(5.0)
        except subprocess.TimeoutExpired:
            pass
    return False, process.poll()


def start_emulator(log_dir, *, hosts: Optional[Iterator[str]] = None,
                   force_model: Optional[str] = None, force_model_kwargs: Optional[dict] = None,
                   initial_pose: Optional[Sequence[float]] = None,
                   noise_floor: Optional[float] = None, extra_args: Sequence[str] = (),
                   ready_timeout: float = 20.0, attempts: int = 6) -> EmulatorProcess:
    """Start an emulator on the first free address of ``hosts``; return it once it is ready.

    Args:
        log_dir: directory of the emulator's stderr log (``emulator_<host>.log``).
        hosts: candidate addresses (default :func:`loopback_hosts`).
        force_model: ``module:factory`` of the force model, and ``force_model_kwargs`` its JSON
            keyword arguments.
        initial_pose: (6,) TCP pose at start, ``base``.
        noise_floor: F/T noise floor of the emulator, N (its default if None).
        extra_args: further command-line words.
        ready_timeout: seconds to wait for the readiness line.
        attempts: addresses tried when one is taken.

    Raises:
        DeviceFault: no emulator became ready (the message carries the end of its log).

    """
    hosts = hosts if hosts is not None else loopback_hosts()
    log_dir = Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    handle = exited = None
    for _ in range(int(attempts)):
        host = next(hosts)
        log_path = log_dir / f'emulator_{host}.log'
        cmd = [sys.executable, '-m', 'pointforce_ros.sim.rtde.emulator', '--host', host]
        if force_model is not None:
            cmd += ['--force-model', force_model]
        if force_model_kwargs is not None:
            cmd += ['--force-model-kwargs', json.dumps(force_model_kwargs)]
        if initial_pose is not None:
            cmd += ['--initial-pose', json.dumps([float(x) for x in initial_pose])]
        if noise_floor is not None:
            cmd += ['--ft-noise-floor', str(noise_floor)]
        cmd += ['--exit-with-parent'] + list(extra_args)
        env = dict(os.environ)
        env['PYTHONPATH'] = os.pathsep.join(
            [str(REPO_ROOT)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
        with open(log_path, 'w') as log:
            # this process keeps the write end of the stdin pipe (not inherited by other
            # children: close_fds); when it dies, even by SIGKILL, the emulator reads
            # end-of-file and stops (--exit-with-parent)
            process = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                       stderr=log, text=True, cwd=str(REPO_ROOT), env=env)
        handle = EmulatorProcess(host, process, log_path)
        ready, exited = _ready_or_exit_code(process, ready_timeout)
        if ready:
            return handle
        handle.stop()
        if process.returncode != ADDRESS_IN_USE:
            break
    tail = handle.log()[-2000:] if handle is not None else ''
    code = handle.process.returncode if handle is not None else None
    if exited is not None:      # it ended by itself (a bad argument, no free address)
        raise DeviceFault(f'rtde_emulator exited with code {code} before it was ready:\n{tail}')
    raise DeviceFault(f'rtde_emulator did not become ready within {ready_timeout} s '
                      f'(stopped, exit code {code}):\n{tail}')


def child_pids(pid: int, needle: str) -> List[int]:
    """Pids of the processes whose parent is ``pid`` and whose command line holds ``needle``.

    Read from ``/proc`` (Linux): how a supervisor's check finds the emulators a cell started
    (``pointforce bench faults`` and the cell's end-to-end tests look for orphans with it).
    """
    found = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/stat') as fh:
                parent = int(fh.read().rsplit(')', 1)[1].split()[1])
            with open(f'/proc/{entry}/cmdline', 'rb') as fh:
                command = fh.read().replace(b'\0', b' ').decode(errors='replace')
        except (OSError, ValueError, IndexError):
            continue
        if parent == pid and needle in command:
            found.append(int(entry))
    return found


def process_alive(pid: int) -> bool:
    """Whether ``pid`` is a running process (a zombie, or no such pid, is not)."""
    try:
        with open(f'/proc/{pid}/stat') as fh:
            return fh.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False
