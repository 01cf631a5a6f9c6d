"""ArduPilot DataFlash `.bin` logs as sample arrays for the calibration session, read with pymavlink.

- `IMU` records: TimeUS (us since boot), AccX..Z (m/s^2), GyrX..Z (rad/s), T (degC). A log of today has one
  IMU message type with an instance field `I`; older logs (ArduPilot before 4.0) have IMU, IMU2, IMU3 for
  instances 0, 1, 2. One instance is read (`instance`, default 0); its T is its temperature stream.
- `ARM` (ArmState) and `EV` events (ARMED/DISARMED, NOT_LANDED/LAND_COMPLETE): the flight state.
- `PARM` records INS_ACCOFFS_* / INS_ACCSCAL_* / INS_ACC1_CALTEMP (INS_ACC2OFFS_*, ... for instance 1): the
  autopilot's own calibration in force while logging. ArduPilot logs IMU values already corrected by it
  (offsets subtracted, then scaled), so a calibration fitted to them is what would change on top of it.

Errors are `DataflashError` (one line naming the file); pymavlink's prints are kept off stdout/stderr, its C
indexer's too (io/captured_output.py), and a log it had to skip damage in is refused.
`write_dataflash` writes a minimal log in the documented format (tests, benchmarks).
"""
from __future__ import annotations

import os
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.flight_state import FlightState
from ..io.captured_output import captured_output, damage_said
from .bag_io import BagError, read_head
from .flight_sources import dataflash_flight_state
from .logged_correction import LoggedCorrection, ardupilot_correction

if TYPE_CHECKING:
    from .progress import ProgressBar

HEAD = b"\xa3\x95"
FMT_ID = 0x80
MAGIC = HEAD + bytes([FMT_ID])  # every DataFlash log starts with the FMT record of FMT itself (or another)
IMU_TYPES = ("IMU", "IMU2", "IMU3")  # the older logs' per-instance types


class DataflashError(BagError):
    """A DataFlash log that cannot give accelerometer samples: one line naming the file."""


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


@dataclass
class _Scan:
    rows: list[tuple[Any, ...]]  # pymavlink's message fields of the instance wanted (it ships no types)
    instances: set[int]
    arm: list[tuple[int, int]]
    events: list[tuple[int, int]]
    params: dict[str, float]
    bytes_read: int


def _scan(path: Path, wanted: int | None) -> _Scan:
    """The IMU records of instance `wanted` (None: none kept), every instance seen, ARM and EV, the parameters;
    one DataflashError line for a log pymavlink cannot read or had to skip damage in."""
    from pymavlink import DFReader

    head = read_head(path, lambda stream: stream.read(len(MAGIC)), DataflashError, "a .bin file")
    if head[:2] != HEAD:
        raise DataflashError(f"{path}: not an ArduPilot DataFlash log (no DataFlash header)")
    scan = _Scan([], set(), [], [], {}, 0)
    failure: str | None = None
    try:
        with captured_output() as chatter:
            log = DFReader.DFReader_binary(str(path), zero_time_base=False)
            try:
                while True:
                    message = log.recv_match(type=[*IMU_TYPES, "ARM", "EV"])
                    if message is None:
                        break
                    kind = message.get_type()
                    if kind == "EV":
                        scan.events.append((int(message.TimeUS), int(message.Id)))
                    elif kind == "ARM":
                        scan.arm.append((int(message.TimeUS), int(message.ArmState)))
                    else:
                        number = int(getattr(message, "I", 0)) if kind == "IMU" else IMU_TYPES.index(kind)
                        scan.instances.add(number)
                        if number == wanted:
                            scan.rows.append((message.TimeUS, message.AccX, message.AccY, message.AccZ,
                                              message.GyrX, message.GyrY, message.GyrZ, getattr(message, "T", np.nan)))
                scan.params = dict(log.params)
                scan.bytes_read = log.data_len
            finally:
                log.close()
    except (AttributeError, ValueError, KeyError, IndexError, struct.error, UnicodeDecodeError) as error:
        failure = f"{path}: unreadable DataFlash log ({type(error).__name__}: {str(error)[:80]})"
    except OSError as error:
        failure = f"{path}: cannot read ({error.strerror or error})"
    except Exception as error:  # noqa: BLE001 - pymavlink raises bare Exception on a bad FMT record
        failure = f"{path}: unreadable DataFlash log ({str(error)[:80]})"
    damage = damage_said(chatter)
    if damage is not None:  # what pymavlink skipped explains any failure that followed
        raise DataflashError(f"{path}: {damage}")
    if failure is not None:
        raise DataflashError(failure)
    return scan


