"""Simulated autopilot logs in the real formats (ArduPilot DataFlash, PX4 ULog): one board of two IMUs with
known raw errors, turned through still poses, a stale calibration in the log's parameters and a 90 deg yaw
board rotation; what the autopilot logs is its correction of the raw samples."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from msg_tools.dataflash_writer import (
    FORMATS_3X,
    FORMATS_4X,
    imu_records,
    imu_records_3x,
    parameter_records,
    write_dataflash,
)
from msg_tools.synthetic_imu import STANDARD_GRAVITY, SensorErrors, SyntheticImu, spread_orientations
from msg_tools.ulog_writer import (
    sensor_combined_array,
    sensor_selection_array,
    sensor_triplet_array,
    write_ulog,
)

G = STANDARD_GRAVITY
MG = G / 1000.0
START_US = 5_000_000
YAW_90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # ROTATION_YAW_90 (both autopilots)
DEVICES = (1310988, 1442060)  # PX4 device IDs of two SPI IMUs


@dataclass
class Imu:
    truth: SensorErrors  # a_true = M (raw - b), the sensor's own axes
    raw: np.ndarray  # (N, 3) the sensor's output
    gyro_raw: np.ndarray
    stale_offset: np.ndarray  # the calibration in force while logging, long out of date
    stale_scale: np.ndarray
    gyro_offset: np.ndarray
    gyro_bias: np.ndarray  # the gyro's true bias (rad/s, its own axes)


@dataclass
class Board:
    t_us: np.ndarray
    temperature: np.ndarray
    imus: list[Imu]
    true_up: np.ndarray  # (N, 3) true specific force in the board's axes


def simulate(seed: int, misaligned: bool = False, mounting_mrad: tuple[float, float, float] = (0.0, 0.0, 0.0)
             ) -> Board:
    """IMU 1 is mounted turned by `mounting_mrad` (a rotation vector) from IMU 0: it reads R u for u."""
    rng = np.random.default_rng(seed)
    motion = SyntheticImu(SensorErrors(), spread_orientations(14, rng), dwell_s=2.5, move_s=1.0, rate_hz=100.0,
                          seed=seed).samples()
    imus = []
    mounting = Rotation.from_rotvec(np.array(mounting_mrad) / 1e3).as_matrix()
    for k in range(2):
        turn = mounting if k == 1 else np.eye(3)
        matrix = np.diag(1.0 + rng.uniform(0.01, 0.03, 3) * rng.choice([-1.0, 1.0], 3))
        if misaligned and k == 1:
            matrix[1, 0], matrix[2, 0], matrix[2, 1] = 0.012, -0.009, 0.015
        truth = SensorErrors(bias_mps2=rng.uniform(0.15, 0.4, 3) * rng.choice([-1.0, 1.0], 3), matrix=matrix)
        noise = rng.normal(0.0, 0.004, motion.accel_true.shape)
        gyro_bias = rng.normal(0.0, 0.01, 3)
        imus.append(Imu(truth, truth.raw_from_true(motion.accel_true @ turn.T) + noise,
                        motion.gyro_raw @ turn.T + gyro_bias + rng.normal(0.0, 0.001, motion.gyro_raw.shape),
                        stale_offset=rng.uniform(-0.3, 0.3, 3), stale_scale=1.0 + rng.uniform(-0.03, 0.03, 3),
                        gyro_offset=gyro_bias + rng.normal(0.0, 0.005, 3), gyro_bias=gyro_bias))
    return Board(START_US + motion.t_ns // 1000, motion.temperature_degc, imus, motion.accel_true)


def logged(imu: Imu) -> tuple[np.ndarray, np.ndarray]:
    """What the autopilot logs: y = R ((x - offset) * scale), w = R (x_gyro - gyro_offset)."""
    return ((imu.raw - imu.stale_offset) * imu.stale_scale) @ YAW_90.T, (imu.gyro_raw - imu.gyro_offset) @ YAW_90.T


def ardupilot_parameters(board: Board, devices: tuple[int, int] | None = None) -> dict[str, float]:
    """`devices`: INS_ACC_ID, INS_ACC2_ID (and the same INS_GYR*_ID: one chip each), logged where given."""
    params = {"AHRS_ORIENTATION": 2.0}
    for k, imu in enumerate(board.imus):
        n = "" if k == 0 else str(k + 1)
        if devices is not None:
            params[f"INS_ACC{n}_ID"] = params[f"INS_GYR{n}_ID"] = float(devices[k])
        for axis, name in enumerate("XYZ"):
            params[f"INS_ACC{n}OFFS_{name}"] = float(imu.stale_offset[axis])
            params[f"INS_ACC{n}SCAL_{name}"] = float(imu.stale_scale[axis])
            params[f"INS_GYR{n}OFFS_{name}"] = float(imu.gyro_offset[axis])
    return params


def write_ardupilot_log(path, board: Board, old_style: bool = False, devices: tuple[int, int] | None = None,
                        changed: dict[str, float] | None = None) -> None:
    """`changed`: parameters logged with other values than the board's (what the autopilot held them at)."""
    records = parameter_records(START_US - 1000, {**ardupilot_parameters(board, devices), **(changed or {})})
    per_imu = []
    for k, imu in enumerate(board.imus):
        accel, gyro = logged(imu)
        make = imu_records_3x if old_style else imu_records
        per_imu.append(make(board.t_us, accel, gyro, board.temperature, instance=k))
    records += [record for pair in zip(*per_imu) for record in pair]  # interleaved, as logged
    write_dataflash(path, FORMATS_3X if old_style else FORMATS_4X, records)


