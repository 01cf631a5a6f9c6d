"""accel-calib export: a calibration in the form its user applies it -- PX4 or ArduPilot parameters,
Kalibr's imu.yaml, OpenVINS' kalibr_imu_chain.yaml -- with what the target cannot hold said in mg.

Where the target holds less than the calibration (the autopilots: no misalignment, no thermal scale),
the export fits the best calibration the target can hold and prints its cost: the worst error over
all orientations of a 1 g specific force, over the calibrated temperature range. Above --max-loss-mg
it refuses unless --force. Values outside the target's accepted ranges are refused with the range."""
from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CalibrationError

if TYPE_CHECKING:  # imported where used: `accel-calib --help` does not pay for YAML and the fits
    from ..core.axis_calibration import AxisWiseCalibration, Cost
    from ..core.calibration import Calibration

TARGETS = ("px4", "ardupilot", "kalibr", "openvins")
DEFAULT_MAX_LOSS_MG = 2.0


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "export", help="write a calibration as PX4/ArduPilot parameters, Kalibr imu.yaml or OpenVINS imu chain",
        description="Write the calibration in the target's own form, units and signs. Where the target holds "
                    "less (the autopilots keep no misalignment and no thermal scale) the best calibration it "
                    "can hold is fitted and its cost printed: the worst error over all orientations at 1 g, in "
                    "mg, over the calibrated temperature range.")
    parser.add_argument("calibration", metavar="CAL.yaml", help="calibration file to export")
    parser.add_argument("--to", required=True, choices=TARGETS, help="target")
    parser.add_argument("--instance", type=int, default=0, metavar="N",
                        help="autopilots: the sensor slot, from 0 (PX4 CAL_ACC0_*, ArduPilot INS_ACCOFFS_*; "
                             "1: CAL_ACC1_*, INS_ACC2OFFS_*) (default 0)")
    parser.add_argument("--device-id", type=int, default=None, metavar="ID",
                        help="PX4: the accelerometer's device ID for CAL_ACCn_ID and TC_An_ID (default: the "
                             "calibration's sensor_id when it is a number)")
    parser.add_argument("--noise", default=None, metavar="IMU.yaml",
                        help="kalibr/openvins: the noise figures, a Kalibr imu.yaml as 'accel-calib noise "
                             "--kalibr' writes it")
    parser.add_argument("--rostopic", default="/imu0", help="kalibr/openvins: the IMU topic (default /imu0)")
    parser.add_argument("--update-rate", type=float, default=None, metavar="HZ",
                        help="kalibr/openvins: the IMU rate (default: the noise file's update_rate)")
    parser.add_argument("--max-loss-mg", type=float, default=DEFAULT_MAX_LOSS_MG,
                        help=f"refuse when what the target cannot hold costs more than this, mg at 1 g "
                             f"(default {DEFAULT_MAX_LOSS_MG:g})")
    parser.add_argument("--force", action="store_true", help="write even above --max-loss-mg")
    parser.add_argument("--output", "-o", default=None, help="file to write (default: standard output)")
    return parser


def _device_id(args: argparse.Namespace, calibration: Calibration) -> int | None:
    if args.device_id is not None:
        if not 0 < args.device_id < 2**32:
            raise CalibrationError(f"--device-id must be a 32-bit device ID above 0, got {args.device_id}")
        return int(args.device_id)
    text = calibration.sensor_id.strip().removeprefix("px4 device ")  # as replay names a ULog's device
    return int(text) if text.isdigit() and 0 < int(text) < 2**32 else None


def fit_for(target: str, calibration: Calibration) -> AxisWiseCalibration:
    """The axis-wise calibration an autopilot target holds closest to ours."""
    from ..core.axis_calibration import fit_axis_wise
    from ..io.autopilot_params import ARDUPILOT_TCAL_REFERENCE_DEGC

    order = 3 if calibration.temperature is not None else 0
    if target == "px4":
        reference = calibration.temperature.reference_degc if calibration.temperature is not None else 0.0
        return fit_axis_wise(calibration, drift_order=order, drift_origin_degc=reference)
    zero = calibration.temperature.reference_degc if calibration.temperature is not None else None
    return fit_axis_wise(calibration, drift_order=order, drift_origin_degc=ARDUPILOT_TCAL_REFERENCE_DEGC,
                         drift_zero_degc=zero)


