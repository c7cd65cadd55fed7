"""The tf buffer without tf2: composition, interpolation, refusals and waiting."""

import math
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pointforce_ros import frames
from pointforce_ros.errors import InvalidInput
from pointforce_ros.frames import Extrapolation, TransformBuffer, TransformUnavailable


def _random_transform(rng):
    m = np.eye(4)
    m[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    m[:3, 3] = rng.uniform(-1.0, 1.0, 3)
    return m


def _set(buf, parent, child, m, stamp=0.0, static=True):
    q = Rotation.from_matrix(m[:3, :3]).as_quat()
    buf.set_transform(parent, child, stamp, m[:3, 3], q, static=static)


def test_chain_and_branches_compose_like_matrices():
    rng = np.random.default_rng(3)
    mount, cam, other = (_random_transform(rng) for _ in range(3))
    buf = TransformBuffer()
    _set(buf, 'base', 'mount', mount)
    _set(buf, 'mount', 'camera_optical', cam)
    _set(buf, '/base', 'tool0', other)     # a ROS 1 style leading slash is dropped
    np.testing.assert_allclose(buf.lookup('base', 'camera_optical'), mount @ cam, atol=1e-12)
    np.testing.assert_allclose(buf.lookup('camera_optical', 'base'),
                               np.linalg.inv(mount @ cam), atol=1e-12)
    # across branches: tool0 <- camera through their common ancestor
    np.testing.assert_allclose(buf.lookup('tool0', 'camera_optical'),
                               np.linalg.inv(other) @ mount @ cam, atol=1e-12)
    np.testing.assert_allclose(buf.lookup('mount', 'mount'), np.eye(4))
    assert buf.frames() == ['base', 'camera_optical', 'mount', 'tool0']


def test_dynamic_edge_interpolates_and_refuses_outside_its_history():
    buf = TransformBuffer()
    buf.set_transform('base', 'tool0', 10.0, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0])
    quarter = Rotation.from_euler('z', 90, degrees=True).as_quat()
    buf.set_transform('base', 'tool0', 11.0, [0.2, 0.0, -0.4], quarter)
    mid = buf.lookup('base', 'tool0', 10.5)
    np.testing.assert_allclose(mid[:3, 3], [0.1, 0.0, -0.2], atol=1e-12)
    angle = Rotation.from_matrix(mid[:3, :3]).as_euler('xyz', degrees=True)
    np.testing.assert_allclose(angle, [0.0, 0.0, 45.0], atol=1e-9)
    with pytest.raises(Extrapolation, match='not arrived yet') as late:
        buf.lookup('base', 'tool0', 11.01)
    assert late.value.future
    with pytest.raises(Extrapolation) as early:
        buf.lookup('base', 'tool0', 9.99)
    assert not early.value.future
    # a tolerance takes the nearest end
    loose = TransformBuffer(tolerance=0.02)
    loose.set_transform('base', 'tool0', 11.0, [0.2, 0.0, -0.4], quarter)
    np.testing.assert_allclose(loose.lookup('base', 'tool0', 11.015)[:3, 3], [0.2, 0.0, -0.4])


def test_latest_lookup_takes_the_latest_time_every_edge_holds():
    buf = TransformBuffer()
    for t in (0.0, 1.0, 2.0, 3.0):
        buf.set_transform('base', 'arm', t, [t, 0.0, 0.0], [0, 0, 0, 1])
    for t in (0.0, 1.0):
        buf.set_transform('arm', 'camera', t, [0.0, t, 0.0], [0, 0, 0, 1])
    # the camera edge ends at 1 s: the arm is taken at 1 s too, not at its own newest 3 s
    np.testing.assert_allclose(buf.lookup('base', 'camera')[:3, 3], [1.0, 1.0, 0.0])


def test_cache_keeps_its_window_only():
    buf = TransformBuffer()
    for t in np.arange(0.0, frames.CACHE_SECONDS + 5.0, 0.5):
        buf.set_transform('base', 'tool0', float(t), [float(t), 0, 0], [0, 0, 0, 1])
    with pytest.raises(Extrapolation, match='older than'):
        buf.lookup('base', 'tool0', 1.0)
    np.testing.assert_allclose(buf.lookup('base', 'tool0', 10.25)[:3, 3], [10.25, 0, 0])


