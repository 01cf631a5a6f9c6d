"""What several commands share: the program's name, the units of a table's accelerations, the replay
settings built from the options exactly as the node builds them (`replay` and `fleet`), with the
flight-state options (which bag topic says armed or flying, the margin kept around a flight, the switch
for a bench log armed on purpose: bag/flight_sources.py reads them), and the check a calibration file
passes before it is put in force (`apply`, `report`)."""
from __future__ import annotations

import argparse
import re
from typing import Any

from ..core.errors import CalibrationError
from ..core.temperature_models import TEMPERATURE_MODELS
from ..core.units import STANDARD_GRAVITY

PROG = "accel-calib"
UNIT_SCALE = {"mps2": 1.0, "g": STANDARD_GRAVITY}  # a reading of 1 g is 9.80665 m/s^2 by definition

DEFAULT_MARGIN_S = 2.0
# rcl's rules for a node's fully qualified name: tokens of letters, digits and underscores, none starting
# with a digit, joined by single slashes; a leading slash optional here (the params file's keys drop it).
_NODE_NAME = re.compile(r"/?(?:[A-Za-z_][A-Za-z0-9_]*/)*[A-Za-z_][A-Za-z0-9_]*", re.ASCII)
MAX_NODE_NAME = 255  # rcl's limit on a node name


def check_node_name(name: str) -> None:
    """One line when `name` (--node) is no node name rcl would accept: it could match no block."""
    if len(name) > MAX_NODE_NAME or _NODE_NAME.fullmatch(name) is None:
        shown = repr(name) if len(name) <= 60 else f"{name[:60]!r}... ({len(name)} characters)"
        raise CalibrationError(f"--node {shown} is not a ROS node name: write /NAMESPACE/NAME or NAME, each part "
                               "letters, digits and underscores, not starting with a digit")


def units_hint(typical_raw: float) -> str:
    """What the typical |a| of a still table or stream, as written in the file, looks like."""
    if 0.7 * STANDARD_GRAVITY <= typical_raw <= 1.3 * STANDARD_GRAVITY:
        return "the file looks like m/s^2: use --units mps2"
    if 0.7 <= typical_raw <= 1.3:
        return "the file looks like g: use --units g"
    if typical_raw > 30.0:
        return f"the file looks like raw counts (~{typical_raw:.0f} per g): fit them with --units mps2"
    return "check the file's units and scaling"


def check_table_units(raw: Any, unit_mps2: float, units: str, gravity: float, source: str) -> None:
    """A pose table's ax,ay,az (as written, read with --units) must be gravity at rest: else one line,
    before any fit (as replay refuses a stream in other units)."""
    import numpy as np

    from ..core.units import units_problem

    raw = np.asarray(raw, dtype=float).reshape(-1, 3)
    if units_problem(raw * unit_mps2, gravity) is None:
        return
    largest = float(np.abs(raw).max()) or 1.0  # the norm of 1e-300s underflows unless scaled first
    typical_raw = float(np.median(np.linalg.norm(raw / largest, axis=1))) * largest
    if units == "mps2" and typical_raw > 30 * gravity:
        return  # raw counts, fitted as they are: M then maps counts to m/s^2 (docs/models.md)
    typical = typical_raw * unit_mps2
    raise CalibrationError(f"{source}: read with --units {units} the poses' median |a| is {typical:.4g} "
                           f"m/s^2, implausible for poses at rest (expected ~{gravity:.2f}): {units_hint(typical_raw)}")


def add_flight_state_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--armed-topic", default=None, metavar="TOPIC",
                        help="bag: topic saying the vehicle is armed or flying (std_msgs/Bool, mavros_msgs/msg/State, "
                             "px4_msgs/msg/VehicleStatus, ...); default: /mavros/state, /fmu/out/vehicle_status and "
                             "/fmu/out/vehicle_land_detected where present. Logs (ULog, DataFlash) carry their own")
    parser.add_argument("--armed-field", default=None, metavar="EXPR",
                        help="with --armed-topic: FIELD, 'not FIELD' or 'FIELD OP VALUE' that is true while flying, "
                             "e.g. armed, 'arming_state == 2' (default: the type's own)")
    parser.add_argument("--armed-margin-s", type=float, default=DEFAULT_MARGIN_S, metavar="S",
                        help="nothing within S seconds before arming or after disarming and landing is a pose "
                             f"(default {DEFAULT_MARGIN_S:g}: motors spin up and run down)")
    parser.add_argument("--ignore-flight-state", action="store_true",
                        help="collect while armed (a bench log recorded armed on purpose)")


