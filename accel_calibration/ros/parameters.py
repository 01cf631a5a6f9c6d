"""The node's parameters: core.settings' PARAMETERS (the session's, written once) and the node's own,
declared with their types and ranges; values checked in one line naming the parameter; a params file
checked before rcl parses it; the read-only mirrors of the calibration in force.

A `ros2 param dump` loads back quietly (`--params-file` or `ros2 param load`): the mirrors and rclpy's own
parameters are known, and setting a parameter that is fixed at start-up to the value it has is accepted
(only a change is refused, with the reason). Those parameters are read-only in their descriptors (`ros2 param
describe`), so rclpy would refuse even the same value, and with its own words: `NodeParameters.screen`
answers them before rclpy sees them (CalibrationNode.set_parameters_atomically).

`gravity` is the gravity in use: with latitude_deg, the normal gravity there."""
from __future__ import annotations

import math
import os
import threading
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter

from ..core.calibration import Calibration
from ..core.errors import SettingsError
from ..core.settings import (
    BY_NAME,
    PARAMETERS,
    RELIABILITIES,
    Parameter,
    Settings,
    changed,
    check_run_time_change,
    check_value,
    fixed_at_start_up,
)

MIRROR_PREFIX = "calibration."
# Parameters of the node itself (not of the session): fixed at start-up.
NODE_PARAMETERS = (
    Parameter("calibration_file", "", "calibration YAML loaded at start and written by /calibrate and "
              "calibration/save; empty = ~/.ros/accel_calibration/<namespace>/<node name>.yaml"),
    Parameter("output_reliability", "reliable", "QoS reliability of imu/data_calibrated: reliable (serves "
              "reliable and best-effort subscribers) or best_effort", choices=RELIABILITIES),
    Parameter("stream_timeout_s", 5.0, "WARN on /diagnostics (and a throttled log line) when imu/data_raw or "
              "imu/temperature has been silent this long, s", 0.5, 3600.0),
)
MIRRORS = (
    ("bias", [0.0, 0.0, 0.0], "bias b of the calibration in force, m/s^2"),
    ("matrix", [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "matrix M of the calibration in force, row-major"),
    ("residual_rms_mg", 0.0, "residual rms of the calibration in force, mg"),
    ("poses", 0, "poses the calibration in force was fitted to"),
)
# rclpy's own parameters: never "unknown".
RCLPY_PARAMETERS = ("use_sim_time", "start_type_description_service")


FIXED = frozenset(p.name for p in PARAMETERS + NODE_PARAMETERS if not p.dynamic)  # read-only while running
_ALL = {**BY_NAME, **{p.name: p for p in NODE_PARAMETERS}}


def _range(parameter: Parameter) -> tuple[list[FloatingPointRange], list[IntegerRange]]:
    """The descriptor's range of a bounded parameter (0 included where 0 means "learned")."""
    if parameter.low is None or parameter.high is None:
        return [], []
    if type(parameter.default) is int:
        return [], [IntegerRange(from_value=int(parameter.low), to_value=int(parameter.high), step=0)]
    low = 0.0 if parameter.zero_means_auto else float(parameter.low)
    return [FloatingPointRange(from_value=low, to_value=float(parameter.high), step=0.0)], []


def _descriptor(parameter: Parameter) -> ParameterDescriptor:
    fixed = "" if parameter.dynamic else " (fixed at start-up)"
    descriptor = ParameterDescriptor(description=parameter.description + fixed, read_only=not parameter.dynamic)
    # rclpy checks a declared value against its range, and NaN ("not given") is within none: such a range is
    # added once declared (NodeParameters._show_ranges).
    if not parameter.nan_means_unset:
        descriptor.floating_point_range, descriptor.integer_range = _range(parameter)
    if parameter.choices:
        descriptor.additional_constraints = "one of: " + ", ".join(parameter.choices)
    return descriptor


class NodeParameters:
    """Declares the parameters on `node` and judges every later change."""

    def __init__(self, node: Node):
        self.node = node
        self._mirroring = threading.local()  # set while the node itself updates its mirrors
        self.settings, self.node_values = self._declare()

    def _declare(self) -> tuple[Settings, dict[str, Any]]:
        """Declare every parameter with its type and range; a value given at start-up that does not fit is
        refused with one line naming the parameter as the user typed it."""
        # rclpy has no public read of the overrides before a parameter is declared; read them so a bad
        # value is refused in one line naming it (rclpy's own refusal is several lines without the name).
        overrides = self.node._parameter_overrides
        values: dict[str, Any] = {}
        for parameter in PARAMETERS + NODE_PARAMETERS:
            if parameter.name in overrides:
                values[parameter.name] = check_value(parameter, overrides[parameter.name].value)
        session_values = {p.name: values[p.name] for p in PARAMETERS if p.name in values}
        settings = Settings.from_parameters(session_values)
        declared = {**values, "gravity": settings.gravity}  # the gravity in use (latitude_deg's, when given)
        for parameter in PARAMETERS + NODE_PARAMETERS:
            self.node.declare_parameter(parameter.name, declared.get(parameter.name, parameter.default),
                                        _descriptor(parameter), ignore_override=True)
        self._show_ranges()
        for name, default, text in MIRRORS:
            # Mirrors of the calibration in force: set by the node alone, never taken from a params file.
            self.node.declare_parameter(MIRROR_PREFIX + name, default,
                                        ParameterDescriptor(description=text + " (read-only mirror)"),
                                        ignore_override=True)
        known = {p.name for p in PARAMETERS + NODE_PARAMETERS} | {MIRROR_PREFIX + m[0] for m in MIRRORS} \
            | set(RCLPY_PARAMETERS)
        for name in sorted(n for n in overrides if n not in known and not n.startswith("qos_overrides.")):
            self.node.get_logger().warning(f"unknown parameter {name!r} ignored (typo?)")
        node_values = {p.name: values.get(p.name, p.default) for p in NODE_PARAMETERS}
        return settings, node_values

    def _show_ranges(self) -> None:
        """The range of a parameter whose default is NaN ("not given"), shown once it is declared. Safe
        because such parameters are fixed at start-up: no later value reaches rclpy's range check."""
        for parameter in PARAMETERS + NODE_PARAMETERS:
            if parameter.nan_means_unset:
                assert parameter.name in FIXED
                descriptor = self.node.describe_parameter(parameter.name)  # the node's own, not a copy
                descriptor.floating_point_range, descriptor.integer_range = _range(parameter)

    def screen(self, parameters: list[RosParameter]) -> tuple[SetParametersResult | None, list[RosParameter]]:
        """Before rclpy applies the descriptors: (the refusal of a change to a parameter fixed at start-up,
        naming it, or None; the parameters left to set, without those set to the value they have)."""
        rest = []
        for parameter in parameters:
            if parameter.name not in FIXED:
                rest.append(parameter)
            elif not self._unchanged(parameter):
                return SetParametersResult(successful=False, reason=fixed_at_start_up(parameter.name)), []
        return None, rest

    def judge(self, parameters: list[RosParameter], settings: Settings) -> tuple[SetParametersResult, Settings | None]:
        """(the answer to a set_parameters, the new settings to take when they changed)."""
        changes: dict[str, Any] = {}
        for parameter in parameters:
            name = parameter.name
            if name.startswith(MIRROR_PREFIX):
                if getattr(self._mirroring, "on", False) or self._unchanged(parameter):
                    continue
                return SetParametersResult(successful=False, reason=f"{name} is a read-only mirror of the "
                                           "calibration in force"), None
            if name in RCLPY_PARAMETERS:
                continue
            if any(p.name == name for p in NODE_PARAMETERS):
                if self._unchanged(parameter):
                    continue
                return SetParametersResult(successful=False, reason=fixed_at_start_up(name)), None
            changes[name] = parameter.value
        if not changes:
            return SetParametersResult(successful=True), None
        try:
            new = Settings.from_parameters(changes, base=settings)
            check_run_time_change(settings, new)
        except SettingsError as error:
            return SetParametersResult(successful=False, reason=str(error)), None
        return SetParametersResult(successful=True), new

    def _unchanged(self, parameter: RosParameter) -> bool:
        try:
            before = self.node.get_parameter(parameter.name).value
        except Exception:  # noqa: BLE001 - not declared: a change
            return False
        declared = _ALL.get(parameter.name)
        if declared is not None and type(declared.default) is float and type(parameter.value) is not float:
            return False  # another type is a change (rclpy's typing refuses it)
        return not changed(before, parameter.value)

    def mirror(self, calibration: Calibration) -> None:
        """Update the read-only mirrors of the calibration in force (a parameter event tells listeners)."""
        quality = calibration.quality
        values = {
            "bias": [float(v) for v in calibration.bias],
            "matrix": [float(v) for v in calibration.matrix.ravel()],
            "residual_rms_mg": (float(quality.residual_rms_mg)
                                if quality and math.isfinite(quality.residual_rms_mg) else 0.0),
            "poses": int(quality.poses) if quality else 0,
        }
        self._mirroring.on = True
        try:
            self.node.set_parameters([RosParameter(MIRROR_PREFIX + name, value=value)
                                      for name, value in values.items()])
        finally:
            self._mirroring.on = False


def calibration_path(configured: str, fully_qualified_name: str) -> Path:
    """The calibration_file parameter's path; empty: one file per node (namespace and name), so two
    instances never write the same file."""
    if configured:
        return Path(os.path.expanduser(configured))
    return Path(os.path.expanduser("~/.ros/accel_calibration")) / f"{fully_qualified_name.lstrip('/')}.yaml"


def usage(program: str) -> str:
    """`calibration_node --help`: how to start it and every parameter with its default (the descriptions:
    `ros2 param describe`, docs/node.md)."""
    lines = [f"usage: {program} [--help] [--ros-args [-p NAME:=VALUE]... [-r FROM:=TO]... [--params-file FILE]]",
             "",
             "Calibrates an IMU live: imu/data_raw (sensor_msgs/Imu) in, imu/data_calibrated out; services calibrate,",
             "calibration/get, calibration/reset, calibration/save, calibration/enable, calibration/pause;",
             "/diagnostics at 1 Hz; calibration/markers for RViz. Details: docs/node.md.",
             "",
             "parameters (-p NAME:=VALUE; * = changeable at run time):"]
    for parameter in PARAMETERS + NODE_PARAMETERS:
        default = parameter.default
        shown = "not given" if isinstance(default, float) and math.isnan(default) else repr(default)
        lines.append(f"  {parameter.name}{' *' if parameter.dynamic else ''} (default {shown})")
    return "\n".join(lines)


def asks_for_help(argv: list[str]) -> bool:
    """-h or --help among the program's own arguments (those after --ros-args are ROS's)."""
    own = argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv
    return any(arg in ("-h", "--help") for arg in own)


def params_file_problem(argv: list[str]) -> str | None:
    """rcl reports a missing or broken --params-file in several lines of its own (or hangs on a FIFO, or
    recurses on deep nesting): say it in one line first."""
    from ..core.errors import SettingsError
    from ..io.params_file import read_params_file

    for flag, path in zip(argv, argv[1:]):
        if flag != "--params-file":
            continue
        try:
            read_params_file(path)  # the CLI's reading: the same one line for the same file
        except SettingsError as error:
            return str(error)
    return None


def first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__