def test_a_publisher_gone_back_in_time_restarts_its_edge():
    buf = TransformBuffer()
    for t in (1000.0, 1000.5):                      # a live cell
        buf.set_transform('base', 'tool0', t, [t, 0, 0], [0, 0, 0, 1])
    buf.set_transform('base', 'tool0', 20.0, [20.0, 0, 0], [0, 0, 0, 1])   # a bag replayed
    buf.set_transform('base', 'tool0', 20.5, [20.5, 0, 0], [0, 0, 0, 1])
    np.testing.assert_allclose(buf.lookup('base', 'tool0', 20.25)[:3, 3], [20.25, 0, 0])
    np.testing.assert_allclose(buf.lookup('base', 'tool0')[:3, 3], [20.5, 0, 0])
    with pytest.raises(Extrapolation):
        buf.lookup('base', 'tool0', 1000.0)
    # a sample late within the window is still put in its place
    buf.set_transform('base', 'tool0', 19.0, [19.0, 0, 0], [0, 0, 0, 1])
    np.testing.assert_allclose(buf.lookup('base', 'tool0', 19.5)[:3, 3], [19.5, 0, 0])


@pytest.mark.parametrize('args, reason', [
    (('base', 'cam', 0.0, [np.nan, 0, 0], [0, 0, 0, 1]), 'non-finite'),
    (('base', 'cam', 0.0, [0, 0, 0], [0, 0, 0, 2.0]), 'not unit'),
    (('base', 'cam', 0.0, [0, 0, 0], [0, 0, 0]), r'\(4,\)'),
    (('', 'cam', 0.0, [0, 0, 0], [0, 0, 0, 1]), 'empty frame'),
    (('cam', 'cam', 0.0, [0, 0, 0], [0, 0, 0, 1]), 'its own parent'),
    (('base', 'cam', math.inf, [0, 0, 0], [0, 0, 0, 1]), 'stamp'),
])
def test_bad_transforms_are_refused_with_the_reason(args, reason):
    buf = TransformBuffer()
    with pytest.raises(InvalidInput, match=reason):
        buf.set_transform(*args)
    assert buf.refused == 1 and buf.frames() == []


def test_a_loop_is_refused_and_a_new_parent_replaces_the_old():
    buf = TransformBuffer()
    _set(buf, 'base', 'mount', np.eye(4))
    _set(buf, 'mount', 'cam', np.eye(4))
    with pytest.raises(InvalidInput, match='a loop'):
        _set(buf, 'cam', 'base', np.eye(4))
    moved = np.eye(4)
    moved[:3, 3] = [0.0, 0.0, 0.3]
    _set(buf, 'tool0', 'cam', moved)        # the camera re-mounted on the tool
    with pytest.raises(TransformUnavailable, match='not connected'):
        buf.lookup('base', 'cam')
    np.testing.assert_allclose(buf.lookup('tool0', 'cam'), moved)


def test_unknown_frames_are_named(monkeypatch):
    buf = TransformBuffer()
    with pytest.raises(TransformUnavailable, match='nothing heard'):
        buf.lookup('base', 'cam')
    _set(buf, 'base', 'cam', np.eye(4))
    with pytest.raises(TransformUnavailable, match="'second_cam' is not in the tf tree"):
        buf.lookup('base', 'second_cam')
    monkeypatch.setattr(frames, 'MAX_FRAMES', 3)
    _set(buf, 'base', 'a', np.eye(4))
    with pytest.raises(InvalidInput, match='at most 3'):
        _set(buf, 'base', 'b', np.eye(4))


def test_chains_are_bounded_and_a_hostile_tree_stays_cheap():
    buf = TransformBuffer()
    eye = ([0, 0, 0], [0, 0, 0, 1])
    for k in range(frames.MAX_DEPTH):           # base <- f1 <- ... <- f1000
        buf.set_transform('base' if k == 0 else f'f{k}', f'f{k + 1}', 0.0, *eye, static=True)
    with pytest.raises(InvalidInput, match='a chain of more than 1000'):
        buf.set_transform(f'f{frames.MAX_DEPTH}', 'deeper', 0.0, *eye, static=True)
    with pytest.raises(InvalidInput, match='a chain of more than 1000'):    # from the top too
        buf.set_transform('world', 'base', 0.0, *eye, static=True)
    np.testing.assert_allclose(buf.lookup('base', f'f{frames.MAX_DEPTH}'), np.eye(4))
    # 5000 leaves under one parent, then 5000 updates of them: each insert is a bounded walk
    for k in range(5000):
        buf.set_transform('f500', f'leaf{k}', 1.0, *eye)
    for k in range(5000):
        buf.set_transform('f500', f'leaf{k}', 2.0, *eye)
    assert len(buf.frames()) == 1 + frames.MAX_DEPTH + 5000


