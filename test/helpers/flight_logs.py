"""Ordinary flight logs in the real formats (PX4 ULog, ArduPilot DataFlash) with known truth: the vehicle
parked still (level, or at a given attitude) before arming and after landing, a flight of turns and vibration
in between, two IMUs of known raw errors and the calibration in force in the log's parameters."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from msg_tools.dataflash_writer import FORMATS_4X, imu_records, parameter_records, write_dataflash
from msg_tools.synthetic_imu import SensorErrors
from msg_tools.ulog_writer import (
    sensor_combined_array,
    sensor_selection_array,
    sensor_triplet_array,
    write_ulog,
)

G = 9.80665
MG = G / 1000.0
RATE_HZ = 100.0
START_US = 9_000_000
DEVICES = (1310988, 1442060)
GROUND_S, FLIGHT_S = 10.0, 20.0  # still on the ground before arming and after disarming; armed in between
NOISE_MPS2 = 0.004


@dataclass(frozen=True)
class InForce:
    """The calibration the autopilot applies: a = (raw - offset) * scale (both autopilots' form)."""

    offset: np.ndarray
    scale: np.ndarray


@dataclass(frozen=True)
class FlightLog:
    t_us: np.ndarray
    raw: list[np.ndarray]  # per IMU, its own output
    gyro: np.ndarray
    temperature: np.ndarray
    arm_us: int
    liftoff_us: int
    touchdown_us: int
    disarm_us: int


def true_in_force(truth: SensorErrors) -> InForce:
    """The calibration in force that is the truth exactly (a diagonal M: offsets and scales say all of it)."""
    return InForce(np.array(truth.bias_mps2, dtype=float), np.diag(truth.matrix).astype(float))


def sensors(seed: int) -> list[SensorErrors]:
    rng = np.random.default_rng(seed)
    return [SensorErrors(bias_mps2=rng.uniform(0.05, 0.3, 3) * rng.choice([-1.0, 1.0], 3),
                         matrix=np.diag(1.0 + rng.uniform(0.005, 0.02, 3) * rng.choice([-1.0, 1.0], 3)))
            for _ in DEVICES]


def fly(truths: list[SensorErrors], seed: int, parked: Rotation | None = None) -> FlightLog:
    """Parked at `parked` (body -> world; default level) for GROUND_S, armed, a flight of turns, landed
    back at the same attitude, disarmed, GROUND_S still."""
    rng = np.random.default_rng(seed)
    parked = parked or Rotation.identity()
    turns = Rotation.from_euler("xyz", rng.uniform(-25, 25, (6, 3)), degrees=True)
    keys = [0.0, GROUND_S + 2.0, GROUND_S + 4.0, *np.linspace(GROUND_S + 6.0, GROUND_S + FLIGHT_S - 6.0, 6),
            GROUND_S + FLIGHT_S - 4.0, 2 * GROUND_S + FLIGHT_S]
    rotations = Rotation.concatenate([parked, parked, parked, *[parked * t for t in turns], parked, parked])
    duration = keys[-1]
    stamps_s = np.arange(int(duration * RATE_HZ)) / RATE_HZ
    turn = Slerp(keys, rotations)
    body = turn(stamps_s)
    later = turn(np.minimum(stamps_s + 1.0 / RATE_HZ, duration))
    airborne = (stamps_s > GROUND_S + 2.0) & (stamps_s < GROUND_S + FLIGHT_S - 2.0)
    shaking = np.where(airborne[:, None], rng.normal(0.0, 0.5, (len(stamps_s), 3)), 0.0)  # the motors' vibration
    accel_true = body.inv().apply([0.0, 0.0, G]) + shaking
    gyro = (body.inv() * later).as_rotvec() * RATE_HZ + rng.normal(0.0, 0.001, (len(stamps_s), 3))
    raw = [truth.raw_from_true(accel_true) + rng.normal(0.0, NOISE_MPS2, accel_true.shape) for truth in truths]
    t_us = START_US + np.round(stamps_s * 1e6).astype(np.int64)
    us = [START_US + int(x * 1e6) for x in (GROUND_S, GROUND_S + 2.0, GROUND_S + FLIGHT_S - 2.0, GROUND_S + FLIGHT_S)]
    return FlightLog(t_us, [r.astype(np.float32).astype(float) for r in raw], gyro, 30.0 + 0.0 * stamps_s, *us)


def _logged(raw: np.ndarray, in_force: InForce) -> np.ndarray:
    return (raw - in_force.offset) * in_force.scale


def write_ulog_flight(path, flight: FlightLog, in_force: list[InForce]) -> None:
    """sensor_accel per IMU (its own output, as PX4 logs it), sensor_combined (IMU 0 corrected), CAL_ACCn_*,
    vehicle_status and vehicle_land_detected."""
    params: dict[str, float | int] = {"SENS_BOARD_ROT": 0, "TC_A_ENABLE": 0, "TC_G_ENABLE": 0}
    topics = []
    for k, calibration in enumerate(in_force):
        params[f"CAL_ACC{k}_ID"] = DEVICES[k]
        params[f"CAL_GYRO{k}_ID"] = DEVICES[k]
        for axis, name in enumerate("XYZ"):
            params[f"CAL_ACC{k}_{name}OFF"] = float(calibration.offset[axis])
            params[f"CAL_ACC{k}_{name}SCALE"] = float(calibration.scale[axis])
        topics.append(("sensor_accel", k, sensor_triplet_array(flight.t_us, flight.raw[k], DEVICES[k],
                                                               flight.temperature)))
    for k in range(len(in_force)):
        topics.append(("sensor_gyro", k, sensor_triplet_array(flight.t_us, flight.gyro, DEVICES[k],
                                                              flight.temperature)))
    topics.append(("sensor_combined", 0, sensor_combined_array(flight.t_us, _logged(flight.raw[0], in_force[0]),
                                                               flight.gyro)))
    topics.append(("sensor_selection", 0, sensor_selection_array(flight.t_us[::100], DEVICES[0], DEVICES[0])))
    stamps = np.unique(np.concatenate([flight.t_us[::100], [flight.arm_us, flight.liftoff_us, flight.touchdown_us,
                                                             flight.disarm_us]]))
    status = np.zeros(len(stamps), dtype=[("timestamp", "<u8"), ("nav_state", "u1"), ("arming_state", "u1")])
    status["timestamp"] = stamps
    status["arming_state"] = np.where((stamps >= flight.arm_us) & (stamps < flight.disarm_us), 2, 1)
    land = np.zeros(len(stamps), dtype=[("timestamp", "<u8"), ("freefall", "u1"), ("landed", "u1")])
    land["timestamp"] = stamps
    land["landed"] = ~((stamps >= flight.liftoff_us) & (stamps < flight.touchdown_us))
    topics += [("vehicle_status", 0, status), ("vehicle_land_detected", 0, land)]
    write_ulog(path, topics, parameters=params)


def write_dataflash_flight(path, flight: FlightLog, in_force: list[InForce]) -> None:
    """IMU records per instance (corrected by INS_ACCnOFFS/SCAL, as ArduPilot logs them), PARM with the
    devices' INS_ACCn_ID, ARM and EV records."""
    params: dict[str, float] = {"AHRS_ORIENTATION": 0.0}
    for k, calibration in enumerate(in_force):
        n = "" if k == 0 else str(k + 1)
        params[f"INS_ACC{n}_ID"] = params[f"INS_GYR{n}_ID"] = float(DEVICES[k])
        for axis, name in enumerate("XYZ"):
            params[f"INS_ACC{n}OFFS_{name}"] = float(calibration.offset[axis])
            params[f"INS_ACC{n}SCAL_{name}"] = float(calibration.scale[axis])
    records = [(START_US - 1000, r) for r in parameter_records(START_US - 1000, params)]
    for k, calibration in enumerate(in_force):
        logged = _logged(flight.raw[k], calibration).astype(np.float32)
        records += [(int(r[1][0]), r) for r in imu_records(flight.t_us, logged, flight.gyro, flight.temperature,
                                                           instance=k)]
    # ARMED 10, NOT_LANDED 28, LAND_COMPLETE 18, DISARMED 11 (ArduPilot's LogEvent)
    for when, kind, body in ((flight.arm_us, "ARM", (1, 0, 0, 0)), (flight.arm_us, "EV", (10,)),
                             (flight.liftoff_us, "EV", (28,)), (flight.touchdown_us, "EV", (18,)),
                             (flight.disarm_us, "ARM", (0, 0, 0, 0)), (flight.disarm_us, "EV", (11,))):
        records.append((when, (kind, (when, *body))))
    records.sort(key=lambda r: r[0])
    write_dataflash(path, FORMATS_4X, [r for _, r in records])
