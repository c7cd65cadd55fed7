"""The frame tree that ``/tf`` and ``/tf_static`` carry, looked up by time, without tf2.

No PyPI wheel carries tf2 or tf2_ros, so the nodes keep their own buffer of the transforms a
real cell publishes (the robot's ``robot_state_publisher``, a hand-eye calibration's static
camera mount, a camera driver's optical frames) and look a cloud's ``frame_id`` up in it at the
cloud's stamp, as ``tf2_ros.Buffer.lookup_transform`` would. This module is the pure part (no
rclpy); :class:`pointforce_ros.nodes.common.TfListener` feeds it from the two topics.

What it keeps, as tf2's ``BufferCore`` does:

- each frame has one parent; a transform ``parent <- child`` is either static (one value for
  all time) or dynamic (a history over the last :data:`CACHE_SECONDS` of its own stamps);
- a lookup at time ``t`` walks both frames up to their common ancestor and composes the edges,
  each dynamic edge interpolated at ``t`` (linear in translation, spherical in rotation);
  ``t`` ``None`` (tf2's time zero) takes the latest time every dynamic edge on the path has;
- a time outside an edge's history is refused (tf2's ``ExtrapolationException``), past the
  ``tolerance`` seconds the caller allows.

What it refuses, with the reason: a non-finite or non-unit transform, an empty frame name, a
frame made its own parent or an ancestor of its parent (a loop), a chain deeper than
:data:`MAX_DEPTH`, more than :data:`MAX_FRAMES` frames or :data:`MAX_TOTAL_SAMPLES` samples. A
child that is given a new parent takes it (its history is restarted), as a re-mounted camera
would; a dynamic sample older than everything its edge keeps restarts that edge's history too
(its publisher went back in time: a bag replayed, a simulator restarted). Thread-safe: the
listener writes from one thread while nodes look up from others;
:meth:`TransformBuffer.wait_transform` waits for a transform still in flight, but not twice
for a frame that no transform has named since a wait for it ran out.
"""

import bisect
import collections
import math
import threading
import time
from typing import Deque, Dict, List, Optional, Tuple

import numpy as np

from pointforce_ros.errors import InvalidInput
from pointforce_ros.rotations import quaternion_to_matrix

CACHE_SECONDS = 10.0
"""How long a dynamic edge's history reaches back from its newest stamp (tf2's default)."""

MAX_SAMPLES = 20_000
"""Most samples one dynamic edge holds, whatever their stamps (a bound on memory against a
publisher with stamps that never advance: 2 kHz for the whole cache)."""

MAX_FRAMES = 10_000
"""Most frames the buffer holds; a transform that would add one more is refused."""

MAX_DEPTH = 1000
"""Most edges from a frame up to its root (tf2's ``MAX_GRAPH_DEPTH``): bounds each lookup and
each loop check, which a hostile chain of thousands of frames made quadratic."""

MAX_TOTAL_SAMPLES = 200_000
"""Most samples all dynamic edges hold together (about 70 MB; a UR's seven links at 500 Hz
hold 35 000); a transform that would add one more is refused."""

MAX_VAIN = 1024
"""Most frame names :meth:`TransformBuffer.wait_transform` remembers having waited for in vain
(the oldest is forgotten first)."""

UNIT_TOLERANCE = 1e-3
"""Largest departure of a quaternion's norm from 1 that is accepted (then normalised)."""


class TransformUnavailable(InvalidInput):
    """A lookup cannot be answered: an unknown frame, frames not connected, a time not held."""


class Extrapolation(TransformUnavailable):
    """The time asked for lies outside what one edge holds; ``future`` says on which side."""

    def __init__(self, message: str, future: bool):
        """Keep the message and whether the time asked for is past the newest sample."""
        super().__init__(message)
        self.future = future


class NotWaited(TransformUnavailable):
    """:meth:`TransformBuffer.wait_transform` did not wait: its frame was waited for in vain."""