def test_total_samples_are_bounded(monkeypatch):
    monkeypatch.setattr(frames, 'MAX_TOTAL_SAMPLES', 5)
    buf = TransformBuffer()
    for t in range(5):
        buf.set_transform('base', 'tool0', float(t), [0, 0, 0], [0, 0, 0, 1])
    with pytest.raises(InvalidInput, match='5 samples'):
        buf.set_transform('base', 'tool0', 5.0, [0, 0, 0], [0, 0, 0, 1])
    buf.clear()
    assert buf.frames() == []
    buf.set_transform('base', 'tool0', 6.0, [0, 0, 0.1], [0, 0, 0, 1])
    np.testing.assert_allclose(buf.lookup('base', 'tool0')[:3, 3], [0, 0, 0.1])


def _wait_for_late(buf, transform, lookup):
    """Return ``buf.wait_transform(*lookup)`` while ``transform`` is set 50 ms later."""
    def late():
        time.sleep(0.05)
        buf.set_transform(*transform)

    thread = threading.Thread(target=late)
    thread.start()
    try:
        return buf.wait_transform(*lookup, timeout=10.0)
    finally:
        thread.join()


def test_wait_transform_waits_for_a_transform_in_flight_only():
    buf = TransformBuffer()
    buf.set_transform('base', 'cam', 1.0, [0, 0, 0], [0, 0, 0, 1])
    got = _wait_for_late(buf, ('base', 'cam', 2.0, [0, 0, 0.5], [0, 0, 0, 1]),
                         ('base', 'cam', 2.0))
    np.testing.assert_allclose(got[:3, 3], [0, 0, 0.5])
    # a time already dropped, or two known frames not connected, is refused without waiting
    _set(buf, 'world', 'map', np.eye(4))
    start = time.monotonic()
    with pytest.raises(Extrapolation):
        buf.wait_transform('base', 'cam', 0.5, timeout=10.0)
    with pytest.raises(TransformUnavailable, match='not connected'):
        buf.wait_transform('base', 'map', None, timeout=10.0)
    assert time.monotonic() - start < 5.0
    with pytest.raises(Extrapolation, match='not arrived'):
        buf.wait_transform('base', 'cam', 3.0, timeout=0.05)


def test_a_frame_waited_for_in_vain_is_not_waited_for_again_until_a_transform_names_it(
        monkeypatch):
    """Session 43: each request in a frame nobody publishes held a service thread the whole
    wait (tf_wait); a client asking again and again could hold every thread."""
    buf = TransformBuffer()
    buf.set_transform('base', 'cam', 0.0, [0, 0, 0], [0, 0, 0, 1], static=True)
    buf.set_transform('base', 'arm', 1.0, [0, 0, 0], [0, 0, 0, 1])
    start = time.monotonic()
    with pytest.raises(TransformUnavailable) as first:
        buf.wait_transform('base', 'ghost', None, timeout=0.2)
    assert time.monotonic() - start >= 0.2 and not isinstance(first.value, frames.NotWaited)
    start = time.monotonic()
    for _ in range(50):                    # refused at once, each counted, saying why
        with pytest.raises(frames.NotWaited, match="no transform has named 'ghost' since a "
                           'wait for it ran out'):
            buf.wait_transform('ghost', 'base', None, timeout=0.2)
    assert time.monotonic() - start < 0.2 and buf.not_waited == 50
    # a future time of a known frame is waited for every time (a /tf that lags, not a frame
    # nobody publishes)
    for _ in range(2):
        start = time.monotonic()
        with pytest.raises(Extrapolation, match='not arrived'):
            buf.wait_transform('base', 'arm', 5.0, timeout=0.1)
        assert time.monotonic() - start >= 0.1
    assert buf.not_waited == 50

    # once a transform names it, it is waited for again (and found)
    buf.set_transform('cam', 'ghost', 1.0, [0, 0, 0.1], [0, 0, 0, 1])
    got = _wait_for_late(buf, ('cam', 'ghost', 2.0, [0, 0, 0.2], [0, 0, 0, 1]),
                         ('base', 'ghost', 2.0))
    np.testing.assert_allclose(got[:3, 3], [0, 0, 0.2])
    # a jump back in time (clear) forgets the frames waited for in vain with the rest
    with pytest.raises(TransformUnavailable):
        buf.wait_transform('base', 'other', None, timeout=0.01)
    buf.clear()
    buf.set_transform('base', 'cam', 1.0, [0, 0, 0], [0, 0, 0, 1])
    start = time.monotonic()
    with pytest.raises(TransformUnavailable) as again:
        buf.wait_transform('base', 'other', None, timeout=0.1)
    assert time.monotonic() - start >= 0.1 and not isinstance(again.value, frames.NotWaited)
    # the memory of such frames is bounded: the oldest is forgotten first
    monkeypatch.setattr(frames, 'MAX_VAIN', 3)
    for name in ('a', 'b', 'c', 'd'):
        with pytest.raises(TransformUnavailable):
            buf.wait_transform('base', name, None, timeout=0.0)
    with pytest.raises(frames.NotWaited):
        buf.wait_transform('base', 'd', None, timeout=1.0)
    start = time.monotonic()
    with pytest.raises(TransformUnavailable) as oldest:
        buf.wait_transform('base', 'a', None, timeout=0.05)
    assert time.monotonic() - start >= 0.05 and not isinstance(oldest.value, frames.NotWaited)


