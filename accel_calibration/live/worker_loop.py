"""The worker process's side: the work (live/calibration_work.py) fed every FEED_PERIOD_S from the shared
rings, the node's jobs in order, its log lines and what it puts in force sent back over the pipe
(live/worker_process.py has the protocol and the node's side)."""
from __future__ import annotations

import gc
import os
import pickle
import signal
import sys
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from ..core.calibration import Calibration
from .calibration_work import LiveCalibration
from .per_message import LOG_THROTTLE_S
from .sample_ring import SampleRing
from .worker_pace import Pacer
from .worker_protocol import (
    FEED_PERIOD_S,
    WORKER_NICENESS,
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
    ToWorker,
    WorkerGone,
    WorkerStart,
)

__all__ = ["run_worker"]


class _PipeLog:
    """The work's log lines go to the node's logger; a throttled line is throttled here, per call site, and
    debug lines only when the node shows them."""

    def __init__(self, conn: Any, debug_logged: bool = False):
        self._conn = conn
        self._debug_logged = debug_logged
        self._last: dict[tuple[str, int], float] = {}

    def _line(self, level: LogLevel, message: str, throttle_duration_sec: float | None = None,
              **kwargs: Any) -> None:
        if throttle_duration_sec:
            caller = sys._getframe(2)
            site, now = (caller.f_code.co_filename, caller.f_lineno), time.monotonic()
            if now - self._last.get(site, -1e18) < throttle_duration_sec:
                return
            self._last[site] = now
        self._conn.send(LogLine(level, message))

    def debug(self, message: str, **kwargs: Any) -> None:
        if self._debug_logged:
            self._line(LogLevel.DEBUG, message, **kwargs)

    def info(self, message: str, **kwargs: Any) -> None:
        self._line(LogLevel.INFO, message, **kwargs)

    def warning(self, message: str, **kwargs: Any) -> None:
        self._line(LogLevel.WARNING, message, **kwargs)

    def error(self, message: str, **kwargs: Any) -> None:
        self._line(LogLevel.ERROR, message, **kwargs)


class _PipeLink:
    """The stream side, as the work sees it from its process."""

    def __init__(self, conn: Any):
        self._conn = conn

    def install(self, calibration: Calibration | None) -> None:
        self._conn.send(Install(calibration))

    def set_noise(self, accel_var: float | None, gyro_var: float | None) -> None:
        self._conn.send(Noise(accel_var, gyro_var))


def run_worker(conn: Any, rings: tuple[Any, Any], start: WorkerStart) -> None:
    """The worker process's main: the work, fed every FEED_PERIOD_S, jobs in order, until told to stop or
    the node is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        os.nice(WORKER_NICENESS)
    except OSError:
        pass
    log = _PipeLog(conn, start.debug_logged)
    live = LiveCalibration(start.settings, start.calibration_path, log, calibrate_service=start.calibrate_service,
                           imu_topic=start.imu_topic,
                           rings=(SampleRing.attach(rings[0]), SampleRing.attach(rings[1])),
                           link=_PipeLink(conn))
    gc.freeze()  # the imports' objects: a full collection scans only the work's own (ms, not ~20 ms)
    pacer = Pacer()
    try:
        _WorkerLoop(conn, live, log, pacer).run()
    except (EOFError, BrokenPipeError, OSError):
        pass  # the node is gone
    finally:
        pacer.close()


class _WorkerLoop:
    def __init__(self, conn: Any, live: LiveCalibration, log: _PipeLog, pacer: Pacer):
        self._conn, self._live, self._log = conn, live, log
        self._pacer = pacer  # while a stream flows, the work goes in slices (live/worker_pace.py)
        self._inbox: deque[ToWorker] = deque()
        self._sent = b""  # the snapshot last sent, pickled (its arrays do not compare with ==)
        self._jobs: dict[str, Callable[[], tuple[bool, str]]] = {
            "calibrate": live.calibrate, "calibration/reset": live.reset, "calibration/save": live.save,
            "refresh_progress": lambda: (True, live.refresh_progress().advice), "ping": lambda: (True, "")}

    def run(self) -> None:
        self._guarded(lambda: self._live.start(open_file=False))  # the node's process has opened it
        self._send_snapshot()
        next_feed = time.monotonic() + FEED_PERIOD_S
        while True:
            if not self._inbox:
                self._conn.poll(max(0.0, next_feed - time.monotonic()))  # a message, or the time to feed
            self._collect()  # every message waiting: a stop refuses the jobs queued before it
            if any(isinstance(message, Stop) for message in self._inbox):
                self._refuse_queued()
                return
            if self._inbox:
                with self._pacer.paced(self._live.stream_flowing):
                    self._handle(self._inbox.popleft())
            if time.monotonic() >= next_feed:
                with self._pacer.paced(self._live.stream_flowing):
                    self._guarded(self._live.feed)
                next_feed = max(next_feed + FEED_PERIOD_S, time.monotonic())
            self._send_snapshot()

    def _collect(self) -> None:
        while self._conn.poll(0):
            self._inbox.append(self._conn.recv())

    def _refuse_queued(self) -> None:
        for message in self._inbox:
            if isinstance(message, Job):
                self._conn.send(Done(message.job_id, WorkerGone("not done: the node is shutting down")))

    def _handle(self, message: ToWorker) -> None:
        match message:
            case Job(job_id, name):
                outcome: tuple[bool, str] | BaseException
                try:
                    outcome = self._jobs[name]()
                except Exception as error:  # noqa: BLE001 - the job's caller gets the error; the work carries on
                    outcome = RuntimeError(f"{type(error).__name__}: {error}")
                self._send_snapshot()  # the node sees the state the answer speaks of
                self._conn.send(Done(job_id, outcome))
            case NewSettings(settings):
                self._guarded(lambda: self._live.update_settings(settings))
            case FrameId(frame_id):
                self._live.set_frame_id(frame_id)

    def _guarded(self, work: Callable[[], Any]) -> None:
        try:
            work()
        except Exception as error:  # noqa: BLE001 - no exception may end the work
            self._live.set_aside["worker_errors"] += 1
            self._log.error(f"calibration work failed ({type(error).__name__}: {error}); it carries on",
                            throttle_duration_sec=LOG_THROTTLE_S)

    def _send_snapshot(self) -> None:
        message = pickle.dumps(Snapshot(self._live.snapshot()), protocol=pickle.HIGHEST_PROTOCOL)
        if message != self._sent:
            self._conn.send_bytes(message)  # recv() unpickles it as any other message
            self._sent = message
