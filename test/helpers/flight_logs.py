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
ALL_DEVICES = (*DEVICES, 3801122)  # a third IMU where a test needs one (`sensors(seed, 3)`)
ESTIMATE_HZ = 10.0  # the filter's bias records
ESTIMATE_NOISE_MPS2 = 0.1 * MG  # its wander about the settled value
ESTIMATE_NOISE_RADPS = 2e-5
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


def sensors(seed: int, count: int = len(DEVICES)) -> list[SensorErrors]:
    rng = np.random.default_rng(seed)
    return [SensorErrors(bias_mps2=rng.uniform(0.05, 0.3, 3) * rng.choice([-1.0, 1.0], 3),
                         matrix=np.diag(1.0 + rng.uniform(0.005, 0.02, 3) * rng.choice([-1.0, 1.0], 3)))
            for _ in range(count)]


@dataclass(frozen=True)
class FilterBias:
    """What the autopilot's filter settles on in flight for one IMU (accel m/s^2, gyro rad/s)."""

    accel_mps2: np.ndarray
    gyro_radps: np.ndarray


def filter_estimates(flight: FlightLog, bias: FilterBias, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                              np.ndarray, np.ndarray]:
    """The filter's records at ESTIMATE_HZ over the whole log: (t_us, accel (N, 3), gyro (N, 3), valid,
    stable). Zero and invalid before arming; from arming it converges to the bias (3 s) with a small
    wander; stable 5 s after arming."""
    rng = np.random.default_rng(seed)
    t_us = np.arange(flight.t_us[0], flight.t_us[-1], int(1e6 / ESTIMATE_HZ), dtype=np.int64)
    since = np.clip((t_us - flight.arm_us) / 1e6, 0.0, None)[:, None]
    reached = 1.0 - np.exp(-since / 3.0)
    accel = bias.accel_mps2 * reached + rng.normal(0.0, ESTIMATE_NOISE_MPS2, (len(t_us), 3)) * (since > 0)
    gyro = bias.gyro_radps * reached + rng.normal(0.0, ESTIMATE_NOISE_RADPS, (len(t_us), 3)) * (since > 0)
    return t_us, accel, gyro, t_us >= flight.arm_us, t_us >= flight.arm_us + 5_000_000


def estimator_sensor_bias_array(flight: FlightLog, bias: FilterBias, device: int, seed: int) -> np.ndarray:
    """PX4's estimator_sensor_bias (msg/EstimatorSensorBias.msg) of one filter on one IMU."""
    t_us, accel, gyro, valid, stable = filter_estimates(flight, bias, seed)
    kinds = [("timestamp", "<u8"), ("timestamp_sample", "<u8"), ("gyro_device_id", "<u4"), ("gyro_bias", "<f4", 3),
             ("gyro_bias_limit", "<f4"), ("gyro_bias_variance", "<f4", 3), ("gyro_bias_valid", "?"),
             ("gyro_bias_stable", "?"), ("accel_device_id", "<u4"), ("accel_bias", "<f4", 3),
             ("accel_bias_limit", "<f4"), ("accel_bias_variance", "<f4", 3), ("accel_bias_valid", "?"),
             ("accel_bias_stable", "?")]
    out = np.zeros(len(t_us), dtype=kinds)
    out["timestamp"] = out["timestamp_sample"] = t_us
    out["gyro_device_id"] = out["accel_device_id"] = device
    out["gyro_bias"], out["accel_bias"] = gyro, accel
    out["gyro_bias_limit"], out["accel_bias_limit"] = 0.4, 0.4
    out["gyro_bias_variance"] = ESTIMATE_NOISE_RADPS**2
    out["accel_bias_variance"] = ESTIMATE_NOISE_MPS2**2
    out["gyro_bias_valid"] = out["accel_bias_valid"] = valid
    out["gyro_bias_stable"] = out["accel_bias_stable"] = stable
    return out


# ArduPilot's EKF records (libraries/AP_NavEKF3/LogStructure.h, AP_NavEKF2/LogStructure.h): `c` is an int16 of
# 100 x the value (XKF2 AX: m/s^2, XKF1 GX: deg/s), NKF2 AZbias an int8 of 100 x m/s^2.
EKF_FORMATS = {
    "XKF1": ("QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH"),
    "XKF2": ("QBccccchhhhhhfff", "TimeUS,C,AX,AY,AZ,VWN,VWE,MN,ME,MD,MX,MY,MZ,IDX,IDY,IS"),
    "NKF1": ("QBccCfffffffccce", "TimeUS,C,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH"),
    "NKF2": ("QBbccccchhhhhhB", "TimeUS,C,AZbias,GSX,GSY,GSZ,VWN,VWE,MN,ME,MD,MX,MY,MZ,MI"),
}


# Before ArduPilot 4.1 a core had message types of its own, without a core field: core 0 in XKF1/XKF2 (NKF1/NKF2),
# core 1 in XKF6/XKF7 (NKF6/NKF7), as in ../shared/data/real/ardupilot/test.BIN.
EKF_FORMATS_OLD = {
    **{name: ("QccCfffffffccce", "TimeUS,Roll,Pitch,Yaw,VN,VE,VD,dPD,PN,PE,PD,GX,GY,GZ,OH")
       for name in ("XKF1", "XKF6", "NKF1", "NKF6")},
    **{name: ("QccccchhhhhhB", "TimeUS,AX,AY,AZ,VWN,VWE,MN,ME,MD,MX,MY,MZ,MI") for name in ("XKF2", "XKF7")},
    **{name: ("QbccccchhhhhhB", "TimeUS,AZbias,GSX,GSY,GSZ,VWN,VWE,MN,ME,MD,MX,MY,MZ,MI") for name in ("NKF2", "NKF7")},
}


