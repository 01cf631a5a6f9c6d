"""sensor_msgs/msg/Imu and sensor_msgs/msg/Temperature from a bag's storage into arrays (SI units, stamps
in ns); a message that does not decode is one line.

Bulk decoding: an Imu's CDR layout is fixed apart from the header's frame_id string, so messages of
one length share every field offset; each such group is one uint8 matrix and each field one column
slice viewed as little-endian int32/uint32/float64. (Per-message deserialization costs ~10-13 us
here; this costs well under 1 us.) Only for the standard sensor_msgs/msg/Imu: a recording whose Imu
definition (or its hash) differs is read message by message through its own recorded definition, by
field name, or refused; and a metadata.yaml whose types disagree with the storage is refused.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from msg_tools.imu_cdr import imu_layout

from .bag_io import (
    IMU,
    TEMPERATURE,
    BagError,
    TopicInfo,
    check_recorded_types,
    declares_other_definition,
    is_standard_definition,
    jazzy_deserialize,
    reader_is_standard,
    recorded_definitions,
    refuse_special_files,
    scan_sqlite,
    storage_of,
)

if TYPE_CHECKING:
    from .progress import ProgressBar

# (raw CDR bytes, message type) -> the decoded message (rosbags' objects: untyped, so Any)
Deserialize = Callable[[bytes, str], Any]
Temperatures = tuple[np.ndarray, np.ndarray]  # (stamps ns, degC)


@dataclass
class ImuData:
    topic: str
    t_ns: np.ndarray  # header stamps, in the order read (not yet sorted)
    accel: np.ndarray  # (N, 3) m/s^2
    gyro: np.ndarray  # (N, 3) rad/s
    frame_id: str


def read_fast(path: str | os.PathLike[str], imu_topic: TopicInfo, temperature_topic: TopicInfo | None,
              progress: ProgressBar | None = None) -> tuple[ImuData, Temperatures | None] | None:
    """Both topics straight from the storage files (no rosbags reader), or None to fall back."""
    refuse_special_files(path)
    wanted = [imu_topic] + ([temperature_topic] if temperature_topic else [])
    if declares_other_definition(wanted):
        return None  # rosbags reads it through its own definition, checked against this hash
    topics = [topic.topic for topic in wanted]
    if storage_of(path) == "mcap":
        from .mcap_scan import scan_topics

        recorded: dict[str, tuple[str, str, str]] | None = {}
        found = scan_topics(path, topics, progress, schemas=recorded)
    else:
        found = scan_sqlite(path, topics, progress)
        recorded = recorded_definitions(path) if found is not None else None
    if found is None or len(found[imu_topic.topic]) != imu_topic.msgcount:
        return None
    check_recorded_types(path, wanted, recorded)
    if not all(is_standard_definition(topic, recorded) for topic in wanted):
        return None
    t, accel, gyro, frame_id, *_ = decode_imus(found[imu_topic.topic], path, jazzy_deserialize)
    imu = ImuData(imu_topic.topic, t, accel, gyro, frame_id)
    temperatures = None
    if temperature_topic is not None:
        temperatures = decode_temperatures(found[temperature_topic.topic], path, jazzy_deserialize)
    return imu, temperatures



def read_imu_and_temperature(reader: Any, imu_connection: Any, temperature_connection: Any,
                             path: str | os.PathLike[str], progress: ProgressBar | None = None
                             ) -> tuple[ImuData, Temperatures | None]:
    """Through rosbags, one pass for both topics (a second pass would decompress every mcap chunk
    again), in rosbags' message order.
    Returns (ImuData, (temperature stamps, values) or None)."""
    raws: list[bytes] = []
    temperature_raws: list[bytes] = []
    connections = [imu_connection] + ([temperature_connection] if temperature_connection is not None else [])
    check_recorded_types(path, [TopicInfo(c.topic, c.msgtype, 0) for c in connections], recorded_definitions(path))
    imu_id = imu_connection.id
    step = 0
    for connection, _, raw in reader.messages(connections=connections):
        if connection.id == imu_id:
            raws.append(raw)
        else:
            temperature_raws.append(raw)
        if progress is not None:
            step += 1
            if step == 4096:
                progress.update(step)
                step = 0
    if progress is not None:
        progress.update(step)
    t, accel, gyro, frame_id, *_ = decode_imus(raws, path, reader.deserialize, fixed_layout=reader_is_standard(reader))
    imu = ImuData(imu_connection.topic, t, accel, gyro, frame_id)
    temperatures = None
    if temperature_connection is not None:
        temperatures = decode_temperatures(temperature_raws, path, reader.deserialize)
    return imu, temperatures



def _fixed_temperatures(raws: Sequence[bytes]) -> Temperatures | None:
    """(stamps ns, degC) of standard little-endian sensor_msgs/Temperature messages read at their fixed
    offsets, as decode_imus does; None when any message is otherwise (decode_temperatures then says which)."""
    from .mcap_scan import PackedMessages

    if not isinstance(raws, PackedMessages) or len(raws) == 0:
        return None
    stamps = np.empty(len(raws), dtype=np.int64)
    values = np.empty(len(raws))
    for length in np.unique(raws.lengths):
        index = np.flatnonzero(raws.lengths == length)
        block = raws.block(index)
        if length < 16 or not (block[:, 1] == 1).all():
            return None
        string_length = block[:, 12:16].copy().view("<u4").ravel()
        if not np.all(string_length == string_length[0]):
            return None
        temperature = 4 + ((12 + int(string_length[0]) + 7) // 8) * 8  # doubles align to 8 in the body
        if temperature + 16 != length:  # temperature, variance: nothing else may follow
            return None
        sec = block[:, 4:8].copy().view("<i4").ravel().astype(np.int64)
        stamps[index] = sec * 1_000_000_000 + block[:, 8:12].copy().view("<u4").ravel().astype(np.int64)
        values[index] = block[:, temperature:temperature + 8].copy().view("<f8").ravel()
    return stamps, values


def decode_temperatures(raws: Sequence[bytes], path: str | os.PathLike[str], deserialize: Deserialize
                        ) -> Temperatures:
    """(stamps ns, degC) of sensor_msgs/Temperature messages: read at their fixed offsets where they are
    packed standard ones (_fixed_temperatures), else one by one; a message that does not decode is one
    BagError naming it."""
    fixed = _fixed_temperatures(raws)
    if fixed is not None:
        return fixed
    stamps = np.empty(len(raws), dtype=np.int64)
    values = np.empty(len(raws))
    for i, raw in enumerate(raws):
        try:
            msg = deserialize(raw, TEMPERATURE)
            stamps[i] = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
            values[i] = float(msg.temperature)
        except Exception as error:  # noqa: BLE001 - rosbags raises several types for damaged bytes
            raise BagError(f"{path}: temperature message {i + 1} does not decode as {TEMPERATURE} "
                           f"({type(error).__name__}): a damaged recording") from None
    return stamps, values



def _imu_by_name(raw: bytes, index: int, path: str | os.PathLike[str], deserialize: Deserialize
                 ) -> tuple[int, tuple[float, float, float], tuple[float, float, float], str]:
    """(stamp ns, accel, gyro, frame_id) of one message through `deserialize` (the recording's own
    definition), by field name; a missing field or damaged bytes is one BagError naming the message."""
    try:
        msg = deserialize(raw, IMU)
    except Exception as error:  # noqa: BLE001 - rosbags raises several types for damaged bytes
        raise BagError(f"{path}: IMU message {index + 1} does not decode as {IMU} ({type(error).__name__}): "
                       "a damaged recording") from None
    try:
        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        a, w = msg.linear_acceleration, msg.angular_velocity
        accel = (float(a.x), float(a.y), float(a.z))
        gyro = (float(w.x), float(w.y), float(w.z))
        frame_id = str(msg.header.frame_id)
    except (AttributeError, TypeError, ValueError, OverflowError) as error:
        raise BagError(f"{path}: its recorded {IMU} definition lacks what an IMU message has "
                       f"({error}): cannot read it as accelerations") from None
    return stamp, accel, gyro, frame_id


def decode_imus(raws: Sequence[bytes], path: str | os.PathLike[str], deserialize: Deserialize,
                fixed_layout: bool = True
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, dict[int, tuple[np.ndarray, dict[str, int]]],
                           np.ndarray, np.ndarray]:
    """`fixed_layout`: the messages are the standard sensor_msgs/msg/Imu, so fields sit at known offsets
    (the bulk path); False reads every message through `deserialize` by field name."""
    from .mcap_scan import PackedMessages  # payload matrices straight from the storage: no join

    if isinstance(raws, PackedMessages):
        lengths = raws.lengths
    else:
        lengths = np.fromiter((len(r) for r in raws), dtype=np.int64, count=len(raws))
    t = np.empty(len(raws), dtype=np.int64)
    accel = np.empty((len(raws), 3))
    gyro = np.empty((len(raws), 3))
    group_of = np.empty(len(raws), dtype=np.int64)
    row_of = np.empty(len(raws), dtype=np.int64)
    groups: dict[int, tuple[np.ndarray, dict[str, int]]] = {}
    frame_id = ""
    for length in np.unique(lengths):
        index = np.flatnonzero(lengths == length)
        if isinstance(raws, PackedMessages):
            block = raws.block(index)
        else:
            joined = b"".join([raws[int(i)] for i in index])
            block = np.frombuffer(joined, dtype=np.uint8).reshape(len(index), int(length))
        layout = None
        if fixed_layout and length >= 16:
            little = block[:, 1] == 1
            string_length = block[:, 12:16].copy().view("<u4").ravel()
            if little.all() and np.all(string_length == string_length[0]):
                layout = imu_layout(int(string_length[0]))
                if layout["size"] != length:
                    layout = None
        if layout is None:
            # Big-endian, unusual or another definition: deserialize one by one (rare; correctness first).
            for i in index:
                t[i], accel[i], gyro[i], message_frame = _imu_by_name(raws[int(i)], int(i), path, deserialize)
                frame_id = frame_id or message_frame
            group_of[index] = -1
            continue
        sec = block[:, 4:8].copy().view("<i4").ravel().astype(np.int64)
        nanosec = block[:, 8:12].copy().view("<u4").ravel().astype(np.int64)
        t[index] = sec * 1_000_000_000 + nanosec
        gyro[index] = block[:, layout["gyro"]:layout["gyro"] + 24].copy().view("<f8")
        accel[index] = block[:, layout["accel"]:layout["accel"] + 24].copy().view("<f8")
        frame_id = frame_id or bytes(block[0, 16:16 + int(string_length[0]) - 1]).decode("utf-8", "replace")
        groups[int(length)] = (block, layout)
        group_of[index] = int(length)
        row_of[index] = np.arange(len(index))
    return t, accel, gyro, frame_id, groups, group_of, row_of
