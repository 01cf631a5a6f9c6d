"""The real recordings' messages read with rosbags (the reference reader, not ours), as arrays."""
from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore


class BagMessages(NamedTuple):
    """Imu rows (stamp ns, ax, ay, az, gx, gy, gz) and Temperature rows (stamp ns, degC), each sorted by
    header stamp; `arrival` lists every message in the order it was logged: (log time ns, is_imu, row)."""
    imu: np.ndarray
    imu_stamps_ns: np.ndarray
    temperature: np.ndarray
    temperature_stamps_ns: np.ndarray
    arrival: list[tuple[int, bool, int]]


@functools.lru_cache(maxsize=4)  # a recording read once per test run, whatever reads it
def read_imu_and_temperature(path: Path) -> BagMessages:
    imu: list[tuple[float, ...]] = []
    temperature: list[tuple[float, ...]] = []
    imu_ns: list[int] = []
    temperature_ns: list[int] = []
    logged: list[tuple[int, bool, int]] = []
    with AnyReader([Path(path)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for connection, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            if connection.msgtype == "sensor_msgs/msg/Imu":
                a, w = msg.linear_acceleration, msg.angular_velocity
                logged.append((log_ns, True, len(imu)))
                imu.append((a.x, a.y, a.z, w.x, w.y, w.z))
                imu_ns.append(stamp)
            else:
                logged.append((log_ns, False, len(temperature)))
                temperature.append((msg.temperature,))
                temperature_ns.append(stamp)
    imu_order, temperature_order = np.argsort(imu_ns, kind="stable"), np.argsort(temperature_ns, kind="stable")
    imu_rank, temperature_rank = np.argsort(imu_order), np.argsort(temperature_order)
    arrival = [(t, is_imu, int((imu_rank if is_imu else temperature_rank)[row])) for t, is_imu, row in sorted(logged)]
    return BagMessages(np.array(imu)[imu_order], np.array(imu_ns, dtype=np.int64)[imu_order],
                       np.array(temperature)[temperature_order, 0],
                       np.array(temperature_ns, dtype=np.int64)[temperature_order], arrival)
