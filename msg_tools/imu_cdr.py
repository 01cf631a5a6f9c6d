"""sensor_msgs/msg/Imu as its CDR bytes: where each field sits in the standard little-endian layout, which is
fixed apart from the header's frame_id string. A bag's reader decodes whole groups of messages with it, and the
node reads and patches each message's bytes in place of building a Python message and serialising it again
(rclpy's conversion is most of a bare relay's CPU per message). Nothing here imports ROS.

Layout (XCDR1, little-endian): 4 bytes of encapsulation (00 01 00 00), stamp (int32 sec, uint32 nanosec),
frame_id (uint32 length with its NUL, the bytes, the NUL), then doubles aligned to 8 from the end of the
encapsulation: orientation (4) and its covariance (9), angular_velocity (3) and its covariance (9),
linear_acceleration (3) and its covariance (9).
"""
from __future__ import annotations

import struct
from functools import lru_cache
from typing import NamedTuple

__all__ = ["STAMP", "VECTOR", "ImuOffsets", "frame_id_length", "imu_layout", "imu_offsets"]

STAMP = struct.Struct("<iI")  # sec, nanosec at byte 4
VECTOR = struct.Struct("<3d")  # a Vector3
COVARIANCE_AFTER = 24  # each covariance follows its vector
FRAME_AT = 16  # the frame_id's first byte


def imu_layout(frame_id_length: int) -> dict[str, int]:
    """Byte offsets in a little-endian CDR Imu whose frame_id has this many bytes (with its NUL)."""
    end_of_string = 4 + 8 + 4 + frame_id_length  # encapsulation, stamp, length, chars
    body = end_of_string - 4
    orientation = 4 + ((body + 7) // 8) * 8  # doubles align to 8 from the start of the body
    gyro = orientation + 32 + 72
    accel = gyro + 24 + 72
    return {"gyro": gyro, "accel": accel, "size": accel + 24 + 72}


class ImuOffsets(NamedTuple):
    frame_end: int  # the frame_id's bytes are raw[FRAME_AT:frame_end] (its NUL excluded)
    gyro: int  # angular_velocity; its covariance at gyro + COVARIANCE_AFTER
    accel: int  # linear_acceleration; its covariance at accel + COVARIANCE_AFTER


def imu_offsets(raw: bytes) -> ImuOffsets | None:
    """The offsets of one serialised Imu when it is the standard little-endian layout, whole; else None
    (big-endian, another encapsulation, another definition, cut short or padded oddly): such a message is
    for the full deserialiser, which decides."""
    if len(raw) < FRAME_AT + 1 or raw[0] != 0 or raw[1] != 1:
        return None
    return _offsets(len(raw), int.from_bytes(raw[12:16], "little"))


def frame_id_length(raw: bytes) -> int | None:
    """The frame_id's length field (its NUL counted) in the message's own byte order, or None where the
    bytes are too short to hold it or the encapsulation is not plain CDR. 0 is no string at all: a damaged
    message, whose fields after it a deserialiser reads shifted."""
    if len(raw) < FRAME_AT or raw[0] != 0 or raw[1] not in (0, 1):
        return None
    return int.from_bytes(raw[12:16], "little" if raw[1] == 1 else "big")


@lru_cache(maxsize=256)
def _offsets(size: int, frame_id_length: int) -> ImuOffsets | None:
    if frame_id_length < 1:  # CDR counts the NUL: an empty frame_id is 1
        return None
    layout = imu_layout(frame_id_length)
    if layout["size"] != size:
        return None
    return ImuOffsets(FRAME_AT + frame_id_length - 1, layout["gyro"], layout["accel"])
