"""accel-calib compare: how far the autopilot's accelerometer calibration is from ours, in mg at 1 g over
all orientations and our calibrated temperature range. Reads a PX4 .params file or the parameters in a
ULog, an ArduPilot .param file or the PARM records of a DataFlash .bin, and applies them with the
autopilot's own formula (io/autopilot_params.py)."""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CalibrationError

if TYPE_CHECKING:  # imported where used: `accel-calib --help` does not pay for YAML and the fits
    from ..core.axis_calibration import AxisWiseCalibration
    from ..io.autopilot_params import ParameterSet


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "compare", help="how far an autopilot's accelerometer calibration is from ours (mg at 1 g)",
        description="Read the autopilot's calibration (PX4 .params or .ulg, ArduPilot .param or DataFlash .bin), "
                    "print it, and say in mg at 1 g, over all orientations and the calibrated temperature range, "
                    "how far it is from CAL.yaml.")
    parser.add_argument("calibration", metavar="CAL.yaml", help="our calibration")
    parser.add_argument("parameters", metavar="PARAMS",
                        help="PX4 .params / .ulg, ArduPilot .param / .bin")
    parser.add_argument("--instance", type=int, default=None, metavar="N",
                        help="the autopilot's sensor slot from 0 (default: PX4 the slot whose CAL_ACCn_ID is the "
                             "calibration's accel_device_id, else 0; ArduPilot 0)")
    return parser


def _instance(args: argparse.Namespace, parameters: ParameterSet, device: int | None) -> int:
    from ..io.autopilot_params import MAX_INSTANCES

    if args.instance is not None:
        return int(args.instance)
    if parameters.autopilot == "px4" and device is not None:
        for slot in range(MAX_INSTANCES["px4"]):
            if parameters.values.get(f"CAL_ACC{slot}_ID") == float(device):
                return slot
    return 0


def describe(parameters: ParameterSet, instance: int, held: AxisWiseCalibration) -> list[str]:
    """The autopilot's calibration as it reads, one line per part."""
    def triple(values: np.ndarray, digits: int) -> str:
        return ", ".join(f"{v:+.{digits}f}" for v in values)

    lines = [f"{parameters.source}: {parameters.autopilot} parameters ({len(parameters.values)}), instance {instance}",
             f"  offset [{triple(held.offset_mps2, 4)}] m/s^2, scale [{triple(held.scale, 5)}]"]
    if held.has_drift:
        low, high = held.clamp_degc if held.clamp_degc is not None else (float("nan"), float("nan"))
        zero = "" if held.drift_zero_degc is None else f", zero at {held.drift_zero_degc:.1f} degC"
        lines.append(f"  thermal bias polynomial about {held.drift_origin_degc:.1f} degC, {low:.1f}..{high:.1f} degC"
                     f"{zero}: constant [{triple(held.drift_constant_mps2, 4)}], "
                     + "; ".join(f"c{k} [{triple(row, 7)}]" for k, row in enumerate(held.drift_coefficients, 1)))
    return lines


def run(args: argparse.Namespace) -> int:
    from ..core.axis_calibration import cost_after_best_rotation, cost_against, rotation_angle_mrad
    from ..io.autopilot_params import MAX_INSTANCES, ardupilot_calibration, px4_calibration, read_parameters
    from ..io.calibration_file import load_calibration

    calibration = load_calibration(args.calibration)
    parameters = read_parameters(args.parameters)
    instance = _instance(args, parameters, calibration.accel_device_id)
    if not 0 <= instance < MAX_INSTANCES[parameters.autopilot]:
        raise CalibrationError(f"--instance must be 0..{MAX_INSTANCES[parameters.autopilot] - 1} for "
                               f"{parameters.autopilot}, got {instance}")
    if parameters.autopilot == "px4":
        held = px4_calibration(parameters.values, instance)
    else:
        held = ardupilot_calibration(parameters.values, instance)
    for line in describe(parameters, instance, held):
        print(line)
    cost = cost_against(calibration, held)
    print(f"difference from {args.calibration}: {cost.describe()}")
    rotated, rotation = cost_after_best_rotation(calibration, held)
    print(f"after the best rotation of the sensor to the vehicle ({rotation_angle_mrad(rotation):.2f} mrad, which the "
          f"level / board-rotation calibration absorbs): worst {rotated.worst_mg:.3f} mg (rms {rotated.rms_mg:.3f} mg)")
    return 0
