"""UrArm against the loopback RTDE emulator: the real ur_rtde code path end to end."""

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from pointforce_ros.drivers.ur_arm import (_realtime_poller, active_fault_message, ArmEvent,
                                           EVENT_CONNECTION_LOST, EVENT_FT_FROZEN,
                                           EVENT_PROTECTIVE_STOP, EVENT_STALL, missing_slots,
                                           PushFault, unreported_runs, UrArm)
from pointforce_ros.errors import DeviceFault, InvalidInput, UnsafeCommand

pytestmark = pytest.mark.e2e

TABLE_Z = 0.25
K = 2000.0
STANDOFF = [0.3, 0.0, TABLE_Z + 0.002, 3.14159265, 0.0, 0.0]
DOWN = [0.0, 0.0, -1.0]


@pytest.fixture
def cell(start_emulator):
    """(emulator, arm): a 2000 N/m table top at z = 0.25 m under the TCP."""
    emu = start_emulator(initial_pose=[0.3, 0.0, 0.27, 3.14159265, 0.0, 0.0],
                         force_model_kwargs={'z0': TABLE_Z, 'k': K})
    arm = UrArm(emu.host)
    try:
        yield emu, arm
    finally:
        emu.control.unstall()
        arm.close()


def _inject_when(arm, condition, action):
    """Run ``action`` once (on its own thread) when ``condition(sample)`` first holds."""
    fired = {}

    def on_sample(sample):
        if 't' not in fired and condition(sample):
            fired['t'] = time.time()
            threading.Thread(target=action).start()
    arm.add_sample_callback(on_sample)
    return fired


def test_connect_failure_names_the_host():
    t0 = time.monotonic()
    with pytest.raises(DeviceFault, match='127.254.254.254'):
        UrArm('127.254.254.254', connect_timeout=2.0)
    assert time.monotonic() - t0 < 2.5


class _Sleeper(threading.Thread):
    """A thread of this process that only sleeps 5 ms at a time: its largest oversleep is how
    long the OS held this process's threads, whatever they do."""

    def __init__(self):
        super().__init__(daemon=True)
        self.stop = threading.Event()
        self.held = 0.0

    def run(self):
        while not self.stop.is_set():
            t0 = time.monotonic()
            time.sleep(0.005)
            self.held = max(self.held, time.monotonic() - t0 - 0.005)


def test_stream_is_250_hz_without_duplicates_or_unreported_gaps(cell):
    emu, arm = cell
    got = []
    before = emu.control.state()
    sleeper = _Sleeper()
    sleeper.start()
    arm.add_sample_callback(got.append)
    time.sleep(3.0)
    arm.remove_sample_callback(got.append)
    sleeper.stop.set()
    sleeper.join()
    starved = emu.control.starved_share(before, emu.control.state())
    t = np.array([s.t_controller for s in got])
    wall = np.array([s.t_wall for s in got])
    rate = (len(t) - 1) / (t[-1] - t[0])
    after, count = missing_slots(t)
    print(f'stream: {len(got)} samples in 3 s, {rate:.1f} Hz, max gap '
          f'{np.diff(t).max() * 1e3:.1f} ms, max wall gap {np.diff(wall).max() * 1e3:.1f} ms '
          f'(a sleeping thread held up to {sleeper.held * 1e3:.1f} ms); '
          f'{int(count.sum())} slots empty in {len(after)} runs; emulator dropped '
          f'{100 * starved:.1f} % of its periods')
    assert np.all(np.diff(t) > 0), 'duplicated or reordered controller timestamps'
    # every slot that passed unread is reported, at the sample after it
    assert not unreported_runs(t, arm.stream_losses())
    if starved > 0.05:
        # a fresh-clone run of the whole suite: 406 samples, the emulator's clock at 57 % of
        # the wall's, 235.5 Hz, a 24 ms gap: the test harness was starved, not the reader
        pytest.skip(f'the emulator was starved ({100 * starved:.0f} % of its periods dropped): '
                    'its stream cannot judge the reader')
    assert abs(rate - 250.0) / 250.0 < 0.05, f'{rate:.1f} Hz'
    # no sample lost against the controller clock (a starved emulator slows its own clock
    # rather than bursting: 2.1-2.6 s of controller time in these 3 s on a busy machine, so
    # wall time only says that the emulator ran at all)
    assert len(got) >= 0.95 * 250 * (t[-1] - t[0])
    assert t[-1] - t[0] >= 1.5
    # delivery to callbacks: below the poke server's F/T stall threshold (50 ms), which is the
    # bound that matters; a fresh-clone CI run on a loaded 2-core machine saw 31 ms, and one
    # 66 ms (session 44, the whole suite on 2 workers): there the bound is what the OS held
    # a thread of this process that only sleeps, plus one 4 ms period
    assert np.diff(wall).max() < max(0.05, sleeper.held + 0.012)
    assert len(arm.samples()) >= len(got)
    assert not arm.active_faults()


