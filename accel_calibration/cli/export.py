"""accel-calib export: a calibration in the form its user applies it -- PX4 or ArduPilot parameters,
Kalibr's imu.yaml, OpenVINS' kalibr_imu_chain.yaml -- with what the target cannot hold said in mg.

Where the target holds less than the calibration (the autopilots: no misalignment, no thermal scale, no
gyro matrix), the export fits the best calibration the target can hold and prints its cost: the worst error
over all orientations of a 1 g specific force, over the calibrated temperature range, as is and after the
rotation the autopilot's level / board-rotation calibration absorbs. Above --max-loss-mg (after that
rotation) it refuses unless --force. A calibration our loader would not put in force, and values outside the
target's accepted ranges, are refused whatever --force says."""
from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CalibrationError

if TYPE_CHECKING:  # imported where used: `accel-calib --help` does not pay for YAML and the fits
    from ..core.axis_calibration import AxisWiseCalibration, Correction, Cost
    from ..core.calibration import Calibration
    from ..io.autopilot_params import Parameter
    from ..io.estimator_yaml import NoiseFigures

TARGETS = ("px4", "ardupilot", "kalibr", "openvins")
DEFAULT_MAX_LOSS_MG = 2.0


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "export", help="write a calibration as PX4/ArduPilot parameters, Kalibr imu.yaml or OpenVINS imu chain",
        description="Write the calibration in the target's own form, units and signs. Where the target holds "
                    "less (the autopilots keep no misalignment, no thermal scale, no gyro matrix) the best "
                    "calibration it can hold is fitted and its cost printed: the worst error over all orientations "
                    "at 1 g, in mg, over the calibrated temperature range.")
    parser.add_argument("calibration", metavar="CAL.yaml", help="calibration file to export")
    parser.add_argument("--to", required=True, choices=TARGETS, help="target")
    parser.add_argument("--instance", type=int, default=0, metavar="N",
                        help="autopilots: the sensor slot, from 0 (PX4 CAL_ACC0_*, ArduPilot INS_ACCOFFS_*; "
                             "1: CAL_ACC1_*, INS_ACC2OFFS_*) (default 0)")
    parser.add_argument("--device-id", type=int, default=None, metavar="ID",
                        help="PX4: the IMU's device ID for CAL_ACCn_ID, CAL_GYROn_ID and TC_An_ID (default: the "
                             "calibration's accel_device_id)")
    parser.add_argument("--noise", default=None, metavar="IMU.yaml",
                        help="kalibr/openvins: the noise figures, a Kalibr imu.yaml as 'accel-calib noise "
                             "--kalibr' writes it (default: the calibration's noise block and --random-walks)")
    parser.add_argument("--random-walks", nargs=2, type=_strict_float, default=None, metavar=("ACCEL", "GYRO"),
                        help="kalibr/openvins without --noise: the random walks the calibration's noise block lacks, "
                             "m/s^3/sqrt(Hz) and rad/s^2/sqrt(Hz)")
    parser.add_argument("--rostopic", default="/imu0", help="kalibr/openvins: the IMU topic (default /imu0)")
    parser.add_argument("--update-rate", type=float, default=None, metavar="HZ",
                        help="kalibr/openvins: the IMU rate (default: the noise file's or noise block's rate)")
    parser.add_argument("--max-loss-mg", type=float, default=DEFAULT_MAX_LOSS_MG,
                        help=f"refuse when what the target cannot hold costs more than this, mg at 1 g, after the "
                             f"rotation the autopilot's level calibration absorbs (default {DEFAULT_MAX_LOSS_MG:g})")
    parser.add_argument("--force", action="store_true", help="write even above --max-loss-mg")
    parser.add_argument("--output", "-o", default=None, help="file to write (default: standard output)")
    return parser


def _strict_float(text: str) -> float:
    from ..io.autopilot_params import parse_number

    value = parse_number(text)
    if value is None:
        raise argparse.ArgumentTypeError(f"{text[:30]!r} is not a number")
    return value


def _device_id(args: argparse.Namespace, calibration: Calibration) -> int | None:
    """--device-id, else the file's; a --device-id other than the device the file names is one line."""
    named = calibration.accel_device_id
    if args.device_id is None:
        return named
    if not 0 < args.device_id < 2**32:
        raise CalibrationError(f"--device-id must be a 32-bit device ID above 0, got {args.device_id}")
    if named is not None and named != args.device_id:
        raise CalibrationError(f"--device-id {args.device_id}: {args.calibration} is the calibration of device "
                               f"{named}, not of this one (leave out --device-id, or export that device's file)")
    return int(args.device_id)


