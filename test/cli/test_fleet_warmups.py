"""accel-calib fleet LOGS... --warmup -o DIR: the warm-ups of a vehicle's logs (DataFlash and ULog in the real
formats) pooled per IMU, matched by device ID, into one curve each covering their joint range; a log of
another sensor under the same device ID left out and named, a log with no warm-up said why."""
from __future__ import annotations

import dataclasses

import numpy as np
from conftest import shared_path

from accel_calibration import load_calibration
from accel_calibration.cli.main import main

from helpers.autopilot_logs import DEVICES, write_ardupilot_log, write_px4_log
from helpers.one_line import assert_one_error_line, run_main
from helpers.warmup_sessions import Heating, temperature_errors, two_imus, warmup_board, warmup_recording

MG = 9.80665e-3
MORNING = Heating(start_degc=0.0, end_degc=22.0, tau_s=200.0, minutes=9.0)  # a cold morning, 0..20.5 degC
AFTERNOON = Heating(start_degc=18.0, end_degc=47.0, tau_s=200.0, minutes=9.0)  # a warm afternoon, 18..45
GYRO_TURN_ON = np.array([0.3, -0.2, 0.25]) * 1e-3  # each power-on's own gyro bias: + in the morning, - after
ACCEL_TURN_ON = np.array([4.0, -3.0, 2.5]) * MG


def board(seed: int, heating: Heating, sign: float = 1.0, strangers: bool = False):
    """Both IMUs of `two_imus` warming still and level, this power-on's turn-on biases (`sign` x the
    constants); `strangers`: another vehicle's sensors under the same device IDs (other drift curves)."""
    made, truths = warmup_board(seed, heating)
    rng = np.random.default_rng(seed + 1000)
    for imu, truth in zip(made.imus, truths):
        if strangers:
            other = dataclasses.replace(truth, accel_amplitude=-truth.accel_amplitude,
                                        gyro_amplitude=truth.gyro_amplitude * np.array([1.0, -1.0, 0.5]))
            recording = warmup_recording(other, rng, heating, rate_hz=50.0)
            imu.raw, imu.gyro_raw = recording.accel_mps2, recording.gyro_radps
        imu.raw = imu.raw + sign * ACCEL_TURN_ON
        imu.gyro_raw = imu.gyro_raw + sign * GYRO_TURN_ON
    return made


def test_fleet_pools_a_cold_morning_and_a_warm_afternoon_per_imu_by_device(tmp_path, capsys):
    """Morning as DataFlash, afternoon as ULog with its IMUs enumerated the other way round, another vehicle's
    sensors under the same device IDs mixed in, and a log with no warm-up: one curve per IMU over 0..45 degC."""
    vehicle = tmp_path / "logs" / "vehicle7"
    vehicle.mkdir(parents=True)
    write_ardupilot_log(vehicle / "morning.bin", board(41, MORNING), devices=DEVICES)
    afternoon = board(42, AFTERNOON, sign=-1.0)
    afternoon.imus.reverse()  # its instance 0 is the second device: matched by device, not by instance
    write_px4_log(vehicle / "afternoon.ulg", afternoon, accel_devices=(DEVICES[1], DEVICES[0]))
    write_px4_log(vehicle / "stranger.ulg", board(43, Heating(8.0, 38.0, tau_s=200.0, minutes=9.0),
                                                  strangers=True))
    write_ardupilot_log(vehicle / "parked.bin", board(44, Heating(30.0, 30.2, minutes=3.0)), devices=DEVICES)
    out = tmp_path / "curves"
    logs = [vehicle / name for name in ("morning.bin", "afternoon.ulg", "stranger.ulg", "parked.bin")]
    code = main(["fleet", *map(str, logs), "--warmup", "-o", str(out), "--workers", "1"])
    printed, err = capsys.readouterr()
    assert code == 1, err  # a log left out is named as an error: the vehicle's logs need a look
    for truth, device in zip(two_imus(), DEVICES):
        calibration = load_calibration(out / "vehicle7" / f"dev{device}.yaml")
        assert calibration.accel_device_id == device
        low, high = calibration.temperature.range_degc
        assert low < 0.5 and high > 44.5
        accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(low, high, 200))
        assert accel_mg <= 1.5 and gyro_mradps <= 0.3, (accel_mg, gyro_mradps)
        line = next(line for line in printed.splitlines() if line.startswith(f"vehicle7 IMU dev{device}:"))
        assert f"{low:.1f}..{high:.1f} degC from 2 of 4 log(s) (morning.bin, afternoon.ulg)" in line
        assert line.endswith("of afternoon.ulg")  # the last log used (the stranger after it left out)
        assert f"vehicle7 IMU dev{device}: stranger.ulg left out: its warm-up disagrees" in err
    assert printed.count("parked.bin: no warm-up: temperature steady") == 2
    assert printed.count("stranger.ulg: left out: its warm-up disagrees with the other logs'") == 2


