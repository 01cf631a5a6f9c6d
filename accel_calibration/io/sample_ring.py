"""A ring of fixed-size records: the one path of raw samples from the stream to the calibration work.

The stream's callback pushes one record per message (a stamp, values, a flag) in about a microsecond and
never waits for the reader; the reader takes everything pushed since its last take, as arrays. The
memory is either this process's own or shared with a worker process (`multiprocessing` RawArray and
Lock, handed to the worker when it is started), so the node's publishing process never shares a GIL with
the calibration work. A reader that falls a whole ring behind loses the oldest records and counts them.

Why a lock for the head: the records must be visible to the reader before the head that announces them,
on any CPU (ARM orders stores weakly); the lock's acquire and release are the barriers, and uncontended
they cost a fraction of a microsecond.
"""
from __future__ import annotations

import struct
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["RING_RECORDS", "RingTake", "SampleRing"]

RING_RECORDS = 1 << 18  # IMU samples the reader may fall behind (~65 s at 4 kHz); beyond, the oldest are lost
_HEAD = struct.Struct("<q")


@dataclass(frozen=True)
class RingTake:
    """What a reader took: stamps (ns), values (n, width), flags, and how many records it lost."""

    stamps_ns: np.ndarray
    values: np.ndarray
    flags: np.ndarray
    lost: int


class SampleRing:
    """Records of (int64 stamp, `width` float64 values, a bool flag). One ring has writers (any thread
    of one process) and one reader (a thread here, or a worker process given `shareable()`)."""

    def __init__(self, width: int, capacity: int = RING_RECORDS, context: Any = None, *,
                 _shared: tuple[Any, Any] | None = None):
        self.width, self.capacity = width, capacity
        self._record = struct.Struct(f"<q{width}d?")
        self._dtype = np.dtype([("stamp_ns", "<i8"), ("values", "<f8", (width,)), ("flag", "?")])
        size = _HEAD.size + capacity * self._record.size
        if _shared is not None:
            self._memory, self._lock = _shared
        elif context is not None:  # multiprocessing: shared with a process started from this context
            self._memory, self._lock = context.RawArray("b", size), context.Lock()
        else:
            self._memory, self._lock = bytearray(size), threading.Lock()
        self._buffer = memoryview(self._memory).cast("B")
        self._records = np.frombuffer(self._buffer, dtype=self._dtype, count=capacity, offset=_HEAD.size)
        self._head = self._read_head()  # the next record a writer of this process fills
        # The next record this reader takes: a worker started after the stream (or again, after one died)
        # takes every record the ring still holds.
        self._tail = max(0, self._head - capacity)

    def shareable(self) -> tuple[int, int, tuple[Any, Any]]:
        """What a worker process needs to read this ring (pickled when the process is started)."""
        return self.width, self.capacity, (self._memory, self._lock)

    @classmethod
    def attach(cls, shared: tuple[int, int, tuple[Any, Any]]) -> SampleRing:
        width, capacity, memory_and_lock = shared
        return cls(width, capacity, _shared=memory_and_lock)

    def _read_head(self) -> int:
        with self._lock:
            return int(_HEAD.unpack_from(self._buffer, 0)[0])

    def push(self, stamp_ns: int, *values_and_flag: Any) -> None:
        """One record: `width` values then the flag."""
        with self._lock:
            head = self._head
            self._record.pack_into(self._buffer, _HEAD.size + (head % self.capacity) * self._record.size,
                                   stamp_ns, *values_and_flag)
            self._head = head + 1
            _HEAD.pack_into(self._buffer, 0, head + 1)

    def take(self) -> RingTake:
        """Every record pushed since the last take, oldest first."""
        head = self._read_head()
        start = max(self._tail, head - self.capacity)
        copied = self._copy(start, head)
        # A writer may have lapped the records while they were copied: those are lost, not half-read.
        overwritten = max(0, min(head, self._read_head() - self.capacity) - start)
        copied = copied[overwritten:]
        lost = start - self._tail + overwritten
        self._tail = head
        return RingTake(copied["stamp_ns"], copied["values"].reshape(-1, self.width), copied["flag"], lost)

    def _copy(self, start: int, stop: int) -> np.ndarray:
        first, last = start % self.capacity, stop % self.capacity
        if stop - start == 0:
            return self._records[:0].copy()
        if first < last:
            return self._records[first:last].copy()
        return np.concatenate((self._records[first:], self._records[:last]))