def _held_matrix_cost(calibration: Calibration) -> Cost:
    """OpenVINS: the matrix at the reference temperature with the bias there (OpenVINS estimates the bias
    online): what a temperature model adds is the cost; without one it is 0."""
    from ..core.axis_calibration import cost_against

    reference = calibration.temperature.reference_degc if calibration.temperature is not None else None
    matrix_terms = calibration.terms_at(reference)
    matrix = np.array(matrix_terms[:9]).reshape(3, 3)
    bias = np.array(matrix_terms[9:])

    def correct(raw: np.ndarray, _temperature: np.ndarray) -> np.ndarray:
        corrected: np.ndarray = (raw - bias) @ matrix.T
        return corrected

    return cost_against(calibration, correct)


def _check_cost(cost: Cost, args: argparse.Namespace) -> None:
    if not (args.max_loss_mg >= 0):
        raise CalibrationError(f"--max-loss-mg must be >= 0, got {args.max_loss_mg}")
    if cost.worst_mg > args.max_loss_mg and not args.force:
        raise CalibrationError(
            f"{args.to} cannot hold this calibration within {args.max_loss_mg:g} mg: {cost.describe()}; "
            "--force writes it anyway, or raise --max-loss-mg")


def export_text(args: argparse.Namespace, calibration: Calibration) -> tuple[str, list[str]]:
    """(file text, lines to tell the user) for args.to."""
    from ..core.axis_calibration import cost_against, lower_triangular_with_rotation
    from ..io.autopilot_params import ardupilot_param_text, ardupilot_parameters, px4_parameters, px4_params_text
    from ..io.estimator_yaml import kalibr_imu_yaml, openvins_imu_chain_yaml, read_noise_figures

    source = f"from accel_calibration {args.calibration} (model {calibration.model}, created {calibration.created})"
    notes: list[str] = []
    if args.to in ("px4", "ardupilot"):
        fitted = fit_for(args.to, calibration)
        cost = cost_against(calibration, fitted)
        held = "offset and scale per axis" + (", bias drift polynomial" if fitted.has_drift else "")
        notes.append(f"{args.to} holds {held}: {cost.describe()}")
        _check_cost(cost, args)
        if args.to == "px4":
            device = _device_id(args, calibration)
            if device is None:
                notes.append("no device ID known (--device-id): PX4 applies CAL_ACCn_* to the device whose ID is "
                             "in CAL_ACCn_ID and TC_An_* only where TC_An_ID matches; check them on the vehicle")
            parameters = px4_parameters(fitted, args.instance, device_id=device,
                                        gyro_bias_radps=calibration.gyro_bias_radps)
            return px4_params_text(parameters, f"Onboard parameters {source}"), notes
        reference = calibration.reference_temperature_degc
        parameters = ardupilot_parameters(fitted, args.instance, reference_degc=reference,
                                          gyro_bias_radps=calibration.gyro_bias_radps)
        if calibration.gyro_bias_radps is not None:
            notes.append("ArduPilot recomputes INS_GYR*OFFS at every boot unless INS_GYR_CAL = 0")
        return ardupilot_param_text(parameters, source), notes
    if args.noise is None:
        raise CalibrationError(f"{args.to} needs the noise figures: measure them with 'accel-calib noise "
                               "RECORDING --kalibr imu.yaml' and give --noise imu.yaml")
    if args.update_rate is not None and not args.update_rate > 0:
        raise CalibrationError(f"--update-rate must be positive, got {args.update_rate}")
    noise = read_noise_figures(args.noise, args.update_rate)
    if args.to == "kalibr":
        notes.append("kalibr: imu.yaml holds the noise figures only; Kalibr estimates the intrinsics itself")
        return kalibr_imu_yaml(noise, args.rostopic, source), notes
    rotation, lower = lower_triangular_with_rotation(calibration.matrix)
    cost = _held_matrix_cost(calibration)
    notes.append(f"openvins holds the matrix (Ta, R_IMUtoACC; exact) and estimates the bias online "
                 f"(ours: {', '.join(f'{v:+.4f}' for v in calibration.bias)} m/s^2): {cost.describe()}")
    _check_cost(cost, args)
    return openvins_imu_chain_yaml(noise, args.rostopic, rotation, lower, source), notes


def run(args: argparse.Namespace) -> int:
    from ..io.calibration_file import load_calibration, write_text_atomically
    from ..io.output_paths import check_outputs

    check_outputs([("--output", args.output)], [args.calibration, args.noise])
    calibration = load_calibration(args.calibration)
    text, notes = export_text(args, calibration)
    for note in notes:
        print(note, file=sys.stderr if args.output is None else sys.stdout)
    if args.output is None:
        sys.stdout.write(text)
    else:
        write_text_atomically(args.output, text)
        print(f"written {args.output}")
    return 0
