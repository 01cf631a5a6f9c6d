"""A synthetic session recorded as a rosbag2 (what `ros2 bag record` of the synthetic publisher would
give), for tests, benchmarks and the demo: serialized by rosbags itself, in either storage."""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from .synthetic_imu import SyntheticSamples

IMU, TEMPERATURE = "sensor_msgs/msg/Imu", "sensor_msgs/msg/Temperature"


def write_session_bag(path: Path | str, samples: SyntheticSamples, *, start_ns: int, storage: str = "sqlite3",
                      frame_id: str = "imu_link", temperature_period_s: float = 0.1, imu_topic: str = "/imu/data_raw",
                      temperature_topic: str | None = "/imu/temperature", shuffle_seed: int | None = None,
                      chunk_compression: str = "", typestore: Any = None, accel_covariance: Any = None,
                      gyro_covariance: Any = None) -> int:
    """Record a SyntheticSamples session as a rosbag2 (what `ros2 bag record` of the synthetic publisher
    would give), serialized by rosbags itself. `shuffle_seed` swaps neighbouring IMU messages in the
    file order, as recorders do when messages arrive out of order. `chunk_compression` ("zstd", "lz4"):
    mcap chunks compressed as rosbag2's storage presets do. `typestore`: message definitions to record
    (e.g. an Imu defined otherwise), by default ROS 2 Jazzy's. `accel_covariance`, `gyro_covariance`: what
    the driver reports (9 values; default zeros: unknown). Returns IMU messages written."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = typestore if typestore is not None else get_typestore(Stores.ROS2_JAZZY)
    Imu, Temperature = store.types[IMU], store.types[TEMPERATURE]
    Header, Time = store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    Vector3, Quaternion = store.types["geometry_msgs/msg/Vector3"], store.types["geometry_msgs/msg/Quaternion"]
    accel_cov = np.zeros(9) if accel_covariance is None else np.asarray(accel_covariance, dtype=float).ravel()
    gyro_cov = np.zeros(9) if gyro_covariance is None else np.asarray(gyro_covariance, dtype=float).ravel()
    no_orientation = np.zeros(9)
    no_orientation[0] = -1.0

    def header(t: int) -> Any:
        sec, nanosec = divmod(int(t), 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id)

    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    records: list[tuple[int, str, int]] = []
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
    writer = Writer(path, version=9, storage_plugin=plugin)
    if chunk_compression and storage == "mcap":
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)  # zstd chunks, metadata says none
    with writer:
        if chunk_compression == "lz4" and storage == "mcap":
            from lz4.frame import compress

            storage_writer: Any = writer.storage  # a private part of rosbags' Writer, set only in a bag's write
            storage_writer.compression, storage_writer.compressor = "lz4", compress  # rosbags writes zstd only
        imu_connection = writer.add_connection(imu_topic, IMU, typestore=store)
        temperature_connection = (writer.add_connection(temperature_topic, TEMPERATURE, typestore=store)
                                  if temperature_topic else None)
        accel, gyro, temps = samples.accel_raw, samples.gyro_raw, samples.temperature_degc
        for log_time, kind, i in records:
            if kind == "t":
                msg = Temperature(header=header(log_time), temperature=float(temps[i]), variance=0.0)
                assert temperature_connection is not None, "temperature records only with a temperature topic"
                writer.write(temperature_connection, log_time, store.serialize_cdr(msg, TEMPERATURE))
                continue
            msg = Imu(
                header=header(log_time),
                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=no_orientation,
                angular_velocity=Vector3(x=float(gyro[i, 0]), y=float(gyro[i, 1]), z=float(gyro[i, 2])),
                angular_velocity_covariance=gyro_cov,
                linear_acceleration=Vector3(x=float(accel[i, 0]), y=float(accel[i, 1]), z=float(accel[i, 2])),
                linear_acceleration_covariance=accel_cov,
            )
            writer.write(imu_connection, log_time, store.serialize_cdr(msg, IMU))
    return len(samples.t_ns)
