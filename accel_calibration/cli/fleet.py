"""accel-calib fleet: recalibrate every recording of a fleet on a Dask cluster and keep the results in
the calibration history.

Each recording is the same replay as `accel-calib replay`, a few recordings a task, run on the workers of a
local cluster started and stopped here (processes, one per core by default) or of an existing cluster
(`--scheduler tcp://HOST:PORT`). Results come back as they finish; this process is the history's one
writer, in batches (cli/fleet_rows.py). A recording that cannot be read or calibrated is reported
in one line and never stops the others. The cluster is cli/dask_cluster.py's, which
`accel-calib replay --jobs N` uses too: one way to run many.

Dask and SQLAlchemy are imported only when a command needs them (the CLI starts fast)."""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.errors import AccelCalibrationError, CalibrationError
from ..core.units import MG
from .dask_cluster import dask_client, default_workers, run_tasks
from .fleet_rows import HistoryWriter
from .fleet_warmups import add_arguments as add_warmup_arguments
from .fleet_warmups import warmup_requested
from .options import add_settings_options, replay_settings

if TYPE_CHECKING:  # imported where used: the CLI's start-up does not pay for the history module
    from ..bag.flight_evidence_bag import GivenCalibration
    from ..bag.replay import ReplayResult, ReplaySettings
    from ..io.flight_history import EvidenceRecord
    from ..io.history import HistoryRecord

RECORDING_SUFFIXES = (".mcap", ".db3", ".ulg", ".csv")
FLIGHT_LOG_SUFFIXES = (".ulg", ".bin")  # autopilot logs: each IMU's flight evidence is kept too
BAG_SUFFIXES = (".mcap", ".db3")  # and bags' (a rosbag2 directory, or one of its storage files)
METADATA_VEHICLE_KEYS = ("vehicle", "vehicle_id", "robot", "robot_name")
DEFAULT_HISTORY = "calibrations.sqlite"


class FleetError(AccelCalibrationError):
    """cli: the fleet cannot run (no recordings, no scheduler); one line."""


# --- which recordings ----------------------------------------------------------------------------------

def _is_bag_directory(path: Path) -> bool:
    return (path / "metadata.yaml").is_file()


def find_recordings(arguments: Sequence[str]) -> tuple[list[str], list[str]]:
    """(recordings, problems): each argument is a recording (a rosbag2 directory, or a .mcap, .db3,
    .ulg or .csv file) or a directory searched for them (a rosbag2 directory is one recording: its
    storage files are not searched again). Resolved paths, each once, in a stable order."""
    found: dict[str, None] = {}
    problems = []
    for argument in arguments:
        path = Path(argument).expanduser()
        if not path.exists():
            problems.append(f"{argument}: no such file or directory")
            continue
        if path.is_file() or _is_bag_directory(path):
            found[str(path.resolve())] = None
            continue
        before = len(found)
        for directory, subdirectories, files in os.walk(path):
            here = Path(directory)
            if _is_bag_directory(here):
                found[str(here.resolve())] = None
                subdirectories.clear()
                continue
            subdirectories.sort()
            for name in sorted(files):
                if name.lower().endswith(RECORDING_SUFFIXES):
                    found[str((here / name).resolve())] = None
        if len(found) == before:
            problems.append(f"{argument}: no recordings in it (rosbag2 directories, "
                            f"{', '.join(RECORDING_SUFFIXES)})")
    return list(found), problems


# --- one recording, on a worker -------------------------------------------------------------------------

@dataclass(frozen=True)
class RecordingOutcome:
    """What a worker sends back: small (never the samples), picklable."""

    path: str
    status: str  # calibrated | refused | failed
    reason: str | None
    record: HistoryRecord | None  # None when the recording could not even be identified
    summary: str  # one line
    peak_rss_mb: float | None  # the worker process's peak resident memory so far
    elapsed_s: float
    # The other IMUs of an autopilot log, one row each (the first IMU's is this one): empty otherwise.
    others: tuple[RecordingOutcome, ...] = ()
    # An autopilot log's IMU: what its still moments on the ground say of the calibration in force.
    evidence: EvidenceRecord | None = None


def _package_version() -> str:
    try:
        from importlib.metadata import version

        return version("accel_calibration")
    except Exception:  # not installed as a distribution (run from a source tree)
        return "unknown"


