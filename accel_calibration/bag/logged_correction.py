"""The correction an autopilot applied before it logged its IMU stream, read from the log's own parameters,
and its undoing: the raw sensor output, in the axes the autopilot's calibration parameters apply in.

Both autopilots log a corrected stream (PX4 `sensor_combined` after `calibration::Accelerometer::Correct`;
ArduPilot `IMU` records after `_rotate_and_correct_accel`), of the same form per sample:

    y = R ((x - drift(T) - offset) * scale)          (accelerometer)
    w = R (x_gyro - gyro_offset)                     (gyro)

with x the sensor's output in the calibration's axes (after the driver's fixed sensor orientation), R the
board rotation (PX4 SENS_BOARD_ROT, or CAL_ACCn_ROT for an external sensor; ArduPilot AHRS_ORIENTATION),
drift(T) the thermal offset where enabled (PX4 TC_A*, ArduPilot INS_TCALn_*). Every part is invertible
per sample (a rotation, a non-zero scale, offsets at the logged temperature), so the raw output is
recovered exactly and the calibration is fitted to it: the written calibration then corrects the raw
sensor, in its own axes, with the uncertainty and canonical form of any fit. (Undoing the samples rather
than composing two calibrations after the fit: the thermal offset varies from pose to pose.)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .bag_io import BagError

if TYPE_CHECKING:
    from ..core.axis_calibration import AxisWiseCalibration

# The rotations PX4 (lib/conversion/rotation.h) and ArduPilot (AP_Math/rotations.h) number alike:
# (roll, pitch, yaw) in degrees, applied as the DCM of those Euler angles (v_body = R v_sensor).
_ROTATIONS_RPY = (
    (0, 0, 0), (0, 0, 45), (0, 0, 90), (0, 0, 135), (0, 0, 180), (0, 0, 225), (0, 0, 270), (0, 0, 315),
    (180, 0, 0), (180, 0, 45), (180, 0, 90), (180, 0, 135), (0, 180, 0), (180, 0, 225), (180, 0, 270),
    (180, 0, 315), (90, 0, 0), (90, 0, 45), (90, 0, 90), (90, 0, 135), (270, 0, 0), (270, 0, 45),
    (270, 0, 90), (270, 0, 135), (0, 90, 0), (0, 270, 0),
)


class LoggedCorrectionError(BagError):
    """A logged correction that cannot be undone: one line naming the file and the part."""


def rotation_matrix(number: int) -> np.ndarray:
    """The board rotation of enum value `number` (both autopilots' ROTATION_* 0..25) as a 3x3 matrix."""
    from scipy.spatial.transform import Rotation

    if not 0 <= number < len(_ROTATIONS_RPY):
        raise ValueError(f"rotation {number} is not one of the 0..{len(_ROTATIONS_RPY) - 1} both autopilots share")
    roll, pitch, yaw = _ROTATIONS_RPY[number]
    matrix: np.ndarray = Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_matrix()
    return np.round(matrix, 15)  # exact zeros and ones where the angle is a right one


@dataclass(frozen=True)
class LoggedCorrection:
    """What the autopilot did to the samples it logged (its parameters at the start of the log)."""

    names: str  # the parameters, e.g. "INS_ACC2OFFS/SCAL, AHRS_ORIENTATION 2"
    axis_wise: AxisWiseCalibration  # offsets, scales and thermal drift, in the sensor's axes
    rotation: np.ndarray  # sensor axes -> logged axes
    gyro_offset_radps: np.ndarray | None  # subtracted from the gyro before the rotation

    def raw_accel(self, logged_mps2: np.ndarray, temperature_degc: np.ndarray | None) -> np.ndarray:
        """x = R^T y / scale + offset + drift(T), per sample; `temperature_degc` per sample where the
        correction has a thermal part (NaN where unknown: refused by the caller)."""
        unrotated = np.asarray(logged_mps2, dtype=float) @ self.rotation  # rows: R^T y
        raw: np.ndarray = unrotated / self.axis_wise.scale + self.axis_wise.offset_mps2
        if self.axis_wise.has_drift:
            assert temperature_degc is not None, "a thermal correction is undone at the logged temperature"
            raw = raw + self.axis_wise.drift(temperature_degc)
        return raw

    def raw_gyro(self, logged_radps: np.ndarray) -> np.ndarray:
        unrotated: np.ndarray = np.asarray(logged_radps, dtype=float) @ self.rotation
        return unrotated if self.gyro_offset_radps is None else unrotated + self.gyro_offset_radps

    def describe(self) -> str:
        offsets = " ".join(f"{v:+.4f}" for v in self.axis_wise.offset_mps2)
        scales = " ".join(f"{v:.5f}" for v in self.axis_wise.scale)
        thermal = ", thermal offset" if self.axis_wise.has_drift else ""
        return f"{self.names} (offsets {offsets} m/s^2, scales {scales}{thermal})"


def undo(correction: LoggedCorrection, accel: np.ndarray, gyro: np.ndarray | None,
         temperature_at_samples: np.ndarray | None, what: str) -> tuple[np.ndarray, np.ndarray | None]:
    """The raw accelerometer and gyro samples under a logged stream; LoggedCorrectionError where the thermal
    part needs a temperature the log does not give."""
    if correction.axis_wise.has_drift and (temperature_at_samples is None
                                           or not np.all(np.isfinite(temperature_at_samples))):
        raise LoggedCorrectionError(f"{what}: the log's thermal compensation is enabled but the log gives no "
                                    "temperature for every sample: cannot undo it (calibrate a raw stream)")
    raw = correction.raw_accel(accel, temperature_at_samples)
    return raw, None if gyro is None else correction.raw_gyro(gyro)


def rotation_of(params: dict[str, float], name: str, what: str) -> np.ndarray:
    """The board rotation parameter `name` (absent: none) as a matrix, or one line saying it is not known."""
    value = params.get(name, 0.0)
    if not np.isfinite(value) or value != int(value) or not 0 <= int(value) < len(_ROTATIONS_RPY):
        raise LoggedCorrectionError(f"{what}: {name} = {value:g} is not a rotation this reader knows "
                                    f"(0..{len(_ROTATIONS_RPY) - 1}): cannot undo the logged correction")
    return rotation_matrix(int(value))


def _invalid(what: str, problem: object, firmware: str) -> LoggedCorrectionError:
    """A logged calibration parameter that is there but invalid: the IMU is refused, not fitted as if the log
    held no correction (its samples are corrected by it, whatever it is)."""
    return LoggedCorrectionError(f"{what}: {problem} ({firmware}, so the logged samples were corrected by it): "
                                 "this IMU is not calibrated from this log; set the parameter right, or calibrate "
                                 "a raw stream")


def ardupilot_correction(params: dict[str, float], instance: int, what: str) -> LoggedCorrection | None:
    """ArduPilot's correction of IMU instance `instance` from its PARM records; None when the log has none
    (absent); LoggedCorrectionError naming the parameter when one is there but invalid. ArduPilot applies
    INS_ACC*OFFS/SCAL as stored (AP_InertialSensor_Backend::_rotate_and_correct_accel; only an all-zero
    scale, never calibrated, is taken as 1), so an out-of-range value corrected the logged samples."""
    from ..io.autopilot_params import ParameterFileError, ParametersAbsentError, ardupilot_calibration

    scale_prefix = "INS_ACCSCAL_" if instance == 0 else f"INS_ACC{instance + 1}SCAL_"
    scales = {axis: params.get(scale_prefix + axis, 1.0) for axis in "XYZ"}
    zero = [axis for axis, value in scales.items() if value == 0]
    if zero and len(zero) < 3 and any(f"INS_ACC{'' if instance == 0 else instance + 1}OFFS_{a}" in params
                                      for a in "XYZ"):
        name = scale_prefix + zero[0]
        raise LoggedCorrectionError(f"{what}: {name} = 0: ArduPilot multiplied that axis by 0 before logging it "
                                    "(it applies the scale as stored), so the log holds none of it to calibrate "
                                    "from; set the parameter right (calibrate the accelerometer on the vehicle)")
    try:
        axis_wise = ardupilot_calibration(params, instance)
    except ParametersAbsentError:
        return None
    except ParameterFileError as error:
        raise _invalid(what, error, "ArduPilot applies it as stored") from None
    rotation = rotation_of(params, "AHRS_ORIENTATION", what)
    prefix = "INS_GYROFFS_" if instance == 0 else f"INS_GYR{instance + 1}OFFS_"
    gyro = np.array([params.get(prefix + axis, 0.0) for axis in "XYZ"])
    n = "" if instance == 0 else str(instance + 1)
    thermal = f", INS_TCAL{instance + 1}" if axis_wise.has_drift else ""
    names = (f"INS_ACC{n}OFFS/INS_ACC{n}SCAL{thermal}, INS_GYR{n}OFFS, "
             f"AHRS_ORIENTATION {int(params.get('AHRS_ORIENTATION', 0))}")
    return LoggedCorrection(names, axis_wise, rotation, gyro)


def px4_slot(params: dict[str, float], kind: str, device_id: int | None) -> int | None:
    """The CAL_<kind>n slot PX4 applies to this device (CAL_<kind>n_ID equal to it), else None."""
    if device_id is None:
        return None
    for slot in range(4):
        if params.get(f"CAL_{kind}{slot}_ID") == device_id and device_id != 0:
            return slot
    return None


def px4_correction(params: dict[str, float], accel_device: int | None, gyro_device: int | None,
                   what: str) -> LoggedCorrection | None:
    """PX4's correction of the selected accelerometer (by device ID) from the log's parameters; None when
    the log holds no calibration slot for it."""
    from ..io.autopilot_params import ParameterFileError, ParametersAbsentError, px4_calibration

    slot = px4_slot(params, "ACC", accel_device)
    if slot is None:
        return None
    params, ignored = _as_px4_applies(params, slot)
    try:
        axis_wise = px4_calibration(params, slot)
    except ParametersAbsentError:  # a slot with an ID and no offsets: nothing known to undo
        return None
    except ParameterFileError as error:
        raise _invalid(what, error, "PX4 applies a positive, finite scale as stored") from None
    # An external sensor carries its own rotation (CAL_ACCn_ROT >= 0); an internal one the board's.
    own = params.get(f"CAL_ACC{slot}_ROT", -1.0)
    rotation_name = f"CAL_ACC{slot}_ROT" if own >= 0 else "SENS_BOARD_ROT"
    rotation = rotation_of(params, rotation_name, what)
    gyro_slot = px4_slot(params, "GYRO", gyro_device)
    gyro = None
    if gyro_slot is not None and params.get("TC_G_ENABLE", 0) != 1:
        gyro = np.array([params.get(f"CAL_GYRO{gyro_slot}_{axis}OFF", 0.0) for axis in "XYZ"])
    thermal = ", TC_A" if axis_wise.has_drift else ""
    gyro_names = f", CAL_GYRO{gyro_slot}_OFF" if gyro is not None else ""
    names = (f"CAL_ACC{slot}_OFF/SCALE{thermal}{gyro_names}, {rotation_name} "
             f"{int(params.get(rotation_name, 0))}{ignored}")
    return LoggedCorrection(names, axis_wise, rotation, gyro)


def _as_px4_applies(params: dict[str, float], slot: int) -> tuple[dict[str, float], str]:
    """The parameters as PX4 put them in force, and what it ignored, said: calibration::Accelerometer's
    set_scale takes a scale only when all three are positive and finite, set_offset an offset only when all
    three are finite; else the sensor keeps its start-up value (scale 1, offset 0)."""
    said = []
    for kind, default, taken in (("SCALE", 1.0, lambda v: math.isfinite(v) and v > 0),
                                 ("OFF", 0.0, math.isfinite)):
        names = [f"CAL_ACC{slot}_{axis}{kind}" for axis in "XYZ"]
        refused = [name for name in names if name in params and not taken(params[name])]
        if refused:
            said.append(f"{refused[0]} = {params[refused[0]]:g} ignored by PX4 (it keeps "
                        f"{'scale 1' if kind == 'SCALE' else 'offset 0'} on every axis)")
            params = {**params, **{name: default for name in names}}
    return params, "".join(f"; {line}" for line in said)


def raw_or_said(correction: LoggedCorrection | None, accel: np.ndarray, gyro: np.ndarray | None,
                temperature_at_samples: np.ndarray | None, stream: str, what: str, absent: str
                ) -> tuple[np.ndarray, np.ndarray | None, str]:
    """(accel, gyro, what the calibration is fitted to) for a logged, corrected stream: the raw samples
    where the log holds its correction, else the samples as logged, said to be corrected by an unknown one
    (`absent`: the parameters looked for)."""
    if correction is None:
        return accel, gyro, (f"{stream} as logged, corrected by a calibration the log does not hold (no {absent}): "
                             "this calibration goes on top of it, in the logged axes")
    raw, raw_gyro = undo(correction, accel, gyro, temperature_at_samples, what)
    return raw, raw_gyro, f"raw: {stream} with the log's correction undone, {correction.describe()}; sensor axes"


def difference_mg(matrix: np.ndarray, bias_mps2: np.ndarray, gravity: float, correction: LoggedCorrection,
                  points: int = 4000) -> float:
    """How far the logged correction (its offsets and scales; no thermal part) is from a calibration of the
    raw sensor a = M (x - b): the largest |M (x - b) - (x - offset) * scale| over the raw outputs x our
    calibration maps to 1 g in every orientation, in mg."""
    from ..core.axis_calibration import sphere_directions

    true = gravity * sphere_directions(points)
    raw = true @ np.linalg.inv(np.asarray(matrix)).T + np.asarray(bias_mps2)
    theirs = (raw - correction.axis_wise.offset_mps2) * correction.axis_wise.scale
    return float(np.max(np.linalg.norm(theirs - true, axis=1)) / (gravity / 1000.0))
