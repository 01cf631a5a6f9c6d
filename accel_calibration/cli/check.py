"""accel-calib check CAL.yaml RECORDING: does this calibration still hold on this recording? The still
poses are found as replay finds them (any format, the flight state kept out), then tested against the
calibration (core/check.py) with the change rule of `accel-calib history`."""
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .history import DRIFT_EXIT_CODE, add_change_rule_options
from .options import (
    add_local_gravity_options,
    add_reader_options,
    add_settings_options,
    instance_of_device,
    local_gravity,
    reader_fields,
    replay_settings,
)

if TYPE_CHECKING:
    from ..bag.replay import ReplayResult
    from ..core.calibration import Calibration
    from ..core.pose import Pose

CANNOT_TELL_EXIT_CODE = 1


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "check", help="does a calibration still hold on a recording's still poses?",
        description="Finds the still poses of the recording as replay does and tests them against the "
                    "calibration: per pose |a| - g with its sigma, per axis the bias and scale changes the "
                    "poses observe. One verdict line, then the figures. Exit code 0: it holds; "
                    f"{DRIFT_EXIT_CODE}: it moved beyond the rule (as 'accel-calib history'); "
                    f"{CANNOT_TELL_EXIT_CODE}: it cannot tell (too few orientations) or an error.")
    parser.add_argument("calibration", metavar="CAL.yaml", help="the calibration to check")
    parser.add_argument("recording", metavar="RECORDING",
                        help="a rosbag2 directory, a .mcap or .db3 file, a PX4 .ulg log, an ArduPilot .bin log, "
                             "or a CSV of raw samples")
    add_reader_options(parser)
    add_settings_options(parser, detector=False, model=False)
    add_change_rule_options(parser)
    add_local_gravity_options(parser)  # default: the g the calibration was fitted with
    return parser


def run(args: argparse.Namespace) -> int:
    from ..bag.replay import replay_bag
    from ..core.change_rule import ChangeRule
    from ..core.check import check_calibration, describe
    from ..core.errors import CalibrationError
    from ..io.calibration_file import load_calibration

    located = local_gravity(args)  # the flags refused before any file is read
    try:
        rule = ChangeRule(k_sigma=args.drift_k_sigma, max_bias_change_mg=args.max_bias_change,
                          max_scale_change=args.max_scale_change)
    except CalibrationError as error:  # the rule's own words, named as the flags are
        raise CalibrationError(str(error).replace("k_sigma", "--k-sigma").replace("_", "-")) from None
    calibration = load_calibration(args.calibration)
    settings = dataclasses.replace(replay_settings(args), **reader_fields(args))
    settings, identity = instance_of_device(calibration, args.calibration, args.recording, settings)
    replay = replay_bag(args.recording, settings)  # its errors are one line (bag/replay.ReplayError)
    poses, quantised = _quantised_poses(replay)
    unchecked_temperature = _temperature_problem(calibration, poses)
    poses = [p if p.temperature_degc is None or np.isfinite(p.temperature_degc)
             else dataclasses.replace(p, temperature_degc=None) for p in poses]
    result = check_calibration(calibration, poses, rule, gravity=None if located is None else located[0])
    lines = describe(result)
    verdict = result.verdict
    if unchecked_temperature is not None:  # never a silent verdict on a model applied where it was not fitted
        if verdict == "moved":
            lines[0] += f"; but {unchecked_temperature}"
        else:
            lines[0:1] = [f"cannot tell: {unchecked_temperature}", f"as corrected there: {lines[0]}"]
            verdict = "cannot tell"
    lines += [line for line in (quantised, identity) if line is not None]
    if replay.flight_state is not None:
        lines.append(replay.flight_state.report_line())
    print("\n".join(lines))
    if verdict == "moved":
        return DRIFT_EXIT_CODE
    return CANNOT_TELL_EXIT_CODE if verdict == "cannot tell" else 0


def _quantised_poses(replay: ReplayResult) -> tuple[list[Pose], str | None]:
    """The poses with the quantisation of their samples in their sigma (core/quantisation.py), and the line
    saying the LSB allowed for; as they are where the samples are on no grid (or were streamed, not kept)."""
    from ..bag.recording import Recording
    from ..core.quantisation import quantisation_steps, with_quantisation
    from ..core.units import MG

    recording = replay.source.recording
    if not isinstance(recording, Recording) or not replay.poses:
        return list(replay.poses), None
    steps = quantisation_steps(recording.accel_mps2)
    if not np.any(steps > 0):
        return list(replay.poses), None
    said = " ".join(f"{step / MG:.3g}" if step > 0 else "-" for step in steps)
    return with_quantisation(replay.poses, steps), (
        f"samples quantised: LSB {said} mg (x y z); a pose's mean is trusted to LSB/sqrt(12) where its noise is "
        "below the LSB, and the sigmas above allow for it")


def _temperature_problem(calibration: Calibration, poses: Sequence[Pose]) -> str | None:
    """Where a temperature model cannot be checked: poses without a temperature (corrected at its reference), or
    outside the range it was calibrated over (clamped to its edge); None for a calibration without one."""
    model = calibration.temperature
    if model is None or not poses:
        return None
    low, high = (float(v) for v in model.range_degc)
    calibrated = f"the calibration's temperature model, calibrated over {low:.1f}..{high:.1f} degC,"
    temperatures = np.array([np.nan if p.temperature_degc is None else p.temperature_degc for p in poses])
    missing = int(np.sum(~np.isfinite(temperatures)))
    if missing:
        return (f"{missing} of {len(poses)} poses have no temperature: {calibrated} cannot be checked without it "
                f"(they were corrected at its reference {model.reference_degc:.1f} degC)")
    outside = temperatures[(temperatures < low) | (temperatures > high)]
    if len(outside):
        return (f"{len(outside)} of {len(poses)} poses at {outside.min():.1f}..{outside.max():.1f} degC, outside "
                f"the range {calibrated} not checked there (it holds its edge)")
    return None
