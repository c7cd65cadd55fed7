"""Fixtures that start the RTDE controller emulator as its own process, one loopback per test.

ur_rtde fixes the ports (30004 RTDE, 29999 dashboard, 30003 script), so tests that run at the
same time (other pytest sessions on this machine too) use different loopback addresses
(:func:`pointforce_ros.sim.rtde.process.loopback_hosts`), with a retry on the next address
when the emulator reports that its address is taken.
"""

import pytest

from pointforce_ros.sim.rtde import process as emulator_process
from pointforce_ros.errors import DeviceFault

_HOSTS = emulator_process.loopback_hosts()


@pytest.fixture
def start_emulator(tmp_path):
    """Return ``start(**options) -> EmulatorProcess``; every process is stopped afterwards.

    Options: ``force_model`` (``module:factory``), ``force_model_kwargs`` (dict),
    ``initial_pose`` (6 floats), ``noise_floor`` (N), ``extra_args`` (list of CLI words).
    """
    started = []

    def start(**options):
        try:
            handle = emulator_process.start_emulator(tmp_path, hosts=_HOSTS, **options)
        except DeviceFault as exc:
            pytest.fail(str(exc))
        started.append(handle)
        return handle

    yield start
    for handle in started:
        handle.stop()
