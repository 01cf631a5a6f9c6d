"""One entry for every recording people have: a rosbag2 directory, a single .mcap or .db3 file, a PX4
ULog, an ArduPilot DataFlash log, a CSV stream of raw samples. `open_recording` finds the format (from
the path and content, or as named) and gives the same sample arrays whatever it was, for the same
calibration session as the node (`replay.replay_recording`); corrected_copy.py writes a corrected copy
in the input's own format.
"""
from __future__ import annotations

import dataclasses
import itertools
import os
import sys
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .bag_io import IMU, TEMPERATURE, BagError

if TYPE_CHECKING:
    from ..core.flight_state import FlightState
    from .bag_io import TopicInfo, TopicLike, TopicT
    from .csv_stream import CsvLayout
    from .dataflash import AutopilotCalibration, DataflashSamples
    from .imu_messages import ImuData, Temperatures
    from .logged_correction import LoggedCorrection
    from .mcap_scan import PackedMessages
    from .progress import ClosableProgressBar
    from .ulog_reader import UlogSamples

    Groups = Iterator[dict[str, PackedMessages]]

FORMATS = ("rosbag2", "mcap", "sqlite3", "ulog", "dataflash", "csv")
KNOWN = ("rosbag2 (a bag directory), mcap (a .mcap file), sqlite3 (a .db3 file), ulog (a PX4 .ulg log), "
         "dataflash (an ArduPilot .bin log), csv (raw samples with a header t,ax,ay,az)")
BAGS = ("rosbag2", "mcap", "sqlite3")
STREAM_GROUP_MESSAGES = 1 << 14  # messages read from a streamed bag at a time (the results do not depend on
# it): a group in cache is faster to decode and feed than a large one (0.25 s against 0.30 s for 155k)
_MAGIC = {b"ULog\x01\x12\x35": "ulog", b"\x89MCAP": "mcap", b"SQLite format 3\x00": "sqlite3",
          b"\xa3\x95\x80": "dataflash"}
_SUFFIX = {".ulg": "ulog", ".mcap": "mcap", ".db3": "sqlite3", ".csv": "csv", ".txt": "csv", ".tsv": "csv"}
# A DataFlash .bin is known by its first FMT record (the magic above); ".bin" alone says nothing.


class RecordingError(BagError):
    """A recording that cannot be read as asked: one line naming the file and what to do."""


@dataclass
class Recording:
    """A recording as the session takes it: SI units, stamps in ns in the order recorded."""

    path: str
    format: str  # one of FORMATS
    stream: str  # what was read: an Imu topic, "sensor_combined", "ax,ay,az (g) at t", ...
    t_ns: np.ndarray  # int64
    accel_mps2: np.ndarray  # (N, 3)
    gyro_radps: np.ndarray | None  # (N, 3); None when the recording has no gyro
    temperature: tuple[np.ndarray, np.ndarray] | None  # (stamps ns, degC), held and filtered by the session
    temperature_stream: str | None
    frame_id: str = ""
    sensor_id: str = ""
    vehicle: str = ""  # the vehicle the recording names (a ULog's sys_uuid), "" when it does not
    source: CsvLayout | None = None  # what writing a corrected copy needs: a CSV's layout
    flight_state: FlightState | None = None  # what a log carries (ULog, DataFlash); None: none read
    autopilot_calibration: AutopilotCalibration | None = None  # in force while logging (DataFlash)
    # What the samples are: raw sensor output, a log's corrected stream with its correction undone, or a
    # corrected stream as logged (then a calibration goes on top of the one in force); "" for a bag or CSV.
    fitted_to: str = ""
    logged_correction: LoggedCorrection | None = None  # the correction undone (a log's own parameters)
    imu_instances: tuple[int, ...] = ()  # a log's IMU instances (ULog sensor_accel, DataFlash IMU), when read
    accel_device_id: int | None = None  # the device IDs of the accelerometer and gyro read, where a log says them
    gyro_device_id: int | None = None
    # A log read for its ground only (open_recording's ground_margin_s): the samples of the stream in the whole
    # log and their first and last stamps (ns), for saying what was read; None where every sample was kept.
    samples_read: int | None = None
    first_last_ns: tuple[int, int] | None = None

    @property
    def unit(self) -> str:
        """What one element of the stream is called when counting them."""
        return "messages" if self.format in BAGS else "samples"


