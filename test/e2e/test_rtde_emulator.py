"""The RTDE controller emulator, driven only through the real ur_rtde 1.6.5 (+ fault channel)."""

import subprocess
import sys
import time

import numpy as np
import pytest

from pointforce_ros.drivers.rtde_host import RtdeHost
from pointforce_ros.errors import DeviceFault
from pointforce_ros.sim.rtde.process import _ready_or_exit_code, start_emulator as start_process

pytestmark = pytest.mark.e2e

START = [0.3, -0.1, 0.3, 3.14159265, 0.0, 0.0]


def _connect(host, frequency=500.0):
    """(control, receive) interfaces with every output variable, in a host process (an
    interface whose controller stalled or dropped can abort the process that destroys it)."""
    rtde = RtdeHost(host, frequency, [], 10.0)
    return rtde.ctrl, rtde.rx


def _disconnect(ctrl, rx):
    ctrl.rtde_host.close()


def _wait_for(condition, timeout, message):
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, message
        time.sleep(0.002)


def _record(rx, seconds, getter='getActualTCPForce'):
    """(t_controller, pose (N, 6), values (N, 6)) of every new sample for ``seconds``."""
    ts, poses, vals = [], [], []
    last = None
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        t = rx.getTimestamp()
        if t != last:
            last = t
            ts.append(t)
            poses.append(rx.getActualTCPPose())
            vals.append(getattr(rx, getter)())
        time.sleep(0.0005)
    return np.array(ts), np.array(poses), np.array(vals)