def test_a_held_up_stream_worker_reports_the_slots_it_missed(cell):
    """SIGSTOP the stream worker for 80 ms: the samples of that time never reach it (ur_rtde
    keeps the newest), and the stream says so, with how long it was held."""
    emu, arm = cell
    got = []
    arm.add_sample_callback(got.append)
    assert arm.wait_samples(50, 2.0)
    pid = arm.stream_pid
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(0.08)
    finally:
        os.kill(pid, signal.SIGCONT)
    assert arm.wait_samples(100, 3.0)
    arm.remove_sample_callback(got.append)
    t = np.array([s.t_controller for s in got])
    after, count = missing_slots(t)
    assert count.max() >= 10, f'no 40 ms run of empty slots: {count}'
    assert not unreported_runs(t, arm.stream_losses())
    big = [loss for loss in arm.stream_losses() if loss.lost == count.max()]
    assert len(big) == 1 and big[0].held_s >= 0.07
    assert arm.lost_samples >= int(count.sum())
    assert not arm.active_faults()


@pytest.mark.parametrize('hold', [0.08, 0.15])
def test_a_held_up_stream_worker_does_not_take_its_own_hold_for_a_controller_stall(cell, hold):
    """SIGSTOP the stream worker (its poller and ur_rtde's receive thread with it) for longer
    than the 50 ms stall timeout: when it runs again the controller has been streaming all
    along, so no stall may be reported, whichever of its threads runs first (a push that saw
    one aborted on a loaded machine, session 44)."""
    emu, arm = cell
    assert arm.wait_samples(50, 2.0)
    for _ in range(5):
        pid = arm.stream_pid
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(hold)
        finally:
            os.kill(pid, signal.SIGCONT)
        assert arm.wait_samples(50, 3.0)
    stalls = [e for e in arm.events() if e.kind == EVENT_STALL]
    assert not stalls, stalls
    assert not arm.active_faults()


def _fifo_permitted() -> bool:
    """Whether a process of ours may take SCHED_FIFO here (tried in a child)."""
    probe = subprocess.run([sys.executable, '-c', 'import os; os.sched_setscheduler('
                            '0, os.SCHED_FIFO, os.sched_param(1))'], capture_output=True)
    return probe.returncode == 0


def _worker_threads(pid):
    tids = [int(t) for t in os.listdir(f'/proc/{pid}/task')]
    return ({os.sched_getscheduler(t) for t in tids},
            sorted(os.sched_getparam(t).sched_priority for t in tids))


def test_stream_worker_runs_under_the_scheduling_the_os_permits(start_emulator):
    emu = start_emulator(initial_pose=[0.3, 0.0, 0.27, 3.14159265, 0.0, 0.0])
    permitted = _fifo_permitted()
    for priority in (40, 0):
        arm = UrArm(emu.host, rt_priority=priority)
        try:
            policies, priorities = _worker_threads(arm.stream_pid)
            print(priority, arm.stream_scheduling, policies, priorities)
            if priority and permitted:
                assert arm.stream_scheduling.startswith('SCHED_FIFO'), arm.stream_scheduling
                # the poller one below ur_rtde's threads, every thread of the worker real-time
                assert policies == {os.SCHED_FIFO}
                assert priorities[0] == priority - 1 and priorities[-1] == priority
            else:
                assert arm.stream_scheduling.startswith('normal priority')
                assert policies == {os.SCHED_OTHER} and set(priorities) == {0}
            assert arm.wait_samples(25, 2.0), 'the stream does not flow'
        finally:
            arm.close()
    with pytest.raises(InvalidInput, match='rt_priority'):
        UrArm(emu.host, rt_priority=99)
    with pytest.raises(InvalidInput, match='rt_priority'):
        UrArm(emu.host, rt_priority=True)


