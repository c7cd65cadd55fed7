"""Suite-wide fixtures: an isolated ROS 2 graph per test process, and seeded randomness.

With ``PYTEST_PHASE_FILE`` set (``make test`` sets it, an absolute path: tests change their
working directory), each test phase writes its node id
there first, so a run that a native crash ends can still say which test it was in.
"""

import os
import zlib

import pytest


def _isolate_ros_graph():
    """Give this test process its own DDS domain on localhost only, before rclpy starts.

    Parallel or repeated runs on one machine then never see each other's nodes.
    """
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    run = os.environ.get('PYTEST_XDIST_TESTRUNUID')
    if worker[2:].isdigit() and run:
        # the workers of one run: odd domains of their own, so no two meet, nor does a test's
        # "other domain" (``domain % 100 + 1``, test_dds_plumbing) meet another worker's
        count = max(1, int(os.environ.get('PYTEST_XDIST_WORKER_COUNT', '1')))
        base = zlib.crc32(run.encode()) % max(1, 50 // count)
        domain = 1 + 2 * ((base * count + int(worker[2:]) % count) % 50)
    else:
        domain = 1 + (os.getpid() * 7) % 100
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')


_isolate_ros_graph()


@pytest.fixture
def ros_graph():
    """A live, isolated ROS 2 graph; nodes added to it spin until the test ends."""
    from pointforce_ros.bringup.launcher import InProcessLauncher
    graph = InProcessLauncher(threads=6)
    try:
        yield graph
    finally:
        graph.close()


PARTICIPANT_SOCKETS = 5
"""A Fast DDS participant holds 5-6 sockets (the first in a process also opens 3 that stay)."""


def _open_sockets() -> int:
    count = 0
    for fd in os.listdir('/proc/self/fd'):
        try:
            count += os.readlink(f'/proc/self/fd/{fd}').startswith('socket:')
        except OSError:    # the listing's own descriptor, or one closed meanwhile
            pass
    return count


@pytest.fixture(autouse=True)
def no_participant_outlives_its_test():
    """Fail a test after which this process holds a DDS participant more than before it.

    A participant left to the garbage collector (a node destroyed while an action client or
    server still held it) stays on every other participant's graph: dozens piled up in one
    test process, and then a launcher could not discover its own poke server in 30 s.
    """
    before = _open_sockets()
    yield
    extra = _open_sockets() - before
    if extra >= PARTICIPANT_SOCKETS:
        pytest.fail(f'{extra} more sockets open after this test than before it: a DDS '
                    'participant (5-6 sockets) outlived the test (destroy nodes with '
                    'pointforce_ros.nodes.common.destroy_node, contexts with destroy())',
                    pytrace=False)


_PHASE_FILE = os.environ.get('PYTEST_PHASE_FILE')
if _PHASE_FILE and os.environ.get('PYTEST_XDIST_WORKER'):
    _PHASE_FILE = f"{_PHASE_FILE}.{os.environ['PYTEST_XDIST_WORKER']}"     # one per worker


def _mark_phase(item, phase):
    if _PHASE_FILE:
        try:   # a bookkeeping write must never fail a test, nor skip its fixtures' teardown
            with open(_PHASE_FILE, 'w') as fh:
                fh.write(f'{item.nodeid} ({phase})\n')
        except OSError:
            pass


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    _mark_phase(item, 'setup')


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_call(item):
    _mark_phase(item, 'call')


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_teardown(item):
    _mark_phase(item, 'teardown')
