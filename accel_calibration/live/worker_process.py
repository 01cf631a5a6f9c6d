"""The calibration work in a process of its own, so the publishing process never waits for it.

A batch of the detector or a fit holds its interpreter's lock for milliseconds; in the publishing process
every message arriving meanwhile would wait (the stream's p99 latency was the batches'). Here the node
keeps the stream side (live/per_message.py) and `WorkerProcess` starts the work (live/calibration_work.py)
in a spawned process (live/worker_main.py, then live/worker_loop.py) that reads the same shared sample rings,
feeds every FEED_PERIOD_S, and runs the services' jobs in order. The two talk over one pipe, in the
messages of live/worker_protocol.py:

- to the work: Job, NewSettings, FrameId, Stop;
- to the node: Done (a job's answer or its error), Install, Noise, Snapshot, LogLine.

The work runs at a lower priority (os.nice) and, while a stream flows, in slices with pauses between
(live/worker_pace.py): on a busy flight computer the stream comes first. It ignores
SIGINT/SIGTERM (a terminal's Ctrl-C reaches the whole process group): the node stops it, letting a save in
flight finish, and it ends by itself when the node's end of the pipe closes. A work that dies is started
again (its poses are lost; the file is whole: saves are atomic).
"""
from __future__ import annotations

import itertools
import pickle
import sys
import threading
import types
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

from ..core.calibration import Calibration
from ..core.settings import Settings
from . import worker_main
from .calibration_work import WorkSnapshot
from .per_message import LOG_THROTTLE_S, Log
from .sample_ring import SampleRing
from .worker_protocol import (
    FEED_PERIOD_S,
    Done,
    FrameId,
    Install,
    Job,
    LogLevel,
    LogLine,
    NewSettings,
    Noise,
    Snapshot,
    Stop,
    ToNode,
    ToWorker,
    WorkerGone,
    WorkerStart,
)

__all__ = ["FEED_PERIOD_S", "WorkerGone", "WorkerProcess", "WorkerStart"]

RESTART_AFTER_S = 5.0  # a work that keeps dying is started again at most this often
STOP_TIMEOUT_S = 60.0  # a save in flight finishes; a fit longer than this is abandoned at shutdown


