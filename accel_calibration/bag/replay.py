"""Recalibrate from a recorded rosbag2: the same detector, temperature filter, pose store, fit and
quality gates as the live node, fed from the bag instead of the network, so a session gives the
same calibration either way. An adapter: bag I/O lives in msg_tools.bag_io."""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core.calibration import STANDARD_GRAVITY, Calibration
from ..core.errors import CalibrationError
from ..core.fit import FitResult
from ..core.online_calibrator import OnlineCalibrator, QualityGates
from ..core.pose import Pose
from ..core.pose_store import PoseStore
from ..core.static_detector import StaticDetector
from ..core.temperature_filter import TemperatureFilter
from ..core.temperature_models import TemperatureOptions


@dataclass(frozen=True)
class ReplaySettings:
    """Defaults are the node's parameter defaults (config/accel_calibration.yaml)."""

    model: str = "sphere9"
    gravity: float = STANDARD_GRAVITY
    temperature: TemperatureOptions = field(default_factory=TemperatureOptions)
    min_poses: int = 12
    max_residual_rms_mg: float = 15.0
    max_bias_sigma_mg: float = 5.0
    max_bias_mps2: float = 2.0
    scale_band: tuple[float, float] = (0.9, 1.1)
    merge_angle_deg: float = 5.0
    max_poses: int = 100
    temperature_bin_degc: float = 5.0
    accel_range_mps2: float = 16 * STANDARD_GRAVITY
    temperature_timeout_s: float = 5.0
    window_s: float = 0.5
    min_hold_s: float = 1.0
    k_sigma: float = 6.0
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


class ReplayError(Exception):
    """One line: the bag and what was (not) found in it."""


def replay_bag(path, settings: ReplaySettings | None = None, progress: bool = False, for_copy: bool = False) -> ReplayResult:
    """`for_copy`: read in rosbags' message order, which write_corrected_bag needs."""
    from .bag_io import BagError

    s = settings or ReplaySettings()
    started = time.perf_counter()
    try:
        loaded = None if for_copy else _read_fast(path, s, progress)
        if loaded is None:
            loaded = _read_with_rosbags(path, s, progress)
    except BagError as error:
        raise ReplayError(str(error)) from None
    imu, temperatures, temperature_topic = loaded

    # Recorders write in arrival order; the session's time is the header stamps.
    order = np.argsort(imu.t_ns, kind="stable")
    t, accel, gyro = imu.t_ns[order], imu.accel[order], imu.gyro[order]
    counts = {}
    finite = np.all(np.isfinite(accel), axis=1)
    counts["non_finite"] = int(np.count_nonzero(~finite))
    with np.errstate(invalid="ignore"):
        saturated = finite & np.any(np.abs(accel) >= 0.995 * s.accel_range_mps2, axis=1)
    counts["saturated"] = int(np.count_nonzero(saturated))
    temperature_filter = TemperatureFilter(timeout_s=s.temperature_timeout_s)
    temps = None
    if temperatures is not None and len(temperatures[0]):
        temps, counts["temperature_stale"] = temperature_filter.series(*temperatures, t)
        counts["temperature_bad"] = temperature_filter.rejected
    use = ~saturated
    detector = StaticDetector(window_s=s.window_s, min_hold_s=s.min_hold_s, k_sigma=s.k_sigma)
    poses = detector.process(t[use], accel[use], gyro[use], None if temps is None else temps[use])
    counts["stamp_not_increasing"] = detector.rejected_samples - counts["non_finite"]

    online = OnlineCalibrator(
        model=s.model,
        gravity=s.gravity,
        gates=QualityGates(min_poses=s.min_poses, max_residual_rms_mg=s.max_residual_rms_mg,
                           max_bias_sigma_mg=s.max_bias_sigma_mg, max_bias_mps2=s.max_bias_mps2, scale_band=s.scale_band),
        store=PoseStore(merge_angle_deg=s.merge_angle_deg, capacity=s.max_poses, temperature_bin_degc=s.temperature_bin_degc),
        temperature=s.temperature,
    )
    for pose in poses:
        online.add_pose(pose)
    result, problem = online.calibrate()
    duration = (t[-1] - t[0]) / 1e9 if len(t) > 1 else 0.0
    if problem is not None:
        if len(online.store) < max(s.min_poses, 9):
            problem = "too few static poses for a calibration (no multi-pose session in this recording): " + problem
        problem = (f"found {len(poses)} static poses ({len(online.store)} distinct) in {imu.topic} "
                   f"({len(t)} messages, {duration:.1f} s): {problem}")
    if result is not None and result.success and problem is None:
        gyro_bias = online.gyro_bias_radps()
        calibration = result.calibration.replace(frame_id=imu.frame_id, gyro_bias_radps=gyro_bias)
        result = dataclasses.replace(result, calibration=calibration)
    temperature_at_samples = None
    if temps is not None:
        temperature_at_samples = np.empty(len(t))
        temperature_at_samples[order] = temps  # back to the bag's message order
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
