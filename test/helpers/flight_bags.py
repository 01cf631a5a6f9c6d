"""Flights recorded as rosbag2 (sqlite3, mcap) written by rosbags: several sensor_msgs/msg/Imu topics (a vehicle
with two or three IMUs), a flight state on /mavros/state (found without a flag) and PX4's
/fmu/out/estimator_sensor_bias as uXRCE-DDS publishes it, its definition (px4_msgs/msg/EstimatorSensorBias,
PX4's msg/EstimatorSensorBias.msg) recorded in the bag."""
from __future__ import annotations

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from helpers.flight_logs import FilterBias, FlightLog, estimator_sensor_bias_array
from helpers.imu_bags import _write_mavros_state

ESTIMATOR_SENSOR_BIAS = """uint64 timestamp
uint64 timestamp_sample
uint32 gyro_device_id
float32[3] gyro_bias
float32 gyro_bias_limit
float32[3] gyro_bias_variance
bool gyro_bias_valid
bool gyro_bias_stable
uint32 accel_device_id
float32[3] accel_bias
float32 accel_bias_limit
float32[3] accel_bias_variance
bool accel_bias_valid
bool accel_bias_stable
uint32 mag_device_id
float32[3] mag_bias
float32 mag_bias_limit
float32[3] mag_bias_variance
bool mag_bias_valid
bool mag_bias_stable
"""
ESTIMATOR_TYPE = "px4_msgs/msg/EstimatorSensorBias"
ESTIMATOR_TOPIC = "/fmu/out/estimator_sensor_bias"


def write_flight_bag(path, flight: FlightLog, streams: dict[str, np.ndarray], storage: str, with_state: bool = True,
                     estimator: tuple[FilterBias, int] | None = None, seed: int = 0):
    """`streams`: {Imu topic: its accel samples (N, 3) at flight.t_us}, each with the flight's gyro; the arming
    state on /mavros/state (`with_state`); `estimator`: (the filter's bias, its device ID) on
    /fmu/out/estimator_sensor_bias at its records' times."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(ESTIMATOR_SENSOR_BIAS, ESTIMATOR_TYPE))
    types = store.types
    t_ns = np.asarray(flight.t_us, np.int64) * 1000
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        for k, (topic, accel) in enumerate(streams.items()):
            connection = writer.add_connection(topic, "sensor_msgs/msg/Imu", typestore=store)
            for stamp, a, g in zip(t_ns.tolist(), accel, flight.gyro):
                writer.write(connection, stamp, _imu(store, types, stamp, a, g, f"imu{k}"))
        if with_state:
            stamps = t_ns[::100]
            _write_mavros_state(writer, store, (stamps, (stamps >= flight.arm_us * 1000)
                                                & (stamps < flight.disarm_us * 1000)))
        if estimator is not None:
            _write_estimator(writer, store, flight, *estimator, seed)
    return path


def _imu(store, types, stamp: int, accel, gyro, frame_id: str) -> bytes:
    vector = types["geometry_msgs/msg/Vector3"]
    sec, nanosec = divmod(stamp, 1_000_000_000)
    message = types["sensor_msgs/msg/Imu"](
        header=types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                            frame_id=frame_id),
        orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=np.r_[-1.0, np.zeros(8)],
        angular_velocity=vector(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
        angular_velocity_covariance=np.zeros(9),
        linear_acceleration=vector(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
        linear_acceleration_covariance=np.zeros(9))
    return bytes(store.serialize_cdr(message, "sensor_msgs/msg/Imu"))


def _write_estimator(writer, store, flight: FlightLog, bias: FilterBias, device: int, seed: int) -> None:
    """The filter's records (helpers/flight_logs.estimator_sensor_bias_array), recorded at their own stamps
    (the autopilot's clock here is the flight's)."""
    message_type = store.types[ESTIMATOR_TYPE]
    connection = writer.add_connection(ESTIMATOR_TOPIC, ESTIMATOR_TYPE, typestore=store)
    for row in estimator_sensor_bias_array(flight, bias, device, seed):
        fields = {name: row[name] for name in row.dtype.names}
        message = message_type(
            **{k: (np.asarray(v, np.float32) if np.ndim(v) else v.item()) for k, v in fields.items()},
            mag_device_id=0, mag_bias=np.zeros(3, np.float32), mag_bias_limit=0.0,
            mag_bias_variance=np.zeros(3, np.float32), mag_bias_valid=False, mag_bias_stable=False)
        writer.write(connection, int(row["timestamp"]) * 1000, bytes(store.serialize_cdr(message, ESTIMATOR_TYPE)))