def _frame_name(name, what: str) -> str:
    name = str(name or '').strip()
    if name.startswith('/'):    # tf2 refuses a leading slash; ROS 1 bags carry them
        name = name[1:]
    if not name:
        raise InvalidInput(f'{what}: empty frame name')
    return name


def _checked(position, quaternion) -> Tuple[np.ndarray, np.ndarray]:
    # copies: the caller's arrays, changed later, must not change the samples held
    p = np.array(position, dtype=np.float64).reshape(-1)
    q = np.array(quaternion, dtype=np.float64).reshape(-1)
    if p.shape != (3,) or q.shape != (4,):
        raise InvalidInput(f'transform: translation (3,) and rotation (4,) needed, got '
                           f'{p.shape} and {q.shape}')
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise InvalidInput(f'transform: non-finite values {p.tolist()} {q.tolist()}')
    norm = math.sqrt(float(q @ q))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        raise InvalidInput(f'transform: rotation quaternion of norm {norm:.4g}, not unit')
    return p, q / norm


def _slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    dot = float(q0 @ q1)
    if dot < 0.0:           # the shorter way round
        q1, dot = -q1, -dot
    if dot > 0.9995:        # nearly equal: linear, normalised
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    angle = math.acos(min(dot, 1.0))
    return (math.sin((1.0 - s) * angle) * q0 + math.sin(s * angle) * q1) / math.sin(angle)