def ekf_records(flight: FlightLog, biases: list[FilterBias], seed: int, ekf: int = 3, old_style: bool = False
                ) -> list[tuple[int, tuple]]:
    """(TimeUS, record) of XKF1/XKF2 (ekf=3) or NKF1/NKF2 (ekf=2) per core, core k on IMU k, as logged;
    `old_style`: two cores in types of their own (XKF6/XKF7 for core 1), no core field."""
    out = []
    prefix = "XKF" if ekf == 3 else "NKF"
    for core, bias in enumerate(biases):
        first, second = (f"{prefix}{1 + 5 * core}", f"{prefix}{2 + 5 * core}") if old_style else \
            (f"{prefix}1", f"{prefix}2")
        which = () if old_style else (core,)
        t_us, accel, gyro, _, _ = filter_estimates(flight, bias, seed + core)
        for t, a, g in zip(t_us, accel, gyro):
            gx, gy, gz = (int(round(100 * np.degrees(v))) for v in g)
            out.append((int(t), (first, (int(t), *which, 0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, gx, gy, gz, 0))))
            if ekf == 3:
                ax, ay, az = (int(round(100 * v)) for v in a)
                tail = (0,) if old_style else (0.0, 0.0, 0.0)  # MI, or IDX, IDY, IS
                out.append((int(t), (second, (int(t), *which, ax, ay, az, 0, 0, 0, 0, 0, 0, 0, 0, *tail))))
            else:
                az = int(round(100 * a[2]))
                out.append((int(t), (second, (int(t), *which, az, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))))
    return out


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


def write_ulog_flight(path, flight: FlightLog, in_force: list[InForce], biases: list[FilterBias] | None = None,
                      seed: int = 0, gyro_offsets: list[np.ndarray] | None = None) -> None:
    """sensor_accel per IMU (its own output, as PX4 logs it), sensor_combined (IMU 0 corrected), CAL_ACCn_*,
    vehicle_status and vehicle_land_detected; with `biases`, estimator_sensor_bias per IMU (one filter each);
    with `gyro_offsets`, each gyro's own output is off by its offset and CAL_GYROn_xOFF in force says it."""
    params: dict[str, float | int] = {"SENS_BOARD_ROT": 0, "TC_A_ENABLE": 0, "TC_G_ENABLE": 0}
    topics = []
    for k, calibration in enumerate(in_force):
        params[f"CAL_ACC{k}_ID"] = ALL_DEVICES[k]
        params[f"CAL_GYRO{k}_ID"] = ALL_DEVICES[k]
        for axis, name in enumerate("XYZ"):
            params[f"CAL_ACC{k}_{name}OFF"] = float(calibration.offset[axis])
            params[f"CAL_ACC{k}_{name}SCALE"] = float(calibration.scale[axis])
        topics.append(("sensor_accel", k, sensor_triplet_array(flight.t_us, flight.raw[k], ALL_DEVICES[k],
                                                               flight.temperature)))
    for k in range(len(in_force)):
        offset = np.zeros(3) if gyro_offsets is None else gyro_offsets[k]
        for axis, name in enumerate("XYZ"):
            params[f"CAL_GYRO{k}_{name}OFF"] = float(offset[axis])
        topics.append(("sensor_gyro", k, sensor_triplet_array(flight.t_us, flight.gyro + offset, ALL_DEVICES[k],
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
    for k, bias in enumerate(biases or []):
        topics.append(("estimator_sensor_bias", k, estimator_sensor_bias_array(flight, bias, ALL_DEVICES[k], seed + k)))
    write_ulog(path, topics, parameters=params)


def write_dataflash_flight(path, flight: FlightLog, in_force: list[InForce], biases: list[FilterBias] | None = None,
                           seed: int = 0, ekf: int = 3, old_style: bool = False) -> None:
    """IMU records per instance (corrected by INS_ACCnOFFS/SCAL, as ArduPilot logs them), PARM with the
    devices' INS_ACCn_ID, ARM and EV records; with `biases`, the filter's records (EKF3 XKF1/XKF2, or EKF2
    NKF1/NKF2), core k on IMU k."""
    params: dict[str, float] = {"AHRS_ORIENTATION": 0.0}
    for k, calibration in enumerate(in_force):
        n = "" if k == 0 else str(k + 1)
        params[f"INS_ACC{n}_ID"] = params[f"INS_GYR{n}_ID"] = float(ALL_DEVICES[k])
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
    formats = dict(FORMATS_4X)
    if biases:
        params_mask = (1 << len(biases)) - 1
        records.append((START_US - 1000, ("PARM", (START_US - 1000, f"EK{ekf}_IMU_MASK", float(params_mask)))))
        records += ekf_records(flight, biases, seed, ekf, old_style)
        formats.update(EKF_FORMATS_OLD if old_style else EKF_FORMATS)
    records.sort(key=lambda r: r[0])
    write_dataflash(path, formats, [r for _, r in records])
