"""Suite-wide fixtures: an isolated ROS 2 graph per test process, and seeded randomness.

With ``PYTEST_PHASE_FILE`` set (``make test`` sets it, an absolute path: tests change their
working directory), each test phase writes its node id
there first, so a run that a native crash ends can still say which test it was in.
"""

import os

import pytest


def _isolate_ros_graph():
    """Give this test process its own DDS domain on localhost only, before rclpy starts.

    Parallel or repeated runs on one machine then never see each other's nodes.
    """
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    index = int(worker[2:]) if worker.startswith('gw') and worker[2:].isdigit() else 0
    domain = 1 + (os.getpid() * 7 + index * 31) % 100
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


_PHASE_FILE = os.environ.get('PYTEST_PHASE_FILE')


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