def detect_format(path: str | os.PathLike[str]) -> str:
    """The format of `path` from its content (magic bytes), else its suffix, else text that looks like CSV."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such bag or file")
    if path.is_dir():
        if (path / "metadata.yaml").exists() or any(path.glob("*.mcap")) or any(path.glob("*.db3")):
            return "rosbag2"
        raise RecordingError(f"{path}: a directory but no rosbag2 (no metadata.yaml, .mcap or .db3 in it); "
                             f"known formats: {KNOWN}")
    _regular_file(path)
    try:
        with open(path, "rb") as stream:
            head = stream.read(4096)
    except OSError as error:
        raise RecordingError(f"{path}: cannot read ({error.strerror})") from None
    for magic, name in _MAGIC.items():
        if head.startswith(magic):
            return name
    by_suffix = _SUFFIX.get(path.suffix.lower())
    if by_suffix is not None:
        return by_suffix
    first_line = head.split(b"\n", 1)[0]
    if head and b"\x00" not in head and any(d in first_line for d in (b",", b";", b"\t")):
        try:
            first_line.decode("utf-8-sig")
            return "csv"
        except UnicodeDecodeError:
            pass
    raise RecordingError(f"{path}: unknown recording format; known: {KNOWN} (or name one with --format)")


def _regular_file(path: Path) -> None:
    if not path.exists():
        raise RecordingError(f"{path}: no such bag or file")
    if not path.is_file():  # a FIFO or a device would block a read, or never end
        raise RecordingError(f"{path}: not a regular file (a directory, FIFO, device or socket): not a "
                             "recording of this format")


def open_recording(path: str | os.PathLike[str], format: str | None = None, *, imu_topic: str | None = None,
                   temperature_topic: str | None = None, instance: int | None = None, time_unit: str | None = None,
                   units: str | None = None, counts_per_g: float | None = None, progress: bool = False,
                   through_rosbags: bool = False, ground_margin_s: float | None = None) -> Recording:
    """The recording at `path` as sample arrays. Options that do not apply to its format are refused
    (one line), not ignored. `through_rosbags`: read a bag with rosbags' reader, message by message, instead
    of its storage directly. `ground_margin_s`: of an autopilot log keep only the samples on the ground and
    next to its flights (FlightState.ground_kept; what the still moments need, memory bounded by the time on
    the ground); other recordings are read as they are."""
    if format is not None and format not in FORMATS:
        raise RecordingError(f"--format {format!r} is not a known format; known: {KNOWN}")
    kind = format or detect_format(path)
    given = {"--imu-topic": imu_topic, "--temperature-topic": temperature_topic, "--instance": instance,
             "--time-unit": time_unit, "--units": units, "--counts-per-g": counts_per_g}
    applies = {"ulog": ("--instance",), "dataflash": ("--instance",),
               "csv": ("--time-unit", "--units", "--counts-per-g")}.get(
        kind, ("--imu-topic", "--temperature-topic"))
    stray = [flag for flag, value in given.items() if value is not None and flag not in applies]
    if stray:
        raise RecordingError(f"{path}: {stray[0]} does not apply to a {kind} recording (it applies to "
                             f"{_where(stray[0])})")
    if kind != "rosbag2":
        _regular_file(Path(path))
    if kind in BAGS:
        return _read_bag(path, kind, imu_topic, temperature_topic, progress, through_rosbags)
    if kind in LOGS:
        return _read_log(path, kind, instance, progress, ground_margin_s)
    return _read_csv(path, time_unit, units or "mps2", counts_per_g, progress)


@dataclass
class BagStream:
    """A bag read a group of messages at a time (the fast path's storage reads, streamed): `pieces()`
    yields (IMU (stamps ns, accel, gyro) or None, temperature (stamps ns, degC) or None) per group, in
    the order the whole read gives. Raises mcap_scan.NotStreamable where streaming cannot give what the
    whole read gives (the caller reads it whole)."""

    path: str
    format: str
    stream: str  # the Imu topic
    temperature_stream: str | None
    expected_messages: int  # the IMU count the topic list declares
    groups: Groups  # iterator of {topic: PackedMessages}
    recorded: dict[str, tuple[str, str, str]]  # {topic: (type, encoding, definition)} as the storage records them
    frame_id: str = ""
    messages: int = 0
    unit: str = "messages"
    sensor_id: str = ""
    vehicle: str = ""  # a bag names its vehicle in its metadata (cli/fleet.py reads it), not in its messages

    def pieces(self) -> Iterator[tuple[tuple[np.ndarray, np.ndarray, np.ndarray] | None, Temperatures | None]]:
        from .bag_io import TopicInfo, check_recorded_types, is_standard_definition, jazzy_deserialize
        from .imu_messages import decode_imus, decode_temperatures
        from .mcap_scan import NotStreamable

        deserialize = jazzy_deserialize
        wanted = [TopicInfo(self.stream, IMU, self.expected_messages)]
        if self.temperature_stream:
            wanted.append(TopicInfo(self.temperature_stream, TEMPERATURE, 0))
        for group in self.groups:
            check_recorded_types(self.path, wanted, self.recorded)
            if not all(is_standard_definition(topic, self.recorded) for topic in wanted):
                raise NotStreamable("another message definition: read through it")
            imu = None
            raws = group[self.stream]
            if len(raws):
                t, accel, gyro, frame_id, *_ = decode_imus(raws, self.path, deserialize)
                self.frame_id = self.frame_id or frame_id
                self.messages += len(t)
                imu = (t, accel, gyro)
            temperatures = None
            if self.temperature_stream and len(group[self.temperature_stream]):
                raws = group[self.temperature_stream]
                temperatures = decode_temperatures(raws, self.path, deserialize)
            yield imu, temperatures
        if self.messages != self.expected_messages:
            raise NotStreamable(f"{self.messages} IMU messages, the bag declares {self.expected_messages}")


def stream_bag(path: str | os.PathLike[str], format: str | None = None, *, imu_topic: str | None = None,
               temperature_topic: str | None = None, progress: bool = False, **other: object) -> BagStream | None:
    """A bag (rosbag2 directory, .mcap or .db3 file) to stream, when its storage can be read directly
    with standard definitions; None for anything else (open_recording reads it whole, or says what is
    wrong, in one line)."""
    from .bag_io import declares_other_definition, metadata_topics, refuse_special_files, storage_of, stream_sqlite
    from .mcap_scan import stream_topics

    other.pop("ground_margin_s", None)  # of autopilot logs only: a bag is streamed whole
    if any(value is not None for value in other.values()):
        return None  # options of other formats: open_recording refuses them in one line
    if format is not None and format not in BAGS:
        return None
    try:
        kind = format or detect_format(path)
    except RecordingError:
        return None
    if kind not in BAGS or (kind == "rosbag2") != Path(path).is_dir():
        return None
    refuse_special_files(path)
    infos = metadata_topics(path) if kind == "rosbag2" else _file_topics(path)
    if infos is None:
        return None
    imu, temperature = _chosen_topics(path, infos, imu_topic, temperature_topic)
    wanted = [imu] + ([temperature] if temperature else [])
    if declares_other_definition(wanted):
        return None
    topics = [topic.topic for topic in wanted]
    bar = _bar(path, imu.msgcount + (temperature.msgcount if temperature else 0), "msg", progress)
    recorded: dict[str, tuple[str, str, str]] = {}
    if storage_of(path) == "mcap":
        groups = stream_topics(path, topics, bar, STREAM_GROUP_MESSAGES, schemas=recorded)
    else:
        from .bag_io import recorded_definitions

        recorded = recorded_definitions(path) or {}
        groups = stream_sqlite(path, topics, bar, STREAM_GROUP_MESSAGES)
    return BagStream(str(path), kind, imu.topic, temperature.topic if temperature else None, int(imu.msgcount),
                     _closing(groups, bar), recorded)


def _closing(groups: Groups, bar: ClosableProgressBar | None) -> Groups:
    """The groups, then the progress bar closed (also when the reader stops early)."""
    try:
        yield from groups
    finally:
        if bar is not None:
            bar.close()


def _where(flag: str) -> str:
    if flag == "--instance":
        return "PX4 ULog and ArduPilot DataFlash logs"
    if flag in ("--imu-topic", "--temperature-topic"):
        return "bags"
    return "CSV streams"


def _bar(path: str | os.PathLike[str], total: int | None, unit: str, progress: bool) -> ClosableProgressBar | None:
    if not progress or not sys.stderr.isatty():  # tqdm would draw nothing (disable=None); not imported
        return None
    from tqdm import tqdm

    bar: ClosableProgressBar = tqdm(total=total, unit=unit, unit_scale=unit == "B", desc=Path(path).name,
                                    leave=False, disable=None)
    return bar


def _read_bag(path: str | os.PathLike[str], kind: str, imu_topic: str | None, temperature_topic: str | None,
              progress: bool, through_rosbags: bool) -> Recording:
    from .bag_io import metadata_topics

    if kind == "rosbag2" and not Path(path).is_dir():
        raise RecordingError(f"{path}: not a directory; a single storage file is --format mcap or sqlite3")
    loaded = None
    if not through_rosbags:
        # Storage read directly; topics from metadata.yaml (a directory) or rosbags' reader (one file).
        infos = metadata_topics(path) if kind == "rosbag2" else _file_topics(path)
        if infos is not None:
            loaded = _read_fast(path, infos, imu_topic, temperature_topic, progress)
    if loaded is None:  # anything unexpected: rosbags, message by message
        loaded = _read_with_rosbags(path, imu_topic, temperature_topic, progress)
    imu, temperatures, temperature_name = loaded
    return Recording(str(path), kind, imu.topic, imu.t_ns, imu.accel, imu.gyro, temperatures, temperature_name,
                     frame_id=imu.frame_id)


def _no_imu(path: str | os.PathLike[str], connections: Iterable[TopicLike]) -> RecordingError:
    have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in connections})) or "no topics"
    return RecordingError(f"{path}: no sensor_msgs/msg/Imu topic; the bag has {have}")


def _file_topics(path: str | os.PathLike[str]) -> list[TopicInfo]:
    from .bag_io import TopicInfo, open_reader, storage_of
    from .mcap_scan import summary_topics

    if storage_of(path) == "mcap":  # the file's own summary: no rosbags reader to import and open
        listed = summary_topics(path)
        if listed is not None:
            return [TopicInfo(topic, msgtype, count) for topic, msgtype, count in listed]
    reader = open_reader(path)
    try:
        return [TopicInfo(c.topic, c.msgtype, int(c.msgcount)) for c in reader.connections]
    finally:
        reader.close()


def _chosen_topics(path: str | os.PathLike[str], topics: Sequence[TopicT], imu_name: str | None,
                   temperature_name: str | None) -> tuple[TopicT, TopicT | None]:
    """(the Imu topic, the Temperature topic or None) among a bag's `topics` (TopicInfo or rosbags
    connections), as asked or the only one of its type; no Imu topic is one line naming what the bag has."""
    from .bag_io import choose_topic

    imu = choose_topic(topics, IMU, imu_name, "imu", path)
    if imu is None:
        raise _no_imu(path, topics)
    return imu, choose_topic(topics, TEMPERATURE, temperature_name, "temperature", path)


def _read_fast(path: str | os.PathLike[str], infos: Sequence[TopicInfo], imu_name: str | None,
               temperature_name: str | None, progress: bool) -> tuple[ImuData, Temperatures | None, str | None] | None:
    """Messages straight from the storage; None when that cannot be trusted (rosbags then)."""
    from .imu_messages import read_fast

    imu_topic, temperature_topic = _chosen_topics(path, infos, imu_name, temperature_name)
    bar = _bar(path, imu_topic.msgcount + (temperature_topic.msgcount if temperature_topic else 0), "msg", progress)
    try:
        read = read_fast(path, imu_topic, temperature_topic, bar)
    finally:
        if bar is not None:
            bar.close()
    if read is None:
        return None
    return read[0], read[1], temperature_topic.topic if temperature_topic else None


def _read_with_rosbags(path: str | os.PathLike[str], imu_name: str | None, temperature_name: str | None,
                       progress: bool) -> tuple[ImuData, Temperatures | None, str | None]:
    from .bag_io import open_reader
    from .imu_messages import read_imu_and_temperature

    reader = open_reader(path)
    try:
        imu_connection, temperature_connection = _chosen_topics(path, reader.connections, imu_name, temperature_name)
        total = imu_connection.msgcount + (temperature_connection.msgcount if temperature_connection else 0)
        bar = _bar(path, total, "msg", progress)
        try:
            imu, temperatures = read_imu_and_temperature(reader, imu_connection, temperature_connection, path, bar)
        finally:
            if bar is not None:
                bar.close()
    finally:
        reader.close()
    return imu, temperatures, temperature_connection.topic if temperature_connection else None


def _read_log(path: str | os.PathLike[str], kind: str, instance: int | None, progress: bool,
              ground_margin_s: float | None = None) -> Recording:
    """An autopilot log (ULog, DataFlash) read whole, or for its ground (`ground_margin_s`): kept by the log's
    pass (ulog_pass.py, dataflash_pass.py), or, where its ground is more than a pass keeps (it never flew, or
    flew a minute of an hour), streamed a block at a time (StreamedLog)."""
    from . import dataflash, dataflash_pass, ulog_pass, ulog_reader

    readers: dict[str, tuple[Any, Any, Callable[..., Recording]]] = {
        "ulog": (ulog_pass, ulog_reader.read_ulog, _ulog_recording),
        "dataflash": (dataflash_pass, dataflash.read_dataflash, _dataflash_recording)}
    log_pass, read_whole, as_recording = readers[kind]
    if instance is not None and (isinstance(instance, bool) or not isinstance(instance, int) or instance < 0):
        raise RecordingError(f"{path}: --instance must be a non-negative integer, got {instance!r}")
    bar = _bar(path, _size(path), "B", progress)
    try:
        log = None if ground_margin_s is None else log_pass.ground_samples(path, instance, ground_margin_s, bar)
        if log is None and ground_margin_s is not None:
            blocks = log_pass.streamed_samples(path, instance, ground_margin_s)
            if blocks is not None:
                return _streamed(path, kind, (as_recording(path, block) for block in blocks))
        if log is None:
            log = read_whole(path, instance, bar)
    finally:
        if bar is not None:
            bar.close()
    return as_recording(path, log)


def _ulog_recording(path: str | os.PathLike[str], log: UlogSamples) -> Recording:
    """A ULog's samples as the session takes them: a corrected stream's correction undone (raw_or_said)."""
    from .logged_correction import raw_or_said

    accel, gyro = log.accel_mps2, log.gyro_radps
    if log.raw:
        fitted_to = f"raw: {log.stream}" + (f" ({log.sensor_id})" if log.sensor_id else "") + "; sensor axes"
    else:
        temperature_at_samples = None
        if log.temperature is not None and len(log.temperature[0]):
            order = np.argsort(log.temperature[0], kind="stable")
            temperature_at_samples = np.interp(log.t_ns, log.temperature[0][order], log.temperature[1][order])
        accel, gyro, fitted_to = raw_or_said(log.logged_correction, accel, gyro, temperature_at_samples, log.stream,
                                             str(path), "CAL_ACCn parameters for the selected sensor")
    return Recording(str(path), "ulog", log.stream, log.t_ns, accel, gyro, log.temperature,
                     log.temperature_stream, sensor_id=log.sensor_id, vehicle=log.vehicle,
                     flight_state=log.flight_state, fitted_to=fitted_to, logged_correction=log.logged_correction,
                     imu_instances=log.imu_instances, accel_device_id=log.accel_device_id,
                     gyro_device_id=log.gyro_device_id, samples_read=log.samples_read, first_last_ns=log.first_last_ns)


@dataclass
class StreamedLog(Recording):
    """An autopilot log that never flew, read for its ground (the fleet's reads): every sample is needed, so
    `blocks` gives them a block at a time, each a Recording of its samples as the session takes them, for
    replay to feed the session (replay._replay_stream), never the whole log at once. Its own arrays are the
    first block's only: enough for what looks at the output's grid (core/quantisation.py)."""

    blocks: Iterator[Recording] | None = None

    def pieces(self) -> Iterator[tuple[tuple[np.ndarray, np.ndarray, np.ndarray] | None, Temperatures | None]]:
        """As BagStream.pieces: (IMU (stamps ns, accel, gyro), temperature readings) per block, the first block's
        (these arrays) first."""
        for block in itertools.chain([self], self.blocks or ()):
            gyro = block.gyro_radps if block.gyro_radps is not None else np.zeros_like(block.accel_mps2)
            yield (block.t_ns, block.accel_mps2, gyro), block.temperature


def _streamed(path: str | os.PathLike[str], kind: str, blocks: Iterator[Recording]) -> Recording:
    """The log's first block as a StreamedLog whose `blocks` give the rest; a log of no block, its whole read's
    word (by the caller's reader: here an empty first block is read whole)."""
    first = next(blocks, None)
    if first is None:
        raise RecordingError(f"{path}: no samples of this IMU in the {kind} log")
    fields = {f.name: getattr(first, f.name) for f in dataclasses.fields(Recording)}
    return StreamedLog(**fields, blocks=blocks)


def _dataflash_recording(path: str | os.PathLike[str], log: DataflashSamples) -> Recording:
    """A DataFlash log's samples as the session takes them: the logged correction undone (raw_or_said)."""
    from .logged_correction import raw_or_said

    temperature_at_samples = None if log.temperature is None else log.temperature[1]  # T of each IMU record
    accel, gyro, fitted_to = raw_or_said(log.logged_correction, log.accel_mps2, log.gyro_radps, temperature_at_samples,
                                         f"DataFlash {log.stream}", str(path), "INS_ACC*OFFS/SCAL PARM records")
    return Recording(str(path), "dataflash", log.stream, log.t_ns, accel, gyro, log.temperature,
                     log.temperature_stream, sensor_id=log.sensor_id, flight_state=log.flight_state,
                     autopilot_calibration=log.autopilot_calibration, fitted_to=fitted_to,
                     logged_correction=log.logged_correction, imu_instances=log.imu_instances,
                     accel_device_id=log.accel_device_id, gyro_device_id=log.gyro_device_id,
                     samples_read=log.samples_read, first_last_ns=log.first_last_ns)


LOGS = ("ulog", "dataflash")  # the formats with IMU instances (--instance)


def log_accel_devices(path: str | os.PathLike[str], format: str | None = None) -> dict[int, int | None]:
    """{IMU instance: its accelerometer's device ID, None where the log names none} of an autopilot log (ULog
    sensor_accel instances, DataFlash IMU instances); {} for any other recording."""
    kind = format or detect_format(path)
    if kind not in LOGS:
        return {}
    _regular_file(Path(path))
    if kind == "ulog":
        from .ulog_pass import cached_devices
        from .ulog_reader import accel_devices

        return cached_devices(path) or accel_devices(path)  # the fleet's pass of this log says it
    from .dataflash import accel_devices as dataflash_devices
    from .dataflash_pass import cached_devices as cached_dataflash_devices

    found = cached_dataflash_devices(path)  # the fleet's pass of this log says it
    return dataflash_devices(path) if found is None else found


def _read_csv(path: str | os.PathLike[str], time_unit: str | None, units: str, counts_per_g: float | None,
              progress: bool) -> Recording:
    from .csv_stream import read_csv_stream

    bar = _bar(path, _size(path), "B", progress)
    try:
        samples = read_csv_stream(path, time_unit=time_unit, units=units, counts_per_g=counts_per_g, progress=bar)
    finally:
        if bar is not None:
            bar.close()
    temperature_stream = "temperature column" if samples.temperature is not None else None
    return Recording(str(path), "csv", samples.stream, samples.t_ns, samples.accel_mps2, samples.gyro_radps,
                     samples.temperature, temperature_stream, source=samples.layout)


def _size(path: str | os.PathLike[str]) -> int | None:
    try:
        return os.path.getsize(path)
    except OSError:
        return None
