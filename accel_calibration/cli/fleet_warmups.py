"""accel-calib fleet LOGS... --warmup -o DIR: the warm-ups a fleet's vehicles log anyway (still after power-on
while they warm), pooled per vehicle and IMU over all its logs into one temperature curve (core/warmup_pool):
a cold morning and a warm afternoon together cover their joint range, each with its own turn-on bias.

Each log is read on a worker (every IMU of an autopilot log, each on top of its own calibration in force, its
warm-up fitted alone); the IMUs are matched across logs by their accelerometer's device ID, not by instance
number (logs of one vehicle may enumerate them differently). One calibration file per vehicle and IMU (as
replay --warmup writes it), written as one set; one line per vehicle and IMU: the joint span, how many logs
gave it, and per log that did not, why (no warm-up: moving, temperature steady, too short; failed to read;
left out: its warm-up disagrees with the others')."""
from __future__ import annotations

import argparse
import dataclasses
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import AccelCalibrationError, CalibrationError

if TYPE_CHECKING:
    from ..bag.replay import ReplaySettings
    from ..bag.warmup_replay import WarmupInput
    from ..core.calibration import Calibration
    from ..core.warmup import WarmupRecording, WarmupResult
    from ..core.warmup_pool import PooledWarmup, PoolMember

SHORT_S = 60.0  # a recording shorter than this is too short to be a warm-up (say so, not "moving")
# fleet's own (cli/fleet.py, which calls in here, so they are handed over rather than imported back):
FindRecordings = Callable[[Sequence[str]], tuple[list[str], list[str]]]  # arguments -> (recordings, problems)
VehicleOf = Callable[[Path, Any, "str | None"], tuple[str, str]]  # (path, its replay or None, --vehicle) -> vehicle


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--warmup", action="store_true",
                        help="the recordings' warm-ups (still while the temperature changes) pooled per vehicle "
                             "and IMU (matched by device ID) into one temperature curve each, written to "
                             "--output DIR; no history rows")
    parser.add_argument("-o", "--output", default=None, metavar="DIR",
                        help="with --warmup: one calibration file per vehicle and IMU, DIR/VEHICLE/devID.yaml")


def warmup_requested(args: argparse.Namespace) -> bool:
    """Whether fleet runs as --warmup; -o without it refused (fleet writes the history, not files)."""
    if args.output is not None and not args.warmup:
        raise CalibrationError("fleet writes --output DIR only with --warmup (without it, rows go to --history)")
    return bool(args.warmup)


@dataclass(frozen=True)
class ImuWarmup:
    """One IMU of one log: who it is, its warm-up (None: none, `reason` says why) and how to name its file."""

    key: str  # how logs are matched: dev<ID>, else imu<N> (a log naming no device), else the sensor's name
    member: PoolMember | None
    reason: str | None
    base_said: str = ""
    names: dict[str, Any] = dataclasses.field(default_factory=dict)  # Calibration fields naming the sensor


@dataclass(frozen=True)
class LogWarmups:
    """What a worker sends back of one log: its vehicle, its IMUs, or why it could not be read at all."""

    path: str
    vehicle: str
    imus: tuple[ImuWarmup, ...]
    reason: str | None = None


def _imu_key(instance: int | None, device: int | None, sensor: str) -> str:
    if device:
        return f"dev{device}"
    if instance is not None:
        return f"imu{instance}"
    return re.sub(r"[^A-Za-z0-9._-]+", "_", sensor).strip("._") or "imu"


def _no_warmup(each: WarmupInput, refusal: str) -> str:
    """Why a log's IMU gives no warm-up, said as what it was: too short, moving, temperature steady."""
    source = each.replay.source
    if source.duration_s < SHORT_S:
        return f"no warm-up: too short ({source.duration_s:.0f} s)"
    if "no still stretch" in refusal:
        detector = f" (the detector: {each.replay.problem})" if not each.replay.poses and each.replay.problem else ""
        return f"no warm-up: moving, no still stretch with a temperature{detector}"
    if "span" in refusal:
        return f"no warm-up: temperature steady ({refusal.removeprefix('warm-up: ')})"
    return f"no warm-up: {refusal.removeprefix('warm-up: ')}"