def write_px4_log(path, board: Board, instances: tuple[int, int] = (0, 1), accel_devices: tuple[int, int] = DEVICES,
                  gyro_devices: tuple[int, int] | None = None, gyro_instances: tuple[int, int] | None = None,
                  changed: dict[str, float] | None = None) -> None:
    """IMU k as sensor_accel instance instances[k] of device accel_devices[k], its gyro as sensor_gyro instance
    gyro_instances[k] (default: the same) of device gyro_devices[k] (default: the accelerometer's, one chip; a
    BMI088's gyro is a die of its own, with its own ID), CAL_ACCk_ID / CAL_GYROk_ID naming them; `changed`:
    parameters logged with other values than those the samples were corrected with."""
    gyro_devices = accel_devices if gyro_devices is None else gyro_devices
    gyro_instances = instances if gyro_instances is None else gyro_instances
    params: dict[str, float | int] = {"SENS_BOARD_ROT": 2, "TC_A_ENABLE": 0, "TC_G_ENABLE": 0}
    topics = []
    for k, imu in enumerate(board.imus):
        params[f"CAL_ACC{k}_ID"] = accel_devices[k]
        params[f"CAL_GYRO{k}_ID"] = gyro_devices[k]
        for axis, name in enumerate("XYZ"):
            params[f"CAL_ACC{k}_{name}OFF"] = float(imu.stale_offset[axis])
            params[f"CAL_ACC{k}_{name}SCALE"] = float(imu.stale_scale[axis])
            params[f"CAL_GYRO{k}_{name}OFF"] = float(imu.gyro_offset[axis])
        topics.append(("sensor_accel", instances[k],
                       sensor_triplet_array(board.t_us, imu.raw, accel_devices[k], board.temperature)))
    for k in sorted(range(len(board.imus)), key=lambda k: gyro_instances[k]):  # uORB instances in order
        topics.append(("sensor_gyro", gyro_instances[k], sensor_triplet_array(board.t_us, board.imus[k].gyro_raw,
                                                                              gyro_devices[k], board.temperature)))
    accel, gyro = logged(board.imus[0])
    topics.append(("sensor_combined", 0, sensor_combined_array(board.t_us, accel, gyro)))
    topics.append(("sensor_selection", 0, sensor_selection_array(board.t_us[::100], accel_devices[0],
                                                                 gyro_devices[0])))
    write_ulog(path, topics, parameters={**params, **(changed or {})})
