"""The autopilot's own in-flight bias estimates of each IMU, read from its flight log: what its navigation
filter had learnt of the accelerometer and gyro bias by the end of the flight, on top of the calibration
in force (the filter subtracts it from the corrected samples).

- PX4 ULog `estimator_sensor_bias` (one instance per filter): accel_device_id, accel_bias[3] (m/s^2),
  accel_bias_variance[3], accel_bias_valid, accel_bias_stable (newer logs), and gyro_device_id,
  gyro_bias[3] (rad/s), gyro_bias_variance[3], gyro_bias_valid, gyro_bias_stable: per device ID.
- ArduPilot DataFlash EKF3 `XKF2` AX, AY, AZ (stored as int16 of 100 x m/s^2, format `c`, which pymavlink
  scales back to m/s^2) and `XKF1` GX, GY, GZ (int16 of 100 x deg/s, `c`: deg/s after pymavlink), per core
  `C`; EKF2 `NKF2` AZbias (int8 of 100 x m/s^2, format `b`: cm/s^2 as read) and `NKF1` GX, GY, GZ. Before
  ArduPilot 4.1 a core had types of its own and no `C`: core 0 XKF1/XKF2, core 1 XKF6/XKF7 (NKF alike). A
  core runs on the IMU of its place among the set bits of EK3_IMU_MASK (EK2_IMU_MASK), default 3: core 0 on
  IMU 0, core 1 on IMU 1. ArduPilot logs no variance of these: the estimate's wander over the settled
  stretch and its logged resolution stand for it.

Per IMU and flight: the samples in flight (the log's flight state), valid (and stable where logged), of the
second half of that stretch (the filter has settled by then); their mean, with a 1 sigma of the filter's
own variance (where logged), the wander of the estimate and the logged resolution added in quadrature."""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.flight_state import FlightState, collecting_mask

XKF_RESOLUTION_MPS2 = 0.01  # 100 x m/s^2 as an integer
XKF_GYRO_RESOLUTION_RADPS = math.radians(0.01)  # 100 x deg/s as an integer
MIN_SETTLED = 5  # estimates in the settled stretch needed for a value
ARDUPILOT_FILTER_TYPES = tuple(f"{p}{n}" for p in ("XKF", "NKF") for n in (1, 2, 6, 7))  # what ardupilot_biases reads


@dataclass(frozen=True)
class EstimatedBias:
    """One IMU's bias as the filter had settled on it in flight; None for what the log does not give."""

    source: str  # "PX4 estimator_sensor_bias", "ArduPilot EKF3 XKF2/XKF1 core 0"
    samples: int
    accel_mps2: tuple[float, float, float] | None = None
    accel_sigma_mps2: tuple[float, float, float] | None = None
    gyro_radps: tuple[float, float, float] | None = None
    gyro_sigma_radps: tuple[float, float, float] | None = None

    def as_json(self) -> dict[str, Any]:
        return {"source": self.source, "samples": self.samples, "accel": self.accel_mps2,
                "accel_sigma": self.accel_sigma_mps2, "gyro": self.gyro_radps, "gyro_sigma": self.gyro_sigma_radps}


def in_flight(t_ns: np.ndarray, flight_state: FlightState | None) -> np.ndarray:
    """One bool per stamp: within a span the log says the vehicle was armed or airborne."""
    if flight_state is None or not flight_state.found:
        return np.zeros(len(t_ns), dtype=bool)
    return ~collecting_mask(np.asarray(t_ns, dtype=np.int64), flight_state.spans_ns, 0.0)


