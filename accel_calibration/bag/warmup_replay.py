"""A recording that is a warm-up (the sensor still while its temperature changes) read for the warm-up fit
(core/warmup.py): the same replay as any recording (the log's own correction undone, the temperature filtered
and held as the node holds it), then its raw samples with the temperature at each, and the calibration the
curves go on top of: --prior's, else the one its poses fit, else the log's own in force, else none."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.calibration import Calibration
from ..core.warmup import WarmupRecording
from .bag_io import BagError
from .logged_correction import LoggedCorrection
from .replay import ReplayError, ReplayResult, ReplaySettings, replay_bag


@dataclass(frozen=True)
class WarmupInput:
    """One recording's samples for the warm-up fit, and what its replay found."""

    recording: WarmupRecording
    replay: ReplayResult
    base: Calibration | None  # what the curves go on top of (None: the raw output)
    base_said: str  # which one it is, as replay says it


def in_force_calibration(logged: LoggedCorrection) -> Calibration:
    """The log's own correction as ours, in the sensor's axes as replay's fits are (the board rotation
    stays the vehicle's), its thermal part left out: (x - offset) scale is M (x - b) with b = offset,
    M = diag(scale); the gyro's x - gyro_offset."""
    wise = logged.axis_wise
    return Calibration(bias=wise.offset_mps2, matrix=np.diag(wise.scale), gyro_bias_radps=logged.gyro_offset_radps)


def _base(replay: ReplayResult, settings: ReplaySettings) -> tuple[Calibration | None, str]:
    from .recording import Recording

    if settings.prior is not None:
        return settings.prior.calibration, f"on top of --prior {settings.prior_path}"
    if replay.calibration is not None:
        return replay.calibration, f"on top of the calibration its {len(replay.poses)} poses fit"
    recording = replay.source.recording
    logged = recording.logged_correction if isinstance(recording, Recording) else None
    if logged is not None:
        thermal = " (its thermal part replaced by the warm-up's)" if logged.axis_wise.has_drift else ""
        return in_force_calibration(logged), f"on top of the log's calibration in force: {logged.names}{thermal}"
    return None, "on the raw output (no calibration fitted or in force)"


def read_warmup(path: str | os.PathLike[str], settings: ReplaySettings, progress: bool = False) -> WarmupInput:
    """The recording replayed, its samples with the held temperature at each (NaN where none or stale);
    ReplayError (one line) when it has no temperature."""
    from .recording import Recording, open_recording

    replay = replay_bag(path, settings, progress=progress)
    recording = replay.source.recording
    if not isinstance(recording, Recording):  # a bag streamed: read whole now
        try:
            recording = open_recording(path, **settings.reader_options())
        except BagError as error:
            raise ReplayError(str(error)) from None
    if replay.temperatures is None:
        raise ReplayError(f"{path}: no temperature stream: a warm-up's curves need the sensor's temperature "
                          "(--temperature-topic, a CSV 'temperature' column, a log's IMU temperature)")
    temperature = replay.temperatures.at(recording.t_ns)
    base, said = _base(replay, settings)
    samples = WarmupRecording(recording.t_ns, recording.accel_mps2, recording.gyro_radps, temperature,
                              name=Path(path).name)
    return WarmupInput(samples, replay, base, said)
