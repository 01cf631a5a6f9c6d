"""rosbag2 in and out with the `rosbags` library (no ROS install): find the IMU and temperature topics,
decode sensor_msgs/Imu in bulk, and write a copy of a bag with the IMU accelerations replaced.

Bulk decoding: an Imu's CDR layout is fixed apart from the header's frame_id string, so messages of
one length share every field offset; each such group is one uint8 matrix and each field one column
slice viewed as little-endian int32/uint32/float64. (Per-message deserialization costs ~10-13 us
here; this costs well under 1 us.)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import AccelCalibrationError

IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"


class BagError(AccelCalibrationError):
    """A bag that cannot be used: the message names the bag and what was found."""


@dataclass
class ImuData:
    topic: str
    t_ns: np.ndarray  # header stamps, in the order read (not yet sorted)
    accel: np.ndarray  # (N, 3) m/s^2
    gyro: np.ndarray  # (N, 3) rad/s
    frame_id: str
    # For writing a corrected copy: per message, its length group and row in that group's matrix.
    groups: dict
    group_of: np.ndarray
    row_of: np.ndarray


def open_reader(path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as error:  # rosbags raises its own types per storage; one line for any of them
        first_line = str(error).splitlines()[0] if str(error) else ""
        raise BagError(f"{path}: not a readable rosbag2 ({type(error).__name__}: {first_line})") from None
    return reader


def storage_of(path) -> str:
    return "mcap" if any(Path(path).glob("*.mcap")) else "sqlite3"


@dataclass(frozen=True)
class TopicInfo:
    """What metadata.yaml says of a topic (enough to choose and read it without opening the bag)."""

    topic: str
    msgtype: str
    msgcount: int


def metadata_topics(path) -> list[TopicInfo] | None:
    """Topics from the bag's metadata.yaml, or None when it is missing or unexpected."""
    import yaml

    try:
        info = yaml.safe_load((Path(path) / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        if info.get("compression_format"):  # whole-file compression: leave it to rosbags
            return None
        return [TopicInfo(t["topic_metadata"]["name"], t["topic_metadata"]["type"], int(t["message_count"]))
                for t in info["topics_with_message_count"]]
    except (OSError, KeyError, TypeError, ValueError, yaml.YAMLError):
        return None


def read_fast(path, imu_topic: TopicInfo, temperature_topic: TopicInfo | None, progress=None):
    """Both topics straight from the storage files (no rosbags reader), or None to fall back."""
    from rosbags.typesys import Stores, get_typestore

    topics = [imu_topic.topic] + ([temperature_topic.topic] if temperature_topic else [])
    if storage_of(path) == "mcap":
        from .mcap_scan import scan_topics

        found = scan_topics(path, topics, progress)
    else:
        found = _scan_sqlite(path, topics, progress)
    if found is None or len(found[imu_topic.topic]) != imu_topic.msgcount:
        return None
    typestore = get_typestore(Stores.ROS2_JAZZY)
    t, accel, gyro, frame_id, groups, group_of, row_of = decode_imus(found[imu_topic.topic], path,
                                                                     typestore.deserialize_cdr)
    imu = ImuData(imu_topic.topic, t, accel, gyro, frame_id, groups, group_of, row_of)
    temperatures = None
    if temperature_topic is not None:
        messages = [typestore.deserialize_cdr(raw, TEMPERATURE) for raw in found[temperature_topic.topic]]
        temperatures = (np.array([m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in messages],
                                 dtype=np.int64),
                        np.array([m.temperature for m in messages], dtype=float))
    return imu, temperatures


def choose_topic(connections, msgtype: str, wanted: str | None, label: str, path) -> object | None:
    """The connection (or TopicInfo) of `msgtype` to use; None when there is none and none was asked for."""
    found = [c for c in connections if c.msgtype == msgtype]
    if wanted is not None:
        chosen = [c for c in found if c.topic == wanted]
        if not chosen:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in connections})) or "no topics"
            raise BagError(f"{path}: no {msgtype} topic {wanted}; the bag has {have}")
        return chosen[0]
    if len(found) > 1:
        raise BagError(f"{path}: several {msgtype} topics ({', '.join(c.topic for c in found)}): "
                       f"choose one with --{label}-topic")
    return found[0] if found else None


