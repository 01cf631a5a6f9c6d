"""Recalibrate from a recorded rosbag2: the same detector, temperature filter, pose store, fit and
quality gates as the live node, fed from the bag instead of the network, so a session gives the
same calibration either way. An adapter: bag I/O lives in msg_tools.bag_io."""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.calibration import Calibration
from ..core.errors import CalibrationError
from ..core.fit import FitResult
from ..core.pose import Pose
from ..core.session import CalibrationSession
from ..core.settings import Settings
from ..core.temperature_filter import TemperatureFilter
from .bag_io import BagError


@dataclass(frozen=True)
class ReplaySettings:
    """The session's settings (the node's parameters, same defaults and checks) and which topics to read."""

    session: Settings = field(default_factory=Settings)
    imu_topic: str | None = None
    temperature_topic: str | None = None


@dataclass
class ReplayResult:
    bag: str
    imu_topic: str
    temperature_topic: str | None
    messages: int
    duration_s: float
    poses: list[Pose]
    result: FitResult | None
    problem: str | None  # why no calibration (None when `calibration` is usable)
    counts: dict
    elapsed_s: float
    frame_id: str = ""
    imu: object = None  # msg_tools.bag_io.ImuData, for writing a corrected copy
    temperature_at_samples: np.ndarray | None = None

    @property
    def calibration(self) -> Calibration | None:
        return self.result.calibration if self.problem is None and self.result is not None else None


class ReplayError(BagError):
    """One line: the bag and what was (not) found in it."""


def replay_bag(path, settings: ReplaySettings | None = None, progress: bool = False,
               for_copy: bool = False) -> ReplayResult:
    """`for_copy`: read in rosbags' message order, which write_corrected_bag needs."""


    s = settings or ReplaySettings()
    started = time.perf_counter()
    try:
        loaded = None if for_copy else _read_fast(path, s, progress)
        if loaded is None:
            loaded = _read_with_rosbags(path, s, progress)
    except BagError as error:
        raise ReplayError(str(error)) from None
    imu, temperatures, temperature_topic = loaded

    # The recording's own order is the order the node received the messages: the session takes them
    # in that order, so a stamp going backwards is dropped here as it is live.
    t = imu.t_ns
    session = CalibrationSession(s.session)
    session.frame_id = imu.frame_id
    temperature_stamps, temperature_values = temperatures if temperatures is not None else (None, None)
    poses = session.add_recording(t, imu.accel, imu.gyro, temperature_stamps, temperature_values)
    for pose in poses:
        session.add_pose(pose)
    verdict = session.calibrate()
    counts = session.counters.as_dict()
    duration = (int(t.max()) - int(t.min())) / 1e9 if len(t) > 1 else 0.0
    problem = None
    if not verdict.success:
        problem = verdict.message
        if len(session.store) < session.settings.min_poses:
            problem = "too few static poses for a calibration (no multi-pose session in this recording): " + problem
        problem = (f"found {len(poses)} static poses ({len(session.store)} distinct) in {imu.topic} "
                   f"({len(t)} messages, {duration:.1f} s): {problem}")
    result = verdict.result
    if verdict.success:
        result = dataclasses.replace(verdict.result, calibration=verdict.calibration)
    temps = None
    if temperature_stamps is not None and len(temperature_stamps):
        temps, _ = TemperatureFilter(timeout_s=s.session.temperature_timeout_s).series(
            temperature_stamps, temperature_values, t)
    temperature_at_samples = temps  # per message, for the corrected copy
    return ReplayResult(
        bag=str(path),
        imu_topic=imu.topic,
        temperature_topic=temperature_topic,
        messages=len(t),
        duration_s=duration,
        poses=poses,
        result=result,
        problem=problem,
        counts=counts,
        elapsed_s=time.perf_counter() - started,
        frame_id=imu.frame_id,
        imu=imu,
        temperature_at_samples=temperature_at_samples,
    )


def _progress_bar(path, total, progress):
    if not progress:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="msg", desc=Path(path).name, leave=False, disable=None)


def _no_imu(path, connections):
    have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in connections})) or "no topics"
    return ReplayError(f"{path}: no sensor_msgs/msg/Imu topic; the bag has {have}")


def _read_fast(path, s: ReplaySettings, progress):
    """Storage files read directly, topics from metadata.yaml; None when that cannot be trusted."""
    from .bag_io import IMU, TEMPERATURE, choose_topic, metadata_topics, read_fast

    if not Path(path).is_dir():
        return None
    topics = metadata_topics(path)
    if topics is None:
        return None
    imu_topic = choose_topic(topics, IMU, s.imu_topic, "imu", path)
    if imu_topic is None:
        raise _no_imu(path, topics)
    temperature_topic = choose_topic(topics, TEMPERATURE, s.temperature_topic, "temperature", path)
    bar = _progress_bar(path, imu_topic.msgcount + (temperature_topic.msgcount if temperature_topic else 0), progress)
    try:
        read = read_fast(path, imu_topic, temperature_topic, bar)
    finally:
        if bar is not None:
            bar.close()
    if read is None:
        return None
    return read[0], read[1], temperature_topic.topic if temperature_topic else None


def _read_with_rosbags(path, s: ReplaySettings, progress):
    from .bag_io import IMU, TEMPERATURE, choose_topic, open_reader, read_imu_and_temperature

    reader = open_reader(path)
    try:
        imu_connection = choose_topic(reader.connections, IMU, s.imu_topic, "imu", path)
        if imu_connection is None:
            raise _no_imu(path, reader.connections)
        temperature_connection = choose_topic(reader.connections, TEMPERATURE, s.temperature_topic, "temperature", path)
        total = imu_connection.msgcount + (temperature_connection.msgcount if temperature_connection else 0)
        bar = _progress_bar(path, total, progress)
        try:
            imu, temperatures = read_imu_and_temperature(reader, imu_connection, temperature_connection, path, bar)
        finally:
            if bar is not None:
                bar.close()
    finally:
        reader.close()
    return imu, temperatures, temperature_connection.topic if temperature_connection else None


def write_corrected_bag(replay: ReplayResult, calibration: Calibration, destination) -> int:
    """A copy of the replayed bag with the IMU accelerations corrected (at each sample's temperature)."""
    from .bag_io import BagError, write_corrected

    imu = replay.imu
    temps = replay.temperature_at_samples
    corrected = imu.accel.copy()
    finite = np.all(np.isfinite(corrected), axis=1)
    if temps is not None and calibration.temperature is not None:
        known = finite & ~np.isnan(temps)
        corrected[known] = calibration.apply(imu.accel[known], temps[known])
        rest = finite & np.isnan(temps)
        corrected[rest] = calibration.apply(imu.accel[rest])
    else:
        corrected[finite] = calibration.apply(imu.accel[finite])
    try:
        return write_corrected(replay.bag, destination, imu, corrected)
    except BagError as error:
        raise CalibrationError(str(error)) from None
