"""accel-calib replay --warmup: a recording of a sensor sitting still while it warms is a calibration of its
biases against temperature, accelerometer and gyro, written with -o; several warm-ups pooled."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path

from accel_calibration import load_calibration
from accel_calibration.bag.csv_stream import samples_csv_text
from accel_calibration.cli.main import main

from helpers.autopilot_logs import write_ardupilot_log, write_px4_log
from helpers.one_line import assert_one_error_line, run_main
from helpers.warmup_sessions import (
    Heating,
    temperature_errors,
    turned_then_warmed,
    two_imus,
    warmup_board,
    warmup_recording,
)


def write_csv(path, recording, every: int = 10) -> None:
    """The warm-up as a CSV stream, the temperature in every `every`-th row (a logger's slower register)."""
    temperature = np.full(len(recording.t_ns), np.nan)
    temperature[::every] = recording.temperature_degc[::every]
    path.write_text(samples_csv_text(recording.t_ns, recording.accel_mps2, recording.gyro_radps, temperature))


def test_replay_warmup_of_a_csv_writes_both_curves_within_1_mg_and_half_a_mrad(tmp_path, capsys):
    truth = two_imus()[0]
    write_csv(tmp_path / "warm.csv", warmup_recording(truth, np.random.default_rng(30), rate_hz=100.0))
    out = tmp_path / "warm.yaml"
    code = main(["replay", str(tmp_path / "warm.csv"), "--warmup", "-o", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    calibration = load_calibration(out)
    assert calibration.temperature is not None and calibration.temperature.kind == "spline"
    low, high = calibration.temperature.range_degc
    assert low < 15.5 and high > 44.0
    accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(low, high, 200))
    assert accel_mg <= 1.0 and gyro_mradps <= 0.5
    assert f"{low:.1f}..{high:.1f} degC" in printed and "held flat outside the range" in printed
    assert "z: along gravity, its curve is bias + scale drift x g together" in printed
    assert "on the raw output (no calibration fitted or in force)" in printed
    assert f"written {out}" in printed


def test_replay_warmup_pools_a_cold_morning_and_a_warm_afternoon(tmp_path, capsys):
    truth = two_imus()[1]
    rng = np.random.default_rng(31)
    write_csv(tmp_path / "morning.csv", warmup_recording(truth, rng, Heating(start_degc=3.0, end_degc=27.0),
                                                         gyro_turn_on=np.array([0.4, -0.3, 0.2]) * 1e-3,
                                                         rate_hz=100.0))
    write_csv(tmp_path / "afternoon.csv", warmup_recording(truth, rng, Heating(start_degc=21.0, end_degc=46.0),
                                                           gyro_turn_on=np.array([-0.4, 0.3, -0.2]) * 1e-3,
                                                           rate_hz=100.0))
    out = tmp_path / "pooled.yaml"
    code = main(["replay", str(tmp_path / "morning.csv"), str(tmp_path / "afternoon.csv"), "--warmup", "-o", str(out)])
    printed, err = capsys.readouterr()
    assert code == 0, err
    calibration = load_calibration(out)
    low, high = calibration.temperature.range_degc
    assert low < 4.0 and high > 44.5 and "in 2 run(s)" in printed
    accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(low, high, 200))
    assert accel_mg <= 1.0 and gyro_mradps <= 0.5


def test_replay_warmup_refuses_in_one_line_without_a_temperature_or_with_outputs_it_does_not_make(tmp_path):
    recording = warmup_recording(two_imus()[0], np.random.default_rng(32),
                                 Heating(start_degc=30.0, end_degc=33.0, minutes=2.0), rate_hz=100.0)
    (tmp_path / "cold.csv").write_text(samples_csv_text(recording.t_ns, recording.accel_mps2, recording.gyro_radps,
                                                        None))
    code, err = run_main(["replay", tmp_path / "cold.csv", "--warmup", "-o", tmp_path / "out.yaml"])
    assert_one_error_line(code, err, "no temperature stream", "temperature")
    assert not (tmp_path / "out.yaml").exists()
    code, err = run_main(["replay", tmp_path / "cold.csv", "--warmup", "--report", tmp_path / "r.png"])
    assert_one_error_line(code, err, "--warmup", "--report")
    write_csv(tmp_path / "short.csv", recording)
    code, err = run_main(["replay", tmp_path / "short.csv", "--warmup", "-o", tmp_path / "out.yaml"])
    assert_one_error_line(code, err, "span", "a temperature curve needs 5 degC")
    assert not (tmp_path / "out.yaml").exists()


def test_replay_warmup_of_an_ardupilot_log_of_two_imus_on_top_of_the_calibration_in_force(tmp_path, capsys):
    """A DataFlash log in the real format: two IMUs still and level for 15 minutes while the board warms
    from 15 to 45 degC, a stale calibration in force (undone by replay), the board turned 90 deg in yaw."""
    board, truths = warmup_board(33)
    write_ardupilot_log(tmp_path / "warm.bin", board)
    for instance, truth in enumerate(truths):
        out = tmp_path / f"imu{instance}.yaml"
        code = main(["replay", str(tmp_path / "warm.bin"), "--warmup", "--instance", str(instance), "-o", str(out)])
        printed, err = capsys.readouterr()
        assert code == 0, err
        assert "on top of the log's calibration in force" in printed
        calibration = load_calibration(out)
        low, high = calibration.temperature.range_degc
        assert low < 15.5 and high > 44.0
        accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(low, high, 200))
        assert accel_mg <= 1.0 and gyro_mradps <= 0.5