def _imu_warmup(path: str, settings: ReplaySettings, instance: int | None, device: int | None
                ) -> tuple[ImuWarmup, WarmupInput | None]:
    from ..bag.warmup_replay import read_warmup
    from ..core.warmup import WarmupOptions, fit_warmup
    from ..core.warmup_pool import PoolMember

    each_settings = settings if instance is None else dataclasses.replace(settings, instance=instance)
    try:
        each = read_warmup(path, each_settings)
    except AccelCalibrationError as error:
        reason = str(error).removeprefix(f"{path}: ")  # the line names the log already
        said = f"no warm-up: {reason}" if "no temperature" in reason else f"failed to read: {reason}"
        return ImuWarmup(_imu_key(instance, device, ""), None, said), None
    source = each.replay.source
    recording = source.recording
    device = device or getattr(recording, "accel_device_id", None)
    key = _imu_key(instance, device, source.sensor_id or source.frame_id or source.imu_topic)
    names = {"frame_id": source.frame_id, "sensor_id": source.sensor_id,
             "fitted_to": getattr(recording, "fitted_to", ""), "accel_device_id": device,
             "gyro_device_id": getattr(recording, "gyro_device_id", None)}
    result = fit_warmup([each.recording], each.base, WarmupOptions(), each_settings.session)
    if result.fit is None:
        return ImuWarmup(key, None, _no_warmup(each, result.refusal or "")), each
    member = PoolMember(Path(path).name, each.recording, result.fit, each.base)
    return ImuWarmup(key, member, None, each.base_said, names), each


def read_log_warmups(path: str, settings: ReplaySettings, vehicle_rule: str | None, vehicle_of: VehicleOf
                     ) -> LogWarmups:
    """Every IMU of one log with its warm-up fitted alone. Runs on a worker; never raises (a log that
    cannot be read is its one-line reason), so one bad log cannot stop the others."""
    from ..bag.recording import detect_format, log_accel_devices

    where = Path(path)
    try:
        devices = log_accel_devices(path, settings.format or detect_format(path))
    except AccelCalibrationError as error:
        devices, failed = {}, str(error).removeprefix(f"{path}: ")
    else:
        failed = ""
    imus, vehicle = [], None
    instances: list[int | None] = [] if failed else [*sorted(devices)] or [None]
    for instance in instances:
        imu, each = _imu_warmup(path, settings, instance, devices.get(instance) if instance is not None else None)
        imus.append(imu)
        if vehicle is None and each is not None:
            try:
                vehicle = vehicle_of(where, each.replay, vehicle_rule)[0]
            except AccelCalibrationError as error:
                return LogWarmups(path, where.parent.name, (), f"failed to read: {error}")
    if vehicle is None:
        try:
            vehicle = vehicle_of(where, None, vehicle_rule)[0]
        except AccelCalibrationError as error:
            return LogWarmups(path, where.parent.name, (), f"failed to read: {error}")
    if not devices and imus and imus[0].member is None and imus[0].reason and not imus[0].names:
        return LogWarmups(path, vehicle, (), imus[0].reason)  # one stream, unread: the log's reason
    return LogWarmups(path, vehicle, tuple(imus), f"failed to read: {failed}" if failed else None)


@dataclass
class _Group:
    """One vehicle's IMU across its logs: the warm-ups found, and per log that gave none, why."""

    vehicle: str
    key: str
    imus: list[ImuWarmup] = dataclasses.field(default_factory=list)
    paths: list[str] = dataclasses.field(default_factory=list)
    not_used: list[tuple[str, str]] = dataclasses.field(default_factory=list)  # (log, why)


