"""accel-calib check CAL.yaml RECORDING: does this calibration still hold on this recording? The still
poses are found as replay finds them (any format, the flight state kept out), then tested against the
calibration (core/check.py) with the change rule of `accel-calib history`."""
from __future__ import annotations

import argparse
import dataclasses

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
    result = check_calibration(calibration, replay.poses, rule, gravity=None if located is None else located[0])
    lines = describe(result)
    if replay.flight_state is not None:
        lines.append(replay.flight_state.report_line())
    if identity is not None:
        lines.append(identity)
    print("\n".join(lines))
    if result.verdict == "moved":
        return DRIFT_EXIT_CODE
    return CANNOT_TELL_EXIT_CODE if result.verdict == "cannot tell" else 0
