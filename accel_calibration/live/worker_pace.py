"""The worker's pace while a stream flows: its work in slices of SLICE_S of wall time, a pause of PAUSE_S
after each, so the stream's processes (the sensor's driver, the node, its subscribers) catch up between
slices instead of queueing behind a whole pass.

Why slices and not a lower priority: on the 2-core machine a 2 kHz stream keeps both cores busy part of
the time, and a feed pass in one piece (4 ms) delayed the messages around it by 2-4 ms (the node's p99
3.5-5 ms against a bare relay's 0.7-0.9 ms). SCHED_IDLE in place of os.nice left it at 2.8-9 ms; the pass in
0.25 ms slices with 0.5 ms pauses took it to 1.0-1.2 ms. The price: a pass takes about three times its CPU
in wall time (12 ms of the 200 ms between passes at 2 kHz), and each pause costs 50-80 us of CPU (the
timer's interrupt and two context switches, in this VM): 4.9 ms of CPU per 2 kHz pass instead of 3.6.

How: a one-shot real-time interval timer (the kernel's high-resolution timers; the CPU-time ones fire only
at the scheduler's tick, 4 ms on a 250 Hz kernel). Python runs its handler in the main thread between
bytecodes; the handler sleeps, then arms the timer again. SA_RESTART is set, so a system call the signal
lands in carries on. A single C call that runs long (a large solve) is not cut: the pace is best effort.
Signals exist only in the main thread: elsewhere (a test driving the work in a thread) the work runs whole.
"""
from __future__ import annotations

import signal
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

__all__ = ["PAUSE_S", "SLICE_S", "Pacer"]

SLICE_S = 0.25e-3
PAUSE_S = 0.5e-3


class Pacer:
    """Owns SIGALRM and ITIMER_REAL in its process while it exists (the worker's process uses neither for
    anything else); `close` gives them back."""

    def __init__(self, slice_s: float = SLICE_S, pause_s: float = PAUSE_S):
        self.slice_s, self.pause_s = slice_s, pause_s
        self.pauses = 0  # taken so far: what a test or a benchmark reads
        self.available = threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
        self._armed = False
        self._previous: Any = None
        if self.available:
            self._previous = signal.signal(signal.SIGALRM, self._pause)
            signal.siginterrupt(signal.SIGALRM, False)

    def _pause(self, signum: int, frame: FrameType | None) -> None:
        if not self._armed:  # a signal that was on its way when the slices ended
            return
        time.sleep(self.pause_s)  # the block cannot end meanwhile: it runs in this thread
        self.pauses += 1
        signal.setitimer(signal.ITIMER_REAL, self.slice_s)

    @contextmanager
    def paced(self, on: bool = True) -> Iterator[None]:
        """The block's work in slices (when `on`: a stream flows), else whole."""
        if not (on and self.available) or self._armed:
            yield
            return
        self._armed = True
        signal.setitimer(signal.ITIMER_REAL, self.slice_s)
        try:
            yield
        finally:
            self._armed = False
            signal.setitimer(signal.ITIMER_REAL, 0)

    def close(self) -> None:
        if self.available:
            self._armed = False
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, self._previous if self._previous is not None else signal.SIG_DFL)
            self.available = False