def _peak_rss_mb() -> float | None:
    """This process's peak resident memory, MB. Linux: VmHWM, the peak of this process image (getrusage's
    ru_maxrss survives exec, so a spawned worker would report its parent's peak)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource
    except ImportError:  # not on POSIX
        return None
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1024.0 if sys.platform != "darwin" else 1024.0**2)


def _bag_metadata(path: Path) -> dict[str, Any]:
    import yaml

    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        return info if isinstance(info, dict) else {}
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        return {}


def _recorded_vehicle(path: Path, replay: ReplayResult) -> str | None:
    """The vehicle as the recording names it: what the reader found (a ULog's sys_uuid), or a rosbag2
    directory's metadata custom_data."""
    recording = replay.source.recording
    if recording.vehicle:
        return str(recording.vehicle)
    if path.is_dir():
        custom = _bag_metadata(path).get("custom_data") or {}
        if isinstance(custom, dict):
            for key in METADATA_VEHICLE_KEYS:
                value = custom.get(key)
                if isinstance(value, str) and value.strip():
                    return value.strip()
    return None


def _vehicle(path: Path, replay: ReplayResult | None, rule: str | None) -> tuple[str, str]:
    from ..io.history import vehicle_from_rule

    if rule:
        found = vehicle_from_rule(rule, path.as_posix())
        if found:
            return found, "rule"
    recorded = _recorded_vehicle(path, replay) if replay is not None else None
    if recorded:
        return recorded, "metadata"
    return path.parent.name, "folder"


def _start_ns(path: Path, replay: ReplayResult) -> int | None:
    """When the recording started: rosbag2's starting_time (receive clock), else the first IMU stamp."""
    if path.is_dir():
        starting = _bag_metadata(path).get("starting_time")
        if isinstance(starting, dict) and isinstance(starting.get("nanoseconds_since_epoch"), int):
            return int(starting["nanoseconds_since_epoch"])
    return replay.source.start_ns


def _replay(path: str, settings: ReplaySettings | None) -> ReplayResult:
    """Replay one recording (the same session as the node) into a ReplayResult. An autopilot log is read for
    its ground only (ReplaySettings.ground_only): the same poses as the whole log, a worker's memory bounded by
    the time on the ground, not by the hours of flight."""
    from ..bag.replay import ReplaySettings, replay_bag

    if Path(path).suffix.lower() in FLIGHT_LOG_SUFFIXES:
        settings = dataclasses.replace(settings or ReplaySettings(), ground_only=True)
    return replay_bag(path, settings)


def _line(record: HistoryRecord, name: str) -> str:
    who = f"{record.vehicle} {record.sensor or '-'} {name}"
    if record.status != "calibrated" or record.bias is None or record.scale is None:
        return f"{record.status:10s} {who}: {record.reason}"
    bias = " ".join(f"{v / MG:+.1f}" for v in record.bias)
    scale = " ".join(f"{v:.5f}" for v in record.scale)
    return (f"calibrated {who}: {record.poses} poses, rms {record.residual_rms_mg:.2f} mg, "
            f"bias {bias} mg, scale {scale}")


def calibrate_recording(path: str, settings: ReplaySettings | None = None, vehicle_rule: str | None = None,
                        given: GivenCalibration | None = None) -> RecordingOutcome:
    """Replay one recording and describe it for the history. Runs on a worker; never raises (the reason
    of any failure is the outcome's, one line), so one bad recording cannot stop a fleet. `given`: the
    calibration in force of a bag's IMU (a bag carries none; an autopilot log's is its own)."""
    from ..io.history import HistoryRecord, recording_identity

    started = time.perf_counter()
    where = Path(path)

    def outcome(status: str, reason: str | None, record: HistoryRecord | None, summary: str) -> RecordingOutcome:
        return RecordingOutcome(str(path), status, reason, record, summary, _peak_rss_mb(),
                                time.perf_counter() - started)

    try:
        recording_id, size = recording_identity(where)
    except AccelCalibrationError as error:
        return outcome("failed", str(error), None, f"failed     {path}: {error}")
    identity: dict[str, Any] = {"recording_id": recording_id, "path": str(where), "size_bytes": size,
                "package_version": _package_version()}
    replay = None
    reason: str | None
    try:
        replay = _replay(path, settings)
    except AccelCalibrationError as error:
        reason = str(error)
    except Exception as error:  # the task boundary: report, never take the fleet down
        first = str(error).splitlines()[0] if str(error) else ""
        reason = f"{path}: internal error ({type(error).__name__}: {first})"
    else:
        reason = None
    try:
        vehicle, vehicle_source = _vehicle(where, replay, vehicle_rule)
    except AccelCalibrationError as error:  # the rule over its time limit on this path
        return outcome("failed", str(error), None, f"failed     {path}: {error}")
    if replay is None:
        record = HistoryRecord(**identity, vehicle=vehicle, vehicle_source=vehicle_source, sensor="",
                               status="failed", reason=reason)
        failed = outcome("failed", reason, record, _line(record, where.name))
        if keeps_evidence(where):  # a flight log that fails is an evidence row too
            from ..io.flight_history import EvidenceRecord

            failed = dataclasses.replace(failed, evidence=EvidenceRecord(
                identity["recording_id"], str(where), vehicle, "", "failed", reason=reason))
        # A log's first IMU refused (its logged calibration invalid, say): its other IMUs still have rows.
        return dataclasses.replace(failed, others=_other_rows(path, settings, None, identity, vehicle,
                                                              vehicle_source, outcome))

    first_row = _with_evidence(_described(replay, identity, vehicle, vehicle_source, where, outcome), replay,
                               _first_instance(replay, settings), given, settings)
    return dataclasses.replace(first_row, others=_other_rows(path, settings, replay, identity, vehicle,
                                                             vehicle_source, outcome))


def _other_rows(path: str, settings: ReplaySettings | None, replay: ReplayResult | None, identity: dict[str, Any],
                vehicle: str, vehicle_source: str,
                outcome: Callable[[str, str | None, HistoryRecord | None, str], RecordingOutcome]
                ) -> tuple[RecordingOutcome, ...]:
    """The rows of an autopilot log's further IMUs: each replayed alone, one that fails with its reason."""
    from ..io.history import HistoryRecord

    where = Path(path)
    kind, others = _other_imus(path, settings, replay)
    rows: list[RecordingOutcome] = []
    for instance, other in others:
        own = {**identity, "recording_id": _imu_identity(identity["recording_id"], instance)}
        if isinstance(other, str):  # its replay failed: a row with the reason, never left out unsaid
            stream = "IMU" if kind == "dataflash" else "sensor_accel"
            record = HistoryRecord(**own, vehicle=vehicle, vehicle_source=vehicle_source,
                                   sensor=f"{stream} instance {instance}", status="failed", reason=other)
            rows.append(outcome("failed", other, record, _line(record, where.name)))
        else:
            rows.append(_with_evidence(_described(other, own, vehicle, vehicle_source, where, outcome), other,
                                       instance))
    return tuple(rows)


def _first_instance(replay: ReplayResult, settings: ReplaySettings | None) -> int | None:
    """The instance of the first row's IMU: a DataFlash log's asked one, a ULog's the sensor_accel instance
    of the device sensor_combined was fed from."""
    from ..bag.recording import Recording, log_accel_devices

    recording = replay.source.recording
    if not isinstance(recording, Recording):
        return None
    if recording.format == "dataflash":
        return (settings.instance if settings is not None else None) or 0
    try:
        devices = log_accel_devices(recording.path, recording.format)
    except AccelCalibrationError:
        return None
    return next((n for n, device in devices.items() if device == recording.accel_device_id), None)


def keeps_evidence(where: Path) -> bool:
    """A recording whose IMUs get flight evidence rows: an autopilot log, a bag (a row even when it fails)."""
    return where.suffix.lower() in FLIGHT_LOG_SUFFIXES + BAG_SUFFIXES or _is_bag_directory(where)


def _with_evidence(row: RecordingOutcome, replay: ReplayResult, instance: int | None,
                   given: GivenCalibration | None = None, settings: ReplaySettings | None = None) -> RecordingOutcome:
    """An autopilot log's or a bag's row with its IMU's flight evidence (bag/flight_evidence.py), keyed as
    the row; `settings`: the replay's (a bag's flight state is read again for its flight as they say)."""
    from ..bag.flight_evidence import evidence_of
    from ..bag.flight_evidence_bag import bag_evidence, is_bag
    from ..bag.recording import LOGS, Recording
    from ..io.flight_history import evidence_record

    recording = replay.source.recording
    log = isinstance(recording, Recording) and recording.format in LOGS
    # A bag that calibrated is a calibration session, its row the calibration: a flight is not one.
    flight_bag = is_bag(replay) and row.status != "calibrated"
    if row.record is None or not (log or flight_bag):
        return row
    try:
        evidence = bag_evidence(replay, given, settings) if flight_bag else evidence_of(replay)
    except AccelCalibrationError as error:  # its parameters unreadable: a row with the reason
        from ..bag.flight_evidence import FlightEvidence

        evidence = FlightEvidence("", 0, "", "none", reason=str(error))
    record = row.record
    return dataclasses.replace(row, evidence=evidence_record(
        evidence, record.recording_id, record.path, record.vehicle, record.sensor, instance, record.start_ns))


def _imu_identity(recording_id: str, instance: int) -> str:
    """The row key of a log's further IMU: the log's content identity and the instance, digested alike."""
    import hashlib

    return hashlib.blake2b(f"{recording_id}:imu{instance}".encode(), digest_size=32).hexdigest()


def _other_imus(path: str, settings: ReplaySettings | None, replay: ReplayResult | None
                ) -> tuple[str, list[tuple[int, ReplayResult | str]]]:
    """The log's format and each further IMU of it, replayed alone (ULog sensor_accel N, DataFlash IMU N):
    those whose device the first replay (None: it failed) did not read; one whose replay fails, with its
    reason (a row of its own)."""
    from ..bag.recording import LOGS, Recording, detect_format, log_accel_devices
    from ..bag.replay import ReplaySettings

    s = settings or ReplaySettings()
    if replay is None:
        try:
            kind = s.format or detect_format(path)
            instances = tuple(sorted(log_accel_devices(path, kind))) if kind in LOGS else ()
        except AccelCalibrationError:  # the first replay's failure says it
            return "", []
    else:
        recording = replay.source.recording
        if not isinstance(recording, Recording) or recording.format not in LOGS:
            return "", []
        kind, instances = recording.format, recording.imu_instances
    found: list[tuple[int, ReplayResult | str]] = []
    for instance in instances:
        if kind == "dataflash" and instance == (s.instance or 0):
            continue  # the first row's IMU
        try:
            other = _replay(path, dataclasses.replace(s, instance=instance))
        except AccelCalibrationError as error:
            found.append((instance, str(error)))
            continue
        # A ULog's first row is sensor_combined: the selected device, which one of these instances is.
        if kind == "dataflash" or replay is None or not other.source.same_device(replay.source):
            found.append((instance, other))
    return kind, found


def _described(replay: ReplayResult, identity: dict[str, Any], vehicle: str, vehicle_source: str, where: Path,
               outcome: Callable[[str, str | None, HistoryRecord | None, str], RecordingOutcome]
               ) -> RecordingOutcome:
    """One replay as a history row and its outcome."""
    from ..io.history import HistoryRecord

    path = str(where)
    result = replay.result
    # Refused by a gate: the fit's calibration still, kept in the history marked refused.
    calibration = replay.calibration
    if calibration is None and result is not None:
        calibration = result.calibration
    temperatures = [p.temperature_degc for p in replay.poses if p.temperature_degc is not None]
    status = "calibrated" if replay.calibration is not None else "refused"
    values: dict[str, Any] = {
        "imu_topic": replay.source.imu_topic, "frame_id": replay.source.frame_id or None,
        "start_ns": _start_ns(where, replay), "duration_s": float(replay.source.duration_s),
        "messages": int(replay.source.messages),
        "temperature_min_degc": min(temperatures) if temperatures else None,
        "temperature_max_degc": max(temperatures) if temperatures else None,
    }
    if result is not None:
        values["poses"] = int(result.poses) if result.poses else len(replay.poses)
        values["outliers"] = len(result.outliers)
        values["model"] = result.model
    if calibration is not None:  # refused by a gate: the numbers are kept, marked refused
        quality = calibration.quality
        values.update(
            model=calibration.model, gravity=calibration.gravity,
            bias=tuple(float(v) for v in calibration.bias),
            bias_sigma=None if calibration.bias_sigma is None else tuple(float(v) for v in calibration.bias_sigma),
            matrix=tuple(float(v) for v in calibration.matrix.ravel()),
            matrix_sigma=(None if calibration.matrix_sigma is None
                          else tuple(float(v) for v in calibration.matrix_sigma.ravel())),
            residual_rms_mg=None if quality is None else quality.residual_rms_mg,
            residual_max_mg=None if quality is None else quality.residual_max_mg,
            condition_number=None if quality is None else quality.condition_number,
            reference_temperature_degc=calibration.reference_temperature_degc,
            temperature_model=None if calibration.temperature is None else calibration.temperature.kind,
        )
    reason = None if status == "calibrated" else f"{path}: {replay.problem}"
    # The sensor as the recording names it: a ULog's device id, a bag's frame_id, else the stream read.
    sensor = replay.source.sensor_id or replay.source.frame_id or replay.source.imu_topic
    record = HistoryRecord(**identity, vehicle=vehicle, vehicle_source=vehicle_source, sensor=sensor,
                           status=status, reason=reason, **values)
    return outcome(status, reason, record, _line(record, where.name))


# --- many recordings: tasks of a few each, a lost worker's recordings failed rows all the same ---------------

TASK_RECORDINGS = 8  # recordings per task at most


def calibrate_recordings(paths: Sequence[str], settings: ReplaySettings | None = None,
                         vehicle_rule: str | None = None, given: GivenCalibration | None = None
                         ) -> list[RecordingOutcome]:
    """A few recordings in one task (calibrate_recording of each): a flight log's replay is a fraction of
    a second, and the scheduler's and the client's work per task runs on the cores the workers use."""
    return [calibrate_recording(path, settings, vehicle_rule, given) for path in paths]


def task_batches(count: int, slots: int) -> list[range]:
    """Which recordings each task takes: up to TASK_RECORDINGS, and at least four tasks per worker thread,
    so that the last tasks, finishing while others idle, are short."""
    size = max(1, min(TASK_RECORDINGS, count // (4 * max(1, slots))))
    return [range(i, min(i + size, count)) for i in range(0, count, size)]


def lost_recording(path: str, reason: str, vehicle_rule: str | None) -> RecordingOutcome:
    """A recording whose worker was lost (killed, out of memory): a failed row with the reason all the same,
    identified here (its content and vehicle), so a rerun that reads it updates that row."""
    from ..io.flight_history import EvidenceRecord
    from ..io.history import HistoryRecord, recording_identity

    where = Path(path)
    try:
        recording_id, size = recording_identity(where)
        vehicle, vehicle_source = _vehicle(where, None, vehicle_rule)
    except AccelCalibrationError as error:
        said = f"{reason}; {error}"
        return RecordingOutcome(path, "failed", said, None, f"failed     {said}", None, 0.0)
    record = HistoryRecord(recording_id=recording_id, path=str(where), size_bytes=size,
                           package_version=_package_version(), vehicle=vehicle, vehicle_source=vehicle_source,
                           sensor="", status="failed", reason=reason)
    evidence = None
    if keeps_evidence(where):
        evidence = EvidenceRecord(recording_id, str(where), vehicle, "", "failed", reason=reason)
    return RecordingOutcome(path, "failed", reason, record, _line(record, where.name), None, 0.0, evidence=evidence)


def _outcomes(client: Any, recordings: list[str], settings: ReplaySettings, vehicle_rule: str | None, slots: int,
              given: GivenCalibration | None) -> Iterator[RecordingOutcome]:
    """Every recording's outcome, as its task finishes. A task whose worker was lost is run again a recording
    a task, so that one recording that kills its worker cannot take the others of its batch with it."""
    batches = task_batches(len(recordings), slots)
    jobs = [([recordings[i] for i in batch], settings, vehicle_rule, given) for batch in batches]
    again: list[int] = []
    for k, outcomes, error in run_tasks(client, calibrate_recordings, jobs, sizes=[len(b) for b in batches]):
        if error is None:
            yield from outcomes
        elif len(batches[k]) > 1:
            again.extend(batches[k])
        else:
            path = recordings[batches[k][0]]
            yield lost_recording(path, f"{path}: worker lost ({error})", vehicle_rule)
    alone = [(recordings[i], settings, vehicle_rule, given) for i in again]
    for k, outcome, error in run_tasks(client, calibrate_recording, alone):
        path = alone[k][0]
        yield outcome if error is None else lost_recording(path, f"{path}: worker lost ({error})", vehicle_rule)


# --- the command -----------------------------------------------------------------------------------------

def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "fleet", help="recalibrate many recordings on a Dask cluster into the calibration history",
        description="Replay every recording (rosbag2 directories; .mcap, .db3, .ulg, .csv files; directories "
                    "are searched) on a Dask cluster and write one row per recording into the calibration "
                    "history. Exit code 0 when every recording calibrated, 1 when some were refused or failed "
                    "(each named on stderr in one line).")
    parser.add_argument("recordings", nargs="+", metavar="RECORDING_OR_DIR")
    parser.add_argument("--history", default=DEFAULT_HISTORY,
                        help=f"history database: a SQLite file (default {DEFAULT_HISTORY}) or a SQLAlchemy URL, "
                             "e.g. postgresql://user@host/calibrations")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None,
                       help="local cluster of this many worker processes (default: one per core)")
    where.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                       help="join an existing Dask cluster instead (its workers must see the same paths)")
    parser.add_argument("--vehicle", default=None, metavar="REGEX",
                        help="rule mapping a recording's path to its vehicle, e.g. '/fleet/(?P<vehicle>[^/]+)/' "
                             "(named group 'vehicle', else the first group, else the match; default: the "
                             "recording's metadata, else the folder holding it)")
    add_settings_options(parser, detector=False)
    parser.add_argument("--calibration", default=None, metavar="CAL.yaml",
                        help="the calibration in force of the bags' IMU, which a bag does not carry: their still "
                             "moments are checked against it (default: against the nominal sensor); an autopilot "
                             "log's is read from the log")
    add_warmup_arguments(parser)  # fleet --warmup -o DIR: cli/fleet_warmups.py
    return parser


