"""accel-calib replay LOG --all-imus -o DIR: every IMU of an autopilot log in one run (PX4 ULog sensor_accel
instances, DataFlash IMU instances), one calibration file each, named by instance and device ID, and the
rotation between the IMUs from the poses they held together."""
from __future__ import annotations

import argparse
import dataclasses
import re
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import AccelCalibrationError, CalibrationError

if TYPE_CHECKING:
    from ..bag.replay import ReplayResult, ReplaySettings

LOG_FORMATS = ("ulog", "dataflash")
SET_FILE_NAME = re.compile(r"imu\d+(_dev\d+)?\.yaml")  # the names file_name gives


def file_name(instance: int, device: int | None) -> str:
    """imu<N>_dev<ID>.yaml (imu<N>.yaml where the log names no device)."""
    return f"imu{instance}" + (f"_dev{device}" if device else "") + ".yaml"


def _is_calibration(path: Path) -> bool:
    from ..io.calibration_file import load_calibration

    try:
        load_calibration(path)
    except (CalibrationError, OSError):
        return False
    return True


def _write_set(directory: Path, texts: dict[Path, str]) -> list[str]:
    """The run's files written as one set (io/output_paths.write_set_atomically): what each did, and the files
    of an earlier run there that this one did not write (an IMU this log lacks or failed), named, kept."""
    from ..io.output_paths import write_set_atomically

    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise CalibrationError(f"cannot make output directory {directory}: {error.strerror}") from None
    earlier = sorted(p for p in directory.iterdir() if SET_FILE_NAME.fullmatch(p.name) and p not in texts)
    written = write_set_atomically({path: text.encode("utf-8") for path, text in texts.items()},
                                   _is_calibration, "a calibration")
    lines = [f"replaced {path} (its earlier calibration)" if replaced else f"written {path}"
             for path, replaced in written]
    if earlier:
        lines.append(f"not of this run, left as they were: {', '.join(map(str, earlier))} (an earlier run's: "
                     "remove them if they are not current)")
    return lines


def _check_arguments(args: argparse.Namespace) -> str:
    """The one log to read; every option that does not fit --all-imus refused before any work."""
    from ..bag.recording import detect_format

    if len(args.bags) != 1:
        raise CalibrationError("--all-imus reads one log at a time")
    if args.instance is not None:
        raise CalibrationError("--all-imus reads every instance: leave out --instance")
    if args.output is None:
        raise CalibrationError("--all-imus needs --output DIR: one calibration file per IMU goes there")
    for flag, value in (("--corrected", args.corrected_bag), ("--report", args.report),
                        ("--poses-out", args.poses_out)):
        if value is not None:
            raise CalibrationError(f"--all-imus writes calibrations only: leave out {flag}")
    bag = str(args.bags[0])
    kind = args.format or detect_format(bag)
    if kind not in LOG_FORMATS:
        raise CalibrationError(f"--all-imus applies to autopilot logs (PX4 ULog, ArduPilot DataFlash); "
                               f"{bag} is {kind}")
    return bag


def replay_every_imu(bag: str, settings: ReplaySettings) -> tuple[dict[int, ReplayResult], dict[int, str]]:
    """Each IMU instance the log holds (whichever numbers they have: a log may lack instance 0), and why each
    that could not be read was not (one line each: the others go on); a --prior that names its device is put
    on that device's instance only (said), and one no IMU of the log is, one line."""
    from ..bag.recording import log_accel_devices
    from ..bag.replay import replay_bag

    devices = log_accel_devices(bag, settings.format)
    instances = sorted(devices) or [0]  # none: instance 0's read says what is wrong
    prior = None if settings.prior is None else settings.prior.calibration.accel_device_id
    named = {n: d for n, d in devices.items() if d is not None}
    if prior is not None and named and prior not in named.values():
        listed = ", ".join(f"{d} (instance {n})" for n, d in named.items())
        raise CalibrationError(f"--prior {settings.prior_path} is the calibration of device {prior}; the IMUs of "
                               f"{bag} are devices {listed}: not this log's")
    replays, unread = {}, {}
    for instance in instances:
        own = dataclasses.replace(settings, instance=instance)
        if prior is not None and named.get(instance, prior) != prior:
            own = dataclasses.replace(own, prior=None, prior_path=None)
            print(f"IMU {instance} (device {named[instance]}): fitted without --prior (it is device {prior}'s)")
        try:
            replays[instance] = replay_bag(bag, own)
        except AccelCalibrationError as error:
            if len(instances) == 1:
                raise
            unread[instance] = str(error)
    return replays, unread


def alignment_lines(replays: dict[int, ReplayResult]) -> list[str]:
    """The rotation of every calibrated IMU relative to the first calibrated one, from their common poses."""
    from ..bag.imu_alignment import common_directions, frame_sigma_mrad, relative_rotation

    calibrated = {n: r for n, r in sorted(replays.items()) if r.calibration is not None}
    if len(calibrated) < 2:
        return []
    reference, *others = calibrated
    lines = []
    base = calibrated[reference]
    assert base.calibration is not None, "calibrated only"
    for other in others:
        replay = calibrated[other]
        assert replay.calibration is not None, "calibrated only"
        ua, ub = common_directions(base.poses, base.calibration, replay.poses, replay.calibration)
        frames = float(np.hypot(frame_sigma_mrad(base.calibration), frame_sigma_mrad(replay.calibration)))
        rotation = relative_rotation(ua, ub, frames)
        if rotation is None:
            lines.append(f"rotation IMU {reference} -> IMU {other}: fewer than 2 poses held by both at once")
        else:
            lines.append(rotation.describe(f"IMU {reference}", f"IMU {other}"))
    return lines


def run_all_imus(args: argparse.Namespace, settings: ReplaySettings) -> int:
    import sys

    from ..io.calibration_file import checked_calibration_text
    from ..io.output_paths import check_outputs
    from .options import PROG

    bag = _check_arguments(args)
    check_outputs([("--output", args.output)], [bag, args.params_file], directories=("--output",))
    replays, unread = replay_every_imu(bag, settings)
    directory = Path(args.output)
    texts: dict[Path, str] = {}
    lines, errors = [], [f"IMU {instance}: {reason}" for instance, reason in sorted(unread.items())]
    for instance, replay in sorted(replays.items()):
        if replay.calibration is None or replay.result is None:
            errors.append(f"{bag}: IMU {instance}: {replay.problem}")
            continue
        target = directory / file_name(instance, replay.source.accel_device_id)
        texts[target] = checked_calibration_text(replay.calibration, str(target))
        lines += [f"IMU {instance} ({replay.source.sensor_id or 'no device ID'}): {len(replay.poses)} static poses; "
                  f"{replay.result.summary()}", f"fitted to {replay.calibration.fitted_to}"]
    lines += alignment_lines(replays)
    if texts:  # every file's text made: now the files, as one set
        lines += _write_set(directory, texts)
    print("\n".join(lines))
    for message in errors:
        print(f"{PROG}: error: {message}", file=sys.stderr)
    return 1 if errors else 0