def flight_state_settings(args: argparse.Namespace) -> dict[str, Any]:
    """ReplaySettings fields from the options (absent options: their defaults), checked."""
    margin = getattr(args, "armed_margin_s", DEFAULT_MARGIN_S)
    if not 0.0 <= margin <= 3600.0:
        raise CalibrationError(f"--armed-margin-s must be from 0 to 3600 seconds, got {margin:g}")
    topic, field = getattr(args, "armed_topic", None), getattr(args, "armed_field", None)
    if field is not None and topic is None:
        raise CalibrationError("--armed-field needs --armed-topic (the topic whose field it reads)")
    if field is not None:
        from ..bag.flight_sources import field_test

        field_test(field)  # refused in one line before any recording is read
    return {"armed_topic": topic, "armed_field": field, "armed_margin_s": margin,
            "ignore_flight_state": bool(getattr(args, "ignore_flight_state", False))}


def add_local_gravity_options(parser: argparse.ArgumentParser) -> None:
    """Local gravity: a number, or the WGS84 normal gravity at a latitude and height (fit, replay, check)."""
    parser.add_argument("--gravity", type=float, default=None, metavar="G",
                        help=f"local gravity, m/s^2 (default {STANDARD_GRAVITY}; -p gravity:=...)")
    parser.add_argument("--latitude", dest="latitude_deg", type=float, default=None, metavar="DEG",
                        help="local gravity from the WGS84 normal gravity at this geodetic latitude, deg "
                             "(instead of --gravity; -p latitude_deg:=...)")
    parser.add_argument("--height", dest="height_m", type=float, default=None, metavar="M",
                        help="with --latitude: height above the WGS84 ellipsoid, m (default 0; -p height_m:=...)")


# The node's own parameters (ros/parameters.NODE_PARAMETERS): its file (replay writes --output), its output's
# QoS and its silence warning mean nothing to a recording.
NODE_ONLY_PARAMETERS = ("calibration_file", "output_reliability", "stream_timeout_s")
GRAVITY_FLAGS = {"gravity": "--gravity", "latitude_deg": "--latitude", "height_m": "--height"}
ParameterSources = list[tuple[str, dict[str, Any]]]


def parameter_sources(args: argparse.Namespace) -> ParameterSources:
    """(where, {parameter: value}) for each place the command's options give the node's parameters: the
    --params-file blocks rcl would give the node, then each -p NAME:=VALUE, in the order they apply."""
    from ..io.calibration_file import safe_yaml_load
    from ..io.params_file import DEFAULT_NODE, params_file_parameters

    sources: ParameterSources = []
    node = getattr(args, "node", None)
    if node is not None:
        check_node_name(node)
    if getattr(args, "params_file", None):
        values = params_file_parameters(args.params_file, node or DEFAULT_NODE, error=CalibrationError)
        for name in NODE_ONLY_PARAMETERS:
            values.pop(name, None)
        sources.append((f"--params-file {args.params_file}", values))
    for item in getattr(args, "param", None) or []:
        name, sep, text = item.partition(":=")
        if not sep:
            raise CalibrationError(f"-p {item}: write NAME:=VALUE, e.g. -p static.window_s:=0.3")
        sources.append((f"-p {name.strip()}", {name.strip(): safe_yaml_load(text, f"-p {item}: value",
                                                                             error=CalibrationError)}))
    return sources


def _said_gravity(args: argparse.Namespace, sources: ParameterSources) -> dict[str, tuple[Any, str]]:
    """{gravity parameter: (value, where)} from the parameters and the flags; two places saying one
    parameter differently are one line. A parameters file's defaults (gravity 9.80665, latitude .nan,
    height 0: the package's own file lists them) say nothing."""
    import math

    defaults = {"gravity": STANDARD_GRAVITY, "height_m": 0.0}
    flags = [(flag, {name: getattr(args, name, None)}) for name, flag in GRAVITY_FLAGS.items()]
    said: dict[str, tuple[Any, str]] = {}
    for where, values in [*sources, *flags]:
        for name in GRAVITY_FLAGS:
            value = values.get(name)
            if value is None:
                continue
            if where.startswith("--params-file") and (
                    value == defaults.get(name) or (isinstance(value, float) and math.isnan(value))):
                continue
            if name in said and not _same_value(said[name][0], value):
                raise CalibrationError(f"{name} is given twice, {value!r} by {where} and {said[name][0]!r} by "
                                       f"{said[name][1]}: give it in one place")
            said[name] = (value, where)
    return said