def _matrix(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = quaternion_to_matrix(q)
    m[:3, 3] = p
    return m


class _Edge:
    """``parent <- child``: one static value, or a history sorted by stamp."""

    __slots__ = ('parent', 'static', 'times', 'values')

    def __init__(self, parent: str, static: bool):
        self.parent = parent
        self.static = static
        self.times: List[float] = []
        self.values: List[Tuple[np.ndarray, np.ndarray]] = []

    def add(self, t: float, p: np.ndarray, q: np.ndarray) -> int:
        """Hold one sample; return the change in the number of samples held."""
        before = len(self.times)
        if self.static:
            self.times, self.values = [t], [(p, q)]
            return len(self.times) - before
        if self.times and t < self.times[-1] - CACHE_SECONDS:
            # older than all the edge keeps: its publisher went back in time (a bag replayed,
            # a simulator restarted); tf2's listener clears its buffer on such a jump
            self.times, self.values = [t], [(p, q)]
            return 1 - before
        i = bisect.bisect_left(self.times, t)
        if i < len(self.times) and self.times[i] == t:
            self.values[i] = (p, q)     # the same stamp again: the newer value
        else:
            self.times.insert(i, t)
            self.values.insert(i, (p, q))
        cut = bisect.bisect_left(self.times, self.times[-1] - CACHE_SECONDS)
        cut = max(cut, len(self.times) - MAX_SAMPLES)
        if cut > 0:
            del self.times[:cut], self.values[:cut]
        return len(self.times) - before

    def at(self, t: float, tolerance: float, child: str) -> np.ndarray:
        if self.static:
            return _matrix(*self.values[0])
        times = self.times
        if t < times[0] - tolerance or t > times[-1] + tolerance:
            future = t > times[-1]
            raise Extrapolation(
                f'{self.parent!r} <- {child!r} is known for stamps {times[0]:.6f} to '
                f'{times[-1]:.6f} s ({len(times)} samples), asked for {t:.6f} s: '
                + ('the transform has not arrived yet' if future else
                   f'older than the {CACHE_SECONDS:g} s kept'), future)
        i = bisect.bisect_left(times, t)
        if i == 0:
            return _matrix(*self.values[0])
        if i == len(times):
            return _matrix(*self.values[-1])
        t0, t1 = times[i - 1], times[i]
        (p0, q0), (p1, q1) = self.values[i - 1], self.values[i]
        s = (t - t0) / (t1 - t0)
        return _matrix(p0 + s * (p1 - p0), _slerp(q0, q1, s))


class TransformBuffer:
    """The frame tree of ``/tf`` and ``/tf_static`` (see the module docstring)."""

    def __init__(self, tolerance: float = 0.0):
        """Keep an empty tree; ``tolerance``: seconds a lookup may lie past an edge's history.

        The transform at the nearest end is used within it (0, tf2's rule, by default).
        """
        if not (math.isfinite(tolerance) and tolerance >= 0.0):
            raise InvalidInput(f'TransformBuffer: tolerance {tolerance!r} must be >= 0 s')
        self.tolerance = float(tolerance)
        self._edges: Dict[str, _Edge] = {}
        self._frames = set()
        self._samples = 0
        self._changed = threading.Condition()
        self._vain: 'collections.OrderedDict[str, float]' = collections.OrderedDict()
        self.refused = 0
        """Transforms :meth:`set_transform` refused since the start."""
        self.not_waited = 0
        """Lookups :meth:`wait_transform` refused at once: their frame was waited for in vain."""

    # ------------------------------------------------------------------ writing
    def set_transform(self, parent: str, child: str, stamp: float, position, quaternion,
                      static: bool = False) -> None:
        """Hold ``parent <- child`` at ``stamp`` (seconds); ``static``: for all time.

        Raises:
            InvalidInput: a bad value or name, a loop, or a tree of :data:`MAX_FRAMES` frames.

        """
        try:
            parent = _frame_name(parent, 'transform parent')
            child = _frame_name(child, 'transform child')
            if parent == child:
                raise InvalidInput(f'transform: {child!r} made its own parent')
            stamp = float(stamp)
            if not math.isfinite(stamp):
                raise InvalidInput(f'transform {parent!r} <- {child!r}: stamp {stamp!r}')
            p, q = _checked(position, quaternion)
            with self._changed:
                new = {parent, child} - self._frames
                if len(self._frames) + len(new) > MAX_FRAMES:
                    raise InvalidInput(f'transform {parent!r} <- {child!r}: the buffer holds '
                                       f'{len(self._frames)} frames, at most {MAX_FRAMES}')
                edge = self._edges.get(child)
                if edge is None or edge.parent != parent:   # a new edge: check the tree
                    above = self._ancestors(parent)
                    if child in above:
                        raise InvalidInput(f'transform {parent!r} <- {child!r}: {child!r} is '
                                           f'already above {parent!r} (a loop)')
                    below = self._height(child) if child in self._frames else 0
                    if len(above) + below > MAX_DEPTH:
                        raise InvalidInput(f'transform {parent!r} <- {child!r}: a chain of '
                                           f'more than {MAX_DEPTH} frames')
                if self._samples >= MAX_TOTAL_SAMPLES:
                    raise InvalidInput(f'transform {parent!r} <- {child!r}: the buffer holds '
                                       f'{self._samples} samples, at most {MAX_TOTAL_SAMPLES}')
                if edge is None or edge.parent != parent or edge.static != bool(static):
                    if edge is not None:
                        self._samples -= len(edge.times)
                    edge = self._edges[child] = _Edge(parent, bool(static))
                self._samples += edge.add(stamp, p, q)
                self._frames |= new
                for frame in new:
                    self._vain.pop(frame, None)
                self._changed.notify_all()
        except InvalidInput:
            self.refused += 1
            raise

    def clear(self) -> None:
        """Forget every transform (a jump back in time, as tf2's listener does on one)."""
        with self._changed:
            self._edges.clear()
            self._frames.clear()
            self._vain.clear()
            self._samples = 0

    # ------------------------------------------------------------------ reading
    def frames(self) -> List[str]:
        """Return the names of every frame the tree holds, sorted."""
        with self._changed:
            return sorted(self._frames)

    def knows(self, frame: str) -> bool:
        """Return whether any transform named ``frame`` (as parent or child)."""
        try:
            frame = _frame_name(frame, 'frame')
        except InvalidInput:
            return False
        with self._changed:
            return frame in self._frames

    def lookup(self, target: str, source: str, stamp: Optional[float] = None) -> np.ndarray:
        """Return the (4, 4) transform ``target <- source`` at ``stamp`` (``None``: latest).

        Raises:
            TransformUnavailable: a frame unknown, the two not connected, or (its subclass
                :class:`Extrapolation`) ``stamp`` outside an edge's history.

        """
        target = _frame_name(target, 'lookup target')
        source = _frame_name(source, 'lookup source')
        with self._changed:
            return self._lookup(target, source, stamp)

    def wait_transform(self, target: str, source: str, stamp: Optional[float],
                       timeout: float) -> np.ndarray:
        """Like :meth:`lookup`, but wait up to ``timeout`` s for a transform not yet arrived.

        Only a time past an edge's newest sample, or a frame not yet heard of, is waited for;
        anything else is refused at once. A frame that a wait ran out on and that no transform
        has named since is not waited for again (its lookups are refused at once, counted in
        :attr:`not_waited`): a client that keeps asking in a frame nobody publishes would
        otherwise hold a thread ``timeout`` per request.
        """
        target = _frame_name(target, 'lookup target')
        source = _frame_name(source, 'lookup source')
        started = time.monotonic()
        deadline = started + max(0.0, float(timeout))
        with self._changed:
            while True:
                try:
                    return self._lookup(target, source, stamp)
                except Extrapolation as exc:
                    if not exc.future:
                        raise
                    last = exc
                except TransformUnavailable as exc:
                    unknown = [f for f in (target, source) if f not in self._frames]
                    if not unknown:
                        raise       # both known, not connected
                    vain = [f for f in unknown if f in self._vain]
                    if vain:
                        self.not_waited += 1
                        raise NotWaited(
                            f'{exc}; not waited for: no transform has named {vain[0]!r} since '
                            f'a wait for it ran out {started - self._vain[vain[0]]:.3g} s '
                            'ago') from None
                    last = exc
                left = deadline - time.monotonic()
                if left <= 0.0:
                    if not isinstance(last, Extrapolation):
                        self._remember_vain(f for f in (target, source)
                                            if f not in self._frames)
                    raise last
                self._changed.wait(left)

    def _remember_vain(self, frames) -> None:
        """Note ``frames`` as waited for in vain now (under the lock)."""
        now = time.monotonic()
        for frame in frames:
            self._vain.pop(frame, None)
            self._vain[frame] = now
        while len(self._vain) > MAX_VAIN:
            self._vain.popitem(last=False)

    # ------------------------------------------------------------------ internals
    def _ancestors(self, frame: str) -> List[str]:
        chain, seen = [frame], {frame}
        while frame in self._edges:
            frame = self._edges[frame].parent
            if frame in seen:   # cannot happen: set_transform refuses loops
                break
            chain.append(frame)
            seen.add(frame)
        return chain

    def _height(self, frame: str) -> int:
        """Edges of the longest chain below ``frame`` (0 for a leaf or a new frame)."""
        children: Dict[str, List[str]] = {}
        for child, edge in self._edges.items():
            children.setdefault(edge.parent, []).append(child)
        height, level = 0, children.get(frame, [])
        while level and height <= MAX_DEPTH:
            height += 1
            level = [c for f in level for c in children.get(f, [])]
        return height

    def _lookup(self, target: str, source: str, stamp: Optional[float]) -> np.ndarray:
        for frame in (target, source):
            if frame not in self._frames:
                known = sorted(self._frames)
                shown = ', '.join(repr(f) for f in known[:8])
                shown += ' ...' if len(known) > 8 else ''
                heard = f'known: {shown}' if known else 'nothing heard on /tf or /tf_static yet'
                raise TransformUnavailable(f'frame {frame!r} is not in the tf tree ({heard})')
        if target == source:
            return np.eye(4)
        up_source, up_target = self._ancestors(source), self._ancestors(target)
        above_target = set(up_target)
        common = next((f for f in up_source if f in above_target), None)
        if common is None:
            raise TransformUnavailable(
                f'frames {target!r} and {source!r} are not connected (their roots are '
                f'{up_target[-1]!r} and {up_source[-1]!r})')
        path_source = up_source[:up_source.index(common)]
        path_target = up_target[:up_target.index(common)]
        if stamp is None:   # the latest time every dynamic edge on the path holds
            ends = [self._edges[f].times[-1] for f in path_source + path_target
                    if not self._edges[f].static]
            stamp = min(ends) if ends else 0.0
        stamp = float(stamp)
        common_from_source = np.eye(4)
        for frame in path_source:       # child up to the common ancestor
            common_from_source = (self._edges[frame].at(stamp, self.tolerance, frame)
                                  @ common_from_source)
        common_from_target = np.eye(4)
        for frame in path_target:
            common_from_target = (self._edges[frame].at(stamp, self.tolerance, frame)
                                  @ common_from_target)
        return _rigid_inverse(common_from_target) @ common_from_source


HOLD_SECONDS = 0.5
"""How far (s of stamps) :class:`AwaitingTransform` holds a sample back for its transform."""

HOLD_SAMPLES = 1024
"""Most samples :class:`AwaitingTransform` holds (2 s of a 500 Hz stream)."""


class AwaitingTransform:
    """Stamped samples held back until the tree can place them (tf2_ros' message filter).

    A pose stream stamped in a frame that ``/tf`` places (a TCP pose in ``world``) runs ahead
    of ``/tf`` when that is the slower: looked up at once, its newest samples were refused as
    extrapolation into the future. Here such a sample waits, in arrival order, and every later
    :meth:`offer` tries the waiting ones first. A sample is refused (with the reason) when its
    lookup fails for any other cause, when :data:`HOLD_SECONDS` of newer stamps or
    :data:`HOLD_SAMPLES` samples are waiting behind it, or when the stream goes back in time
    (a replayed bag). One thread offers (not thread-safe).
    """

    def __init__(self, seconds: float = HOLD_SECONDS, size: int = HOLD_SAMPLES):
        """Hold at most ``seconds`` of stamps and ``size`` samples."""
        self.seconds, self.size = float(seconds), int(size)
        self._held: Deque[Tuple[float, object]] = collections.deque()
        self.held_back = 0
        """Samples that had to wait (all time)."""

    def __len__(self) -> int:
        """Return how many samples wait now."""
        return len(self._held)

    def offer(self, stamp: float, item, place) -> Tuple[list, list]:
        """Add one sample; return ``(placed, refused)`` in arrival order.

        ``place(item)`` gives the placed value or raises; :class:`Extrapolation` into the
        future keeps the item (and those after it) waiting. ``placed``: the values of the
        samples placed now; ``refused``: ``(item, reason)`` of those given up.
        """
        placed, refused = [], []
        if self._held and float(stamp) < self._held[-1][0]:
            # the stream went back in time (a bag replayed, a simulator restarted): what
            # waits is of the old timeline, and would hold the new one up behind it
            refused = [(waiting, 'the stream went back in time while it waited for its '
                        'transform') for _, waiting in self._held]
            self._held.clear()
        self._held.append((float(stamp), item))
        while self._held:
            t, waiting = self._held[0]
            try:
                placed.append(place(waiting))
            except Extrapolation as exc:
                if not exc.future:
                    refused.append((waiting, str(exc)))
                elif (self._held[-1][0] - t > self.seconds or len(self._held) > self.size):
                    refused.append((waiting, f'{exc}; no transform came while '
                                    f'{len(self._held) - 1} newer sample(s) waited'))
                else:
                    break
            except Exception as exc:  # noqa: BLE001 - any failure refuses this sample only
                refused.append((waiting, str(exc)))
            self._held.popleft()
        if self._held and self._held[-1][1] is item:
            self.held_back += 1
        return placed, refused


def _rigid_inverse(m: np.ndarray) -> np.ndarray:
    inv = np.eye(4)
    inv[:3, :3] = m[:3, :3].T
    inv[:3, 3] = -m[:3, :3].T @ m[:3, 3]
    return inv