def fit_for(target: str, calibration: Calibration) -> AxisWiseCalibration:
    """The axis-wise calibration an autopilot target holds closest to ours."""
    from ..core.axis_calibration import fit_axis_wise
    from ..io.autopilot_params import ARDUPILOT_TCAL_REFERENCE_DEGC

    order = 3 if calibration.temperature is not None else 0
    # A warm-up's spline is no cubic: the cubic closest at the worst temperature, not on average.
    worst_case = calibration.temperature is not None and calibration.temperature.kind == "spline"
    if target == "px4":
        reference = calibration.temperature.reference_degc if calibration.temperature is not None else 0.0
        return fit_axis_wise(calibration, drift_order=order, drift_origin_degc=reference, worst_case=worst_case)
    zero = calibration.temperature.reference_degc if calibration.temperature is not None else None
    return fit_axis_wise(calibration, drift_order=order, drift_origin_degc=ARDUPILOT_TCAL_REFERENCE_DEGC,
                         drift_zero_degc=zero, worst_case=worst_case)


def _matrix_correction(calibration: Calibration, with_bias: bool) -> Correction:
    """OpenVINS' correction: the matrix at the reference temperature, with our bias there (what its online
    bias state converges to) or with its starting bias of 0."""
    reference = calibration.temperature.reference_degc if calibration.temperature is not None else None
    matrix_terms = calibration.terms_at(reference)
    matrix = np.array(matrix_terms[:9]).reshape(3, 3)
    bias = np.array(matrix_terms[9:]) if with_bias else np.zeros(3)

    def correct(raw: np.ndarray, _temperature: np.ndarray) -> np.ndarray:
        corrected: np.ndarray = (raw - bias) @ matrix.T
        return corrected

    return correct


def _check_cost(cost: Cost, args: argparse.Namespace, after: str = "") -> None:
    if not (args.max_loss_mg >= 0):
        raise CalibrationError(f"--max-loss-mg must be >= 0, got {args.max_loss_mg}")
    if cost.worst_mg > args.max_loss_mg and not args.force:
        raise CalibrationError(
            f"{args.to} cannot hold this calibration within {args.max_loss_mg:g} mg{after}: {cost.describe()}; "
            "--force writes it anyway, or raise --max-loss-mg")


