"""The node's hot path: one Imu in, the raw sample pushed into the ring (live/per_message.py), the correction
in force applied, the corrected Imu out. Nothing here waits for a fit, a file or the worker process.

The message comes as its serialised bytes: the stamp, frame_id and both vectors are read at their CDR
offsets (msg_tools/imu_cdr.py) and the output is the same bytes patched in place (the covariances written
through numpy views of it); building a Python Imu and serialising it again is most of a relay's CPU per
message. Any layout but the standard little-endian one, and a frame_id that is not UTF-8, go through the
message path (`take`), which publishes what serialising its output gives: the same bytes
(test_imu_cdr_path.py). core.correction's one correction, as every corrected copy of a recording.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu

from msg_tools.imu_cdr import COVARIANCE_AFTER, FRAME_AT, STAMP, VECTOR, frame_id_length, imu_offsets

from ..core.correction import Correction
from ..live.per_message import LiveStream

__all__ = ["ImuPath"]


class ImuPath:
    def __init__(self, stream: LiveStream, publisher: Any):
        self._stream = stream
        self._publisher = publisher  # imu/data_calibrated
        self.last_seen: float | None = None  # monotonic time of the latest Imu (the silence check reads it)
        self._frame_bytes: bytes | None = None  # the frame_id of the last Imu read as bytes

    def take_cdr(self, raw: bytes) -> None:
        """One Imu as its serialised bytes: the same correction as `take`, the same bytes out as
        serialising its message (test_imu_cdr_path); any layout but the standard little-endian one goes
        through `take`."""
        offsets = imu_offsets(raw)
        if offsets is None:
            if frame_id_length(raw) == 0:
                raise ValueError("an Imu whose frame_id length is 0 (a CDR string counts its NUL) is damaged: "
                                 "not published")
            self.take(deserialize_message(raw, Imu))
            return
        frame_end, gyro_at, accel_at = offsets
        stream = self._stream
        frame = raw[FRAME_AT:frame_end]
        if frame != self._frame_bytes:  # the frame_id's text only when its bytes change
            try:
                frame_id = frame.decode()
            except UnicodeDecodeError:  # rclpy replaces each bad byte, which changes the message's length
                self.take(deserialize_message(raw, Imu))
                return
            if frame_id != stream.frame_id:
                stream.set_frame_id(frame_id)
            self._frame_bytes = frame
        self.last_seen = time.monotonic()
        sec, nanosec = STAMP.unpack_from(raw, 4)
        gx, gy, gz = VECTOR.unpack_from(raw, gyro_at)
        ax, ay, az = VECTOR.unpack_from(raw, accel_at)
        stream.buffer_imu(sec * 1_000_000_000 + nanosec, ax, ay, az, gx, gy, gz)
        correction = self._correction_for(ax, ay, az)
        if correction is not None:
            out = bytearray(raw)
            VECTOR.pack_into(out, accel_at, *correction.apply(ax, ay, az))
            VECTOR.pack_into(out, gyro_at, *correction.apply_gyro(gx, gy, gz))
            correction.covariance_into(np.frombuffer(out, "<f8", 9, accel_at + COVARIANCE_AFTER))
            correction.angular_covariance_into(np.frombuffer(out, "<f8", 9, gyro_at + COVARIANCE_AFTER), gx, gy, gz)
            raw = bytes(out)
        self._publisher.publish(raw)

    def take(self, msg: Imu) -> None:
        """One Imu as rclpy's message."""
        header = msg.header
        stream = self._stream
        if header.frame_id != stream.frame_id:
            stream.set_frame_id(header.frame_id)
            self._frame_bytes = None  # the bytes path compares its next frame_id again
        self.last_seen = time.monotonic()
        a, w = msg.linear_acceleration, msg.angular_velocity
        ax, ay, az, gx, gy, gz = a.x, a.y, a.z, w.x, w.y, w.z
        stream.buffer_imu(header.stamp.sec * 1_000_000_000 + header.stamp.nanosec, ax, ay, az, gx, gy, gz)
        correction = self._correction_for(ax, ay, az)
        if correction is not None:
            a.x, a.y, a.z = correction.apply(ax, ay, az)
            w.x, w.y, w.z = correction.apply_gyro(gx, gy, gz)
            correction.covariance_into(msg.linear_acceleration_covariance)
            correction.angular_covariance_into(msg.angular_velocity_covariance, gx, gy, gz)
        self._publisher.publish(msg)  # non-finite samples pass on untouched: the stack sees what the driver sent

    def _correction_for(self, ax: float, ay: float, az: float) -> Correction | None:
        """The correction a sample gets, both paths: none while switched off, or for a non-finite acceleration
        (it passes on untouched: the stack sees what the driver sent)."""
        stream = self._stream
        correction = stream.in_force.correction
        if correction is None or not stream.enabled \
                or not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az)):
            return None
        return correction
