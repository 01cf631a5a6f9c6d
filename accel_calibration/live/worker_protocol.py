"""What the node's process and its worker process share: how the worker is started, its pace, its error,
and the messages over their one pipe, each a frozen dataclass that the receiver matches by its type.
Nothing here loads numpy (the worker's entry point imports it before numpy is loaded)."""
from __future__ import annotations

import enum
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..core.calibration import Calibration
    from ..core.settings import Settings
    from .calibration_work import WorkSnapshot

__all__ = ["FEED_PERIOD_S", "WORKER_NICENESS", "Done", "FrameId", "Install", "Job", "LogLevel", "LogLine", "Noise",
           "NewSettings", "Snapshot", "Stop", "ToNode", "ToWorker", "WorkerGone", "WorkerStart"]

# The work takes the rings this often: poses are found within a fifth of a second.
FEED_PERIOD_S = 0.2
WORKER_NICENESS = 5  # below the stream, not starved: on 2 busy cores the fits still run


class WorkerGone(RuntimeError):
    """The worker process ended before answering (stopped, or died)."""


@dataclass(frozen=True)
class WorkerStart:
    """What the worker process is started with, besides the rings (pickled to it)."""

    settings: Settings
    calibration_path: Path
    calibrate_service: str
    imu_topic: str
    # The node's logger shows debug lines (its level when the worker started): else the work's are not sent.
    debug_logged: bool = False


# ---------------------------------------------------------------------- to the worker
@dataclass(frozen=True)
class Job:
    """A service's job by its name (calibrate, calibration/reset, calibration/save, refresh_progress, ping),
    answered by a `Done` of the same id."""

    job_id: int
    name: str


@dataclass(frozen=True)
class NewSettings:
    settings: Settings


@dataclass(frozen=True)
class FrameId:
    """The Imu stream's frame: the work's calibration is of that frame."""

    frame_id: str


@dataclass(frozen=True)
class Stop:
    """Finish the job in flight, refuse those queued, end."""


ToWorker = Job | NewSettings | FrameId | Stop


# ---------------------------------------------------------------------- to the node
@dataclass(frozen=True)
class Done:
    """A job's answer: (success, one line), or the error that kept it from one."""

    job_id: int
    outcome: tuple[bool, str] | BaseException


@dataclass(frozen=True)
class Install:
    """A calibration put in force by the work (None: none), for the stream side to correct with."""

    calibration: Calibration | None


@dataclass(frozen=True)
class Noise:
    """The white noise measured at the poses, per axis: (m/s^2)^2 and (rad/s)^2."""

    accel_var: float | None
    gyro_var: float | None


@dataclass(frozen=True)
class Snapshot:
    """The work's state as the diagnostics show it, after each feed or job."""

    snapshot: WorkSnapshot


class LogLevel(enum.Enum):
    DEBUG = enum.auto()
    INFO = enum.auto()
    WARNING = enum.auto()
    ERROR = enum.auto()


@dataclass(frozen=True)
class LogLine:
    """One of the work's log lines, for the node's logger."""

    level: LogLevel
    text: str


ToNode = Done | Install | Noise | Snapshot | LogLine
