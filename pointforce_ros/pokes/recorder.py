"""Rebuild poke records from the live or replayed pose, wrench and poke_record streams.

A learner running away from the poke server's disk (or fed from a bag replay) records the
``tcp_pose`` / ``wrench`` / ``poke_record`` topics with this.

Samples are buffered by stamp; when a ``poke_record`` header arrives, the samples whose stamps
lie in its ``t_start``..``t_end`` span are paired (same stamp on pose and wrench, as the poke
server publishes them) and turned into a :class:`~pointforce_ros.types.PokeRecord`.
"""

import threading
from collections import OrderedDict

import numpy as np

from pointforce_ros.errors import DataError, InvalidInput
from pointforce_ros.pokes.store import check_header, RECORD_FORMAT, record_from_samples
from pointforce_ros.types import PokeRecord

MAX_STAMP = 1e12
"""Largest stamp magnitude (s) read from a header: ROS time is seconds since 1970."""


class StreamRecorder:
    """Thread-safe buffer of pose and wrench samples keyed by stamp (nanoseconds)."""

    def __init__(self, max_samples: int = 100_000):
        """Keep at most ``max_samples`` unpaired samples of each stream (oldest dropped)."""
        self.max_samples = int(max_samples)
        self._poses: 'OrderedDict[int, tuple]' = OrderedDict()
        self._wrenches: 'OrderedDict[int, tuple]' = OrderedDict()
        self._lock = threading.Condition()

    @staticmethod
    def _key(t: float) -> int:
        return int(round(t * 1e9))

    def _put(self, store, t, value):
        with self._lock:
            store[self._key(t)] = value
            while len(store) > self.max_samples:
                store.popitem(last=False)
            self._lock.notify_all()

    def add_pose(self, t: float, position, quaternion) -> None:
        """Buffer a ``tcp_pose`` sample: stamp s, position (3,) m, quaternion (x, y, z, w)."""
        self._put(self._poses, t, (t, *position, *quaternion))

    def add_wrench(self, t: float, force, torque) -> None:
        """Buffer a ``wrench`` sample (``tool0_controller``): stamp s, N, N m."""
        self._put(self._wrenches, t, (*force, *torque))

    def finish(self, header: dict, timeout: float = 20.0) -> PokeRecord:
        """Cut the poke described by ``header`` out of the buffers and return its record.

        Waits up to ``timeout`` seconds for the poke's last sample to arrive on both streams
        (the header can overtake a backlog of samples).

        Raises:
            DataError: unknown header format, a header with a missing or mistyped field
                (:func:`~pointforce_ros.pokes.store.check_header`; ``t_start`` and ``t_end``
                finite numbers), or samples missing from the streams (dropped messages): the
                poke is then not silently shortened.

        """
        if not isinstance(header, dict):
            raise DataError(f'poke_record is not a JSON object but a {type(header).__name__}')
        if header.get('format') != RECORD_FORMAT:
            raise DataError(f'poke_record of unknown format {header.get("format")!r}')
        try:
            check_header(header)
            span = [header.get(name) for name in ('t_start', 't_end')]
            if not all(isinstance(t, (int, float)) and not isinstance(t, bool)
                       and abs(t) < MAX_STAMP for t in span):
                raise InvalidInput(f'{header["poke_id"]}: t_start and t_end must be finite '
                                   f'stamps in seconds, got {span[0]!r:.40} and {span[1]!r:.40}')
        except InvalidInput as exc:
            raise DataError(f'poke_record refused: {exc}') from exc
        lo, hi = self._key(span[0]), self._key(span[1])
        with self._lock:
            self._lock.wait_for(lambda: hi in self._poses and hi in self._wrenches, timeout)
            keys = [k for k in self._poses if lo <= k <= hi and k in self._wrenches]
            poses = np.array([self._poses[k] for k in keys]).reshape(-1, 8)
            wrenches = np.array([self._wrenches[k] for k in keys]).reshape(-1, 6)
            for k in [k for k in self._poses if k <= hi]:
                del self._poses[k]
            for k in [k for k in self._wrenches if k <= hi]:
                del self._wrenches[k]
        try:
            return record_from_samples(header, poses, wrenches)
        except InvalidInput as exc:
            raise DataError(f'poke {header.get("poke_id")}: incomplete stream: {exc}') from exc
