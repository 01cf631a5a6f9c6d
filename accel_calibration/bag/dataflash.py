"""ArduPilot DataFlash `.bin` logs as sample arrays for the calibration session, read block by block with
numpy (dataflash_records.py; pymavlink, which makes a Python object of every record, is the tests' reference).

- `IMU` records: TimeUS (us since boot), AccX..Z (m/s^2), GyrX..Z (rad/s), T (degC). A log of today has one
  IMU message type with an instance field `I`; older logs (ArduPilot before 4.0) have IMU, IMU2, IMU3 for
  instances 0, 1, 2. One instance is read (`instance`, default 0); its T is its temperature stream.
- `ARM` (ArmState) and `EV` events (ARMED/DISARMED, NOT_LANDED/LAND_COMPLETE): the flight state.
- `PARM` records INS_ACCOFFS_* / INS_ACCSCAL_* / INS_ACC1_CALTEMP (INS_ACC2OFFS_*, ... for instance 1): the
  autopilot's own calibration in force while logging. ArduPilot logs IMU values already corrected by it
  (offsets subtracted, then scaled), so a calibration fitted to them is what would change on top of it.

Errors are `DataflashError` (one line naming the file); a log with bytes that are no record where
pymavlink would skip them is refused. `read_dataflash(..., ground_margin_s=...)` keeps only the samples on
the ground (and a border of each flight), for a long log's still moments in bounded memory.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.flight_state import FlightState
from .bag_io import read_head
from .dataflash_records import IMU_TYPES as IMU_TYPES  # re-exported: the older logs' per-instance IMU types
from .dataflash_records import DataflashError as DataflashError  # re-exported: the error of every DataFlash read
from .dataflash_records import RecordReader, read_records
from .flight_sources import dataflash_flight_state
from .logged_correction import LoggedCorrection, ardupilot_correction

if TYPE_CHECKING:
    from .progress import ProgressBar

HEAD = b"\xa3\x95"
FMT_ID = 0x80
MAGIC = HEAD + bytes([FMT_ID])  # every DataFlash log starts with the FMT record of FMT itself (or another)
@dataclass(frozen=True)
class AutopilotCalibration:
    """ArduPilot's accelerometer calibration of one instance as its parameters were logged: the IMU records
    are corrected as a = (raw - offsets) * scale (per axis)."""

    instance: int
    offsets_mps2: np.ndarray  # INS_ACCOFFS_X/Y/Z (instance 0), INS_ACC2OFFS_* (1), INS_ACC3OFFS_* (2)
    scale: np.ndarray  # INS_ACCSCAL_X/Y/Z, ...
    caltemp_degc: float | None  # INS_ACC1_CALTEMP, ...: the temperature it was calibrated at (-300: unknown)

    def describe(self) -> str:
        offsets = " ".join(f"{v:+.4f}" for v in self.offsets_mps2)
        scale = " ".join(f"{v:.5f}" for v in self.scale)
        temperature = f", calibrated at {self.caltemp_degc:.1f} degC" if self.caltemp_degc is not None else ""
        return (f"the autopilot's calibration at the time (instance {self.instance}): offsets {offsets} m/s^2, "
                f"scale {scale}{temperature}")


@dataclass
class DataflashSamples:
    stream: str  # "IMU instance N"
    t_ns: np.ndarray
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray
    temperature: tuple[np.ndarray, np.ndarray] | None
    temperature_stream: str | None
    sensor_id: str
    flight_state: FlightState
    autopilot_calibration: AutopilotCalibration | None
    # What ArduPilot did to these samples before logging them (its PARM records), to be undone; None when
    # the log holds no calibration of this instance (the samples are then corrected by one not known).
    logged_correction: LoggedCorrection | None = None
    imu_instances: tuple[int, ...] = ()  # every IMU instance the log holds
    accel_device_id: int | None = None  # INS_ACC_ID, INS_ACC2_ID, ... of the instance read, where logged
    gyro_device_id: int | None = None  # INS_GYR_ID, INS_GYR2_ID, ...
    samples_read: int = 0  # IMU records of this instance in the whole log (a ground-only read keeps fewer)
    first_last_ns: tuple[int, int] | None = None  # the first and last stamps of them


def _parameter_names(instance: int) -> tuple[str, str, str]:
    prefix = "INS_ACC" if instance == 0 else f"INS_ACC{instance + 1}"
    return f"{prefix}OFFS_", f"{prefix}SCAL_", f"INS_ACC{instance + 1}_CALTEMP"


def autopilot_calibration(params: Mapping[str, float], instance: int) -> AutopilotCalibration | None:
    offsets_name, scale_name, caltemp_name = _parameter_names(instance)
    try:
        offsets = np.array([float(params[offsets_name + axis]) for axis in "XYZ"])
        scale = np.array([float(params[scale_name + axis]) for axis in "XYZ"])
    except KeyError:
        return None
    if not np.all(np.isfinite(offsets)) or not np.all(np.isfinite(scale)) or np.all(scale == 0):
        return None  # an instance that was never calibrated (scale 0: not set)
    caltemp = params.get(caltemp_name)
    caltemp = float(caltemp) if caltemp is not None and np.isfinite(caltemp) and caltemp > -273.15 else None
    return AutopilotCalibration(instance, offsets, scale, caltemp)


def _device_ids(params: Mapping[str, float], instance: int) -> tuple[int | None, int | None]:
    """(INS_ACC_ID, INS_GYR_ID) of an instance (INS_ACC2_ID, INS_GYR2_ID for 1, ...); None where not logged or 0."""
    suffix = "" if instance == 0 else str(instance + 1)
    devices = []
    for name in (f"INS_ACC{suffix}_ID", f"INS_GYR{suffix}_ID"):
        value = params.get(name)
        devices.append(int(value) if value is not None and np.isfinite(value) and 0 < value < 2**32 else None)
    return devices[0], devices[1]


IMU_COLUMNS = ("AccX", "AccY", "AccZ", "GyrX", "GyrY", "GyrZ")


def _check_head(path: Path) -> None:
    head = read_head(path, lambda stream: stream.read(len(MAGIC)), DataflashError, "a .bin file")
    if head[:2] != HEAD:
        raise DataflashError(f"{path}: not an ArduPilot DataFlash log (no DataFlash header)")


def _instance_rows(block: Mapping[str, np.ndarray], wanted: int) -> np.ndarray | None:
    """The IMU records of instance `wanted` in one block: today's IMU by its field I, or IMU/IMU2/IMU3."""
    today = block.get("IMU")
    if today is not None and "I" in (today.dtype.names or ()):
        mine: np.ndarray = today[today["I"] == wanted]
        return mine
    if wanted < len(IMU_TYPES):
        return block.get(IMU_TYPES[wanted])
    return None


