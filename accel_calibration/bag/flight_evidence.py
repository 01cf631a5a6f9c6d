"""What an ordinary flight log says of each IMU's calibration in force: the still moments on the ground
(before arming, after landing; the flight state replay reads keeps the rest out) checked against the
calibration the autopilot applied while logging, read from the log's own parameters, with `check`'s
statistics (core/check.py) and its one observability rule. A vehicle parked level sees only the z bias and
z gain together ("bias z or scale z", their effect on |a| at 1 g); parked at other attitudes it sees more.

The poses are the raw sensor output (the log's correction undone, or a PX4 sensor_accel instance as
logged), so the calibration in force is the log's offsets and scales as a_true = diag(scale) (raw - offset):
the board rotation turns the force, never its magnitude, and check reads magnitudes only."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import AccelCalibrationError
from .correction_in_force import calibration_in_force
from .correction_in_force import ulog_correction as _ulog_correction

if TYPE_CHECKING:
    from ..core.check import CheckResult
    from ..core.pose import Pose
    from .replay import ReplayResult

Z_GROUP = "bias z or scale z"  # what level ground sees of the z axis (check's name for it)


@dataclass(frozen=True)
class FlightEvidence:
    """One IMU of one flight log. `changes`: what the poses observe, (name, change, sigma): a bias in
    m/s^2 (b_new - b), a scale as a fraction, a group of changes the poses cannot tell apart as its effect
    on |a| at 1 g in m/s^2. Empty with `reason` set when the log gives no evidence."""

    device: str  # the IMU's device ID as the log names it, "" where it names none
    poses: int
    in_force: str  # the log's parameters read as the calibration in force
    verdict: str  # holds | moved | cannot tell (check's), or "none": no evidence (the reason says why)
    changes: tuple[tuple[str, float, float], ...] = ()
    reason: str | None = None
    temperature_degc: float | None = None  # the poses' mean temperature, where the log gives one
    # In flight (bag/in_flight_evidence.py), as stored: the filter's settled bias (bag/estimator_bias.py) and
    # the agreement with the IMU's siblings (bag/imu_agreement.py); {"reason": ...} where the log gives none.
    estimator: dict[str, Any] | None = None
    agreement: dict[str, Any] | None = None

    def change(self, name: str) -> tuple[float, float] | None:
        return next(((value, sigma) for n, value, sigma in self.changes if n == name), None)

    @property
    def z(self) -> tuple[float, float] | None:
        """What the poses say of the z axis at 1 g (m/s^2, sigma): the level-ground group, else bias z."""
        return self.change(Z_GROUP) or self.change("bias z")


def _none(device: str, reason: str, in_force: str = "", poses: int = 0) -> FlightEvidence:
    return FlightEvidence(device, poses, in_force, "none", reason=reason)


def evidence_of(replay: ReplayResult) -> FlightEvidence:
    """The evidence of one IMU from its replay (bag/replay.replay_bag of a ULog instance or the selected
    sensor_combined, or a DataFlash IMU instance): its still moments on the ground, then what the log says of
    it in flight; never raises for what the log lacks: the reason says it. A rosbag2's: flight_evidence_bag.py."""
    import dataclasses

    from .in_flight_evidence import in_flight_of

    ground = _ground_evidence(replay)
    estimator, agreement = in_flight_of(replay.source.recording)
    return dataclasses.replace(ground, estimator=estimator, agreement=agreement)


def _ground_evidence(replay: ReplayResult) -> FlightEvidence:
    from ..core.check import check_calibration
    from .recording import LOGS, Recording

    recording = replay.source.recording
    name = Path(str(getattr(recording, "path", ""))).name
    if not isinstance(recording, Recording) or recording.format not in LOGS:
        return _none("", f"{name}: not an autopilot log: it carries no calibration in force to check")
    device = "" if recording.accel_device_id is None else str(recording.accel_device_id)
    correction = recording.logged_correction
    if correction is None and recording.format == "ulog":
        try:
            correction = _ulog_correction(recording.path, recording.accel_device_id)
        except AccelCalibrationError as error:  # its calibration parameters there but invalid: named
            return _none(device, str(error))
    if correction is None:
        return _none(device, f"{name}: the log holds no calibration of this IMU (no calibration parameters for it)")
    if correction.axis_wise.has_drift:
        return _none(device, f"{name}: a thermal compensation is in force: not checked on ground poses",
                     correction.names)
    if replay.flight_state is None or not replay.flight_state.found:
        return _none(device, f"{name}: no flight state in the log: the still moments on the ground cannot be "
                             "told from the flight", correction.names)
    poses = list(replay.poses)
    if not poses:
        return _none(device, f"{name}: no still moment on the ground (before arming or after landing)",
                     correction.names)
    result = check_calibration(calibration_in_force(correction), _quantised(replay, poses))
    temperatures = [p.temperature_degc for p in poses if p.temperature_degc is not None
                    and np.isfinite(p.temperature_degc)]
    return FlightEvidence(device, len(poses), correction.describe(), result.verdict, _observed(result),
                          temperature_degc=float(np.mean(temperatures)) if temperatures else None)


def _quantised(replay: ReplayResult, poses: list[Pose]) -> list[Pose]:
    """The poses with their samples' quantisation in their sigma, as check takes them."""
    from ..core.quantisation import quantisation_steps, with_quantisation
    from .recording import Recording

    recording = replay.source.recording
    if not isinstance(recording, Recording):
        return poses
    steps = quantisation_steps(recording.accel_mps2)
    return list(with_quantisation(poses, steps)) if np.any(steps > 0) else poses


def _observed(result: CheckResult) -> tuple[tuple[str, float, float], ...]:
    out = [(c.name, float(c.change), float(c.sigma)) for c in result.changes
           if c.change is not None and c.sigma is not None]
    out += [(g.name, float(g.change), float(g.sigma)) for g in result.groups if g.members]
    return tuple(out)


def log_evidence(path: str, settings: object | None = None) -> list[FlightEvidence]:
    """Every IMU of a flight log (ULog sensor_accel instances, DataFlash IMU instances), each replayed alone;
    an IMU whose replay fails is evidence "none" with the reason, never left out."""
    import dataclasses

    from ..core.errors import AccelCalibrationError
    from .recording import LOGS, detect_format, log_accel_devices
    from .replay import ReplaySettings, replay_bag

    base = settings if isinstance(settings, ReplaySettings) else ReplaySettings()
    try:
        devices: dict[int | None, int | None] = {k: v for k, v in log_accel_devices(path).items()}
        if not devices and detect_format(path) in LOGS:
            devices = {None: None}  # a ULog of sensor_combined alone: the selected IMU
    except AccelCalibrationError as error:  # unreadable: one row with its reason
        return [_none("", str(error))]
    if not devices:
        return [_none("", f"{Path(path).name}: not an autopilot log (PX4 ULog, ArduPilot DataFlash): it "
                          "carries no calibration in force to check")]
    out = []
    for instance, device in devices.items():
        try:
            replay = replay_bag(path, dataclasses.replace(base, instance=instance))
        except AccelCalibrationError as error:
            out.append(_none("" if device is None else str(device), str(error)))
            continue
        out.append(evidence_of(replay))
    return out
