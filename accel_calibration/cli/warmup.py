"""accel-calib replay --warmup: the biases' temperature curves (accelerometer and gyro) from recordings where
the sensor sits still while it warms or cools, several recordings pooled into one curve (a cold morning and
a warm afternoon), on top of the calibration --prior gives, its poses fit, or the log has in force. Says the
range, what one orientation cannot separate, the steps found and what was left out; writes it to -o."""
from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CalibrationError
from ..core.warmup import WarmupOptions, fit_warmup, warmup_calibration

if TYPE_CHECKING:
    from ..bag.replay import ReplaySettings
    from ..bag.warmup_replay import WarmupInput
    from ..core.calibration import Calibration
    from ..core.warmup import WarmupResult

# The replay outputs a warm-up does not make (a corrected copy, a report and a pose table of a warm-up
# are replay's without --warmup).
NOT_WITH_WARMUP = (("--corrected", "corrected_bag"), ("--report", "report"), ("--poses-out", "poses_out"))


def _refused_options(args: argparse.Namespace) -> None:
    given = [flag for flag, name in NOT_WITH_WARMUP if getattr(args, name, None)]
    if given:
        raise CalibrationError(f"--warmup fits the temperature curves and writes them with -o; it does "
                               f"not take {', '.join(given)} (replay without --warmup does)")


def run_warmup(args: argparse.Namespace, settings: object) -> int:
    """The warm-up fit over every recording given; 0 when a curve was fitted (and written with -o)."""
    from ..bag.replay import ReplaySettings
    from ..bag.warmup_replay import read_warmup
    from ..io.calibration_file import checked_calibration_text, write_text_atomically
    from ..io.output_paths import check_output_places, check_outputs

    assert isinstance(settings, ReplaySettings)
    _refused_options(args)
    if args.all_imus:
        return _every_imu(args, settings)
    inputs = [*args.bags, args.params_file, args.prior]
    check_outputs([("--output", args.output)], inputs)
    check_output_places([("--output", args.output)])
    read = [read_warmup(bag, settings, progress=len(args.bags) == 1) for bag in args.bags]
    first = read[0]
    result, base_said = fit_warmup([each.recording for each in read], first.base,
                                   WarmupOptions(), settings.session), first.base_said
    if settings.prior is None and len(read) == 1:
        refitted = refit_poses_under_curves(first, settings)
        if refitted is not None:
            result, base = refitted
            first = dataclasses.replace(first, base=base)
            base_said = (f"on top of the calibration its {len(first.replay.poses)} poses fit, refitted with the "
                         "warm-up's drift taken off the poses held while it warmed")
    lines = [_source_line(bag, each) for bag, each in zip(args.bags, read)]
    if result.fit is None:
        print("\n".join(lines + list(result.said)))
        # No still stretch at all: the detector's own reason (noise, too short) is the one to give.
        found_none = [each.replay.problem for each in read if not each.replay.poses and each.replay.problem]
        said = f" (the detector: {found_none[0]})" if len(found_none) == len(read) else ""
        raise CalibrationError(f"{_names(args.bags)}: {result.refusal}{said}")
    calibration = _named(warmup_calibration(result.fit, first.base), first)
    lines += [f"warm-up {base_said}", *result.said]
    if args.output:
        text = checked_calibration_text(calibration, args.output)
        write_text_atomically(args.output, text)
        lines.append(f"written {args.output}")
    print("\n".join(lines))
    return 0


REFITS = 3


def refit_poses_under_curves(read: WarmupInput, settings: ReplaySettings
                             ) -> tuple[WarmupResult, Calibration] | None:
    """The recording's poses refitted with the warm-up's drift taken off (those held while it warmed count at
    the curves' reference, not as a scale), and the curves fitted again on top, zero where the poses were
    held (their median temperature); None when no pose drifted or the refit does not pass. Also when the poses
    as they were failed the gates: the curves are fitted on the raw output first."""
    from ..core.session import CalibrationSession
    from ..core.warmup_poses import poses_at_reference

    poses = read.replay.poses
    degc = [pose.temperature_degc for pose in poses if pose.temperature_degc is not None]
    if not degc or (read.base is not None and read.replay.calibration is None):
        return None  # curves on the log's calibration in force: no poses' fit to put right
    options = WarmupOptions(reference_degc=float(np.median(degc)))
    base, result = read.base, fit_warmup([read.recording], read.base, options, settings.session)
    refitted = None
    for _ in range(REFITS):  # the curves are fitted in the corrected frame: again once the poses' fit moved
        if result.fit is None:
            break
        at_reference = poses_at_reference(warmup_calibration(result.fit, base), poses)
        if at_reference is None:
            break
        again = CalibrationSession(settings.session).verdict_of(at_reference)
        if not again.success or again.calibration is None:
            break
        base = again.calibration if read.base is None else read.base.replace(bias=again.calibration.bias,
                                                                              matrix=again.calibration.matrix)
        result = fit_warmup([read.recording], base, options, settings.session)
        refitted = None if result.fit is None else (result, base)
    return refitted


def _named(calibration: Calibration, each: WarmupInput) -> Calibration:
    """The recording's frame, sensor and what the samples were, where the calibration gone on top of says none."""
    source = each.replay.source
    recording = source.recording
    return dataclasses.replace(
        calibration, frame_id=calibration.frame_id or source.frame_id, sensor_id=calibration.sensor_id
        or source.sensor_id, fitted_to=calibration.fitted_to or getattr(recording, "fitted_to", ""),
        accel_device_id=calibration.accel_device_id or getattr(recording, "accel_device_id", None),
        gyro_device_id=calibration.gyro_device_id or getattr(recording, "gyro_device_id", None))


def _every_imu(args: argparse.Namespace, settings: ReplaySettings) -> int:
    """--warmup --all-imus LOG -o DIR: each IMU of an autopilot log its own warm-up, on top of its own
    calibration in force, one file each (named as replay --all-imus names them, written as one set)."""
    import sys

    from ..bag.recording import log_accel_devices
    from ..bag.warmup_replay import read_warmup
    from ..io.calibration_file import checked_calibration_text
    from ..io.output_paths import check_outputs
    from .all_imus import _check_arguments, _write_set, file_name
    from .options import PROG

    bag = _check_arguments(args)
    if settings.prior is not None:
        raise CalibrationError("--warmup --all-imus puts each IMU's curves on top of its own calibration; "
                               "--prior is one IMU's: give it with --instance")
    check_outputs([("--output", args.output)], [bag, args.params_file], directories=("--output",))
    texts: dict[Path, str] = {}
    lines, errors = [], []
    for instance in sorted(log_accel_devices(bag, settings.format)) or [0]:
        each = read_warmup(bag, dataclasses.replace(settings, instance=instance))
        result = fit_warmup([each.recording], each.base, WarmupOptions(), settings.session)
        if result.fit is None:
            errors.append(f"{bag}: IMU {instance}: {result.refusal}")
            continue
        sensor = each.replay.source.sensor_id
        target = Path(args.output) / file_name(instance, each.replay.source.accel_device_id)
        texts[target] = checked_calibration_text(_named(warmup_calibration(result.fit, each.base), each), target)
        lines += [f"IMU {instance} ({sensor or 'no device ID'}): warm-up {each.base_said}", *result.said]
    if texts:
        lines += _write_set(Path(args.output), texts)
    print("\n".join(lines))
    for message in errors:
        print(f"{PROG}: error: {message}", file=sys.stderr)
    return 1 if errors else 0


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
