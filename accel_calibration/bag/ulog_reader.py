"""PX4 ULog flight logs as sample arrays for the calibration session, read with pyulog.

Two sources in a log:
- `sensor_combined` (default): the estimator's IMU stream, accel in m/s^2 at `timestamp` +
  `accelerometer_timestamp_relative` (us), gyro in rad/s. Its temperature is the `temperature` field of
  the `sensor_accel` instance that `sensor_selection` names as the one feeding it (when logged).
- `sensor_accel` / `sensor_gyro` of one IMU (`instance=N`): accel at `timestamp_sample`, its gyro
  interpolated to those stamps, the instance's `temperature` field as its temperature stream. The gyro is
  paired with the accelerometer by device, not by instance number (paired_gyro): a gyro of its own die (BMI055,
  BMI088) has an ID of its own, and the uORB instances of accelerometers and gyros need not line up.

Errors are `UlogError` (one line naming the file); pyulog's own prints are kept off stdout.
A log cut short mid-record (power lost while logging) is refused: pyulog would stop there without a word.

`write_ulog` writes a minimal ULog (tests, benchmarks, turning arrays into a log).
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import struct
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from .bag_io import BagError, read_head
from .logged_correction import LoggedCorrection, px4_correction

if TYPE_CHECKING:
    from ..core.flight_state import FlightState
    from .progress import ProgressBar

# pyulog ships no type information: a ULog and its datasets are Any here; a dataset's `data` is
# {field name: array}.
_Fields = Mapping[str, np.ndarray]


MAGIC = b"ULog\x01\x12\x35"
RELATIVE_TIMESTAMP_INVALID = 0x7FFFFFFF  # PX4: this sensor had no new sample in the message
COMBINED = "sensor_combined"
ACCEL, GYRO, SELECTION = "sensor_accel", "sensor_gyro", "sensor_selection"
VEHICLE_IMU = "vehicle_imu"  # PX4's pairing of an accelerometer and a gyro (accel_device_id, gyro_device_id)


class UlogError(BagError):
    """A ULog that cannot give accelerometer samples: the message names the file and what was found."""


@dataclass
class UlogSamples:
    """What a log gives the session (SI units; stamps in ns of the log's clock, in logged order)."""

    stream: str  # "sensor_combined" or "sensor_accel instance N"
    t_ns: np.ndarray
    accel_mps2: np.ndarray  # (N, 3)
    gyro_radps: np.ndarray | None  # (N, 3)
    temperature: tuple[np.ndarray, np.ndarray] | None  # (stamps ns, degC)
    temperature_stream: str | None
    sensor_id: str  # "px4 device <id>" when the log says which device
    flight_state: FlightState | None = None  # armed or airborne (flight_sources)
    vehicle: str = ""  # the flight controller the log names (logged_vehicle), "" when it does not
    # sensor_combined is corrected: PX4's correction of the selected sensor from the log's parameters (None:
    # the log holds none for it); `raw` says the stream is a sensor's own output (sensor_accel).
    logged_correction: LoggedCorrection | None = None
    raw: bool = False
    imu_instances: tuple[int, ...] = ()  # the sensor_accel instances the log holds (read with instance=N)
    accel_device_id: int | None = None  # the device IDs of what was read, where the log says them
    gyro_device_id: int | None = None
    # A read of the ground only (ulog_pass.ground_samples): the samples the whole log holds and their first and
    # last stamps (ns); None where every sample was kept.
    samples_read: int | None = None
    first_last_ns: tuple[int, int] | None = None


def read_ulog(path: str | os.PathLike[str], instance: int | None = None, progress: ProgressBar | None = None
              ) -> UlogSamples:
    """`progress`: a tqdm bar counting bytes read. (A read of the ground only, a block at a time: ulog_pass.py.)"""
    from .flight_sources import ULOG_TOPICS

    path = Path(path)
    topics = [COMBINED, ACCEL, SELECTION] if instance is None else [ACCEL, GYRO, VEHICLE_IMU]
    return samples_of_log(path, _load(path, topics + list(ULOG_TOPICS), progress), instance)


def samples_of_log(path: Path, log: Any, instance: int | None) -> UlogSamples:
    """The samples of sensor_combined (`instance` None) or of sensor_accel `instance`, from a log read with
    their topics and the flight state's (pyulog's, or its datasets as ulog_pass.py keeps them)."""
    from .flight_sources import ulog_flight_state

    samples = _from_combined(path, log) if instance is None else _from_instance(path, log, instance)
    samples.flight_state = ulog_flight_state(log)
    samples.vehicle = logged_vehicle(log.msg_info_dict)
    return samples


def topic_blocks(path: str | os.PathLike[str], names: set[str]) -> Iterator[list[tuple[Any, dict[str, np.ndarray]]]]:
    """Every instance of the topics `names`, a block of the file at a time (ulog_stream.stream_topics); a log
    that cannot be streamed, whole through pyulog as one block. One UlogError line for a log cut short."""
    from .ulog_stream import Corrupt, CutShort, NotStreamable, Subscription, stream_topics

    path = Path(path)
    _check_definitions(path)
    try:
        yield from stream_topics(path, names)
    except NotStreamable:
        log = _load(path, sorted(names))
        yield [(Subscription(d.name, d.multi_id, len(d.data["timestamp"])), d.data) for d in log.data_list
               if d.name in names]
    except CutShort:
        raise UlogError(_truncation(path)) from None
    except Corrupt as error:
        raise UlogError(f"{path}: {error}") from None
    except OSError as error:
        raise UlogError(f"{path}: cannot read ({error.strerror or error})") from None


@dataclass
class _Dataset:
    """A topic instance's rows as pyulog gives them (name, multi_id, {field: values})."""

    name: str
    multi_id: int
    data: dict[str, np.ndarray]


def accel_devices(path: str | os.PathLike[str]) -> dict[int, int | None]:
    """{sensor_accel instance: its device ID, None where not logged} of the log: which IMUs it holds (the first
    row of each instance, the log read a block at a time)."""
    devices: dict[int, int | None] = {}
    for block in topic_blocks(path, {ACCEL}):
        for subscription, columns in block:
            if subscription.multi_id not in devices:
                devices[subscription.multi_id] = _device_id({k: v[:1] for k, v in columns.items()})
    return dict(sorted(devices.items()))


# pyulog stops without a word at a record cut short by the end of the file. So the file is read with one
# more, whole, record after it: a logged string that pyulog reports last only when the record chain ends
# exactly at the end of the file. A cut record swallows it. (Costs nothing; a header walk costs ~10 %.)
END_MARKER = "accel_calibration: end of file"


def _load(path: Path, topics: list[str], progress: ProgressBar | None = None) -> Any:
    from pyulog import ULog
    from pyulog.exceptions import ULogException

    _check_definitions(path)
    marker = _record(b"L", struct.pack("<BQ", ord("6"), 0) + END_MARKER.encode())
    chatter = io.StringIO()  # pyulog prints warnings on stdout; they must not interleave with ours
    source = None
    try:
        source = io.BufferedReader(_MarkedFile(path, marker, progress), buffer_size=1 << 20)
        with contextlib.redirect_stdout(chatter):
            log = ULog(source, message_name_filter_list=topics)
    except ULogException as error:
        raise UlogError(f"{path}: unreadable ULog ({error})") from None
    except (ValueError, KeyError, IndexError, struct.error, UnicodeDecodeError, OverflowError, MemoryError) as error:
        raise UlogError(f"{path}: unreadable ULog ({type(error).__name__}: {str(error)[:80]})") from None
    except OSError as error:
        raise UlogError(f"{path}: cannot read ({error.strerror or error})") from None
    finally:
        if source is not None:
            source.close()  # pyulog closes it only when it finishes
    messages = log.logged_messages
    if not messages or messages[-1].message != END_MARKER:
        raise UlogError(_truncation(path))
    messages.pop()
    log.formats_defined = sorted(log.message_formats)  # for saying what the log has
    return log


def _check_definitions(path: Path) -> None:
    """One UlogError line for a file that is no ULog, or whose definitions are cut short or corrupt."""
    head = read_head(path, lambda stream: stream.read(len(MAGIC)), UlogError, "a .ulg file")
    if head != MAGIC:
        raise UlogError(f"{path}: not a PX4 ULog (no ULog header)")
    problem = _definitions_problem(path)
    if problem is not None:
        raise UlogError(f"{path}: {problem}")


class _MarkedFile(io.RawIOBase):
    """The file followed by `marker`, as one seekable stream (moving a tqdm bar by the bytes read)."""

    def __init__(self, path: Path, marker: bytes, progress: ProgressBar | None = None) -> None:
        self._file = open(path, "rb")  # noqa: SIM115 (closed by close(), which pyulog calls)
        self._size = self._file.seek(0, io.SEEK_END)
        self._file.seek(0)
        self._marker = marker
        self._pos = 0
        self._progress = progress

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:  # a writable buffer (collections.abc.Buffer from Python 3.12)
        view = memoryview(buffer).cast("B")
        if self._pos < self._size:
            count = self._file.readinto(view[:self._size - self._pos])
        else:
            tail = self._marker[self._pos - self._size:self._pos - self._size + len(view)]
            view[:len(tail)] = tail
            count = len(tail)
        self._pos += count
        if self._progress is not None and count:
            self._progress.update(count)
        return count

    def seek(self, offset: int, whence: int = io.SEEK_SET) -> int:
        base = {io.SEEK_SET: 0, io.SEEK_CUR: self._pos, io.SEEK_END: self._size + len(self._marker)}[whence]
        if base + offset < 0:
            raise OSError(22, "Invalid argument")  # as a file does
        self._pos = base + offset
        self._file.seek(min(self._pos, self._size))
        return self._pos

    def tell(self) -> int:
        return self._pos

    def close(self) -> None:
        self._file.close()
        super().close()


_DEFINITIONS = frozenset(b"IMFPQB")  # record types pyulog parses before the data section
_DATA_STARTS = frozenset(b"ALC")  # the first of these ends the definitions


def _definitions_problem(path: Path) -> str | None:
    """A definitions section cut short or corrupt, said plainly. pyulog must not see one: at a corrupt
    record there it steps back by the record's size, and near the end of a cut file that can be further
    than it went forward, for ever. (Few records: formats, parameters; the data section is not walked.)"""
    import mmap

    unpack = struct.Struct("<HB").unpack_from
    with open(path, "rb") as stream:
        size = stream.seek(0, io.SEEK_END)
        if size < 16:
            return f"truncated ULog: {size} bytes, shorter than the 16-byte file header"
        if size == 16:
            return "truncated ULog: a file header and nothing after it"
        with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as data:
            pos = 16
            formats: dict[int, bytes] = {}
            while pos < size:
                if pos + 3 > size:
                    return f"truncated ULog: the record at byte {pos} is cut short in its header"
                length, kind = unpack(data, pos)
                if kind in _DATA_STARTS:
                    return _formats_problem(formats)
                if kind not in _DEFINITIONS and (kind == 0 or length == 0 or length > 10_000):
                    return f"corrupt ULog: no valid record at byte {pos} of its definitions"
                if pos + 3 + length > size:
                    return (f"truncated ULog: the record at byte {pos} needs {3 + length} bytes, the file ends "
                            f"{size - pos} bytes after its start (cut short before any data)")
                if kind == ord("F"):
                    formats[pos] = bytes(data[pos + 3:pos + 3 + length])
                pos += 3 + length
    # Definitions only (cut between two of them): a type defined later may be missing; no data, said by the reader.
    return _formats_problem(formats, whole=False)


_ULOG_TYPES = frozenset({"int8_t", "uint8_t", "int16_t", "uint16_t", "int32_t", "uint32_t", "int64_t", "uint64_t",
                         "float", "double", "bool", "char"})
_FIELD = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(\[[0-9]+\])? ([A-Za-z_][A-Za-z0-9_]*(\[[0-9]+\])?)")


def _format_fields(body: bytes) -> tuple[str, list[str]] | str:
    """(name, field types) of a format record ("name:type field;type field;..."), or what is wrong with it.
    pyulog drops a format without ':' and keeps one of an unknown type, its data then silently missing."""
    try:
        text = body.decode("ascii")
    except UnicodeDecodeError:
        return "is not ASCII text"
    name, colon, fields = text.partition(":")
    if not colon or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        return f"is not 'name:type field;...' ({text[:40]!r})"
    types = []
    for field in filter(None, fields.split(";")):
        match = _FIELD.fullmatch(field)
        if match is None:
            return f"of {name} has a field {field[:40]!r} that is not 'type name'"
        types.append(match.group(1))
    return name, types


def _formats_problem(formats: dict[int, bytes], whole: bool = True) -> str | None:
    """The first broken format record (by its byte offset): not parseable, or (`whole`: every definition is
    there) a field of a type that is neither ULog's nor another format of the log."""
    parsed = {pos: _format_fields(body) for pos, body in formats.items()}
    names = {entry[0] for entry in parsed.values() if isinstance(entry, tuple)}
    for pos, entry in sorted(parsed.items()):
        if isinstance(entry, str):
            return f"corrupt ULog: the format record at byte {pos} {entry}"
        unknown = [kind for kind in entry[1] if kind not in _ULOG_TYPES and kind not in names]
        if unknown and whole:
            return f"corrupt ULog: the format of {entry[0]} (byte {pos}) has a field of unknown type {unknown[0]!r}"
    return None


def _truncation(path: Path) -> str:
    try:
        cut = _cut_at(path.read_bytes())
    except OSError:
        cut = None
    if cut is None:
        return f"{path}: truncated or corrupt ULog (its records do not end with the file)"
    offset, needed, have = cut
    return (f"{path}: truncated ULog: the record at byte {offset} needs {needed} bytes, the file ends {have} bytes "
            "after its start (cut short while logging?)")


def _cut_at(data: bytes) -> tuple[int, int, int] | None:
    """(offset, bytes needed, bytes there) of a last record cut short by the end of the file, else None.
    Walks the record headers (uint16 size, uint8 type) after the 16-byte file header: ~0.2 us a record."""
    unpack = struct.Struct("<H").unpack_from
    pos, end, last = 16, len(data), 16
    while pos + 3 <= end:
        last = pos
        pos += 3 + unpack(data, pos)[0]
    if pos == end:
        return None
    if pos < end:  # one or two bytes of a record header
        return pos, 3, end - pos
    return last, pos - last, end - last


def logged_vehicle(info: Mapping[str, object]) -> str:
    """The vehicle as the log names it: its board's unique id (info message `sys_uuid`, from the MCU's
    serial number), after the system's name (`sys_name`) when logged: "PX4 000200000000353338373138511600380018".
    `sys_name` alone names the firmware (every PX4 log says "PX4"), not a vehicle: "" then."""
    def text(key: str) -> str:
        value = info.get(key)
        return value.strip() if isinstance(value, str) else ""

    uuid = text("sys_uuid")
    if not uuid:
        return ""
    return f"{text('sys_name')} {uuid}".strip()


# A stamp in ns is an int64: microseconds beyond this (292 years, less room for a relative offset) would wrap.
MAX_STAMP_US = (2**63 - 1) // 1000 - 2**31


def _stamps_us(path: Path, values: npt.ArrayLike, what: str) -> np.ndarray:
    """Logged uint64 microsecond stamps as int64, or one UlogError for stamps that would wrap as ns."""
    raw = np.asarray(values)
    if len(raw) and (raw.astype(np.uint64) > MAX_STAMP_US).any():
        top = int(raw.astype(np.uint64).max())
        raise UlogError(f"{path}: {what} stamps reach {top} us, beyond the {MAX_STAMP_US} us (292 years) a "
                        "nanosecond stamp holds: a corrupt log")
    return raw.astype(np.int64)


def _datasets(log: Any, name: str) -> list[Any]:
    return [d for d in log.data_list if d.name == name and len(d.data["timestamp"])]


def _no_accel(path: Path, log: Any, wanted: str) -> UlogError:
    have = [name for name in log.formats_defined if name.startswith(("sensor_", "vehicle_imu"))]
    listed = ", ".join(have[:8]) + (", ..." if len(have) > 8 else "") if have else "no sensor topics"
    return UlogError(f"{path}: no accelerometer data ({wanted}) in this log; it defines {listed}")


def _xyz(data: _Fields, names: tuple[str, str, str]) -> np.ndarray:
    return np.column_stack([np.asarray(data[n], dtype=float) for n in names])


def _from_combined(path: Path, log: Any) -> UlogSamples:
    found = _datasets(log, COMBINED)
    if not found:
        raise _no_accel(path, log, "sensor_combined; or sensor_accel with --instance N")
    data = found[0].data
    stamp_us = _stamps_us(path, data["timestamp"], COMBINED)
    if "accelerometer_timestamp_relative" in data:
        relative = data["accelerometer_timestamp_relative"].astype(np.int64)
        has_accel = relative != RELATIVE_TIMESTAMP_INVALID
        stamp_us = stamp_us + np.where(has_accel, relative, 0)
    else:
        has_accel = np.ones(len(stamp_us), dtype=bool)
    accel = _xyz(data, ("accelerometer_m_s2[0]", "accelerometer_m_s2[1]", "accelerometer_m_s2[2]"))
    gyro = None
    if "gyro_rad[0]" in data:
        gyro = _xyz(data, ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"))
    if not has_accel.all():
        accel, stamp_us = accel[has_accel], stamp_us[has_accel]
        gyro = None if gyro is None else gyro[has_accel]
    temperature, temperature_stream, sensor_id = _selected_accel_temperature(path, log)
    selection = _datasets(log, SELECTION)
    selected = selection[0].data if selection else {}
    return UlogSamples(COMBINED, stamp_us * 1000, accel, gyro, temperature, temperature_stream, sensor_id,
                       logged_correction=_combined_correction(path, log),
                       imu_instances=tuple(sorted({d.multi_id for d in _datasets(log, ACCEL)})),
                       accel_device_id=_device_id(selected, "accel_device_id", -1),
                       gyro_device_id=_device_id(selected, "gyro_device_id", -1))


def _combined_correction(path: Path, log: Any) -> LoggedCorrection | None:
    """PX4's correction of the sensors sensor_selection names, from the parameters the log starts with."""
    selection = _datasets(log, SELECTION)
    params = {str(k): float(v) for k, v in log.initial_parameters.items()}
    if not selection or not params:
        return None
    data = selection[0].data
    accel = int(data["accel_device_id"][-1]) if "accel_device_id" in data else None
    gyro = int(data["gyro_device_id"][-1]) if "gyro_device_id" in data else None
    return px4_correction(params, accel, gyro, str(path))


def _selected_accel_temperature(path: Path, log: Any
                                ) -> tuple[tuple[np.ndarray, np.ndarray] | None, str | None, str]:
    """The temperature of the sensor_accel instance sensor_combined is fed from (sensor_selection names
    its device), or of the only instance; None when the log does not say."""
    instances = _datasets(log, ACCEL)
    selection = _datasets(log, SELECTION)
    chosen = None
    if selection and "accel_device_id" in selection[0].data:
        devices = selection[0].data["accel_device_id"]
        device = int(devices[-1])  # the one in force at the end (a switch mid-log is rare)
        chosen = next((d for d in instances if "device_id" in d.data and int(d.data["device_id"][0]) == device), None)
    elif len(instances) == 1:
        chosen = instances[0]
    if chosen is None or "temperature" not in chosen.data:
        sensor_id = f"px4 device {int(selection[0].data['accel_device_id'][-1])}" if selection else ""
        return None, None, sensor_id
    stamps, degc = _temperature_of(path, chosen.data)
    return (stamps, degc), f"sensor_accel instance {chosen.multi_id} temperature", _device(chosen.data)


def _temperature_of(path: Path, data: _Fields) -> tuple[np.ndarray, np.ndarray]:
    stamp_us = data["timestamp_sample"] if "timestamp_sample" in data else data["timestamp"]
    return _stamps_us(path, stamp_us, "temperature") * 1000, np.asarray(data["temperature"], dtype=float)


def _device(data: _Fields) -> str:
    return f"px4 device {int(data['device_id'][0])}" if "device_id" in data else ""


def _device_id(data: _Fields, field: str = "device_id", row: int = 0) -> int | None:
    """A logged device ID; None where not logged, or 0 (PX4: no device)."""
    if field not in data or not len(data[field]):
        return None
    device = int(data[field][row])
    return device if 0 < device < 2**32 else None


def paired_gyro(log: Any, instance: int, accel_device: int | None) -> Any | None:
    """The sensor_gyro dataset of the IMU whose accelerometer is sensor_accel `instance` of `accel_device`,
    by device: the gyro of the same device (one chip: PX4's drivers register both under one ID), else the
    gyro vehicle_imu pairs with it, else the gyro CAL_GYROn_ID names where CAL_ACCn_ID is the accelerometer.
    Among gyros of one device the same instance first (two IMUs logged under one ID); the same instance
    number only where nothing names the pair."""
    from .logged_correction import px4_slot

    gyros = {d.multi_id: d for d in _datasets(log, GYRO)}
    if accel_device is None:
        return gyros.get(instance)
    params = {str(k): float(v) for k, v in log.initial_parameters.items()}
    slot = px4_slot(params, "ACC", accel_device)
    by_parameters = None if slot is None else params.get(f"CAL_GYRO{slot}_ID")
    paired = [d.data["gyro_device_id"][i] for d in _datasets(log, VEHICLE_IMU)
              if "accel_device_id" in d.data and "gyro_device_id" in d.data
              for i in np.flatnonzero(np.asarray(d.data["accel_device_id"]) == accel_device)[:1]]
    for device in (accel_device, *paired, by_parameters):
        if device is None or not 0 < int(device) < 2**32:
            continue
        same = [n for n, g in sorted(gyros.items()) if _device_id(g.data) == int(device)]
        if same:
            return gyros[instance] if instance in same else gyros[same[0]]
    return gyros.get(instance)


def _from_instance(path: Path, log: Any, instance: int) -> UlogSamples:
    accels = {d.multi_id: d for d in _datasets(log, ACCEL)}
    if not accels:
        raise _no_accel(path, log, f"sensor_accel instance {instance}")
    if instance not in accels:
        raise UlogError(f"{path}: no sensor_accel instance {instance}; the log has instance(s) "
                        f"{', '.join(map(str, sorted(accels)))}")
    data = accels[instance].data
    stamp_us = _stamps_us(path, data["timestamp_sample"] if "timestamp_sample" in data else data["timestamp"], ACCEL)
    accel = _xyz(data, ("x", "y", "z"))
    gyro_set = paired_gyro(log, instance, _device_id(data))
    gyro = None
    if gyro_set is not None:
        g = gyro_set.data
        g_us = _stamps_us(path, g["timestamp_sample"] if "timestamp_sample" in g else g["timestamp"], GYRO)
        order = np.argsort(g_us, kind="stable")
        gyro = np.column_stack([np.interp(stamp_us, g_us[order], np.asarray(g[axis], dtype=float)[order])
                                for axis in ("x", "y", "z")])
    temperature = temperature_stream = None
    if "temperature" in data:
        temperature = _temperature_of(path, data)
        temperature_stream = f"sensor_accel instance {instance} temperature"
    return UlogSamples(f"sensor_accel instance {instance}", stamp_us * 1000, accel, gyro, temperature,
                       temperature_stream, _device(data), raw=True, imu_instances=tuple(sorted(accels)),
                       accel_device_id=_device_id(data),
                       gyro_device_id=None if gyro_set is None else _device_id(gyro_set.data))


def _record(kind: bytes, body: bytes) -> bytes:
    return struct.pack("<HB", len(body), kind[0]) + body
