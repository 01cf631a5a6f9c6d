"""sensor_msgs <-> numpy and stamps <-> integer nanoseconds. Per-message helpers use plain attribute
access (cheaper than numpy on 3-vectors); list helpers build arrays once."""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import Imu, Temperature

NS = 1_000_000_000


def stamp_to_ns(stamp: Any) -> int:
    """A builtin_interfaces Time (or anything with sec and nanosec) as integer nanoseconds."""
    return int(stamp.sec) * NS + int(stamp.nanosec)


def ns_to_stamp(t_ns: int) -> Time:
    sec, nanosec = divmod(int(t_ns), NS)
    return Time(sec=sec, nanosec=nanosec)


def imu_to_tuple(msg: Imu) -> tuple[int, tuple[float, float, float], tuple[float, float, float]]:
    """(t_ns, (ax, ay, az), (gx, gy, gz)) in m/s^2 and rad/s."""
    a, w = msg.linear_acceleration, msg.angular_velocity
    return stamp_to_ns(msg.header.stamp), (a.x, a.y, a.z), (w.x, w.y, w.z)


def imus_to_arrays(msgs: Iterable[Imu]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rows = [imu_to_tuple(m) for m in msgs]
    t = np.array([r[0] for r in rows], dtype=np.int64)
    return (t, np.array([r[1] for r in rows], dtype=float).reshape(-1, 3),
            np.array([r[2] for r in rows], dtype=float).reshape(-1, 3))


def make_imu(t_ns: int, accel: Iterable[float], gyro: Iterable[float], frame_id: str = "imu_link",
             accel_cov: Any = None, gyro_cov: Any = None) -> Imu:
    msg = Imu()
    msg.header.stamp = ns_to_stamp(t_ns)
    msg.header.frame_id = frame_id
    msg.orientation_covariance[0] = -1.0  # REP-145: no orientation estimate
    a, w = msg.linear_acceleration, msg.angular_velocity
    a.x, a.y, a.z = (float(v) for v in accel)
    w.x, w.y, w.z = (float(v) for v in gyro)
    if accel_cov is not None:
        msg.linear_acceleration_covariance = [float(v) for v in np.asarray(accel_cov).ravel()]
    if gyro_cov is not None:
        msg.angular_velocity_covariance = [float(v) for v in np.asarray(gyro_cov).ravel()]
    return msg


def temperature_to_tuple(msg: Temperature) -> tuple[int, float]:
    return stamp_to_ns(msg.header.stamp), msg.temperature


def make_temperature(t_ns: int, degc: float, frame_id: str = "imu_link") -> Temperature:
    msg = Temperature()
    msg.header.stamp = ns_to_stamp(t_ns)
    msg.header.frame_id = frame_id
    msg.temperature = float(degc)
    return msg