def test_handshake_stream_and_registers_in_use(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        assert ctrl.isConnected() and rx.isConnected()
        assert ctrl.isProgramRunning()
        assert rx.getRuntimeState() == 2
        assert rx.getRobotMode() == 7 and rx.getSafetyMode() == 1
        assert not rx.isProtectiveStopped()
        np.testing.assert_allclose(rx.getActualTCPPose(), START, atol=1e-9)
        # 500 Hz controller clock; periods the starved emulator skipped are counted
        s0, w0 = emu.control.state(), time.monotonic()
        time.sleep(0.5)
        s1, w1 = emu.control.state(), time.monotonic()
        periods = (s1['tick'] - s0['tick']) + (s1['late_ticks'] - s0['late_ticks'])
        assert abs(periods * 0.002 / (w1 - w0) - 1.0) < 0.05
        assert s1['timestamp'] == pytest.approx(s1['tick'] * 0.002)
        ts, _, _ = _record(rx, 0.3)
        steps = np.round(np.diff(ts) / 0.002).astype(int)
        assert steps.min() >= 1 and np.all(np.abs(np.diff(ts) - steps * 0.002) < 1e-9)
        # a second control interface wants the same input registers: the controller refuses
        with pytest.raises(RuntimeError, match='in use'):
            _connect(emu.host)
    finally:
        _disconnect(ctrl, rx)
    emu.stop()   # SIGTERM: clean exit
    assert emu.process.returncode == 0, emu.log()


def test_movel_sync_reaches_target_with_trapezoidal_timing(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        target = [0.35, -0.05, 0.25, 3.0, 0.2, -0.1]
        speed, accel = 0.1, 1.0
        dist = np.linalg.norm(np.subtract(target[:3], START[:3]))
        expected = dist / speed + speed / accel
        t0 = rx.getTimestamp()
        assert ctrl.moveL(target, speed, accel)
        elapsed = rx.getTimestamp() - t0   # controller time (rx may be one period behind)
        time.sleep(0.02)
        np.testing.assert_allclose(rx.getActualTCPPose()[:3], target[:3], atol=1e-9)
        np.testing.assert_allclose(rx.getActualTCPPose()[3:], target[3:], atol=1e-9)
        assert expected - 0.01 < elapsed < expected + 0.1, (elapsed, expected)
        np.testing.assert_allclose(rx.getActualTCPSpeed(), np.zeros(6), atol=1e-12)
        assert ctrl.getAsyncOperationProgress() < 0
    finally:
        _disconnect(ctrl, rx)


def test_async_movel_then_stopl_stops_early(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        target = list(START)
        target[0] += 0.1
        speed, decel = 0.05, 0.5
        assert ctrl.moveL(target, speed, 1.0, True)
        assert ctrl.getAsyncOperationProgress() >= 0
        time.sleep(0.5)
        x_at_stop = rx.getActualTCPPose()[0]
        ctrl.stopL(decel)
        time.sleep(0.02)   # rx may be a controller period behind the control interface
        x_end = rx.getActualTCPPose()[0]
        time.sleep(0.05)
        np.testing.assert_allclose(rx.getActualTCPSpeed(), np.zeros(6), atol=1e-12)
        assert rx.getActualTCPPose()[0] == x_end
        assert ctrl.getAsyncOperationProgress() < 0
        travelled = x_end - START[0]
        assert 0.01 < travelled < 0.09
        braking = speed ** 2 / (2 * decel)
        # stopL returns once at rest: braking distance plus a few controller cycles of latency
        assert x_at_stop + 0.5 * braking < x_end < x_at_stop + braking + 0.01 * speed
    finally:
        _disconnect(ctrl, rx)


def test_speedl_and_speedstop(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        xd = [0.0, 0.0, 0.02, 0.0, 0.0, 0.0]
        assert ctrl.speedL(xd, 0.5, 0.0)
        time.sleep(0.3)
        np.testing.assert_allclose(rx.getActualTCPSpeed(), xd, atol=1e-12)
        z_before = rx.getActualTCPPose()[2]
        assert ctrl.speedStop(0.5)
        time.sleep(0.02)
        np.testing.assert_allclose(rx.getActualTCPSpeed(), np.zeros(6), atol=1e-12)
        stop_dist = rx.getActualTCPPose()[2] - z_before
        braking = 0.02 ** 2 / (2 * 0.5)
        assert braking * 0.9 < stop_dist < braking + 0.02 * 0.02, (stop_dist, braking)
    finally:
        _disconnect(ctrl, rx)


def test_zero_ft_sensor_removes_the_offset(start_emulator):
    # the TCP starts 2 mm inside a 1000 N/m table: 2 N before the tare
    pose = [0.3, 0.0, 0.298, 3.14159265, 0.0, 0.0]
    emu = start_emulator(initial_pose=pose,
                         force_model_kwargs={'z0': 0.3, 'k': 1000.0})
    ctrl, rx = _connect(emu.host)
    try:
        # starting the control program re-tared the sensor, so undo that first
        up = list(pose)
        up[2] = 0.31
        assert ctrl.moveL(up, 0.1, 1.0)
        time.sleep(0.05)
        np.testing.assert_allclose(rx.getActualTCPForce()[2], -2.0, atol=0.03)
        assert ctrl.zeroFtSensor()
        time.sleep(0.05)
        np.testing.assert_allclose(rx.getActualTCPForce(), np.zeros(6), atol=0.03)
        assert ctrl.moveL(pose, 0.1, 1.0)
        time.sleep(0.05)
        np.testing.assert_allclose(rx.getActualTCPForce()[:3], [0.0, 0.0, 2.0], atol=0.03)
    finally:
        _disconnect(ctrl, rx)


def test_push_into_half_space_spring_gives_its_stiffness(start_emulator):
    k = 2500.0
    emu = start_emulator(initial_pose=[0.3, 0.0, 0.302, 3.14159265, 0.0, 0.0],
                         force_model_kwargs={'z0': 0.3, 'k': k, 'noise_std': 0.05, 'seed': 3})
    ctrl, rx = _connect(emu.host)
    try:
        assert ctrl.zeroFtSensor()
        assert ctrl.moveL([0.3, 0.0, 0.296, 3.14159265, 0.0, 0.0], 0.005, 0.5, True)
        ts, poses, forces = _record(rx, 1.4)
        ctrl.stopL(1.0)
        depth = 0.3 - poses[:, 2]
        inside = depth > 0.0005
        slope, _ = np.polyfit(depth[inside], forces[inside, 2], 1)
        assert abs(slope - k) / k < 0.05, f'slope {slope:.0f} N/m against k = {k:.0f} N/m'
        assert np.all(np.abs(forces[depth < -0.0005, 2]) < 0.3)  # no force before contact
        # live parameter change on the fault channel: same depth, new stiffness
        emu.control.model_params(k=1000.0, noise_std=0.0)
        time.sleep(0.05)
        z = rx.getActualTCPPose()[2]
        np.testing.assert_allclose(rx.getActualTCPForce()[2], 1000.0 * (0.3 - z)
                                   - (forces[0, 2] - k * max(depth[0], 0.0)), atol=0.2)
    finally:
        _disconnect(ctrl, rx)


def test_protective_stop_injection_halts_motion(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        target = list(START)
        target[1] += 0.2
        assert ctrl.moveL(target, 0.1, 1.0, True)
        time.sleep(0.2)
        emu.control.protective_stop()
        _wait_for(rx.isProtectiveStopped, 0.1, 'isProtectiveStopped not true within 100 ms')
        time.sleep(0.05)
        y = rx.getActualTCPPose()[1]
        time.sleep(0.1)
        assert rx.getActualTCPPose()[1] == y and y < target[1] - 0.1
        assert rx.getSafetyMode() == 3
        assert not ctrl.moveL(START, 0.1, 1.0)   # refused while protective stopped
        assert emu.control.unlock()
        _wait_for(lambda: not rx.isProtectiveStopped(), 0.1, 'protective stop not released')
        assert ctrl.reuploadScript()   # returns once the script is sent, not yet running
        _wait_for(lambda: rx.getRuntimeState() == 2, 1.0, 'script not running after re-upload')
        # the control interface reads its own state stream: moveL refuses until it too sees
        # the program running (a cycle or more after the receive interface on a busy machine)
        _wait_for(ctrl.isProgramRunning, 1.0, 'the control interface never saw the script run')
        assert ctrl.moveL(START, 0.1, 1.0)
        # the receive stream may still hold the sample from one period before the move ended
        _wait_for(lambda: np.allclose(rx.getActualTCPPose(), START, rtol=1e-7, atol=1e-9), 0.1,
                  'the arm is not reported back at START within 100 ms of moveL returning')
    finally:
        _disconnect(ctrl, rx)


def test_move_until_contact_returns_to_the_contact_point(start_emulator):
    emu = start_emulator(initial_pose=[0.3, 0.0, 0.31, 3.14159265, 0.0, 0.0],
                         force_model_kwargs={'z0': 0.3, 'k': 5000.0})
    ctrl, rx = _connect(emu.host)
    try:
        assert ctrl.moveUntilContact([0, 0, -0.02, 0, 0, 0], [0, 0, -1, 0, 0, 0], 0.5)
        time.sleep(0.02)
        z = rx.getActualTCPPose()[2]
        # contact threshold 1 N at 5000 N/m is 0.2 mm deep; onset is at 0.05 mm
        assert 0.3 - 0.0002 < z <= 0.3, z
        assert abs(rx.getActualTCPSpeed()[2]) < 1e-12
    finally:
        _disconnect(ctrl, rx)


def test_contact_detection_stops_an_async_move(start_emulator):
    emu = start_emulator(initial_pose=[0.3, 0.0, 0.305, 3.14159265, 0.0, 0.0],
                         force_model_kwargs={'z0': 0.3, 'k': 5000.0})
    ctrl, rx = _connect(emu.host)
    try:
        assert ctrl.startContactDetection([0, 0, -1, 0, 0, 0])
        assert ctrl.moveL([0.3, 0.0, 0.28, 3.14159265, 0.0, 0.0], 0.02, 0.5, True)
        # no command while waiting: the control script drops its internal contact-stop command
        # when it coincides with the first idle cycle after another command (a race that is in
        # ur_rtde's script as well), so polling readContactDetection could swallow the stop
        _wait_for(lambda: rx.getActualTCPPose()[2] < 0.3 and rx.getActualTCPSpeed()[2] == 0.0,
                  3.0, 'the move did not stop at the contact')
        time.sleep(0.1)
        assert ctrl.readContactDetection()
        assert ctrl.stopContactDetection()
        assert 0.3 - 0.0005 < rx.getActualTCPPose()[2] <= 0.3
        assert abs(rx.getActualTCPSpeed()[2]) < 1e-12
    finally:
        _disconnect(ctrl, rx)


def test_program_stop_and_dropped_connection(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        emu.control.program_stop()
        time.sleep(0.02)
        assert not ctrl.isProgramRunning() and rx.getRuntimeState() == 1
        assert not ctrl.moveL(START, 0.1, 1.0)
        emu.control.drop(refuse_s=2.0)
        _wait_for(lambda: not rx.isConnected(), 0.5, 'receive interface connected after a drop')
    finally:
        _disconnect(ctrl, rx)


def test_force_and_stream_stalls(start_emulator):
    emu = start_emulator(initial_pose=START)
    ctrl, rx = _connect(emu.host)
    try:
        emu.control.stall('force')
        time.sleep(0.02)
        # every poll is a round trip to the host process: 0.2 s gave 29-43 samples on a busy
        # machine, so the frozen force is watched over half a second
        _, _, forces = _record(rx, 0.5)
        assert len(forces) > 50 and np.all(forces == forces[0])
        emu.control.unstall()
        _, _, forces = _record(rx, 0.1)
        assert len(np.unique(forces[:, 0])) > 10
        emu.control.stall('stream', 0.3)
        time.sleep(0.01)
        t0 = rx.getTimestamp()
        time.sleep(0.2)
        assert rx.getTimestamp() == t0
        time.sleep(0.3)
        assert rx.getTimestamp() > t0 and rx.isConnected()
    finally:
        _disconnect(ctrl, rx)


def test_an_emulator_that_exits_at_start_says_so_with_its_reason(tmp_path):
    # a bad argument ends it at once: that is not a readiness timeout
    with pytest.raises(DeviceFault, match=r'exited with code 2 before it was ready:'
                                          r'(.|\n)*--rtde-port'):
        start_process(tmp_path, extra_args=['--rtde-port', 'not-a-port'], ready_timeout=60.0)


def test_a_process_that_closes_its_stdout_before_it_exits_is_not_a_readiness_timeout():
    # stdout reaches end-of-file before the exit status exists (session 37: the test above
    # read "did not become ready" once); here the gap is half a second, not a race
    quitter = subprocess.Popen(
        [sys.executable, '-c', 'import os, sys, time; os.close(1); time.sleep(0.5); sys.exit(2)'],
        stdout=subprocess.PIPE, text=True)
    try:
        assert _ready_or_exit_code(quitter, 30.0) == (False, 2)
    finally:
        quitter.kill()
        quitter.communicate()
    waiter = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)'],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert _ready_or_exit_code(waiter, 0.5) == (False, None)     # still running: a timeout
    finally:
        waiter.kill()
        waiter.communicate()
