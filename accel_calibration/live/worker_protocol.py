"""What the node's process and its worker process share: how the worker is started, its pace, its error.
Nothing here loads numpy (the worker's entry point imports it before numpy is loaded)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..core.settings import Settings

__all__ = ["FEED_PERIOD_S", "WORKER_NICENESS", "WorkerGone", "WorkerStart"]

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