def _groups(logs: Sequence[LogWarmups]) -> list[_Group]:
    """The logs' IMUs per (vehicle, device); a log that could not be read at all, or lacks an IMU its
    vehicle's other logs have, named under each of the vehicle's IMUs."""
    groups: dict[tuple[str, str], _Group] = {}
    for log in logs:
        for imu in log.imus:
            group = groups.setdefault((log.vehicle, imu.key), _Group(log.vehicle, imu.key))
            if imu.member is not None:
                group.imus.append(imu)
                group.paths.append(log.path)
            else:
                group.not_used.append((log.path, imu.reason or "no warm-up"))
    for log in logs:
        keys = {imu.key for imu in log.imus}
        for (vehicle, key), group in groups.items():
            if vehicle == log.vehicle and key not in keys:
                group.not_used.append((log.path, log.reason or f"no IMU {key} in it"))
    vehicles = {vehicle for vehicle, _ in groups}
    for log in logs:  # a vehicle none of whose logs could be read: a group of its own, to say so
        if log.vehicle not in vehicles:
            groups.setdefault((log.vehicle, ""), _Group(log.vehicle, "")).not_used.append(
                (log.path, log.reason or "no IMU in it"))
    return [groups[key] for key in sorted(groups)]


def _file_stem(vehicle: str) -> str:
    """A vehicle's name as a directory name (a rule's match may hold anything)."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", vehicle).strip(".")
    return stem or "vehicle"


def _pooled(group: _Group, settings: ReplaySettings, directory: Path) -> tuple[list[str], list[str],
                                                                           tuple[Path, str] | None]:
    """One vehicle's IMU pooled: (lines, errors, (file, text) to write or None)."""
    from ..core.warmup import warmup_calibration
    from ..io.calibration_file import checked_calibration_text

    who = f"{group.vehicle} IMU {group.key or '-'}"
    logs = len(group.imus) + len(group.not_used)
    notes = [f"  {Path(path).name}: {why}" for path, why in group.not_used]
    if not group.imus:
        unread = not group.key and all(why.startswith("failed") for _, why in group.not_used)
        return [f"{who}: no curve, none of its {logs} log(s) holds a warm-up", *notes], \
            [] if unread else [f"{who}: no warm-up in any of its {logs} log(s)"], None  # unread: said once
    members = [imu.member for imu in group.imus if imu.member is not None]  # every one of group.imus has one
    pooled, newest = _pool(members, settings)
    base = members[newest].base
    errors = [f"{who}: {Path(group.paths[i]).name} left out: {why}" for i, why in pooled.left_out]
    notes += [f"  {Path(group.paths[i]).name}: left out: {why}" for i, why in pooled.left_out]
    fit = pooled.result.fit
    if fit is None:
        return [f"{who}: no curve: {pooled.result.refusal}", *notes], \
            [*errors, f"{who}: {pooled.result.refusal}"], None
    low, high = fit.range_degc
    names = ", ".join(Path(group.paths[i]).name for i in pooled.used)
    target = directory / _file_stem(group.vehicle) / f"{group.key}.yaml"
    calibration = _named(warmup_calibration(fit, base), group.imus[newest].names)
    lines = [f"{who}: {low:.1f}..{high:.1f} degC from {len(pooled.used)} of {logs} log(s) ({names}), "
             f"warm-up {group.imus[newest].base_said} of {Path(group.paths[newest]).name}",
             *(f"  {line}" for line in fit.describe()[1:]), *notes]
    return lines, errors, (target, checked_calibration_text(calibration, target))


def _pool(members: list[PoolMember], settings: ReplaySettings) -> tuple[PooledWarmup, int]:
    """The members pooled on top of the calibration in force in the last log used (as given; a directory's by
    name, as autopilots number their logs; a log's own stamps count from boot): the one the vehicle flies
    with. Returns the pool and which member's calibration it is on top of."""
    from ..core.warmup import WarmupOptions, fit_warmup
    from ..core.warmup_pool import PooledWarmup, pool_warmups

    def fit_on(base: Calibration | None) -> Callable[[list[WarmupRecording]], WarmupResult]:
        return lambda recordings: fit_warmup(recordings, base, WarmupOptions(), settings.session)

    last = len(members) - 1
    pooled = pool_warmups(members, members[last].base, fit_on(members[last].base))
    if pooled.result.fit is not None and last not in pooled.used:  # the last log left out: the last one used
        last = pooled.used[-1]
        refit = fit_on(members[last].base)([members[i].recording for i in pooled.used])
        pooled = PooledWarmup(refit, pooled.used, pooled.left_out)
    return pooled, last