# ---------------------------------------------------------------------- the node's side
class WorkerProcess:
    def __init__(self, start: WorkerStart, rings: tuple[SampleRing, SampleRing], log: Log,
                 on_install: Callable[[Calibration | None], None],
                 on_noise: Callable[[float | None, float | None], None], context: Any):
        self._start = pickle.dumps(start)
        self._rings = tuple(ring.shareable() for ring in rings)
        self._log, self._context = log, context
        self._on_install, self._on_noise = on_install, on_noise
        self.snapshot: WorkSnapshot | None = None  # the work's latest, replaced whole
        self.restarts = 0
        self._jobs: dict[int, Future[tuple[bool, str]]] = {}
        self._ids = itertools.count()
        self._send_lock = threading.Lock()  # services, parameters and timers send from several threads
        self._closing = False
        self._closed = threading.Event()  # set at close: a restart waiting out its pause gives up at once
        # Why jobs cannot be served now (the work died and is not yet started again); None while it runs.
        self._down: str | None = None
        self._settings: Settings | None = None  # the latest sent, for a restarted work
        self._frame_id: str | None = None
        self._spawn()

    def _spawn(self) -> None:
        self._conn, child = self._context.Pipe()
        self._process = self._context.Process(target=worker_main.main, args=(child, self._rings, self._start),
                                              daemon=True, name="accel_calibration_worker")
        # A spawned child runs the parent's main script again unless it is guarded by __name__ (a user's
        # script, a test runner): the work needs nothing of it, so the child is shown none.
        main = sys.modules["__main__"]
        sys.modules["__main__"] = types.ModuleType("__main__")
        try:
            self._process.start()
        finally:
            sys.modules["__main__"] = main
        child.close()
        self._receiver = threading.Thread(target=self._receive, args=(self._conn,), daemon=True,
                                          name="accel_calibration_worker_pipe")
        self._receiver.start()

    # ------------------------------------------------------------------ to the work
    def submit(self, job: str) -> Future[tuple[bool, str]]:
        """A job by name (calibrate, calibration/reset, calibration/save, refresh_progress, ping), answered
        (success, one line) when the work has done it."""
        future: Future[tuple[bool, str]] = Future()
        with self._send_lock:
            if self._closing or self._down is not None:
                # Never silence: no work would ever answer a job sent now.
                future.set_exception(WorkerGone("the node is shutting down" if self._closing else self._down))
                return future
            job_id = next(self._ids)
            self._jobs[job_id] = future
            self._send(Job(job_id, job))
        return future

    def update_settings(self, settings: Settings) -> None:
        with self._send_lock:
            self._settings = settings
            self._send(NewSettings(settings))

    def set_frame_id(self, frame_id: str) -> None:
        with self._send_lock:
            self._frame_id = frame_id
            self._send(FrameId(frame_id))

    def _send(self, message: ToWorker) -> None:
        """Caller holds the send lock. A work that died meanwhile is restarted by the receiver, which
        answers the jobs it lost."""
        try:
            self._conn.send(message)
        except (OSError, ValueError):
            pass

    # ------------------------------------------------------------------ from the work
    def _receive(self, conn: Any) -> None:
        while True:
            try:
                message = conn.recv()
            except (EOFError, OSError):
                break
            try:
                self._take(message)
            except Exception as error:  # noqa: BLE001 - the pipe's thread must outlive one bad message
                self._log.error(f"calibration worker: {type(error).__name__}: {error}",
                                throttle_duration_sec=LOG_THROTTLE_S)
        self._gone()

    def _take(self, message: ToNode) -> None:
        match message:
            case Done(job_id, outcome):
                future = self._jobs.pop(job_id, None)
                if future is not None:
                    _settle(future, outcome)
            case Install(calibration):
                self._on_install(calibration)
            case Noise(accel_var, gyro_var):
                self._on_noise(accel_var, gyro_var)
            case Snapshot(snapshot):
                self.snapshot = snapshot
            case LogLine(level, text):
                self._forward(level, text)

    def _forward(self, level: LogLevel, text: str) -> None:
        """One call site per severity: rclpy refuses a call site whose severity changes."""
        match level:
            case LogLevel.DEBUG:
                self._log.debug(text)
            case LogLevel.INFO:
                self._log.info(text)
            case LogLevel.WARNING:
                self._log.warning(text)
            case LogLevel.ERROR:
                self._log.error(text)

    def _gone(self) -> None:
        """The pipe closed: the work stopped (at close) or died. Its unanswered jobs fail; a death restarts it."""
        pause = RESTART_AFTER_S if self.restarts else 0.0
        with self._send_lock:
            jobs, self._jobs = self._jobs, {}
            closing = self._closing
            # Jobs submitted from now until the new work runs are refused at once (sent to the dead work's
            # pipe, they would never be answered).
            self._down = (f"the calibration worker process ended and is being started again (within {pause:g} s; "
                          "the poses held are lost); call again then")
        for future in jobs.values():
            future.set_exception(WorkerGone("the node is shutting down" if closing
                                            else "the calibration worker process ended before answering; it is "
                                                 "started again (the poses held are lost)"))
        if closing:
            return
        self._process.join(timeout=1.0)
        self._log.error(f"calibration worker process ended (exit code {self._process.exitcode}); its poses are "
                        "lost, restarting it")
        if self._closed.wait(pause):
            return
        with self._send_lock:
            if self._closing:
                return
            self.restarts += 1
            self._spawn()
            self._down = None
            if self._settings:
                self._send(NewSettings(self._settings))
            if self._frame_id:  # an empty frame is no frame
                self._send(FrameId(self._frame_id))

    @property
    def alive(self) -> bool:
        return bool(self._process.is_alive())

    def close(self) -> None:
        """Let a job in flight finish (a save leaves the old file or the new one, whole); jobs still queued
        are answered 'not done'."""
        with self._send_lock:
            self._closing = True
            self._closed.set()
            self._send(Stop())
        self._process.join(timeout=STOP_TIMEOUT_S)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(timeout=5.0)
        self._conn.close()
        self._receiver.join(timeout=5.0)


def _settle(future: Future[tuple[bool, str]], outcome: tuple[bool, str] | BaseException) -> None:
    if isinstance(outcome, BaseException):
        future.set_exception(outcome)
    else:
        future.set_result(outcome)


