"""Minimal PX4 ULog files (the format pyulog and the PX4 logger speak), for tests and benchmarks: topics
of structured arrays, interleaved by timestamp, and the info messages a log carries (sys_name, sys_uuid)."""
from __future__ import annotations

import os
import struct

import numpy as np

MAGIC = b"ULog\x01\x12\x35"
_TYPES = {np.dtype("<u8"): "uint64_t", np.dtype("<i8"): "int64_t", np.dtype("<u4"): "uint32_t",
          np.dtype("<i4"): "int32_t", np.dtype("<u2"): "uint16_t", np.dtype("<i2"): "int16_t",
          np.dtype("u1"): "uint8_t", np.dtype("i1"): "int8_t", np.dtype("<f4"): "float", np.dtype("<f8"): "double",
          np.dtype("?"): "bool"}


def _field(kind: np.dtype, name: str) -> str:
    """A field's ULog declaration: `float x;`, or `float[3] accel_bias;` for a sub-array (pyulog reads it as
    accel_bias[0], accel_bias[1], accel_bias[2])."""
    if kind.subdtype is not None:
        base, shape = kind.subdtype
        return f"{_TYPES[base.newbyteorder('<')]}[{int(np.prod(shape))}] {name};"
    return f"{_TYPES[kind.newbyteorder('<')]} {name};"


def _record(kind: bytes, body: bytes) -> bytes:
    return struct.pack("<HB", len(body), kind[0]) + body


def write_ulog(path: str | os.PathLike[str], topics: list[tuple[str, int, np.ndarray]], start_us: int = 0,
               info: dict[str, str] | None = None, parameters: dict[str, float | int] | None = None) -> int:
    """Write a minimal ULog: `topics` are (name, multi_id, structured array with a uint64 `timestamp` field
    first and scalar fields of the C types ULog knows). Messages of all topics are interleaved by timestamp,
    as the PX4 logger writes them. `info`: the info messages (key: text; default sys_name only).
    `parameters`: the parameters the log starts with (int: int32_t, float: float), as 'P' records.
    Returns the data messages written."""
    out = [MAGIC + b"\x01" + struct.pack("<Q", start_us),
           _record(b"B", bytes(16) + struct.pack("<3Q", 0, 0, 0))]
    formats: dict[str, str] = {}
    for name, _, array in topics:
        if name not in formats:
            if array.dtype.names is None:
                raise ValueError(f"topic {name}: a structured array is needed (timestamp first)")
            fields = "".join(_field(array.dtype[field], field) for field in array.dtype.names)
            formats[name] = fields
            out.append(_record(b"F", f"{name}:{fields}".encode()))
    for key, text in ({"sys_name": "accelcal"} if info is None else info).items():
        encoded = text.encode()
        declaration = f"char[{len(encoded)}] {key}".encode()
        out.append(_record(b"I", bytes([len(declaration)]) + declaration + encoded))
    for name, number in (parameters or {}).items():
        kind, packed = ("int32_t", struct.pack("<i", number)) if isinstance(number, int) else \
            ("float", struct.pack("<f", number))
        parameter_key = f"{kind} {name}".encode()
        out.append(_record(b"P", bytes([len(parameter_key)]) + parameter_key + packed))
    keys, blocks = [], []
    for msg_id, (name, multi_id, array) in enumerate(topics):
        out.append(_record(b"A", struct.pack("<BH", multi_id, msg_id) + name.encode()))
        size = 2 + array.dtype.itemsize
        rows = np.zeros((len(array), 3 + size), dtype=np.uint8)
        rows[:, 0:2] = np.frombuffer(struct.pack("<H", size), dtype=np.uint8)
        rows[:, 2] = ord("D")
        rows[:, 3:5] = np.frombuffer(struct.pack("<H", msg_id), dtype=np.uint8)
        rows[:, 5:] = np.ascontiguousarray(array).view(np.uint8).reshape(len(array), array.dtype.itemsize)
        blocks.append(rows)
        keys.append(np.asarray(array["timestamp"], dtype=np.int64))
    # Interleave: every message's bytes go to its place in timestamp order.
    stamps = np.concatenate(keys) if keys else np.zeros(0, dtype=np.int64)
    lengths = np.concatenate([np.full(len(b), b.shape[1]) for b in blocks]) if blocks else np.zeros(0, dtype=np.int64)
    order = np.argsort(stamps, kind="stable")
    starts = np.empty(len(order), dtype=np.int64)
    starts[order] = np.concatenate(([0], np.cumsum(lengths[order])[:-1])) if len(order) else []
    body = np.empty(int(lengths.sum()), dtype=np.uint8)
    first = 0
    for rows in blocks:
        where = starts[first:first + len(rows)]
        body[where[:, None] + np.arange(rows.shape[1])] = rows
        first += len(rows)
    with open(path, "wb") as stream:
        stream.write(b"".join(out))
        stream.write(body.tobytes())
    return len(order)


def sensor_combined_array(t_us: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray) -> np.ndarray:
    """A sensor_combined dataset as PX4 v1.14 logs it (for write_ulog)."""
    dtype = np.dtype([("timestamp", "<u8"), ("gyro_rad[0]", "<f4"), ("gyro_rad[1]", "<f4"), ("gyro_rad[2]", "<f4"),
                      ("gyro_integral_dt", "<u4"), ("accelerometer_timestamp_relative", "<i4"),
                      ("accelerometer_m_s2[0]", "<f4"), ("accelerometer_m_s2[1]", "<f4"),
                      ("accelerometer_m_s2[2]", "<f4"), ("accelerometer_integral_dt", "<u4"),
                      ("accelerometer_clipping", "u1"), ("accel_calibration_count", "u1"),
                      ("gyro_calibration_count", "u1")])  # trailing padding is not logged
    out = np.zeros(len(t_us), dtype=dtype)
    out["timestamp"] = t_us
    for i in range(3):
        out[f"gyro_rad[{i}]"] = gyro_radps[:, i]
        out[f"accelerometer_m_s2[{i}]"] = accel_mps2[:, i]
    return out


def sensor_triplet_array(t_us: np.ndarray, values: np.ndarray, device_id: int, temperature_degc: float | np.ndarray,
                         ) -> np.ndarray:
    """A sensor_accel or sensor_gyro dataset (PX4 v1.14 fields the readers use: timestamp, timestamp_sample,
    device_id, x, y, z, temperature) for write_ulog: one sensor's own output."""
    dtype = np.dtype([("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("device_id", "<u4"), ("x", "<f4"),
                      ("y", "<f4"), ("z", "<f4"), ("temperature", "<f4"), ("error_count", "<u4")])
    out = np.zeros(len(t_us), dtype=dtype)
    out["timestamp"] = t_us
    out["timestamp_sample"] = t_us
    out["device_id"] = device_id
    for i, axis in enumerate("xyz"):
        out[axis] = values[:, i]
    out["temperature"] = temperature_degc
    return out


def sensor_selection_array(t_us: np.ndarray, accel_device_id: int, gyro_device_id: int) -> np.ndarray:
    """sensor_selection: the devices sensor_combined is fed from."""
    dtype = np.dtype([("timestamp", "<u8"), ("accel_device_id", "<u4"), ("gyro_device_id", "<u4")])
    out = np.zeros(len(t_us), dtype=dtype)
    out["timestamp"] = t_us
    out["accel_device_id"] = accel_device_id
    out["gyro_device_id"] = gyro_device_id
    return out