def accel_devices(path: str | os.PathLike[str]) -> dict[int, int | None]:
    """{IMU instance: its accelerometer's device ID (INS_ACC_ID, ...), None where not logged} of the log."""
    scan = _scan(Path(path), None)
    return {n: _device_ids(scan.params, n)[0] for n in sorted(scan.instances)}


def read_dataflash(path: str | os.PathLike[str], instance: int | None = None, progress: ProgressBar | None = None
                   ) -> DataflashSamples:
    """`instance`: the IMU instance to read (default 0). `progress`: a tqdm bar counting bytes read."""
    path = Path(path)
    wanted = 0 if instance is None else instance
    scan = _scan(path, wanted)
    rows, params = scan.rows, scan.params
    if progress is not None:
        progress.update(scan.bytes_read)
    if not rows:
        if not scan.instances:
            raise DataflashError(f"{path}: no accelerometer data (IMU records) in this DataFlash log")
        raise DataflashError(f"{path}: no IMU instance {wanted}; the log has instance(s) "
                             f"{', '.join(map(str, sorted(scan.instances)))}")
    table = np.array(rows, dtype=float)
    t_ns = _stamps_ns(path, [row[0] for row in rows], "IMU")
    temperature = None
    temperature_stream = None
    if np.any(np.isfinite(table[:, 7])):
        temperature = (t_ns.copy(), table[:, 7].copy())
        temperature_stream = f"IMU instance {wanted} T"
    flight = dataflash_flight_state(_series(path, scan.arm, "ARM"), _series(path, scan.events, "EV"))
    accel_device, gyro_device = _device_ids(params, wanted)
    sensor_id = f"ardupilot accel {accel_device}" if accel_device else ""
    return DataflashSamples(f"IMU instance {wanted}", t_ns, table[:, 1:4].copy(), table[:, 4:7].copy(), temperature,
                            temperature_stream, sensor_id, flight, autopilot_calibration(params, wanted),
                            ardupilot_correction(params, wanted, str(path)), tuple(sorted(scan.instances)),
                            accel_device, gyro_device)


def _series(path: Path, pairs: list[tuple[int, int]], what: str) -> tuple[np.ndarray, np.ndarray] | None:
    if not pairs:
        return None
    return _stamps_ns(path, [p[0] for p in pairs], what), np.array([p[1] for p in pairs], dtype=np.int64)


def _stamps_ns(path: Path, stamps_us: list[Any], what: str) -> np.ndarray:
    """Logged TimeUS (uint64 us) as int64 ns, or one DataflashError where the ns would wrap."""
    from .ulog_reader import MAX_STAMP_US

    top = max((int(v) for v in stamps_us), default=0)
    if top > MAX_STAMP_US or min((int(v) for v in stamps_us), default=0) < 0:
        raise DataflashError(f"{path}: {what} TimeUS reaches {top} us, beyond the {MAX_STAMP_US} us (292 years) a "
                             "nanosecond stamp holds: a corrupt log")
    return np.array([int(v) for v in stamps_us], dtype=np.int64) * 1000


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


def scan_messages(path: Path, kinds: list[str]) -> tuple[dict[str, list[dict[str, Any]]], dict[str, float]]:
    """Every record of the given types as {field: value} (pymavlink's scaling of its format characters
    applied), and the log's parameters; one DataflashError line for a log pymavlink cannot read."""
    from pymavlink import DFReader

    head = read_head(path, lambda stream: stream.read(len(MAGIC)), DataflashError, "a .bin file")
    if head[:2] != HEAD:
        raise DataflashError(f"{path}: not an ArduPilot DataFlash log (no DataFlash header)")
    found: dict[str, list[dict[str, Any]]] = {}
    try:
        with captured_output() as chatter:
            log = DFReader.DFReader_binary(str(path), zero_time_base=False)
            try:
                while (message := log.recv_match(type=kinds)) is not None:
                    found.setdefault(message.get_type(), []).append(message.to_dict())
                params = {str(k): float(v) for k, v in log.params.items()}
            finally:
                log.close()
    except OSError as error:
        raise DataflashError(f"{path}: cannot read ({error.strerror or error})") from None
    except Exception as error:  # noqa: BLE001 - pymavlink raises bare Exception on a bad FMT record
        raise DataflashError(f"{path}: unreadable DataFlash log ({type(error).__name__}: {str(error)[:80]})") from None
    damage = damage_said(chatter)
    if damage is not None:
        raise DataflashError(f"{path}: {damage}")
    return found, params