def test_a_refused_real_time_priority_is_reported_and_the_poller_stays_normal():
    # a child without the right: no rtprio limit and, where we are root, not root any more
    code = ('import os, resource\n'
            'from pointforce_ros.drivers.ur_arm import _realtime_poller\n'
            'resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))\n'
            'if os.geteuid() == 0:\n'
            '    os.setgid(65534); os.setuid(65534)\n'
            'print(_realtime_poller(80))\n'
            'print(os.sched_getscheduler(0) == os.SCHED_OTHER)\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=60, cwd=os.path.dirname(os.path.dirname(os.path.dirname(
                             os.path.abspath(__file__)))))
    assert out.returncode == 0, out.stderr[-2000:]
    message, normal = out.stdout.strip().splitlines()[-2:]
    assert message.startswith('normal priority: SCHED_FIFO 79 refused'), message
    assert 'CAP_SYS_NICE' in message and normal == 'True'
    assert _realtime_poller(0) == 'normal priority (rt_priority 0)'


def test_a_subscriber_that_raises_is_counted_and_the_stream_goes_on(cell):
    _, arm = cell
    seen = []

    def broken(sample):
        raise MemoryError('a subscriber out of memory')
    arm.add_sample_callback(broken)
    arm.add_sample_callback(seen.append)   # after the broken one: still called every time
    assert arm.wait_samples(50, 5.0), 'the stream stopped'
    times = [s.t_controller for s in seen]   # read before the count: each failure comes first
    assert arm.callback_errors >= len(times) >= 50
    assert all(b > a for a, b in zip(times, times[1:]))
    assert 'broken' in arm.last_callback_error and 'MemoryError' in arm.last_callback_error
    arm.remove_sample_callback(broken)
    assert arm.wait_samples(2, 5.0)   # a delivery under way when it was removed has ended
    errors = arm.callback_errors
    assert arm.wait_samples(10, 5.0)
    assert arm.callback_errors == errors and arm.is_connected()


def test_move_speed_and_stop_commands(cell):
    emu, arm = cell
    start = arm.tcp_pose()
    with pytest.raises(UnsafeCommand):
        arm.move_linear(start, speed=2.0)
    with pytest.raises(InvalidInput):
        arm.move_linear(start[:5])
    target = start.copy()
    target[0] += 0.05
    arm.move_linear(target, 0.05, 0.5, asynchronous=True)
    assert arm.is_moving()
    time.sleep(0.3)
    arm.stop(0.5)
    assert not arm.is_moving()
    x = arm.tcp_pose()[0]
    assert start[0] + 0.005 < x < target[0] - 0.02
    arm.speed_linear([0.0, 0.02, 0.0, 0.0, 0.0, 0.0], accel=0.5)
    time.sleep(0.3)
    arm.stop(0.5)
    moved = arm.tcp_pose()[1] - start[1]
    assert 0.002 < moved < 0.008
    arm.move_linear(start, 0.1, 0.5)
    arm.wait_samples(3, 1.0)
    np.testing.assert_allclose(arm.tcp_pose(), start, atol=1e-9)
    arm.tare()
    np.testing.assert_allclose(arm.tcp_wrench(), np.zeros(6), atol=0.03)
    assert arm.is_program_running() and not arm.is_protective_stopped()