def test_samples_ahead_of_tf_wait_for_it_in_order_and_are_given_up_with_a_reason():
    """Session 42: a pose stream in a frame /tf places ran ahead of a slower /tf, and its
    newest samples were refused as extrapolation instead of waiting for the transform."""
    buf = TransformBuffer()
    world = np.eye(4)
    world[:3, 3] = [1.0, 0.0, 0.0]
    _set(buf, 'base', 'world', world, stamp=0.0, static=False)

    def place(stamp):
        return stamp, buf.lookup('base', 'world', stamp)[0, 3]

    waiting = frames.AwaitingTransform(seconds=0.3)
    assert waiting.offer(0.0, 0.0, place) == ([(0.0, 1.0)], [])
    for t in (0.1, 0.2):                    # tf's newest sample is at 0: these wait
        assert waiting.offer(t, t, place) == ([], [])
    assert len(waiting) == 2 and waiting.held_back == 2
    world[:3, 3] = [2.0, 0.0, 0.0]         # the buffer holds a copy (it held the caller's
    _set(buf, 'base', 'world', world, stamp=0.2, static=False)   # array before session 42)
    placed, refused = waiting.offer(0.25, 0.25, place)      # both placed, in order, at their
    np.testing.assert_allclose(placed, [(0.1, 1.5), (0.2, 2.0)])  # own stamps; 0.25 waits
    assert refused == [] and len(waiting) == 1
    placed, refused = [], []
    for t in (0.3, 0.4, 0.5, 0.6):          # no tf for over 0.3 s of newer stamps: given up
        out = waiting.offer(t, t, place)
        placed, refused = placed + out[0], refused + out[1]
    assert placed == [] and [r[0] for r in refused] == [0.25]
    assert 'no transform came while 4 newer sample(s) waited' in refused[0][1]
    # a stream gone back in time (a bag replayed) gives up what waits: it would hold the new
    # timeline up behind it
    placed, refused = waiting.offer(0.0, 0.0, place)
    assert placed == [(0.0, 1.0)] and [r[0] for r in refused] == [0.3, 0.4, 0.5, 0.6]
    assert 'went back in time' in refused[0][1] and len(waiting) == 0

    def bad(_):
        raise InvalidInput('non-finite position')

    fresh = frames.AwaitingTransform()     # one that cannot be placed is refused at once
    assert fresh.offer(1.0, 'x', bad) == ([], [('x', 'non-finite position')])
    assert len(fresh) == 0
    past = frames.AwaitingTransform()
    placed, refused = past.offer(-5.0, -5.0, place)
    assert placed == [] and refused[0][0] == -5.0 and len(past) == 0


def test_held_samples_are_bounded_in_number():
    buf = TransformBuffer()
    _set(buf, 'base', 'world', np.eye(4), stamp=0.0, static=False)
    waiting = frames.AwaitingTransform(seconds=100.0, size=5)
    refused = []
    for k in range(1, 9):
        refused += waiting.offer(k * 1e-3, k, lambda t: buf.lookup('base', 'world', t * 1e-3))[1]
    assert len(waiting) == 5 and [r[0] for r in refused] == [1, 2, 3]