def test_each_log_alone_covers_only_its_part(tmp_path, capsys):
    """The morning alone: a curve over its 0..20.5 degC, held flat above, misses the afternoon's drift."""
    write_ardupilot_log(tmp_path / "morning.bin", board(41, MORNING), devices=DEVICES)
    code = main(["fleet", str(tmp_path / "morning.bin"), "--warmup", "-o", str(tmp_path / "curves"),
                 "--workers", "1"])
    printed, err = capsys.readouterr()
    assert code == 0, err
    for truth, device in zip(two_imus(), DEVICES):
        calibration = load_calibration(tmp_path / "curves" / tmp_path.name / f"dev{device}.yaml")
        low, high = calibration.temperature.range_degc
        assert low < 0.5 and 19.5 < high < 21.0
        accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(0.0, 45.0, 200))
        assert accel_mg > 5.0 and gyro_mradps > 1.0
        assert f"IMU dev{device}: {low:.1f}..{high:.1f} degC from 1 of 1 log(s)" in printed


def test_fleet_warmup_bad_input_is_one_line(tmp_path):
    (tmp_path / "broken.ulg").write_bytes(b"ULog\x01\x12\x35" + b"\x00" * 40)
    code, err = run_main(["fleet", tmp_path / "broken.ulg", "--warmup", "--workers", "1"])
    assert_one_error_line(code, err, "--warmup needs --output DIR")
    code, err = run_main(["fleet", tmp_path / "broken.ulg", "-o", tmp_path / "curves", "--workers", "1"])
    assert_one_error_line(code, err, "--output DIR only with --warmup")
    code, err = run_main(["fleet", tmp_path / "broken.ulg", "--warmup", "-o", tmp_path / "broken.ulg"])
    assert_one_error_line(code, err, "is the input")
    code, err = run_main(["fleet", tmp_path / "broken.ulg", "--warmup", "-o", tmp_path / "curves", "--workers", "1"])
    assert code == 1 and "Traceback" not in err, err
    assert "broken.ulg: failed to read" in err and not (tmp_path / "curves").exists()


def test_a_real_log_without_a_temperature_says_why_in_one_line(tmp_path, capsys):
    """PX4's sample.ulg logs no IMU temperature (and no sensor_accel, only sensor_combined): its line says why
    there is no curve, one error line, exit 1, nothing written."""
    code = main(["fleet", str(shared_path("real/px4_ulog/sample.ulg")), "--warmup", "-o", str(tmp_path / "curves"),
                 "--workers", "1"])
    printed, err = capsys.readouterr()
    assert_one_error_line(code, err, "no warm-up in any of its 1 log(s)")
    assert "no curve, none of its 1 log(s) holds a warm-up\n  sample.ulg: no warm-up: no temperature stream" in printed
    assert not (tmp_path / "curves").exists()


def test_a_log_in_motion_throughout_says_moving(tmp_path, capsys):
    """Two minutes turning at 0.5 rad/s while the temperature rises 10 degC: no still stretch, said so."""
    from accel_calibration.bag.csv_stream import samples_csv_text

    t = np.arange(0.0, 120.0, 0.01)
    angle = 0.5 * t
    accel = 9.80665 * np.column_stack([np.zeros_like(t), np.sin(angle), np.cos(angle)])
    accel += np.random.default_rng(45).normal(0.0, 0.04, accel.shape)
    gyro = np.tile([0.5, 0.0, 0.0], (len(t), 1))
    (tmp_path / "rover").mkdir()
    (tmp_path / "rover" / "turning.csv").write_text(samples_csv_text(np.round(t * 1e9).astype(np.int64), accel, gyro,
                                                                     20.0 + t / 12.0))
    code = main(["fleet", str(tmp_path / "rover" / "turning.csv"), "--warmup", "-o", str(tmp_path / "curves"),
                 "--workers", "1"])
    printed, err = capsys.readouterr()
    assert_one_error_line(code, err, "no warm-up in any of its 1 log(s)")
    assert "turning.csv: no warm-up: moving, no still stretch with a temperature" in printed