def test_push_stops_at_force_limit_and_retracts(cell):
    emu, arm = cell
    with pytest.raises(UnsafeCommand):
        arm.push_until(STANDOFF, DOWN, force_limit=500.0, travel_limit=0.01)
    with pytest.raises(InvalidInput):
        arm.push_until([0.3, 0.0, float('nan'), 0, 0, 0], DOWN, force_limit=5.0,
                       travel_limit=0.01)
    limit = 4.0
    res = arm.push_until(STANDOFF, DOWN, force_limit=limit, travel_limit=0.01, speed=0.004)
    assert res.outcome == 'force_limit'
    force = res.push_force()
    print(f'force limit {limit} N at 4 mm/s into {K:.0f} N/m: peak {res.peak_force:.3f} N')
    # 4 mm/s into 2000 N/m is 8 N/s: one 4 ms sample plus the stop is ~0.05 N
    assert limit <= res.peak_force < limit + 0.1
    assert force.max() == pytest.approx(res.peak_force)
    np.testing.assert_allclose(res.max_travel, 0.002 + limit / K, atol=5e-5)
    assert np.all(np.diff(res.t_controller) > 0)
    np.testing.assert_allclose(res.tcp_pose[-1], STANDOFF, atol=1e-6)   # retracted
    np.testing.assert_allclose(arm.tcp_pose(), STANDOFF, atol=1e-6)
    # recorded from before contact: tared zero first, spring law in contact
    assert abs(force[0]) < 0.05
    inside = res.travel() > 0.0025
    slope = np.polyfit(res.travel()[inside], force[inside], 1)[0]
    print(f'slope through UrArm: {slope:.0f} N/m (k = {K:.0f})')
    assert abs(slope - K) / K < 0.05


def test_push_into_air_ends_at_the_depth_limit(cell):
    emu, arm = cell
    high = list(STANDOFF)
    high[2] = TABLE_Z + 0.02
    res = arm.push_until(high, DOWN, force_limit=5.0, travel_limit=0.005, speed=0.01)
    assert res.outcome == 'depth_limit'
    np.testing.assert_allclose(res.max_travel, 0.005, atol=1e-6)
    assert res.peak_force < 0.1


def test_cancel_ends_the_push(cell):
    emu, arm = cell
    t0 = time.monotonic()
    res = arm.push_until(STANDOFF, DOWN, force_limit=50.0, travel_limit=0.01, speed=0.002,
                         cancel=lambda: time.monotonic() - t0 > 0.6)
    assert res.outcome == 'canceled'
    assert 0.0 < res.max_travel < 0.005


def test_protective_stop_mid_push_raises_with_samples_kept(cell):
    emu, arm = cell
    fired = _inject_when(arm, lambda s: s.wrench[2] > 2.0, emu.control.protective_stop)
    with pytest.raises(PushFault) as info:
        arm.push_until(STANDOFF, DOWN, force_limit=20.0, travel_limit=0.01, speed=0.004)
    fault = info.value
    assert fault.kind == EVENT_PROTECTIVE_STOP and not fault.retracted
    assert fault.result.outcome == 'aborted: protective_stop'
    assert len(fault.result) > 100 and fault.result.push_force().max() > 2.0
    assert fault.detected_wall - fired['t'] < 0.1
    assert arm.is_protective_stopped()
    assert any(e.kind == EVENT_PROTECTIVE_STOP for e in fault.result.events)
    with pytest.raises(DeviceFault, match='protective'):
        arm.move_linear(STANDOFF, 0.05, 0.5)


@pytest.mark.parametrize('what, kind', [('force', EVENT_FT_FROZEN), ('stream', EVENT_STALL)])
def test_ft_stall_raises_within_100_ms(cell, what, kind):
    emu, arm = cell
    before, t0 = emu.control.state(), time.monotonic()
    fired = _inject_when(arm, lambda s: s.wrench[2] > 1.0, lambda: emu.control.stall(what))
    with pytest.raises(PushFault) as info:
        arm.push_until(STANDOFF, DOWN, force_limit=20.0, travel_limit=0.01, speed=0.004)
    fault = info.value
    assert fault.kind == kind
    latency = fault.detected_wall - fired['t']
    # the frozen-force timeout counts controller time, and a starved emulator's clock runs
    # slower than the wall's (a fresh-clone run: 101 ms): the bound is in the emulator's time
    after, t1 = emu.control.state(), time.monotonic()
    dilation = max(1.0, (t1 - t0) / max(after['timestamp'] - before['timestamp'], 1e-3))
    print(f'{kind} detected {latency * 1e3:.0f} ms after the injection (wall / controller '
          f'clock {dilation:.2f})')
    assert latency < 0.1 * dilation, f'{kind} detected after {latency * 1e3:.0f} ms'
    assert len(fault.result) > 50, (fired['t'] - fault.result.t_wall[0], fault.result.events,
                                    fault.result.push_force()[-5:])
    emu.control.unstall()
    if what == 'force':
        assert fault.retracted   # the controller still takes commands: stopped and retracted
        arm.wait_samples(3, 1.0)
        np.testing.assert_allclose(arm.tcp_pose(), STANDOFF, atol=1e-6)