def _same_value(a: Any, b: Any) -> bool:
    import math

    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def local_gravity(args: argparse.Namespace, sources: ParameterSources | None = None) -> tuple[float, str] | None:
    """(g, where it came from) from every place a command takes it: --gravity, --latitude [--height], and
    the parameters gravity, latitude_deg and height_m of -p and --params-file (parameter_sources); checked
    as the node's settings check them. Given in two places differently, or g and a latitude both: one
    line. None when no place gives it."""
    from ..core.settings import Settings

    said = _said_gravity(args, parameter_sources(args) if sources is None else sources)
    gravity, latitude, height = (said.get(name) for name in GRAVITY_FLAGS)
    if gravity is not None and latitude is not None:
        if (gravity[1], latitude[1]) == ("--gravity", "--latitude"):
            raise CalibrationError("--gravity and --latitude exclude each other: give the local g or where it is")
        raise CalibrationError(f"gravity ({gravity[1]}) and latitude_deg ({latitude[1]}) exclude each other: give "
                               "the local g or where it is")
    if height is not None and latitude is None:
        raise CalibrationError("--height needs --latitude (the normal gravity's height above the ellipsoid)"
                               if height[1] == "--height" else
                               f"height_m ({height[1]}) needs latitude_deg (the normal gravity's height above the "
                               "ellipsoid)")
    if not said:
        return None
    try:
        settings = Settings.from_parameters({name: value for name, (value, _) in said.items()})
    except CalibrationError as error:  # named as the user gave them
        text = str(error)
        for name, (_, where) in said.items():
            if where in GRAVITY_FLAGS.values():
                text = text.replace(f"{name} must", f"{where} must")
        raise CalibrationError(text) from None
    return settings.gravity, settings.gravity_source


def add_reader_options(parser: argparse.ArgumentParser) -> None:
    """How to read a recording other than a bag directory (bag/recording.open_recording)."""
    from ..bag.recording import FORMATS

    parser.add_argument("--format", choices=FORMATS, default=None,
                        help="the recording's format (default: found from the path and content)")
    parser.add_argument("--instance", type=int, default=None, metavar="N",
                        help="ULog: sensor_accel/sensor_gyro instance N (default: sensor_combined); "
                             "DataFlash: IMU instance N (default 0)")
    parser.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default=None,
                        help="CSV: unit of the time column (default: s for t, ns for t_ns)")
    parser.add_argument("--units", choices=("mps2", "g", "counts"), default=None,
                        help="CSV: units of ax,ay,az (default mps2; gx,gy,gz are rad/s)")
    parser.add_argument("--counts-per-g", type=float, default=None, metavar="COUNTS",
                        help="CSV with --units counts: the sensor's counts per g (e.g. 16384: MPU-6050 at +-2 g)")


def reader_fields(args: argparse.Namespace) -> dict[str, Any]:
    """ReplaySettings' reader fields from add_reader_options' options."""
    return {"format": args.format, "instance": args.instance, "time_unit": args.time_unit, "units": args.units,
            "counts_per_g": args.counts_per_g}


def add_settings_options(parser: argparse.ArgumentParser, *, detector: bool, model: bool = True) -> None:
    """The topics, the node's settings (--params-file, -p, the flags standing for parameters) and the
    flight state. `detector`: also the flags for the detector and the temperature model (replay); `model`:
    the flags for the model and min_poses (not for `check`, which fits nothing)."""
    parser.add_argument("--imu-topic", default=None, help="sensor_msgs/Imu topic (default: the only one)")
    parser.add_argument("--temperature-topic", default=None,
                        help="sensor_msgs/Temperature topic (default: the only one)")
    parser.add_argument("--params-file", default=None,
                        help="ROS 2 parameters YAML (config/accel_calibration.yaml): the node's settings")
    parser.add_argument("--node", default=None, metavar="/NAMESPACE/NAME",
                        help="the node whose --params-file blocks apply, as rcl matches them "
                             "(default /accel_calibration)")
    parser.add_argument("--param", "-p", action="append", default=[], metavar="NAME:=VALUE",
                        help="one setting as the node takes it, e.g. -p static.window_s:=0.3 (repeatable)")
    if model:
        parser.add_argument("--model", choices=("six", "sphere9"), default=None, help="same as -p model:=...")
        parser.add_argument("--min-poses", type=int, default=None, help="same as -p min_poses:=...")
    if detector:
        parser.add_argument("--temperature-model", dest="temperature.model", choices=TEMPERATURE_MODELS, default=None,
                            help="same as -p temperature.model:=...")
        parser.add_argument("--min-span", dest="temperature.min_span_degc", type=float, default=None,
                            help="same as -p temperature.min_span_degc:=...")
        add_local_gravity_options(parser)
        parser.add_argument("--window", dest="static.window_s", type=float, default=None,
                            help="detector window, s (-p static.window_s:=...)")
        parser.add_argument("--min-hold", dest="static.min_hold_s", type=float, default=None,
                            help="shortest still interval, s (-p static.min_hold_s:=...)")
        parser.add_argument("--k-sigma", dest="static.k_sigma", type=float, default=None,
                            help="detector threshold over the noise floor (-p static.k_sigma:=...)")
    add_flight_state_options(parser)


