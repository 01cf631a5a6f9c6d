"""sensor_msgs messages built from numbers (the synthetic publisher, the tests): integer nanoseconds as
stamps, plain attribute access (cheaper than numpy on 3-vectors)."""
from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import Imu, Temperature

NS = 1_000_000_000


def ns_to_stamp(t_ns: int) -> Time:
    sec, nanosec = divmod(int(t_ns), NS)
    return Time(sec=sec, nanosec=nanosec)


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


def make_temperature(t_ns: int, degc: float, frame_id: str = "imu_link") -> Temperature:
    msg = Temperature()
    msg.header.stamp = ns_to_stamp(t_ns)
    msg.header.frame_id = frame_id
    msg.temperature = float(degc)
    return msg