def _layout(frame_id_length: int) -> dict:
    """Byte offsets in a little-endian CDR Imu whose frame_id has this many bytes (with its NUL)."""
    end_of_string = 4 + 8 + 4 + frame_id_length  # encapsulation, stamp, length, chars
    body = end_of_string - 4
    orientation = 4 + ((body + 7) // 8) * 8  # doubles align to 8 from the start of the body
    gyro = orientation + 32 + 72
    accel = gyro + 24 + 72
    return {"gyro": gyro, "accel": accel, "size": accel + 24 + 72}


def decode_imus(raws: list, path, deserialize
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, str, dict, np.ndarray, np.ndarray]:
    lengths = np.fromiter((len(r) for r in raws), dtype=np.int64, count=len(raws))
    t = np.empty(len(raws), dtype=np.int64)
    accel = np.empty((len(raws), 3))
    gyro = np.empty((len(raws), 3))
    group_of = np.empty(len(raws), dtype=np.int64)
    row_of = np.empty(len(raws), dtype=np.int64)
    groups = {}
    frame_id = ""
    for length in np.unique(lengths):
        index = np.flatnonzero(lengths == length)
        block = np.frombuffer(b"".join([raws[i] for i in index]), dtype=np.uint8).reshape(len(index), int(length))
        little = block[:, 1] == 1
        string_length = block[:, 12:16].copy().view("<u4").ravel()
        layout = None
        if little.all() and np.all(string_length == string_length[0]):
            layout = _layout(int(string_length[0]))
            if layout["size"] != length:
                layout = None
        if layout is None:
            # Big-endian or unusual messages: deserialize one by one (rare; correctness first).
            for i in index:
                msg = deserialize(raws[i], IMU)
                t[i] = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                a, w = msg.linear_acceleration, msg.angular_velocity
                accel[i], gyro[i] = (a.x, a.y, a.z), (w.x, w.y, w.z)
                frame_id = frame_id or msg.header.frame_id
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


def read_imu_and_temperature(reader, imu_connection, temperature_connection, path, progress=None):
    """Through rosbags, one pass for both topics (a second pass would decompress every mcap chunk
    again), in rosbags' message order, which writing a corrected copy relies on.
    Returns (ImuData, (temperature stamps, values) or None)."""
    raws = []
    temperature_raws = []
    connections = [imu_connection] + ([temperature_connection] if temperature_connection is not None else [])
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
    t, accel, gyro, frame_id, groups, group_of, row_of = decode_imus(raws, path, reader.deserialize)
    imu = ImuData(imu_connection.topic, t, accel, gyro, frame_id, groups, group_of, row_of)
    temperatures = None
    if temperature_connection is not None:
        stamps, values = [], []
        for raw in temperature_raws:
            msg = reader.deserialize(raw, TEMPERATURE)
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            values.append(msg.temperature)
        temperatures = (np.array(stamps, dtype=np.int64), np.array(values, dtype=float))
    return imu, temperatures


def _scan_sqlite(path, topics, progress=None) -> dict[str, list] | None:
    """{topic: [data, ...]} straight from rosbag2's sqlite3 tables (one query per file), or None when
    the layout is not the expected one (the caller falls back to rosbags)."""
    import sqlite3

    out = {topic: [] for topic in topics}
    try:
        for file in sorted(Path(path).glob("*.db3")):
            connection = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
            try:
                ids = dict(connection.execute("SELECT id, name FROM topics").fetchall())
                for topic_id, name in ids.items():
                    if name in out:
                        rows = connection.execute("SELECT data FROM messages WHERE topic_id = ? ORDER BY timestamp, id",
                                                  (topic_id,)).fetchall()
                        out[name].extend(row[0] for row in rows)
                        if progress is not None:
                            progress.update(len(rows))
            finally:
                connection.close()
    except sqlite3.Error:
        return None
    return out


def write_corrected(source, destination, imu: ImuData, corrected_accel: np.ndarray) -> int:
    """Copy every topic of `source` to a new bag `destination`, unchanged except the IMU topic's
    linear_acceleration (same topic, same stamps, same storage type). Returns messages written."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    destination = Path(destination)
    if destination.exists():
        raise BagError(f"{destination}: already exists (rosbag2 writes a new directory)")
    patched = {length: block.copy() for length, (block, _) in imu.groups.items()}
    for length, (_block, layout) in imu.groups.items():
        rows = np.flatnonzero(imu.group_of == length)
        values = np.ascontiguousarray(corrected_accel[rows], dtype="<f8").view(np.uint8).reshape(len(rows), 24)
        patched[length][imu.row_of[rows], layout["accel"]:layout["accel"] + 24] = values
    plugin = StoragePlugin.MCAP if storage_of(source) == "mcap" else StoragePlugin.SQLITE3
    reader = open_reader(source)
    written = 0
    try:
        with Writer(destination, version=9, storage_plugin=plugin) as writer:
            out = {}
            for c in reader.connections:
                out[c.id] = writer.add_connection(
                    c.topic, c.msgtype, typestore=reader.typestore,
                    msgdef=c.msgdef.data if c.msgdef else None, rihs01=c.digest,
                    serialization_format=c.ext.serialization_format, offered_qos_profiles=c.ext.offered_qos_profiles,
                )
            k = 0
            for c, timestamp, raw in reader.messages():
                if c.topic == imu.topic and c.msgtype == IMU:
                    group = imu.group_of[k]
                    if group >= 0:
                        raw = patched[int(group)][imu.row_of[k]].tobytes()
                    else:
                        raw = _patch_one(reader, raw, corrected_accel[k])
                    k += 1
                writer.write(out[c.id], timestamp, raw)
                written += 1
    finally:
        reader.close()
    return written


def _patch_one(reader, raw, accel) -> bytes:
    msg = reader.deserialize(raw, IMU)
    msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = (float(v) for v in accel)
    return bytes(reader.typestore.serialize_cdr(msg, IMU))


def write_session_bag(path, samples, *, start_ns: int, storage: str = "sqlite3", frame_id: str = "imu_link",
                      temperature_period_s: float = 0.1, imu_topic: str = "/imu/data_raw",
                      temperature_topic: str | None = "/imu/temperature", shuffle_seed: int | None = None) -> int:
    """Record a SyntheticSamples session as a rosbag2 (what `ros2 bag record` of the synthetic publisher
    would give), serialized by rosbags itself. `shuffle_seed` swaps neighbouring IMU messages in the
    file order, as recorders do when messages arrive out of order. Returns IMU messages written."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    Imu, Temperature = store.types[IMU], store.types[TEMPERATURE]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    Vector3, Quaternion = store.types["geometry_msgs/msg/Vector3"], store.types["geometry_msgs/msg/Quaternion"]
    covariance = np.zeros(9)
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0

    def header(t):
        sec, nanosec = divmod(int(t), 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    records = []
    next_temperature = -1
    for i, t in enumerate(samples.t_ns.tolist()):
        stamp = start_ns + t
        if temperature_topic and t >= next_temperature:
            records.append((stamp, "t", i))
            next_temperature = t + int(temperature_period_s * 1e9)
        records.append((stamp, "i", i))
    if shuffle_seed is not None:
        rng = np.random.default_rng(shuffle_seed)
        imu_positions = [k for k, r in enumerate(records) if r[1] == "i"]
        for k in rng.choice(len(imu_positions) - 1, size=len(imu_positions) // 20, replace=False):
            a, b = imu_positions[k], imu_positions[k + 1]
            records[a], records[b] = records[b], records[a]
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        imu_connection = writer.add_connection(imu_topic, IMU, typestore=store)
        temperature_connection = (writer.add_connection(temperature_topic, TEMPERATURE, typestore=store)
                                  if temperature_topic else None)
        accel, gyro, temps = samples.accel_raw, samples.gyro_raw, samples.temperature_degc
        for log_time, kind, i in records:
            if kind == "t":
                msg = Temperature(header=header(log_time), temperature=float(temps[i]), variance=0.0)
                writer.write(temperature_connection, log_time, store.serialize_cdr(msg, TEMPERATURE))
                continue
            msg = Imu(
                header=header(log_time),
                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=no_orientation,
                angular_velocity=Vector3(x=float(gyro[i, 0]), y=float(gyro[i, 1]), z=float(gyro[i, 2])),
                angular_velocity_covariance=covariance,
                linear_acceleration=Vector3(x=float(accel[i, 0]), y=float(accel[i, 1]), z=float(accel[i, 2])),
                linear_acceleration_covariance=covariance,
            )
            writer.write(imu_connection, log_time, store.serialize_cdr(msg, IMU))
    return len(samples.t_ns)
