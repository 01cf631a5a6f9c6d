"""A copy of a bag with its IMU messages corrected: every other message, topic and definition copied as
recorded, the IMU messages' angular_velocity, linear_acceleration and their covariances replaced, read and
written a group at a time (memory bounded whatever the bag's size)."""
from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from .bag_io import IMU, BagError, open_reader, reader_is_standard, storage_of
from .imu_messages import decode_imus

# A corrected copy is read, corrected and written a group at a time: this many IMU messages, or this many
# bytes of messages of any topic (camera images between them), whichever comes first.
COPY_GROUP_MESSAGES = 1 << 14
COPY_GROUP_BYTES = 64 << 20

# (stamps ns, accel (N, 3), gyro (N, 3), linear_acceleration_covariance (N, 9), angular_velocity_covariance
# (N, 9)) -> the same four corrected
CorrectImu = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                      tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]


def write_corrected(source: str | os.PathLike[str], destination: str | os.PathLike[str], imu_topic: str,
                    correct: CorrectImu, *,
                    group_messages: int = COPY_GROUP_MESSAGES, group_bytes: int = COPY_GROUP_BYTES) -> int:
    """Copy every topic of `source` to a new bag `destination`, unchanged except the IMU topic's
    angular_velocity, linear_acceleration and their covariances, which become what `correct` gives (same
    topic, same stamps, same storage type). Streamed: memory is a group of messages, whatever the bag's
    length; the result does not depend on the groups. Returns messages written."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    destination = Path(destination)
    if destination.exists():
        raise BagError(f"{destination}: already exists (rosbag2 writes a new directory)")
    plugin = StoragePlugin.MCAP if storage_of(source) == "mcap" else StoragePlugin.SQLITE3
    reader = open_reader(source)
    written = 0
    created = False  # the destination is ours to remove only once our Writer has made it
    try:
        standard = reader_is_standard(reader)
        with Writer(destination, version=9, storage_plugin=plugin) as writer:
            created = True
            out: dict[int, Any] = {}  # connection id: the writer's connection (rosbags ships no types)
            for c in reader.connections:
                out[c.id] = writer.add_connection(
                    c.topic, c.msgtype, typestore=reader.typestore,
                    # A single storage file read without metadata.yaml has no digest: the typestore gives both.
                    msgdef=c.msgdef.data if c.msgdef else None, rihs01=c.digest or None,
                    serialization_format=c.ext.serialization_format, offered_qos_profiles=c.ext.offered_qos_profiles,
                )
            pending: list[tuple[int, int, bytes | None]] = []  # (connection id, log time, raw; None for an IMU
            # message), in log order
            imu_raws: list[bytes] = []
            held = 0

            def flush() -> None:
                corrected = iter(_corrected_imus(imu_raws, reader, correct, source, standard))
                for connection_id, timestamp, raw in pending:
                    writer.write(out[connection_id], timestamp, next(corrected) if raw is None else raw)
                pending.clear()
                imu_raws.clear()

            for c, timestamp, raw in reader.messages():
                if c.topic == imu_topic and c.msgtype == IMU:
                    imu_raws.append(raw)
                    pending.append((c.id, timestamp, None))
                else:
                    pending.append((c.id, timestamp, raw))
                held += len(raw)
                written += 1
                if len(imu_raws) >= group_messages or held >= group_bytes:
                    flush()
                    held = 0
            flush()
    except Exception as error:  # noqa: BLE001 - rosbags' reader and writer raise their own types
        import shutil

        if created:  # ours, half written; never another writer's bag that appeared after our check
            shutil.rmtree(destination, ignore_errors=True)
        if isinstance(error, BagError):
            raise
        first_line = str(error).splitlines()[0][:120] if str(error) else ""
        raise BagError(f"{destination}: corrected bag not written ({type(error).__name__}: {first_line})") from None
    finally:
        reader.close()
    return written


def _corrected_imus(raws: list[bytes], reader: Any, correct: CorrectImu, path: str | os.PathLike[str],
                    standard: bool) -> list[bytes]:
    """The IMU messages `raws` with angular_velocity, linear_acceleration and their covariances replaced by
    what `correct` gives: the bytes patched in place where the layout is the standard one, else through the
    recorded definition."""
    if not raws:
        return []
    t, accel, gyro, _, groups, group_of, row_of = decode_imus(raws, path, reader.deserialize, fixed_layout=standard)
    # Each covariance follows its vector in the message (CDR: 3 doubles, then 9).
    covariance, angular = np.zeros((len(t), 9)), np.zeros((len(t), 9))
    for length, (block, layout) in groups.items():
        rows = np.flatnonzero(group_of == length)
        for values, field in ((covariance, "accel"), (angular, "gyro")):
            start = layout[field] + 24
            values[rows] = block[row_of[rows], start:start + 72].copy().view("<f8").reshape(len(rows), 9)
    by_name = np.flatnonzero(group_of < 0)
    messages = {int(i): reader.deserialize(raws[int(i)], IMU) for i in by_name}
    for i, msg in messages.items():
        covariance[i] = np.asarray(msg.linear_acceleration_covariance, dtype=float)
        angular[i] = np.asarray(msg.angular_velocity_covariance, dtype=float)
    accel, gyro, covariance, angular = correct(t, accel, gyro, covariance, angular)
    patched = {}
    for length, (block, layout) in groups.items():
        rows = np.flatnonzero(group_of == length)
        block = block.copy()
        for field, values, width in (("gyro", gyro, 24), ("accel", accel, 24)):
            block[row_of[rows], layout[field]:layout[field] + width] = \
                np.ascontiguousarray(values[rows], dtype="<f8").view(np.uint8).reshape(len(rows), width)
        for field, values in (("accel", covariance), ("gyro", angular)):
            start = layout[field] + 24
            block[row_of[rows], start:start + 72] = \
                np.ascontiguousarray(values[rows], dtype="<f8").view(np.uint8).reshape(len(rows), 72)
        patched[length] = block
    out = []
    for i, (group, row) in enumerate(zip(group_of.tolist(), row_of.tolist())):
        if group >= 0:
            out.append(patched[int(group)][row].tobytes())
            continue
        msg = messages[i]
        msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (float(v) for v in accel[i])
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = (float(v) for v in gyro[i])
        msg.linear_acceleration_covariance = np.asarray(covariance[i], dtype=float)
        msg.angular_velocity_covariance = np.asarray(angular[i], dtype=float)
        out.append(bytes(reader.typestore.serialize_cdr(msg, IMU)))
    return out