def test_dropped_connection_raises(cell):
    emu, arm = cell
    _inject_when(arm, lambda s: s.wrench[2] > 1.0, lambda: emu.control.drop(refuse_s=1.0))
    with pytest.raises(PushFault) as info:
        arm.push_until(STANDOFF, DOWN, force_limit=20.0, travel_limit=0.01, speed=0.004)
    assert info.value.kind == EVENT_CONNECTION_LOST
    assert len(info.value.result) > 50
    assert not arm.is_connected()
    with pytest.raises(DeviceFault, match='connection lost'):
        arm.tare()


def test_an_abort_message_names_only_the_faults_still_active():
    """Issue 16: 'no new controller sample for 0.050 s; controller samples flowing again; RTDE
    connection ... lost' named a stall and its recovery beside the fault that ended the push.
    """
    events = [ArmEvent(EVENT_STALL, 1.0, 'no new controller sample for 0.050 s'),
              ArmEvent(EVENT_STALL + '_cleared', 1.1, 'controller samples flowing again'),
              ArmEvent(EVENT_CONNECTION_LOST, 1.2, 'RTDE connection to 127.0.0.2 lost')]
    message = active_fault_message(events, [EVENT_CONNECTION_LOST])
    assert message == 'RTDE connection to 127.0.0.2 lost'
    # a stall that came back is named again, after the more fundamental fault
    events.append(ArmEvent(EVENT_STALL, 1.3, 'no new controller sample for 0.060 s'))
    assert active_fault_message(events, [EVENT_STALL, EVENT_CONNECTION_LOST]) == (
        'RTDE connection to 127.0.0.2 lost; no new controller sample for 0.060 s')
    # an active fault whose events fell out of the log is still named by its kind
    assert active_fault_message(events[-1:], [EVENT_FT_FROZEN]) == EVENT_FT_FROZEN


def test_an_aborted_interface_host_is_a_lost_connection_not_a_lost_process(cell):
    """CI, session 17: a ur_rtde destructor that threw (std::terminate) aborted the poke
    server in destroy_node and the whole test session with it. The interfaces now live in a
    host process; its abort mid-push is a fault of this push, with the samples kept.
    """
    emu, arm = cell
    assert arm.host_pid != os.getpid()
    _inject_when(arm, lambda s: s.wrench[2] > 1.0,
                 lambda: os.kill(arm.host_pid, signal.SIGABRT))
    with pytest.raises(PushFault) as info:
        arm.push_until(STANDOFF, DOWN, force_limit=20.0, travel_limit=0.01, speed=0.004)
    # the push ends on the dead host, or on the stall its death causes first: the emulator's
    # 500 Hz loop pauses while the control connection drops, and the stream worker, real-time
    # now, sees a 50 ms pause at once (seen once in this file's runs of session 33)
    message = str(info.value)
    assert ('host process is gone (killed by signal 6)' in message
            or 'no new controller sample' in message), message
    assert len(info.value.result) > 50
    assert not arm.is_connected()
    with pytest.raises(DeviceFault, match='connection lost'):
        arm.tare()
    t0 = time.monotonic()
    arm.close()
    assert time.monotonic() - t0 < 3.0
    # the controller is fine: a new arm connects, pushes and closes
    with UrArm(emu.host) as again:
        result = again.push_until(STANDOFF, DOWN, force_limit=2.0, travel_limit=0.01,
                                  speed=0.004)
        assert result.outcome == 'force_limit'


def test_a_ur_rtde_error_comes_back_with_its_type_and_message(cell):
    _, arm = cell
    with pytest.raises(TypeError, match='incompatible function arguments'):
        arm._ctrl.moveL('not a pose')
    assert arm.is_connected()   # a refused call leaves the interface usable
    up = arm.tcp_pose() + [0.0, 0.0, 0.05, 0.0, 0.0, 0.0]
    with pytest.raises(RuntimeError, match='no reply within 0.05 s'):
        arm._ctrl.call('moveL', (up.tolist(), 0.05, 0.5, False), 0.05)   # takes ~1 s
    with pytest.raises(RuntimeError, match='abandoned'):
        arm._ctrl.isConnected()   # its late answer would be read as this one's: refused
    assert not arm.is_connected()
