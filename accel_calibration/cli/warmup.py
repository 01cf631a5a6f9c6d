"""accel-calib replay --warmup: the biases' temperature curves (accelerometer and gyro) from recordings where
the sensor sits still while it warms or cools, several recordings pooled into one curve (a cold morning and
a warm afternoon), on top of the calibration --prior gives, its poses fit, or the log has in force. Says the
range, what one orientation cannot separate, the steps found and what was left out; writes it to -o."""
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence

from ..core.errors import CalibrationError
from ..core.warmup import WarmupOptions, fit_warmup, warmup_calibration

# The replay outputs a warm-up does not make (a corrected copy, a report and a pose table of a warm-up
# are replay's without --warmup).
NOT_WITH_WARMUP = (("--all-imus", "all_imus"), ("--corrected", "corrected_bag"), ("--report", "report"),
                   ("--poses-out", "poses_out"))


def _refused_options(args: argparse.Namespace) -> None:
    given = [flag for flag, name in NOT_WITH_WARMUP if getattr(args, name, None)]
    if given:
        raise CalibrationError(f"--warmup fits the temperature curves of one IMU and writes them with -o; it does "
                               f"not take {', '.join(given)} (replay without --warmup does)")


def run_warmup(args: argparse.Namespace, settings: object) -> int:
    """The warm-up fit over every recording given; 0 when a curve was fitted (and written with -o)."""
    from ..bag.replay import ReplaySettings
    from ..bag.warmup_replay import read_warmup
    from ..io.calibration_file import checked_calibration_text, write_text_atomically
    from ..io.output_paths import check_output_places, check_outputs

    assert isinstance(settings, ReplaySettings)
    _refused_options(args)
    inputs = [*args.bags, args.params_file, args.prior]
    check_outputs([("--output", args.output)], inputs)
    check_output_places([("--output", args.output)])
    read = [read_warmup(bag, settings, progress=len(args.bags) == 1) for bag in args.bags]
    first = read[0]
    result = fit_warmup([each.recording for each in read], first.base,
                        WarmupOptions(), settings.session)
    lines = [_source_line(bag, each) for bag, each in zip(args.bags, read)]
    if result.fit is None:
        print("\n".join(lines + [f"left out: {why}" for why in result.said]))
        # No still stretch at all: the detector's own reason (noise, too short) is the one to give.
        found_none = [each.replay.problem for each in read if not each.replay.poses and each.replay.problem]
        said = f" (the detector: {found_none[0]})" if len(found_none) == len(read) else ""
        raise CalibrationError(f"{_names(args.bags)}: {result.refusal}{said}")
    calibration = warmup_calibration(result.fit, first.base)
    source = first.replay.source
    calibration = dataclasses.replace(
        calibration, frame_id=calibration.frame_id or source.frame_id, sensor_id=calibration.sensor_id
        or source.sensor_id, fitted_to=calibration.fitted_to or getattr(source.recording, "fitted_to", ""))
    lines += [f"warm-up {first.base_said}", *result.said]
    if args.output:
        text = checked_calibration_text(calibration, args.output)
        write_text_atomically(args.output, text)
        lines.append(f"written {args.output}")
    print("\n".join(lines))
    return 0


def _source_line(bag: str, each: object) -> str:
    from ..bag.warmup_replay import WarmupInput

    assert isinstance(each, WarmupInput)
    source = each.replay.source
    temperatures = each.recording.temperature_degc
    known = temperatures[temperatures == temperatures]
    span = f"{known.min():.1f}..{known.max():.1f} degC" if len(known) else "no temperature"
    return (f"{bag}: {source.messages} {source.recording.unit} on {source.imu_topic} over {source.duration_s:.1f} s, "
            f"temperature {span}")


def _names(bags: Sequence[str]) -> str:
    return bags[0] if len(bags) == 1 else f"{bags[0]} and {len(bags) - 1} more"