def _autopilot_text(args: argparse.Namespace, calibration: Calibration, source: str) -> tuple[str, list[str]]:
    from ..core.axis_calibration import (
        cost_after_best_rotation,
        cost_against,
        fit_gyro_drift,
        gyro_matrix_loss_mrad_per_radps,
        rotation_angle_mrad,
    )
    from ..io.autopilot_params import (
        ARDUPILOT_TCAL_REFERENCE_DEGC,
        ardupilot_param_text,
        ardupilot_parameters,
        px4_parameters,
        px4_params_text,
    )

    fitted = fit_for(args.to, calibration)
    cost = cost_against(calibration, fitted)
    rotated, rotation = cost_after_best_rotation(calibration, fitted)
    held = "offset and scale per axis" + (", bias drift polynomial" if fitted.has_drift else "")
    notes = [f"{args.to} holds {held}: {cost.describe()}; after the best rotation of the sensor to the vehicle "
             f"({rotation_angle_mrad(rotation):.2f} mrad, which the level / board-rotation calibration absorbs): "
             f"worst {rotated.worst_mg:.3f} mg (rms {rotated.rms_mg:.3f} mg)"]
    if calibration.gyro_matrix is not None:
        notes.append(f"{args.to} holds no gyro scale or misalignment, only the gyro offset: up to "
                     f"{gyro_matrix_loss_mrad_per_radps(calibration.gyro_matrix):.1f} mrad per rad/s of rate lost")
    _check_cost(rotated, args, " after the best rotation of the sensor to the vehicle")
    if args.to == "px4":
        device = _device_id(args, calibration)
        if device is None:
            notes.append("no device ID known (--device-id): PX4 applies CAL_ACCn_* and CAL_GYROn_* to the device "
                         "whose ID is in CAL_ACCn_ID / CAL_GYROn_ID and TC_An_* only where TC_An_ID matches; "
                         "check them on the vehicle")
        elif calibration.gyro_bias_radps is not None and calibration.gyro_device_id is None:
            notes.append(f"CAL_GYRO{args.instance}_ID = {device}, the accelerometer's: the file names no gyro "
                         "device (right for a one-chip IMU; a BMI055/BMI088 gyro has an ID of its own: check it "
                         "on the vehicle)")
        gyro_rows = None
        if fitted.has_drift and fitted.clamp_degc is not None:
            gyro_drift = fit_gyro_drift(calibration, drift_origin_degc=fitted.drift_origin_degc,
                                        drift_zero_degc=fitted.drift_origin_degc, clamp_degc=fitted.clamp_degc)
            if gyro_drift is not None:
                gyro_rows = np.vstack([gyro_drift[1], gyro_drift[0]])  # X0 (the constant), X1..X3
                notes.append(f"px4 holds the gyro drift as a cubic (TC_G{args.instance}_X0..X3, TC_G_ENABLE 1): "
                             f"worst {gyro_drift[2] * 1e3:.3f} mrad/s from ours over the range")
        parameters = px4_parameters(fitted, args.instance, device_id=device,
                                    gyro_bias_radps=calibration.gyro_bias_radps,
                                    gyro_device_id=calibration.gyro_device_id, gyro_drift_rows=gyro_rows)
        return px4_params_text(parameters, f"Onboard parameters {source}"), notes + _thermal_notes(parameters)
    gyro_drift, gyro_bias = None, calibration.gyro_bias_radps
    if fitted.has_drift and fitted.drift_zero_degc is not None:
        gyro_drift = fit_gyro_drift(calibration, drift_origin_degc=ARDUPILOT_TCAL_REFERENCE_DEGC,
                                    drift_zero_degc=fitted.drift_zero_degc, clamp_degc=fitted.clamp_degc)
        notes.append("ardupilot holds the gyro drift as a cubic (INS_TCALn_GYR1..3, zero at INS_GYRn_CALTEMP): "
                     + ("none in this calibration, zeros written" if gyro_drift is None else
                        f"worst {gyro_drift[2] * 1e3:.3f} mrad/s from ours over the range"))
        if gyro_drift is not None and gyro_bias is not None:
            gyro_bias = gyro_bias + gyro_drift[1]  # the cubic's constant: the offset's
        if calibration.temperature is not None and fitted.clamp_degc != calibration.temperature.range_degc:
            low, high = fitted.clamp_degc or calibration.temperature.range_degc
            notes.append(f"TMIN {low:.1f}, TMAX {high:.1f} degC, inside the range calibrated "
                         f"({calibration.temperature.range_degc[0]:.1f}..{calibration.temperature.range_degc[1]:.1f} "
                         "degC): ArduPilot holds the correction flat beyond them, which follows our curve's levelling "
                         "off better than its cubic does")
    parameters = ardupilot_parameters(fitted, args.instance, reference_degc=calibration.reference_temperature_degc,
                                      gyro_bias_radps=gyro_bias,
                                      gyro_drift_coefficients=None if gyro_drift is None else gyro_drift[0])
    notes += _thermal_notes(parameters)
    if calibration.gyro_bias_radps is not None:
        notes.append("ArduPilot recomputes INS_GYR*OFFS at every boot unless INS_GYR_CAL = 0")
    return ardupilot_param_text(parameters, source), notes


def _thermal_notes(parameters: list[Parameter]) -> list[str]:
    """What the switch-offs of the vehicle's own thermal compensation among `parameters` do, one line each."""
    off = {p.name for p in parameters if p.name.endswith("_ENABLE") and p.value == 0}
    raw = ("this calibration is of the raw sensor (replay undoes the compensation a log had on), so the vehicle's "
           "own compensation must not be applied before it")
    notes = []
    if "TC_A_ENABLE" in off:
        gyro = " and TC_G_ENABLE 0 (the gyro offset too)" if "TC_G_ENABLE" in off else ""
        notes.append(f"TC_A_ENABLE 0{gyro} written: {raw}; it is one switch for every accelerometer of the "
                     "vehicle: load every IMU's calibration (replay --all-imus), or those left keep no thermal "
                     "compensation")
    notes += [f"{name} 0 written: {raw} (ArduPilot's INS_TCALn holds this IMU's accelerometer and gyro)"
              for name in sorted(off) if name.startswith("INS_TCAL")]
    return notes