def test_replay_warmup_of_a_px4_log_reads_each_imu_with_its_temperature(tmp_path, capsys):
    board, truths = warmup_board(34)
    write_px4_log(tmp_path / "warm.ulg", board)
    for instance, truth in enumerate(truths):
        out = tmp_path / f"imu{instance}.yaml"
        code = main(["replay", str(tmp_path / "warm.ulg"), "--warmup", "--instance", str(instance), "-o", str(out)])
        printed, err = capsys.readouterr()
        assert code == 0, err
        calibration = load_calibration(out)
        low, high = calibration.temperature.range_degc
        assert low < 15.5 and high > 44.0
        accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(low, high, 200))
        assert accel_mg <= 1.0 and gyro_mradps <= 0.5


@pytest.mark.parametrize("recording, reason", [
    ("real/bags/sunsided_full_sphere_imu_temp_mcap_zstd", "static.max_noise_mg"),  # hand-held, 24.7-24.9 degC
    ("real/ardupilot/test.BIN", "45 samples"),  # 1 s of IMU records
    ("real/px4_ulog/sample.ulg", "no temperature stream"),
    ("real/px4_ulog/sample_logging_tagged_and_default_params.ulg", "span 0.0 degC"),  # its register reads 0
])
def test_the_real_logs_with_a_temperature_say_why_they_give_no_warm_up(recording, reason, tmp_path):
    """None of the real recordings is a warm-up: each says why in one line, nothing written."""
    code, err = run_main(["replay", shared_path(recording), "--warmup", "-o", tmp_path / "out.yaml"])
    assert_one_error_line(code, err, reason)
    assert not (tmp_path / "out.yaml").exists()


def test_replay_warmup_all_imus_writes_each_imus_curves_on_top_of_its_own_calibration(tmp_path, capsys):
    """The first thing seen: a two-IMU log still and level while it warms gave 'too few static poses'."""
    board, truths = warmup_board(36)
    write_ardupilot_log(tmp_path / "warm.bin", board, devices=(1310988, 1442060))
    code = main(["replay", str(tmp_path / "warm.bin"), "--warmup", "--all-imus", "-o", str(tmp_path / "cal")])
    printed, err = capsys.readouterr()
    assert code == 0, err
    for instance, (truth, device) in enumerate(zip(truths, (1310988, 1442060))):
        calibration = load_calibration(tmp_path / "cal" / f"imu{instance}_dev{device}.yaml")
        assert calibration.accel_device_id == device
        low, high = calibration.temperature.range_degc
        accel_mg, gyro_mradps = temperature_errors(calibration, truth, np.linspace(low, high, 200))
        assert accel_mg <= 1.0 and gyro_mradps <= 0.5
        assert f"IMU {instance} (" in printed
    code, err = run_main(["replay", tmp_path / "warm.bin", "--warmup", "--all-imus"])
    assert_one_error_line(code, err, "--all-imus needs --output DIR")


@pytest.mark.parametrize("seed", [9, 10])
def test_poses_held_while_it_warmed_are_refitted_at_the_reference(tmp_path, capsys, seed):
    """16 orientations at 30 degC, then still while it warms to 44 degC, in one CSV: the detector makes poses
    of the warm-up too (one orientation, its mean drifting 11 mg). Fitted as they were, the sphere took the
    drift for a scale (10.9 mg off) or its gates refused the poses and the curves went on the raw output
    (63 mg); refitted with the drift taken off, the correction at every orientation and temperature is within
    4 mg of the truth."""
    from accel_calibration.core.units import MG, STANDARD_GRAVITY
    from msg_tools.synthetic_imu import spread_orientations

    truth = two_imus()[0]
    c = truth.calibration
    turned, warm, rng = turned_then_warmed(truth, seed)
    both = type(warm)(np.concatenate([turned.t_ns, warm.t_ns]), np.vstack([turned.accel_mps2, warm.accel_mps2]),
                      np.vstack([turned.gyro_radps, warm.gyro_radps]),
                      np.concatenate([turned.temperature_degc, warm.temperature_degc]))
    write_csv(tmp_path / "turned_then_warmed.csv", both)
    out = tmp_path / "out.yaml"
    assert main(["replay", str(tmp_path / "turned_then_warmed.csv"), "--warmup", "-o", str(out)]) == 0
    assert "refitted with the warm-up's drift taken off the poses held while it warmed" in capsys.readouterr().out
    calibration = load_calibration(out)
    true = STANDARD_GRAVITY * np.vstack([np.eye(3), -np.eye(3), spread_orientations(8, rng)[0].apply(np.eye(3))])
    worst_mg = 0.0
    for degc in np.linspace(*calibration.temperature.range_degc, 12):
        raw = true @ np.linalg.inv(c.matrix).T + c.bias + truth.accel_drift(np.array([degc]))
        worst_mg = max(worst_mg, np.abs(calibration.apply(raw, np.full(len(raw), degc)) - true).max() / MG)
    assert worst_mg < 4.0, worst_mg
