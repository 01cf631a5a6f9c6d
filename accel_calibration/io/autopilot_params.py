"""Autopilot parameter files: PX4 (QGroundControl `.params`, ULog) and ArduPilot (`.param`, DataFlash
`.bin` PARM records), written from and read into the axis-wise form both apply
(core/axis_calibration.py).

What each name means, from the autopilots' own source:
- PX4 `calibration::Accelerometer::Correct`: a = (raw - thermal_offset - CAL_ACCn_OFF) * CAL_ACCn_SCALE;
  `TemperatureCompensation::calc_thermal_offsets_3D`: thermal_offset = X0 + X1 dT + X2 dT^2 + X3 dT^3,
  dT = clamp(T, TMIN, TMAX) - TREF, applied only when TC_A_ENABLE = 1 and TC_An_ID is the device's ID.
  Scales outside CAL_ACCn_xSCALE's declared range 0.1..3.0 are refused (module.yaml), and not positive
  ones by `Accelerometer::set_scale`. Gyro: raw - CAL_GYROn_OFF.
- ArduPilot `AP_InertialSensor_Backend::_rotate_and_correct_accel`: tcal correction, then
  a = (raw - INS_ACCOFFS) * INS_ACCSCAL; `TCal::correct_sensor`: raw -= P(T - 35) - P(CALTEMP - 35) with
  T and CALTEMP clamped to TMIN..TMAX and P(d) = (ACC1 d + ACC2 d^2 + ACC3 d^3) * 1e-6 (parameters stored
  x 1e6, reference 35 degC). Declared ranges: offsets -3.5..3.5 m/s^2, scales 0.8..1.2, TMIN/TMAX -70..80
  degC. An all-zero INS_ACCSCAL is the never-calibrated default, which the autopilot replaces by 1.
  Instance names: INS_ACCOFFS_X, INS_ACC2OFFS_X, INS_ACC3OFFS_X (likewise SCAL, GYROFFS/GYR2OFFS, ACC_ID);
  INS_ACC1_CALTEMP and INS_TCAL1_* count from 1.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.axis_calibration import AxisWiseCalibration
from ..core.errors import CalibrationError
from .calibration_file import read_regular_file

AXES = "XYZ"
PX4_SCALE_RANGE = (0.1, 3.0)
ARDUPILOT_OFFSET_RANGE_MPS2 = (-3.5, 3.5)
ARDUPILOT_SCALE_RANGE = (0.8, 1.2)
ARDUPILOT_TEMPERATURE_RANGE_DEGC = (-70.0, 80.0)
ARDUPILOT_TCAL_REFERENCE_DEGC = 35.0
ARDUPILOT_TCAL_SCALE = 1e6
MAX_INSTANCES = {"px4": 4, "ardupilot": 3}
MAX_PARAMETER_BYTES = 4 << 20  # a full parameter file is ~30-100 KB
FLOAT32_MAX = 3.4028234663852886e38  # both autopilots keep REAL32 parameters
# A decimal number as the autopilots' files write it; Python's float() also takes '1_0', 'nan', 'inf' and
# non-ASCII digits, which no autopilot writes or reads.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


class ParameterFileError(CalibrationError):
    """io: an autopilot parameter file that cannot be read, or values the autopilot would not accept."""


class ParametersAbsentError(ParameterFileError):
    """The calibration parameters of an instance are not there at all (not invalid: absent)."""


@dataclass(frozen=True)
class Parameter:
    name: str
    value: float
    integer: bool = False

    def text(self) -> str:
        if self.integer:
            return str(int(self.value))
        return f"{self.value:.9g}"  # float32 parameters: 9 significant digits round-trip


@dataclass(frozen=True)
class ParameterSet:
    """Parameters read from a file, and whose they are."""

    autopilot: str  # "px4" or "ardupilot"
    values: dict[str, float]
    source: str


def _check_range(name: str, value: float, low: float, high: float) -> None:
    if not (math.isfinite(value) and low <= value <= high):
        raise ParameterFileError(f"{name} = {value:.6g} is outside the range the autopilot accepts, "
                                 f"{low:g}..{high:g}")


def _check_float32(name: str, value: float) -> None:
    if not (math.isfinite(value) and abs(value) <= FLOAT32_MAX):
        raise ParameterFileError(f"{name} = {value:.6g} is not a float32, which the autopilot's parameters are")


def _check_temperature_span(low_name: str, low: float, high_name: str, high: float) -> None:
    if not low <= high:
        raise ParameterFileError(f"{low_name} {low:g} above {high_name} {high:g}: the autopilot's clamp range is empty")


def parse_number(text: str) -> float | None:
    """A decimal number written as the autopilots write one, else None."""
    return float(text) if _NUMBER.fullmatch(text) else None


def _check_instance(autopilot: str, instance: int) -> None:
    count = MAX_INSTANCES[autopilot]
    if not (isinstance(instance, int) and 0 <= instance < count):
        raise ParameterFileError(f"--instance must be 0..{count - 1} for {autopilot}, got {instance}")


# ---------------------------------------------------------------------------------------------- PX4

def px4_parameters(fitted: AxisWiseCalibration, instance: int, *, device_id: int | None = None,
                   gyro_bias_radps: np.ndarray | None = None, gyro_device_id: int | None = None,
                   gyro_drift_rows: np.ndarray | None = None) -> list[Parameter]:
    """CAL_ACCn_* (and CAL_ACCn_ID when the device ID is known), TC_A* when the fit carries a drift
    polynomial, else TC_A_ENABLE 0 (the calibration is of the raw sensor: PX4's thermal offset, left on, would
    be subtracted before it), CAL_GYROn_*OFF from the gyro bias, with TC_G_ENABLE 0 and CAL_GYROn_ID (PX4
    applies a gyro slot only to the device whose ID it holds): the gyro's own ID where known (a BMI088's gyro
    is a die of its own), else the accelerometer's (PX4's drivers of a one-chip IMU register its accel and
    gyro under one device ID). With `gyro_drift_rows` (X0..X3 per axis, rad/s per degC^k, in the accelerometer
    drift's TREF, TMIN, TMAX) the gyro's thermal offset instead: TC_G_ENABLE 1 and TC_Gn_*.
    Refuses values outside PX4's accepted ranges."""
    _check_instance("px4", instance)
    out: list[Parameter] = []
    prefix = f"CAL_ACC{instance}_"
    if device_id is not None:
        out.append(Parameter(prefix + "ID", device_id, integer=True))
    for axis, name in enumerate(AXES):
        out.append(Parameter(f"{prefix}{name}OFF", float(fitted.offset_mps2[axis])))
    for axis, name in enumerate(AXES):
        value = float(fitted.scale[axis])
        _check_range(f"{prefix}{name}SCALE", value, *PX4_SCALE_RANGE)
        out.append(Parameter(f"{prefix}{name}SCALE", value))
    if not fitted.has_drift:
        # Ours is of the raw sensor: a thermal offset left on would be subtracted before it.
        out.append(Parameter("TC_A_ENABLE", 0, integer=True))
    else:
        if fitted.clamp_degc is None or fitted.drift_zero_degc is not None:
            raise ParameterFileError("PX4's thermal offset needs a clamp range and no zero temperature")
        tc = f"TC_A{instance}_"
        out.append(Parameter("TC_A_ENABLE", 1, integer=True))
        if device_id is not None:
            out.append(Parameter(tc + "ID", device_id, integer=True))
        out.append(Parameter(tc + "TREF", fitted.drift_origin_degc))
        out.append(Parameter(tc + "TMIN", fitted.clamp_degc[0]))
        out.append(Parameter(tc + "TMAX", fitted.clamp_degc[1]))
        rows = np.zeros((4, 3))
        rows[0] = fitted.drift_constant_mps2
        rows[1:1 + len(fitted.drift_coefficients)] = fitted.drift_coefficients
        for power in range(4):
            for axis in range(3):
                out.append(Parameter(f"{tc}X{power}_{axis}", float(rows[power, axis])))
    if gyro_bias_radps is not None:
        gyro_device = device_id if gyro_device_id is None else gyro_device_id
        if gyro_drift_rows is None or fitted.clamp_degc is None:
            out.append(Parameter("TC_G_ENABLE", 0, integer=True))  # the gyro bias too is of the raw gyro
        else:
            out += _px4_gyro_thermal(instance, gyro_drift_rows, gyro_device, fitted)
        if gyro_device is not None:
            out.append(Parameter(f"CAL_GYRO{instance}_ID", gyro_device, integer=True))
        for axis, name in enumerate(AXES):
            out.append(Parameter(f"CAL_GYRO{instance}_{name}OFF", float(gyro_bias_radps[axis])))
    return out


def _px4_gyro_thermal(instance: int, rows: np.ndarray, device: int | None,
                      fitted: AxisWiseCalibration) -> list[Parameter]:
    """TC_G_ENABLE 1 and TC_Gn_*: calc_thermal_offsets_3D's X0 + X1 dT + X2 dT^2 + X3 dT^3, dT = clamp(T, TMIN,
    TMAX) - TREF, taken off the raw gyro before CAL_GYROn_OFF (Gyroscope::Correct)."""
    assert fitted.clamp_degc is not None
    tc = f"TC_G{instance}_"
    out = [Parameter("TC_G_ENABLE", 1, integer=True)]
    if device is not None:
        out.append(Parameter(tc + "ID", device, integer=True))
    out += [Parameter(tc + "TREF", fitted.drift_origin_degc), Parameter(tc + "TMIN", fitted.clamp_degc[0]),
            Parameter(tc + "TMAX", fitted.clamp_degc[1])]
    values = np.asarray(rows, dtype=float).reshape(4, 3)
    for power in range(4):
        for axis in range(3):
            _check_float32(f"{tc}X{power}_{axis}", float(values[power, axis]))
            out.append(Parameter(f"{tc}X{power}_{axis}", float(values[power, axis])))
    return out


def px4_params_text(parameters: list[Parameter], comment: str) -> str:
    """QGroundControl's parameter file: tab-separated vehicle, component, name, value, MAV_PARAM_TYPE
    (6 INT32, 9 REAL32)."""
    lines = [f"# {line}" for line in comment.splitlines()]
    lines.append("# Vehicle-Id Component-Id Name Value Type")
    for p in parameters:
        lines.append(f"1\t1\t{p.name}\t{p.text()}\t{6 if p.integer else 9}")
    return "\n".join(lines) + "\n"


def px4_calibration(values: dict[str, float], instance: int) -> AxisWiseCalibration:
    """PX4's accelerometer correction of this calibration slot, with its thermal offset when enabled."""
    _check_instance("px4", instance)
    prefix = f"CAL_ACC{instance}_"
    offset = [values.get(f"{prefix}{a}OFF", 0.0) for a in AXES]
    scale = [values.get(f"{prefix}{a}SCALE", 1.0) for a in AXES]
    if not any(f"{prefix}{a}OFF" in values for a in AXES):
        raise ParametersAbsentError(f"no {prefix}XOFF/YOFF/ZOFF parameters: not this instance, or not PX4")
    for a, value in zip(AXES, offset):
        _check_float32(f"{prefix}{a}OFF", value)
    for a, value in zip(AXES, scale):
        _check_range(f"{prefix}{a}SCALE", value, *PX4_SCALE_RANGE)
    slot = _px4_thermal_slot(values, instance)
    if slot is not None:
        tc = f"TC_A{slot}_"
        rows = np.array([[values.get(f"{tc}X{p}_{axis}", 0.0) for axis in range(3)] for p in range(4)])
        for name in [f"{tc}TREF", f"{tc}TMIN", f"{tc}TMAX"] + [f"{tc}X{p}_{i}" for p in range(4) for i in range(3)]:
            if name in values:
                _check_float32(name, values[name])
        _check_temperature_span(f"{tc}TMIN", values.get(f"{tc}TMIN", -math.inf),
                                f"{tc}TMAX", values.get(f"{tc}TMAX", math.inf))
        return AxisWiseCalibration(
            offset_mps2=np.array(offset), scale=np.array(scale), drift_constant_mps2=rows[0],
            drift_coefficients=rows[1:], drift_origin_degc=values[f"{tc}TREF"],
            clamp_degc=(values.get(f"{tc}TMIN", -math.inf), values.get(f"{tc}TMAX", math.inf)))
    return AxisWiseCalibration(offset_mps2=np.array(offset), scale=np.array(scale))


def _px4_thermal_slot(values: dict[str, float], instance: int) -> int | None:
    """The TC_Aj slot PX4 applies to calibration slot `instance`: thermal compensation enabled and the slot
    whose TC_Aj_ID is CAL_ACCn_ID (PX4 maps by device ID); slot n itself when the file has no IDs."""
    if values.get("TC_A_ENABLE", 0) != 1:
        return None
    device = values.get(f"CAL_ACC{instance}_ID")
    for slot in range(MAX_INSTANCES["px4"]):
        if f"TC_A{slot}_TREF" not in values:
            continue
        thermal_device = values.get(f"TC_A{slot}_ID")
        if device is not None and thermal_device is not None:
            if device == thermal_device and device != 0:
                return slot
        elif slot == instance:
            return slot
    return None


# ----------------------------------------------------------------------------------------- ArduPilot

def _ardupilot_names(instance: int) -> tuple[str, str, str, str]:
    """(offset prefix, scale prefix, gyro offset prefix, ID name) of instance 0, 1, 2."""
    if instance == 0:
        return "INS_ACCOFFS_", "INS_ACCSCAL_", "INS_GYROFFS_", "INS_ACC_ID"
    n = instance + 1
    return f"INS_ACC{n}OFFS_", f"INS_ACC{n}SCAL_", f"INS_GYR{n}OFFS_", f"INS_ACC{n}_ID"


def ardupilot_parameters(fitted: AxisWiseCalibration, instance: int, *, reference_degc: float | None,
                         gyro_bias_radps: np.ndarray | None = None,
                         gyro_drift_coefficients: np.ndarray | None = None) -> list[Parameter]:
    """INS_ACC*OFFS/SCAL of this instance, INS_ACCn_CALTEMP, INS_TCALn_* when the fit carries a drift
    (its own polynomial: reference 35 degC, coefficients x 1e6, zero at CALTEMP), else INS_TCALn_ENABLE 0
    (the calibration is of the raw sensor), INS_GYR*OFFS. With a drift, INS_TCALn_GYR1..3 too (ArduPilot's
    one switch applies both): `gyro_drift_coefficients` (rows k = 1..3, rad/s per degC^k, zero at the same
    CALTEMP, written as INS_GYRn_CALTEMP), else zeros (no gyro drift of ours: none of the vehicle's left
    on). Refuses values outside ArduPilot's declared ranges."""
    _check_instance("ardupilot", instance)
    offset_prefix, scale_prefix, gyro_prefix, _ = _ardupilot_names(instance)
    out: list[Parameter] = []
    for axis, name in enumerate(AXES):
        value = float(fitted.offset_mps2[axis])
        _check_range(offset_prefix + name, value, *ARDUPILOT_OFFSET_RANGE_MPS2)
        out.append(Parameter(offset_prefix + name, value))
    for axis, name in enumerate(AXES):
        value = float(fitted.scale[axis])
        _check_range(scale_prefix + name, value, *ARDUPILOT_SCALE_RANGE)
        out.append(Parameter(scale_prefix + name, value))
    n = instance + 1
    if not fitted.has_drift:  # ours is of the raw sensor: a temperature calibration left on would go before it
        out.append(Parameter(f"INS_TCAL{n}_ENABLE", 0, integer=True))
    calibration_temperature = fitted.drift_zero_degc if fitted.has_drift else reference_degc
    if calibration_temperature is not None:
        _check_range(f"INS_ACC{n}_CALTEMP", calibration_temperature, *ARDUPILOT_TEMPERATURE_RANGE_DEGC)
        out.append(Parameter(f"INS_ACC{n}_CALTEMP", float(calibration_temperature)))
    if fitted.has_drift:
        if (fitted.clamp_degc is None or fitted.drift_zero_degc is None
                or fitted.drift_origin_degc != ARDUPILOT_TCAL_REFERENCE_DEGC or np.any(fitted.drift_constant_mps2)):
            raise ParameterFileError("ArduPilot's temperature calibration needs its own polynomial form "
                                     "(reference 35 degC, zero at CALTEMP, a clamp range)")
        tcal = f"INS_TCAL{n}_"
        out.append(Parameter(tcal + "ENABLE", 1, integer=True))
        for name, value in (("TMIN", fitted.clamp_degc[0]), ("TMAX", fitted.clamp_degc[1])):
            _check_range(tcal + name, value, *ARDUPILOT_TEMPERATURE_RANGE_DEGC)
            out.append(Parameter(tcal + name, float(value)))
        rows = np.zeros((3, 3))
        rows[:len(fitted.drift_coefficients)] = fitted.drift_coefficients
        for power in range(3):
            for axis, name in enumerate(AXES):
                out.append(Parameter(f"{tcal}ACC{power + 1}_{name}", float(rows[power, axis]) * ARDUPILOT_TCAL_SCALE))
        out += _ardupilot_gyro_tcal(n, gyro_drift_coefficients, fitted.drift_zero_degc)
    if gyro_bias_radps is not None:
        for axis, name in enumerate(AXES):
            out.append(Parameter(gyro_prefix + name, float(gyro_bias_radps[axis])))
    return out


def _ardupilot_gyro_tcal(n: int, coefficients: np.ndarray | None, calibration_temperature: float) -> list[Parameter]:
    """INS_TCALn_GYR1..3_X/Y/Z (x 1e6) and INS_GYRn_CALTEMP, where TCal::correct_gyro takes the gyro's zero."""
    rows = np.zeros((3, 3)) if coefficients is None else np.asarray(coefficients, dtype=float).reshape(3, 3)
    out = [Parameter(f"INS_GYR{n}_CALTEMP", float(calibration_temperature))]
    for power in range(3):
        for axis, name in enumerate(AXES):
            value = float(rows[power, axis]) * ARDUPILOT_TCAL_SCALE
            _check_float32(f"INS_TCAL{n}_GYR{power + 1}_{name}", value)
            out.append(Parameter(f"INS_TCAL{n}_GYR{power + 1}_{name}", value))
    return out


def ardupilot_param_text(parameters: list[Parameter], comment: str) -> str:
    """Mission Planner's `.param` file: NAME,VALUE per line (MAVProxy reads it too)."""
    lines = [f"# {line}" for line in comment.splitlines()]
    lines += [f"{p.name},{p.text()}" for p in parameters]
    return "\n".join(lines) + "\n"


def ardupilot_calibration(values: dict[str, float], instance: int) -> AxisWiseCalibration:
    """ArduPilot's accelerometer correction of this instance, with its temperature calibration when enabled."""
    _check_instance("ardupilot", instance)
    offset_prefix, scale_prefix, _, _ = _ardupilot_names(instance)
    if not any(offset_prefix + a in values for a in AXES):
        raise ParametersAbsentError(f"no {offset_prefix}X/Y/Z parameters: not this instance, or not ArduPilot")
    offset = np.array([values.get(offset_prefix + a, 0.0) for a in AXES])
    scale = np.array([values.get(scale_prefix + a, 1.0) for a in AXES])
    for a, value in zip(AXES, offset):
        _check_range(offset_prefix + a, float(value), *ARDUPILOT_OFFSET_RANGE_MPS2)
    if not np.any(scale):
        scale = np.ones(3)  # the never-calibrated default, replaced by 1 at start-up
    for a, value in zip(AXES, scale):
        _check_range(scale_prefix + a, float(value), *ARDUPILOT_SCALE_RANGE)
    n = instance + 1
    tcal = f"INS_TCAL{n}_"
    if values.get(tcal + "ENABLE", 0) == 1:
        rows = np.array([[values.get(f"{tcal}ACC{p}_{a}", 0.0) for a in AXES] for p in (1, 2, 3)])
        for name in (tcal + "TMIN", tcal + "TMAX"):
            if name in values:
                _check_range(name, values[name], *ARDUPILOT_TEMPERATURE_RANGE_DEGC)
        _check_temperature_span(tcal + "TMIN", values.get(tcal + "TMIN", 0.0), tcal + "TMAX",
                                values.get(tcal + "TMAX", 70.0))
        for name in [f"{tcal}ACC{p}_{a}" for p in (1, 2, 3) for a in AXES] + [f"INS_ACC{n}_CALTEMP"]:
            if name in values:
                _check_float32(name, values[name])
        return AxisWiseCalibration(
            offset_mps2=offset, scale=scale, drift_coefficients=rows / ARDUPILOT_TCAL_SCALE,
            drift_origin_degc=ARDUPILOT_TCAL_REFERENCE_DEGC,
            drift_zero_degc=values.get(f"INS_ACC{n}_CALTEMP", -300.0),
            clamp_degc=(values.get(tcal + "TMIN", 0.0), values.get(tcal + "TMAX", 70.0)))
    return AxisWiseCalibration(offset_mps2=offset, scale=scale)


# ------------------------------------------------------------------------------------------- reading

def _autopilot_of(names: set[str], source: str) -> str:
    px4 = any(n.startswith(("CAL_ACC", "TC_A", "SYS_AUTOSTART")) for n in names)
    ardupilot = any(n.startswith(("INS_ACC", "INS_GYR", "INS_TCAL")) for n in names)
    if px4 == ardupilot:
        raise ParameterFileError(f"{source}: cannot tell PX4 (CAL_ACC*) from ArduPilot (INS_ACC*) parameters: "
                                 "it holds " + ("both" if px4 else "neither"))
    return "px4" if px4 else "ardupilot"


def parse_parameter_text(text: str, source: str) -> ParameterSet:
    """A QGroundControl `.params` (vehicle, component, name, value, type; tabs), a Mission Planner / MAVProxy
    `.param` (NAME,VALUE or NAME VALUE), '#' comments."""
    values: dict[str, float] = {}
    for number, raw_line in enumerate(text.splitlines(), start=1):
        line = raw_line.split("#", 1)[0].strip()
        if not line:
            continue
        fields = line.replace(",", " ").split()
        if len(fields) == 5:
            name, value_text = fields[2], fields[3]
        elif len(fields) in (2, 3):  # NAME VALUE [TYPE]
            name, value_text = fields[0], fields[1]
        else:
            raise ParameterFileError(f"{source}: line {number}: expected NAME,VALUE or QGroundControl's "
                                     f"5 columns, got {raw_line.strip()[:60]!r}")
        value = parse_number(value_text)
        if value is None:
            raise ParameterFileError(f"{source}: line {number}: {name} value {value_text[:30]!r} is not a number")
        if not math.isfinite(value):
            raise ParameterFileError(f"{source}: line {number}: {name} = {value_text[:30]} is not finite")
        values[name] = value
    if not values:
        raise ParameterFileError(f"{source}: no parameters in it")
    return ParameterSet(_autopilot_of(set(values), source), values, source)


def read_ulog_parameters(path: str | Path) -> ParameterSet:
    """The parameters at the start of a PX4 ULog (pyulog), as the autopilot had them when it logged."""
    from pyulog import ULog

    try:
        ulog = ULog(str(path), [], False)
    except Exception as error:  # pyulog raises bare exceptions on damaged files
        raise ParameterFileError(f"{path}: not a readable ULog ({type(error).__name__}: {str(error)[:80]})") from None
    values: dict[str, float] = {}
    for key, value in ulog.initial_parameters.items():
        # PX4 logs int32 and float parameters; anything else is no value the autopilot would apply.
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ParameterFileError(f"{path}: parameter {str(key)[:40]} is not a number "
                                     f"({type(value).__name__} {str(value)[:20]!r})")
        values[str(key)] = float(value)
    if not values:
        raise ParameterFileError(f"{path}: the ULog holds no parameters")
    return ParameterSet(_autopilot_of(set(values), str(path)), values, str(path))


def read_dataflash_parameters(path: str | Path) -> ParameterSet:
    """The PARM records of an ArduPilot DataFlash log (pymavlink); a parameter set twice keeps its last value."""
    try:
        from pymavlink import DFReader
    except ModuleNotFoundError:
        raise ParameterFileError(f"{path}: reading DataFlash logs needs pymavlink: pip install pymavlink") from None
    from .captured_output import captured_output, damage_said

    failure = None
    values: dict[str, float] = {}
    try:
        with captured_output() as chatter:  # pymavlink prints, its C indexer on descriptor 2
            reader = DFReader.DFReader_binary(str(path), zero_time_base=True)
            try:  # closed here: left to the garbage collector, the file stays open until it runs
                while True:
                    message = reader.recv_match(type=["PARM"])
                    if message is None:
                        break
                    values[str(message.Name)] = float(message.Value)
            finally:
                reader.close()
    except Exception as error:  # pymavlink raises what it meets in a damaged log
        failure = f"{path}: not a readable DataFlash log ({type(error).__name__}: {str(error)[:80]})"
    damage = damage_said(chatter)
    if damage is not None or failure is not None:
        raise ParameterFileError(f"{path}: {damage}" if damage is not None else str(failure))
    if not values:
        raise ParameterFileError(f"{path}: no PARM records in this log")
    return ParameterSet(_autopilot_of(set(values), str(path)), values, str(path))


def read_parameters(path: str | Path) -> ParameterSet:
    """Parameters from a PX4 .params file or ULog, or an ArduPilot .param file or DataFlash .bin, by content."""
    p = Path(path)
    head = _head(p)
    if head.startswith(b"ULog\x01\x12\x35"):
        return read_ulog_parameters(p)
    if head[:2] == b"\xa3\x95":  # DataFlash message header
        return read_dataflash_parameters(p)
    raw = read_regular_file(p, MAX_PARAMETER_BYTES, "parameter file", error=ParameterFileError)
    try:
        text = raw.decode("utf-8-sig")  # Windows editors begin a file with a byte-order mark
    except UnicodeDecodeError:
        raise ParameterFileError(f"{p}: neither a parameter text file, a ULog nor a DataFlash log") from None
    return parse_parameter_text(text, str(p))


def _head(path: Path) -> bytes:
    """The first bytes of a file, with the checks of read_regular_file (kind, existence) but no size limit."""
    import os
    import stat

    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise ParameterFileError(f"{path}: parameter file or log not found") from None
    except OSError as problem:
        raise ParameterFileError(f"{path}: cannot read it ({problem.strerror or problem})") from None
    if not stat.S_ISREG(info.st_mode):
        raise ParameterFileError(f"{path}: not a regular file")
    with open(path, "rb") as handle:
        return handle.read(16)