def replay_settings(args: argparse.Namespace) -> Any:
    """ReplaySettings as the node builds its settings: defaults, then --params-file, then -p NAME:=VALUE,
    then the flags standing for parameters the command offers (add_settings_options: each keeps its value
    under the parameter's own name)."""
    from ..bag.replay import ReplaySettings
    from ..core.settings import BY_NAME, Settings

    sources = parameter_sources(args)
    local_gravity(args, sources)  # the local g given in two places differently refused in one line first
    values: dict[str, Any] = {}
    for _, given in sources:
        values.update(given)
    offered = vars(args)
    for name in BY_NAME:
        if offered.get(name) is not None:  # a flag this command does not offer is absent, not None
            values[name] = offered[name]
    return ReplaySettings(session=Settings.from_parameters(values), imu_topic=args.imu_topic,
                          temperature_topic=args.temperature_topic, **flight_state_settings(args))


def instance_of_device(calibration: Any, what: str, recording: str, settings: Any) -> tuple[Any, str | None]:
    """(settings, line) to read an autopilot log as the IMU `calibration` is for (`what` names the file): the
    instance whose accelerometer is the file's device, picked and said when no --instance was given; a
    --instance of another device, or a log none of whose IMUs is it, one line. A file or a log that names no
    device: the settings as they are (the line says a log names none)."""
    import dataclasses

    from ..bag.recording import detect_format, log_accel_devices

    device = calibration.accel_device_id
    kind = settings.format or detect_format(recording)
    if device is None or kind not in ("ulog", "dataflash"):
        return settings, None
    named = {n: d for n, d in log_accel_devices(recording, kind).items() if d is not None}
    if not named:
        return settings, f"{recording} names no device for its IMUs: not checked that it is {what}'s device {device}"
    matching = [n for n, d in named.items() if d == device]
    if settings.instance is not None:
        if named.get(settings.instance, device) == device:
            return settings, None
        hint = f"; its device is --instance {matching[0]}" if matching else ", which the log does not hold"
        raise CalibrationError(f"{what} is the calibration of device {device}, but {recording} --instance "
                               f"{settings.instance} is device {named[settings.instance]}{hint}")
    if not matching:
        listed = ", ".join(f"{d} (instance {n})" for n, d in named.items())
        raise CalibrationError(f"{what} is the calibration of device {device}; the IMUs of {recording} are devices "
                               f"{listed}: not this sensor's recording")
    stream = "sensor_accel instance" if kind == "ulog" else "IMU instance"
    return (dataclasses.replace(settings, instance=matching[0]),
            f"read {stream} {matching[0]} (device {device}) of {recording}: the device {what} is for")


def calibration_in_force(path: str) -> Any:
    """A calibration file fit to be put in force (what the node checks at start-up): loaded safely and
    plausible under the default gates, else one line naming the problem. A gyro matrix whose gains are
    beyond the default gyro.scale_max (a file fitted with it raised) is left out, said in one line: these
    commands take no parameters, and replay at the default keeps the gyro's bias only too."""
    import sys

    from ..core.plausibility import gyro_gain_outside, implausible_text, plausibility_refusal
    from ..core.settings import Settings
    from ..io.calibration_file import load_calibration

    calibration = load_calibration(path)
    outside = gyro_gain_outside(calibration)
    if outside is not None:
        calibration = calibration.replace(gyro_matrix=None, gyro_quality=None)
        print(f"{PROG}: note: {path}: gyro matrix not used here ({outside}, the default gyro.scale_min.."
              "gyro.scale_max; the node takes its own): the gyro's bias only", file=sys.stderr)
    defaults = Settings()
    refusal = plausibility_refusal(calibration, max_bias_mps2=defaults.max_bias_mps2,
                                   scale_band=(defaults.scale_min, defaults.scale_max))
    if refusal is not None:
        raise CalibrationError(f"{path}: implausible, not used ({implausible_text(refusal)})")
    return calibration