@dataclass
class _ImuRead:
    """The samples of one IMU instance gathered block by block (those `keep` keeps, every one without it),
    and how many the whole log held of it, from when to when."""

    path: Path
    wanted: int
    keep: Callable[[np.ndarray], np.ndarray] | None = None
    stamps: list[np.ndarray] = field(default_factory=list)
    values: list[np.ndarray] = field(default_factory=list)  # (n, 7): AccX..Z, GyrX..Z (as logged), T
    read: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    def add(self, block: Mapping[str, np.ndarray]) -> None:
        found = self.rows(block)
        if found is not None:
            self.keep_rows(*found)

    def rows(self, block: Mapping[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
        """This instance's records of one block as (stamps ns, values (n, 7)), counted; None where it has none."""
        rows = _instance_rows(block, self.wanted)
        if rows is None or not len(rows):
            return None
        missing = [c for c in ("TimeUS", *IMU_COLUMNS) if c not in (rows.dtype.names or ())]
        if missing:
            raise DataflashError(f"{self.path}: unreadable DataFlash log (its IMU records have no {missing[0]} field)")
        t_ns = _stamps_ns(self.path, rows["TimeUS"], "IMU")
        self.read += len(rows)
        self.first_ns = int(t_ns[0]) if self.first_ns is None else self.first_ns
        self.last_ns = int(t_ns[-1])
        temperature = rows["T"] if "T" in (rows.dtype.names or ()) else np.full(len(rows), np.nan)
        return t_ns, np.column_stack([*(rows[c] for c in IMU_COLUMNS), temperature]).astype(float)

    def keep_rows(self, t_ns: np.ndarray, values: np.ndarray) -> None:
        """Of the rows `rows` gave, those `keep` keeps (every one without it)."""
        if self.keep is not None:
            kept = self.keep(t_ns)
            t_ns, values = t_ns[kept], values[kept]
        self.stamps.append(t_ns)
        self.values.append(values)


def accel_devices(path: str | os.PathLike[str]) -> dict[int, int | None]:
    """{IMU instance: its accelerometer's device ID (INS_ACC_ID, ...), None where not logged} of the log."""
    _check_head(Path(path))
    log = read_records(path, [])
    return {n: _device_ids(log.params, n)[0] for n in log.imu_instances}


def read_dataflash(path: str | os.PathLike[str], instance: int | None = None, progress: ProgressBar | None = None,
                   ground_margin_s: float | None = None) -> DataflashSamples:
    """`instance`: the IMU instance to read (default 0). `progress`: a tqdm bar counting bytes read.
    `ground_margin_s`: keep only the samples a read for the still moments on the ground needs
    (FlightState.ground_kept with that margin: the ground and a border of each flight), read block by
    block after a first pass over the flight state (ARM, EV): memory follows the time on the ground, not
    the log's length. `samples_read` and `first_last_ns` still count the whole log's samples."""
    path = Path(path)
    wanted = 0 if instance is None else instance
    _check_head(path)
    imu = _ImuRead(path, wanted)
    if ground_margin_s is None:  # one pass: the IMU records and the flight state together
        reader = RecordReader(path, [*IMU_TYPES, "ARM", "EV"])
        small: dict[str, list[np.ndarray]] = {"ARM": [], "EV": []}
        for block in _progressed(reader, progress):
            imu.add(block)
            for kind, pieces in small.items():
                if kind in block:
                    pieces.append(block[kind])
        flight = _flight_state(path, *(np.concatenate(p) if p else None for p in small.values()))
    else:
        states = read_records(path, ["ARM", "EV"])
        flight = _flight_state(path, states.records.get("ARM"), states.records.get("EV"))
        margin = float(ground_margin_s)
        imu.keep = lambda t_ns: flight.ground_kept(t_ns, margin)
        reader = RecordReader(path, IMU_TYPES)
        for block in _progressed(reader, progress):
            imu.add(block)
    return _samples(path, imu, reader.params, reader.imu_instances, flight)


def _progressed(reader: RecordReader, progress: ProgressBar | None) -> Iterator[dict[str, np.ndarray]]:
    done = 0
    for block in reader.blocks():
        if progress is not None:
            progress.update(reader.bytes_read - done)
            done = reader.bytes_read
        yield block
    if progress is not None:
        progress.update(reader.bytes_read - done)


def _samples(path: Path, imu: _ImuRead, params: dict[str, float], instances: tuple[int, ...],
             flight: FlightState) -> DataflashSamples:
    """The samples `imu` gathered (its lists emptied as they are joined), with what the log says of them."""
    wanted = imu.wanted
    if not imu.read:
        if not instances:
            raise DataflashError(f"{path}: no accelerometer data (IMU records) in this DataFlash log")
        raise DataflashError(f"{path}: no IMU instance {wanted}; the log has instance(s) "
                             f"{', '.join(map(str, instances))}")
    t_ns = np.concatenate(imu.stamps)
    table = np.concatenate(imu.values) if imu.values else np.zeros((0, 7))
    imu.stamps.clear()
    imu.values.clear()
    temperature = None
    temperature_stream = None
    if np.any(np.isfinite(table[:, 6])):
        temperature = (t_ns.copy(), table[:, 6].copy())
        temperature_stream = f"IMU instance {wanted} T"
    accel_device, gyro_device = _device_ids(params, wanted)
    sensor_id = f"ardupilot accel {accel_device}" if accel_device else ""
    assert imu.first_ns is not None and imu.last_ns is not None
    return DataflashSamples(f"IMU instance {wanted}", t_ns, table[:, 0:3].copy(), table[:, 3:6].copy(), temperature,
                            temperature_stream, sensor_id, flight, autopilot_calibration(params, wanted),
                            ardupilot_correction(params, wanted, str(path)), instances, accel_device, gyro_device,
                            samples_read=imu.read, first_last_ns=(imu.first_ns, imu.last_ns))


def _flight_state(path: Path, arm: np.ndarray | None, events: np.ndarray | None) -> FlightState:
    """From the ARM (TimeUS, ArmState) and EV (TimeUS, Id) records; a type without those fields says nothing."""
    def series(rows: np.ndarray | None, value: str, what: str) -> tuple[np.ndarray, np.ndarray] | None:
        if rows is None or not len(rows) or not {"TimeUS", value} <= set(rows.dtype.names or ()):
            return None
        return _stamps_ns(path, rows["TimeUS"], what), rows[value].astype(np.int64)

    return dataflash_flight_state(series(arm, "ArmState", "ARM"), series(events, "Id", "EV"))


def _stamps_ns(path: Path, stamps_us: np.ndarray, what: str) -> np.ndarray:
    """Logged TimeUS (uint64 us) as int64 ns, or one DataflashError where the ns would wrap."""
    from .ulog_reader import MAX_STAMP_US

    stamps = np.asarray(stamps_us)
    if len(stamps) and (stamps.astype(np.uint64) > MAX_STAMP_US).any():
        top = int(stamps.astype(np.uint64).max())
        raise DataflashError(f"{path}: {what} TimeUS reaches {top} us, beyond the {MAX_STAMP_US} us (292 years) a "
                             "nanosecond stamp holds: a corrupt log")
    return stamps.astype(np.int64) * 1000


def correction_on_top_mg(matrix: np.ndarray, bias_mps2: np.ndarray, gravity: float, points: int = 4000) -> float:
    """How far a calibration a = M (x - b) fitted to already corrected samples moves them: the largest
    |M (x - b) - x| over |x| = 1 g (every orientation), in mg. The autopilot's calibration is the identity
    on its own output, so this is how far ours is from it, on the raw readings too."""
    # A Fibonacci sphere: the largest of a smooth function over the sphere, to well under 0.01 mg.
    k = np.arange(points) + 0.5
    polar = np.arccos(1.0 - 2.0 * k / points)
    azimuth = np.pi * (1.0 + 5.0**0.5) * k
    directions = np.column_stack([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)])
    x = gravity * directions
    moved = (x - np.asarray(bias_mps2)) @ np.asarray(matrix).T - x
    return float(np.max(np.linalg.norm(moved, axis=1)) / (gravity / 1000.0))


def scan_messages(path: Path, kinds: list[str]) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Every record of the given types as a structured array of its fields (pymavlink's scaling of its
    format characters applied), and the log's parameters; one DataflashError line for a damaged log."""
    _check_head(Path(path))
    log = read_records(path, kinds)
    return log.records, log.params
