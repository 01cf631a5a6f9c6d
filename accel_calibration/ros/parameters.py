"""The node's parameters: core.settings' PARAMETERS (the session's, written once) and the node's own,
declared with their types and ranges; values checked in one line naming the parameter; a params file
checked before rcl parses it; the read-only mirrors of the calibration in force.

A `ros2 param dump` loads back quietly (`--params-file` or `ros2 param load`): the mirrors and rclpy's own
parameters are known, and setting a parameter that is fixed at start-up to the value it has is accepted
(only a change is refused, with the reason)."""
from __future__ import annotations

import math
import threading
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter

from ..core.calibration import Calibration
from ..core.errors import SettingsError
from ..core.settings import PARAMETERS, RELIABILITIES, Parameter, Settings, changed, check_value

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


def _descriptor(parameter: Parameter) -> ParameterDescriptor:
    fixed = "" if parameter.dynamic else " (fixed at start-up)"
    descriptor = ParameterDescriptor(description=parameter.description + fixed)
    # rclpy checks a declared default against its range, and NaN ("not given") is within none.
    if parameter.low is not None and parameter.high is not None and not parameter.nan_means_unset:
        if type(parameter.default) is int:
            descriptor.integer_range = [IntegerRange(from_value=int(parameter.low), to_value=int(parameter.high),
                                                     step=0)]
        else:
            low = 0.0 if parameter.zero_means_auto else float(parameter.low)
            descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=float(parameter.high),
                                                                  step=0.0)]
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
            self.node.declare_parameter(parameter.name, values.get(parameter.name, parameter.default),
                                        _descriptor(parameter), ignore_override=True)
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
        session_values = {p.name: values[p.name] for p in PARAMETERS if p.name in values}
        return Settings.from_parameters(session_values), node_values

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
                return SetParametersResult(successful=False, reason=f"{name} is fixed at start-up (read-only); "
                                           "restart to change it"), None
            changes[name] = parameter.value
        if not changes:
            return SetParametersResult(successful=True), None
        try:
            new = Settings.from_parameters(changes, base=settings)
            fixed = [p.name for p in PARAMETERS
                     if not p.dynamic and changed(getattr(settings, p.field), getattr(new, p.field))]
            if fixed:
                raise SettingsError(f"{fixed[0]} is fixed at start-up (read-only); restart to change it")
        except SettingsError as error:
            return SetParametersResult(successful=False, reason=str(error)), None
        return SetParametersResult(successful=True), new

    def _unchanged(self, parameter: RosParameter) -> bool:
        try:
            return bool(self.node.get_parameter(parameter.name).value == parameter.value)
        except Exception:  # noqa: BLE001 - not declared: a change
            return False

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