def settled(t_ns: np.ndarray, values: np.ndarray, usable: np.ndarray, flying: np.ndarray,
            variances: np.ndarray | None, resolution: float
            ) -> tuple[tuple[float, float, float], tuple[float, float, float], int] | None:
    """The mean of the second half of the usable in-flight estimates (N, 3) and its 1 sigma; None when
    fewer than MIN_SETTLED."""
    chosen = np.flatnonzero(usable & flying & np.all(np.isfinite(values), axis=1))
    chosen = chosen[np.argsort(t_ns[chosen], kind="stable")]
    late = chosen[len(chosen) // 2:]
    if len(late) < MIN_SETTLED:
        return None
    mean = np.mean(values[late], axis=0)
    variance = np.var(values[late], axis=0) + resolution**2 / 12.0
    if variances is not None:
        filter_variance = np.median(variances[late], axis=0)
        variance = variance + np.where(np.isfinite(filter_variance), np.maximum(filter_variance, 0.0), 0.0)
    sigma = np.sqrt(variance)
    return (float(mean[0]), float(mean[1]), float(mean[2])), (float(sigma[0]), float(sigma[1]), float(sigma[2])), \
        len(late)


def _columns(data: Mapping[str, np.ndarray], name: str) -> np.ndarray | None:
    names = [f"{name}[{k}]" for k in range(3)]
    if not all(n in data for n in names):
        return None
    return np.column_stack([np.asarray(data[n], dtype=float) for n in names])


def _flag(data: Mapping[str, np.ndarray], name: str, rows: int) -> np.ndarray:
    return np.asarray(data[name], dtype=bool) if name in data else np.ones(rows, dtype=bool)


def px4_biases(path: str, flight_state: FlightState | None, log: Any = None) -> dict[int, EstimatedBias] | str:
    """{accelerometer device ID: its settled bias} from `estimator_sensor_bias`, or why there is none; `log`:
    the log already read with that topic among others."""
    from .ulog_reader import _load

    log = _load(Path(path), ["estimator_sensor_bias"]) if log is None else log
    found = [d for d in log.data_list if d.name == "estimator_sensor_bias" and len(d.data["timestamp"])]
    name = Path(path).name
    if not found:
        return f"{name}: the log has no estimator_sensor_bias topic (the filter's bias estimates were not logged)"
    return px4_settled([(np.asarray(d.data["timestamp"], dtype=np.int64) * 1000, d.data) for d in found],
                       flight_state, name)


def px4_settled(datasets: Sequence[tuple[np.ndarray, Mapping[str, np.ndarray]]], flight_state: FlightState | None,
                name: str) -> dict[int, EstimatedBias] | str:
    """{accelerometer device ID: its settled bias} from estimator_sensor_bias as columns, whatever carried them
    (a ULog's datasets, a bag's messages): per dataset its stamps (ns, the flight state's clock) and its fields
    as the ULog names them (accel_bias[0], accel_bias_valid, ...); or why there is none."""
    per_device: dict[int, list[dict[str, np.ndarray]]] = {}
    for t_ns, data in datasets:
        if "accel_device_id" not in data:
            continue
        devices = np.asarray(data["accel_device_id"], dtype=np.int64)
        stamps = np.asarray(t_ns, dtype=np.int64)
        for device in np.unique(devices):
            if device:
                rows = devices == device
                part = {k: np.asarray(v)[rows] for k, v in data.items()}
                per_device.setdefault(int(device), []).append({**part, "t_ns": stamps[rows]})
    out: dict[int, EstimatedBias] = {}
    for device, parts in per_device.items():
        data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        t_ns = data["t_ns"]
        flying = in_flight(t_ns, flight_state)
        rows = len(t_ns)
        accel = _px4_part(data, "accel", t_ns, flying, rows)
        gyro = _px4_part(data, "gyro", t_ns, flying, rows)
        if accel is None and gyro is None:
            continue
        out[device] = EstimatedBias("PX4 estimator_sensor_bias", max(p[2] for p in (accel, gyro) if p is not None),
                                    *(accel[:2] if accel else (None, None)), *(gyro[:2] if gyro else (None, None)))
    if not out:
        stable = any("accel_bias_stable" in data for _, data in datasets)
        return f"{name}: estimator_sensor_bias holds no valid{' and stable' if stable else ''} estimate in flight"
    return out


def _px4_part(data: Mapping[str, np.ndarray], part: str, t_ns: np.ndarray, flying: np.ndarray, rows: int
              ) -> tuple[tuple[float, float, float], tuple[float, float, float], int] | None:
    values = _columns(data, f"{part}_bias")
    if values is None:
        return None
    usable = _flag(data, f"{part}_bias_valid", rows) & _flag(data, f"{part}_bias_stable", rows)
    return settled(t_ns, values, usable, flying, _columns(data, f"{part}_bias_variance"), 0.0)


def core_imus(params: Mapping[str, float], mask_name: str) -> list[int]:
    """The IMU each core runs on, in core order: the set bits of the filter's IMU mask (default 3)."""
    mask = int(params.get(mask_name, 3))
    return [bit for bit in range(8) if mask >> bit & 1]


def ardupilot_biases(path: str, flight_state: FlightState | None,
                     read: tuple[Mapping[str, np.ndarray], Mapping[str, float]] | None = None
                     ) -> dict[int, EstimatedBias] | str:
    """{IMU instance: its settled bias} from EKF3's XKF2/XKF1, else EKF2's NKF2/NKF1, or why there is none;
    `read`: the records of ARDUPILOT_FILTER_TYPES and the parameters already read (the fleet's pass of the log)."""
    from .dataflash import scan_messages

    found, params = read if read is not None else scan_messages(Path(path), list(ARDUPILOT_FILTER_TYPES))
    name = Path(path).name
    ekf3 = bool(len(found.get("XKF2", ())) or len(found.get("XKF1", ())))
    if not ekf3 and not (len(found.get("NKF2", ())) or len(found.get("NKF1", ()))):
        return f"{name}: the log has no EKF3 XKF1/XKF2 or EKF2 NKF1/NKF2 records (the filter's bias estimates)"
    prefix, mask = ("XKF", "EK3_IMU_MASK") if ekf3 else ("NKF", "EK2_IMU_MASK")
    # ArduPilot 4.1 on: every core in XKF1/XKF2 with its core field C; before: core 0 in XKF1/XKF2, core 1 in
    # types of its own, XKF6/XKF7 (NKF likewise), no core field.
    with_core = any("C" in (found[kind].dtype.names or ()) for kind in (f"{prefix}1", f"{prefix}2") if kind in found)
    out: dict[int, EstimatedBias] = {}
    for core, imu in enumerate(core_imus(params, mask)):
        first = 1 if with_core else 1 + 5 * core
        accel_kind, gyro_kind = f"{prefix}{first + 1}", f"{prefix}{first}"
        accel = _ardupilot_part(_of_core(found.get(accel_kind), core, with_core), flight_state, ekf3, accel=True)
        gyro = _ardupilot_part(_of_core(found.get(gyro_kind), core, with_core), flight_state, ekf3, accel=False)
        if accel is None and gyro is None:
            continue
        source = f"ArduPilot {'EKF3' if ekf3 else 'EKF2'} {accel_kind}/{gyro_kind} core {core}"
        out[imu] = EstimatedBias(source, max(p[2] for p in (accel, gyro) if p is not None),
                                 *(accel[:2] if accel else (None, None)), *(gyro[:2] if gyro else (None, None)))
    if not out:
        return f"{name}: the filter's bias records hold no estimate in flight"
    return out


def _of_core(rows: np.ndarray | None, core: int, with_core: bool) -> np.ndarray | None:
    """The records of one core (structured, as dataflash_records reads them)."""
    if rows is None or not with_core:
        return rows
    return rows[rows["C"] == core] if "C" in (rows.dtype.names or ()) else rows[:0]


def _ardupilot_part(mine: np.ndarray | None, flight_state: FlightState | None, ekf3: bool, accel: bool
                    ) -> tuple[tuple[float, float, float], tuple[float, float, float], int] | None:
    if mine is None or not len(mine):
        return None
    t_ns = mine["TimeUS"].astype(np.int64) * 1000
    if accel and ekf3:
        values = np.column_stack([mine[c] for c in ("AX", "AY", "AZ")]).astype(float)  # m/s^2 (`c` scaled on read)
        resolution = XKF_RESOLUTION_MPS2
    elif accel:  # EKF2 estimates the z bias alone; as logged: cm/s^2 (format `b`, not scaled on read)
        values = np.column_stack([np.full(len(mine), np.nan), np.full(len(mine), np.nan),
                                  mine["AZbias"] / 100.0]).astype(float)
        resolution = XKF_RESOLUTION_MPS2
    else:
        values = np.radians(np.column_stack([mine[c] for c in ("GX", "GY", "GZ")]).astype(float))  # deg/s as read
        resolution = XKF_GYRO_RESOLUTION_RADPS
    usable = np.ones(len(mine), dtype=bool)
    flying = in_flight(t_ns, flight_state)
    if accel and not ekf3:  # the z axis alone: x and y stay unknown (NaN), not zero
        result = settled(t_ns, np.nan_to_num(values), usable, flying, None, resolution)
        if result is None:
            return None
        mean, sigma, n = result
        return (math.nan, math.nan, mean[2]), (math.nan, math.nan, sigma[2]), n
    return settled(t_ns, values, usable, flying, None, resolution)