def _noise_figures(args: argparse.Namespace, calibration: Calibration) -> NoiseFigures:
    """From --noise; else the calibration's noise block (densities, rate) and --random-walks, which the block
    cannot hold (the poses are seconds long; a random walk needs a long still recording)."""
    from ..io.estimator_yaml import NoiseFigures, read_noise_figures

    if args.update_rate is not None and not args.update_rate > 0:
        raise CalibrationError(f"--update-rate must be positive, got {args.update_rate}")
    if args.noise is not None:
        return read_noise_figures(args.noise, args.update_rate)
    block = calibration.noise
    if block is None:
        raise CalibrationError(f"{args.to} needs the noise figures: measure them with 'accel-calib noise "
                               "RECORDING --kalibr imu.yaml' and give --noise imu.yaml")
    missing = ([] if block.gyro_density is not None else ["gyroscope_noise_density"]) + \
        ([] if args.random_walks is not None else ["the random walks"])
    if missing:
        gyro = "" if block.gyro_density is None else f", gyro {block.gyro_density:.3e} rad/s/sqrt(Hz)"
        raise CalibrationError(
            f"{args.calibration}'s noise block has the white noise at the poses (accel {block.accel_density:.3e} "
            f"m/s^2/sqrt(Hz){gyro} at {block.rate_hz:g} Hz) but not {' and '.join(missing)} {args.to} needs: "
            "give --random-walks ACCEL GYRO, or --noise imu.yaml from 'accel-calib noise RECORDING --kalibr imu.yaml'")
    assert block.gyro_density is not None and args.random_walks is not None
    return NoiseFigures(accelerometer_noise_density=block.accel_density, accelerometer_random_walk=args.random_walks[0],
                        gyroscope_noise_density=block.gyro_density, gyroscope_random_walk=args.random_walks[1],
                        update_rate_hz=args.update_rate if args.update_rate is not None else block.rate_hz)


def _estimator_text(args: argparse.Namespace, calibration: Calibration, source: str) -> tuple[str, list[str]]:
    from ..core.axis_calibration import cost_against, lower_triangular_with_rotation
    from ..io.estimator_yaml import checked_topic, kalibr_imu_yaml, openvins_imu_chain_yaml

    checked_topic(args.rostopic)
    noise = _noise_figures(args, calibration)
    if args.noise is not None:  # which figures the noise file carries (static or in operation), carried on
        from ..io.estimator_yaml import noise_statements

        source = "\n".join([source, *noise_statements(args.noise)])
    if args.to == "kalibr":
        return kalibr_imu_yaml(noise, args.rostopic, source), \
            ["kalibr: imu.yaml holds the noise figures only; Kalibr estimates the intrinsics itself"]
    rotation, lower = lower_triangular_with_rotation(calibration.matrix)
    gyro_rotation, gyro_lower = (None, None) if calibration.gyro_matrix is None \
        else lower_triangular_with_rotation(calibration.gyro_matrix)
    cost = cost_against(calibration, _matrix_correction(calibration, with_bias=True))
    gyro = "no gyro matrix in the calibration (Tw, R_IMUtoGYRO identity)" if gyro_lower is None \
        else "the gyro matrix (Tw, R_IMUtoGYRO; exact)"
    unbiased = cost_against(calibration, _matrix_correction(calibration, with_bias=False))
    notes = [f"openvins holds the accelerometer matrix (Ta, R_IMUtoACC; exact) and {gyro}: {cost.describe()}",
             f"openvins estimates the accelerometer bias online from 0 (no file entry): until it has, ours "
             f"([{', '.join(f'{v:+.4f}' for v in calibration.bias)}] m/s^2) is {unbiased.worst_mg:.1f} mg at worst"]
    _check_cost(cost, args)
    return openvins_imu_chain_yaml(noise, args.rostopic, rotation, lower, source, gyro_rotation, gyro_lower), notes


def export_text(args: argparse.Namespace, calibration: Calibration) -> tuple[str, list[str]]:
    """(file text, lines to tell the user) for args.to."""
    source = f"from accel_calibration {args.calibration} (model {calibration.model}, created {calibration.created})"
    if args.to in ("px4", "ardupilot"):
        return _autopilot_text(args, calibration, source)
    return _estimator_text(args, calibration, source)


def run(args: argparse.Namespace) -> int:
    from ..io.calibration_file import write_text_atomically
    from ..io.output_paths import check_outputs
    from .options import calibration_in_force

    check_outputs([("--output", args.output)], [args.calibration, args.noise])
    calibration = calibration_in_force(args.calibration)
    text, notes = export_text(args, calibration)
    for note in notes:
        print(note, file=sys.stderr if args.output is None else sys.stdout)
    if args.output is None:
        sys.stdout.write(text)
    else:
        write_text_atomically(args.output, text)
        print(f"written {args.output}")
    return 0
