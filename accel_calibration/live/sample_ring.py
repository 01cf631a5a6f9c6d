"""A ring of fixed-size records: the one path of raw samples from the stream to the calibration work.

The stream's callback pushes one record per message (a stamp, values, a flag) in about a microsecond and
never waits for the reader; the reader takes everything pushed since its last take, as arrays. The
memory is either this process's own or shared with a worker process (`multiprocessing` RawArray and
Lock, handed to the worker when it is started), so the node's publishing process never shares a GIL with
the calibration work. A reader that falls a whole ring behind loses the oldest records and counts them.

The head (how many records were pushed) is published under a lock shared with the reader: the records must
be visible to the reader before the head that announces them, on any CPU (ARM orders stores weakly), and
the writer's release of the lock after its record, with the reader's acquire before it reads them, orders
them. The writer never waits for that lock: a reader in another process may be descheduled while it holds
it (a worker at a low priority, on a busy machine, for milliseconds), so the writer only tries it, and
when the reader has it, leaves the head to the next push (a few records later; `flush` for the last ones).
"""
from __future__ import annotations

import struct
import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["RING_RECORDS", "UNPUBLISHED_MAX", "RingTake", "SampleRing"]

RING_RECORDS = 1 << 18  # IMU samples the reader may fall behind (~65 s at 4 kHz); beyond, the oldest are lost
# Records a writer may push without publishing the head (the reader held the lock each time) before it waits
# for the lock after all: the reader holds it for a microsecond, so this bounds a pathological case only,
# and how far the writer can be ahead of the head the reader sees. A ring of fewer than 64 times as many
# records always waits (its reader could not otherwise tell the records it loses exactly).
UNPUBLISHED_MAX = 64
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
        self._writing = threading.Lock()  # writers of this process, one at a time; never the reader's
        self._buffer = memoryview(self._memory).cast("B")
        self._records = np.frombuffer(self._buffer, dtype=self._dtype, count=capacity, offset=_HEAD.size)
        self._head = self._read_head()  # the next record a writer of this process fills
        self._published = self._head  # the head the reader was last shown
        # Records the writer may be ahead of the head it showed (a small ring: none, its losses counted exactly).
        self._slack = UNPUBLISHED_MAX if capacity >= 64 * UNPUBLISHED_MAX else 0
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
        """One record: `width` values then the flag. Never waits for the reader (a ring of fewer than
        64 x UNPUBLISHED_MAX records waits for its microsecond)."""
        with self._writing:
            head = self._head
            if not self._slack:
                with self._lock:  # written under the reader's lock: its count of what it lost is exact
                    self._pack(head, stamp_ns, values_and_flag)
                    self._show(head + 1)
                return
            self._pack(head, stamp_ns, values_and_flag)
            self._head = head + 1
            if head + 1 - self._published > self._slack:
                with self._lock:
                    self._show(head + 1)
            elif self._lock.acquire(False):
                try:
                    self._show(head + 1)
                finally:
                    self._lock.release()

    def _pack(self, index: int, stamp_ns: int, values_and_flag: tuple[Any, ...]) -> None:
        self._record.pack_into(self._buffer, _HEAD.size + (index % self.capacity) * self._record.size,
                               stamp_ns, *values_and_flag)

    def _show(self, head: int) -> None:
        """Caller holds the reader's lock."""
        _HEAD.pack_into(self._buffer, 0, head)
        self._head = self._published = head

    def flush(self) -> bool:
        """Show the reader the records it was not yet shown, unless it holds the head right now (a writer
        calls this when its stream may have stopped). True when every record is shown."""
        with self._writing:
            if self._published != self._head and self._lock.acquire(False):
                try:
                    self._show(self._head)
                finally:
                    self._lock.release()
            return self._published == self._head

    def take(self) -> RingTake:
        """Every record pushed since the last take, oldest first."""
        head = self._read_head()
        start = max(self._tail, head - self.capacity)
        copied = self._copy(start, head)
        # A writer may have lapped the records while they were copied: those are lost, not half-read (it may
        # be writing up to its slack + 1 records beyond the head it showed).
        ahead = self._slack + 1 if self._slack else 0
        overwritten = max(0, min(head, self._read_head() + ahead - self.capacity) - start)
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
