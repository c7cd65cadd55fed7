"""Fixtures that start the RTDE controller emulator as its own process, one loopback per test.

ur_rtde fixes the ports (30004 RTDE, 29999 dashboard, 30003 script), so tests that run at the
same time (other pytest sessions on this machine too) must use different loopback addresses:
``127.<64 + pid % 128>.<n // 250>.<2 + n % 250>`` with a per-session counter ``n``, and a retry
on the next address when the emulator reports that its address is taken (exit code 3).
"""

import itertools
import json
import os
from pathlib import Path
import selectors
import subprocess
import sys
import time

import pytest

from pointforce_ros.cell.rtde_emulator import EmulatorControl

READY_TIMEOUT = 20.0
_COUNTER = itertools.count()
_SECOND_OCTET = 64 + os.getpid() % 128
REPO_ROOT = Path(__file__).resolve().parents[2]


def _next_host() -> str:
    n = next(_COUNTER)
    return f'127.{_SECOND_OCTET}.{n // 250}.{2 + n % 250}'


class EmulatorProcess:
    """A running emulator: its address, fault channel, process and log file."""

    def __init__(self, host: str, process: subprocess.Popen, log_path: Path):
        self.host = host
        self.process = process
        self.log_path = log_path
        self.control = EmulatorControl(host)

    def log(self) -> str:
        """Return what the emulator wrote to stderr so far."""
        return self.log_path.read_text(errors='replace') if self.log_path.exists() else ''

    def stop(self) -> None:
        """SIGTERM, then SIGKILL after 5 s."""
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5.0)
        if self.process.stdout is not None:
            self.process.stdout.close()


def _wait_ready(process: subprocess.Popen, deadline: float) -> str:
    sel = selectors.DefaultSelector()
    sel.register(process.stdout, selectors.EVENT_READ)
    try:
        while time.monotonic() < deadline:
            if not sel.select(timeout=max(0.0, min(0.2, deadline - time.monotonic()))):
                if process.poll() is not None:
                    return ''
                continue
            line = process.stdout.readline()
            if not line:
                return ''
            if line.startswith('rtde_emulator ready'):
                return line
        return ''
    finally:
        sel.close()


@pytest.fixture
def start_emulator(tmp_path):
    """Return ``start(**options) -> EmulatorProcess``; every process is stopped afterwards.

    Options: ``force_model`` (``module:factory``), ``force_model_kwargs`` (dict),
    ``initial_pose`` (6 floats), ``noise_floor`` (N), ``extra_args`` (list of CLI words).
    """
    started = []

    def start(*, force_model=None, force_model_kwargs=None, initial_pose=None,
              noise_floor=None, extra_args=()):
        for attempt in range(6):
            host = _next_host()
            log_path = tmp_path / f'emulator_{host}.log'
            cmd = [sys.executable, '-m', 'pointforce_ros.cell.rtde_emulator', '--host', host]
            if force_model is not None:
                cmd += ['--force-model', force_model]
            if force_model_kwargs is not None:
                cmd += ['--force-model-kwargs', json.dumps(force_model_kwargs)]
            if initial_pose is not None:
                cmd += ['--initial-pose', json.dumps([float(x) for x in initial_pose])]
            if noise_floor is not None:
                cmd += ['--ft-noise-floor', str(noise_floor)]
            cmd += list(extra_args)
            env = dict(os.environ)
            env['PYTHONPATH'] = os.pathsep.join(
                [str(REPO_ROOT)] + [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p])
            with open(log_path, 'w') as log:
                process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True,
                                           cwd=str(REPO_ROOT), env=env)
            handle = EmulatorProcess(host, process, log_path)
            started.append(handle)
            if _wait_ready(process, time.monotonic() + READY_TIMEOUT):
                return handle
            handle.stop()
            if process.returncode != 3:
                break
        pytest.fail(f'rtde_emulator did not become ready on {host} within {READY_TIMEOUT} s '
                    f'(exit code {process.returncode}):\n{handle.log()}')

    yield start
    for handle in started:
        handle.stop()
