"""A fleet of simulated vehicles written as recordings (bags, CSV, ULog), and the drift check that a
history of them must give, on every history backend."""
from __future__ import annotations

import math

import numpy as np

from accel_calibration.cli.main import main
from accel_calibration.core.units import MG
from accel_calibration.io.history import open_history
from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations
from msg_tools.ulog_writer import sensor_combined_array, write_ulog

from helpers.history_records import START_NS

WEEK_NS = 7 * 86_400 * 10**9
PX4_UUID = "000200000000353338373138511600380018"  # a Pixhawk 5's sys_uuid, as its logs carry it
STEP_MG = 6.0  # sensor B's bias z between its two flights: far beyond its sigma, far below any bound


def write_flight(path, errors, seed, start_ns, storage, poses=14):
    rng = np.random.default_rng(seed)
    imu = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.0, move_s=0.8, rate_hz=100.0, seed=seed)
    samples = imu.samples()
    path.parent.mkdir(parents=True, exist_ok=True)
    if storage == "csv":
        columns = np.column_stack([samples.accel_raw, samples.gyro_raw, samples.temperature_degc])
        rows = [f"{start_ns + t},{','.join(repr(float(v)) for v in row)}" for t, row in zip(samples.t_ns, columns)]
        path.write_text("t_ns,ax,ay,az,gx,gy,gz,temperature\n" + "\n".join(rows) + "\n")
    elif storage == "ulog":
        t_us = (start_ns + samples.t_ns) // 1000
        write_ulog(path, [("sensor_combined", 0, sensor_combined_array(t_us, samples.accel_raw, samples.gyro_raw))],
                   info={"sys_name": "PX4", "sys_uuid": PX4_UUID})  # as PX4 logs its board
    else:
        write_session_bag(path, samples, start_ns=start_ns, storage=storage)


def two_vehicles(root):
    """uav07: sensor A, stable over two flights a week apart; uav08: sensor B, whose bias z steps by
    STEP_MG between its two flights (mcap and sqlite3 bags). Returns (sensor A, sensor B)."""
    sensor_a = SensorErrors.mpu6050_like(np.random.default_rng(70), noise_mps2=0.02)
    sensor_b = SensorErrors.mpu6050_like(np.random.default_rng(80), noise_mps2=0.02)
    stepped = SensorErrors(bias_mps2=sensor_b.bias_mps2 + [0.0, 0.0, STEP_MG * MG], matrix=sensor_b.matrix,
                           noise_mps2=sensor_b.noise_mps2, gyro_bias_radps=sensor_b.gyro_bias_radps,
                           gyro_noise_radps=sensor_b.gyro_noise_radps)
    write_flight(root / "uav07" / "flight1", sensor_a, 1, START_NS, "mcap")
    write_flight(root / "uav07" / "flight2", sensor_a, 2, START_NS + WEEK_NS, "sqlite3")
    write_flight(root / "uav08" / "flight1", sensor_b, 3, START_NS, "sqlite3")
    write_flight(root / "uav08" / "flight2", stepped, 4, START_NS + WEEK_NS, "mcap")
    return sensor_a, sensor_b


def assert_flags_the_stepped_sensor_only(history_target: str, capsys) -> None:
    """`accel-calib history` on a history of two_vehicles: one line for uav08's bias step, measured within
    1 mg and far beyond its sigmas; uav07 stays quiet."""
    capsys.readouterr()
    assert main(["history", "--history", history_target]) == 3
    flagged = [line.strip() for line in capsys.readouterr().out.splitlines() if " moved " in line]
    with open_history(history_target) as history:
        b1, b2 = history.records(vehicle="uav08")
    change_mg = (b2.bias[2] - b1.bias[2]) / MG
    sigmas = abs(b2.bias[2] - b1.bias[2]) / math.hypot(b1.bias_sigma[2], b2.bias_sigma[2])
    assert abs(change_mg - STEP_MG) < 1.0 and sigmas > 10
    assert flagged == [f"vehicle uav08 imu_link: bias z moved {abs(change_mg):.3g} mg ({sigmas:.1f} sigma) "
                       "between 2026-11-02 and 2026-11-09"]
    assert main(["history", "--history", history_target, "--vehicle", "uav07"]) == 0  # the stable one: quiet
    assert "no change beyond what the sigmas explain" in capsys.readouterr().out