def _given_calibration(path: str | None) -> GivenCalibration | None:
    """fleet --calibration: loaded before any work (a bad file is one line, nothing run)."""
    if path is None:
        return None
    from ..bag.flight_evidence_bag import GivenCalibration
    from ..io.calibration_file import load_calibration

    return GivenCalibration(load_calibration(path), str(Path(path).expanduser().resolve()))


def run(args: argparse.Namespace) -> int:
    from ..core.text import printable_text
    from ..io.history import open_history, vehicle_from_rule

    if warmup_requested(args):  # the logs' warm-ups pooled per vehicle and IMU, no history rows
        from .fleet_warmups import run_warmups

        return run_warmups(args, find_recordings, _vehicle)
    if args.workers is not None and args.workers < 1:
        raise CalibrationError(f"--workers must be at least 1, got {args.workers}")
    settings = replay_settings(args)
    given = _given_calibration(args.calibration)
    recordings, problems = find_recordings(args.recordings)
    if args.vehicle is not None:  # the rule tried on every path here, before any work (each within a time limit)
        for path in recordings:
            vehicle_from_rule(args.vehicle, Path(path).as_posix())
    for problem in problems:
        print(f"accel-calib: error: {printable_text(problem)}", file=sys.stderr)
    if not recordings:
        raise FleetError("no recordings to calibrate")
    started = time.perf_counter()
    with open_history(args.history) as history:
        workers = None if args.scheduler else min(args.workers or default_workers(), len(recordings))
        writer = HistoryWriter(history)
        with dask_client(workers=workers, scheduler=args.scheduler) as client:
            cores = sum(client.nthreads().values()) or 1
            for task_outcome in _outcomes(client, recordings, settings, args.vehicle, cores, given):
                for outcome in (task_outcome, *task_outcome.others):  # an autopilot log: a row per IMU
                    writer.add(outcome)
        writer.flush()
    counts, rows = writer.counts, writer.rows
    elapsed = time.perf_counter() - started
    per_minute = 60.0 * len(recordings) / elapsed if elapsed > 0 else float("inf")
    shared = sum(len(paths) - 1 for paths in rows.values())
    same = f" ({shared} recording{'s' if shared != 1 else ''} with the content of another: one row each)" \
        if shared else ""
    total = counts["calibrated"] + counts["refused"] + counts["failed"]
    sensors = f" ({total} sensors: a row per IMU of an autopilot log)" if total != len(recordings) else ""
    print(f"{len(recordings)} recordings{sensors}: {counts['calibrated']} calibrated, {counts['refused']} refused, "
          f"{counts['failed']} failed; {len(rows)} row{'s' if len(rows) != 1 else ''} written{same} "
          f"to {history.name}; {elapsed:.1f} s "
          f"({per_minute:.1f} recordings/min on {cores} worker thread{'s' if cores != 1 else ''})")
    if counts["evidence"] or counts["no evidence"]:
        print(f"flight evidence: {counts['evidence'] + counts['no evidence']} IMU rows, {counts['evidence']} with "
              f"evidence from the still moments on the ground, {counts['no evidence']} without; in flight, "
              f"{counts['estimator']} with the filter's settled bias, {counts['agreement']} with "
              "their agreement with their siblings (see 'accel-calib history')")
    return 0 if counts["calibrated"] == total and not problems else 1