def _named(calibration: Calibration, names: dict[str, Any]) -> Calibration:
    """The sensor's names where the calibration gone on top of says none (as replay --warmup names it)."""
    given = {name: value for name, value in names.items() if value and not getattr(calibration, name)}
    return dataclasses.replace(calibration, **given)


def _read_all(recordings: list[str], settings: ReplaySettings, args: argparse.Namespace, vehicle_of: VehicleOf
              ) -> list[LogWarmups]:
    """Every log read on the cluster (fleet's own: --workers, --scheduler), in the order given."""
    from .dask_cluster import dask_client, default_workers, run_tasks

    logs: list[LogWarmups | None] = [None] * len(recordings)
    workers = None if args.scheduler else min(args.workers or default_workers(), len(recordings))
    with dask_client(workers=workers, scheduler=args.scheduler) as client:
        jobs = [(path, settings, args.vehicle, vehicle_of) for path in recordings]
        for i, outcome, error in run_tasks(client, read_log_warmups, jobs, label="logs"):
            logs[i] = outcome if error is None else LogWarmups(
                recordings[i], Path(recordings[i]).parent.name, (), f"failed to read: worker lost ({error})")
    return [log for log in logs if log is not None]


def run_warmups(args: argparse.Namespace, find_recordings: FindRecordings, vehicle_of: VehicleOf) -> int:
    """fleet --warmup: 0 when every vehicle's IMU got a curve and no log failed or was left out."""
    from ..core.text import printable_text
    from ..io.output_paths import check_outputs
    from .all_imus import _is_calibration
    from .options import PROG, replay_settings

    if args.output is None:
        raise CalibrationError("fleet --warmup needs --output DIR: one calibration file per vehicle and IMU "
                               "goes there")
    if args.workers is not None and args.workers < 1:
        raise CalibrationError(f"--workers must be at least 1, got {args.workers}")
    settings = replay_settings(args)
    recordings, problems = find_recordings(args.recordings)
    check_outputs([("--output", args.output)], [*recordings, *args.recordings, args.params_file],
                  directories=("--output",))
    for problem in problems:
        print(f"{PROG}: error: {printable_text(problem)}", file=sys.stderr)
    if not recordings:
        raise CalibrationError("no recordings to read warm-ups from")
    logs = _read_all(recordings, settings, args, vehicle_of)
    lines, errors, texts = [], [], {}
    for group in _groups(logs):
        said, wrong, written = _pooled(group, settings, Path(args.output))
        lines += said
        errors += wrong
        if written is not None:
            texts[written[0]] = written[1]
    for log in logs:  # each log that could not be read, once (its IMUs' lines name it too)
        failed = [f"{log.path}: {log.reason}"] if log.reason and log.reason.startswith("failed") else []
        errors += failed or [f"{log.path}: IMU {imu.key}: {imu.reason}" for imu in log.imus
                             if imu.reason and imu.reason.startswith("failed")]
    if texts:
        from ..io.output_paths import write_set_atomically

        for directory in {path.parent for path in texts}:
            try:
                directory.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                raise CalibrationError(f"cannot make output directory {directory}: {error.strerror}") from None
        written_set = write_set_atomically({path: text.encode("utf-8") for path, text in texts.items()},
                                           _is_calibration, "a calibration")
        lines += [f"replaced {path} (its earlier calibration)" if replaced else f"written {path}"
                  for path, replaced in written_set]
    print(printable_text("\n".join(lines)))
    for message in errors:
        print(f"{PROG}: error: {printable_text(message)}", file=sys.stderr)
    return 1 if errors or problems or not texts else 0
