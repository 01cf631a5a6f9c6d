"""Autopilot logs carry corrected streams (ArduPilot IMU records, PX4 sensor_combined): replay undoes the
correction the log's own parameters describe, so the calibration written corrects the RAW sensor in its
own axes. End to end through the CLI on simulated logs in the real formats (two IMUs, known raw errors,
a stale calibration in the parameters, a 90 deg yaw board rotation): replay -> export per IMU -> the
exported parameters applied with each autopilot's own formula (re-implemented here from its source) to
the raw samples -> the truth."""
from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from accel_calibration.cli.main import main
from accel_calibration.io.autopilot_params import parse_parameter_text
from accel_calibration.io.calibration_file import load_calibration
from msg_tools.dataflash_writer import FORMATS_4X, imu_records, parameter_records, write_dataflash

from helpers.autopilot_logs import (
    DEVICES,
    MG,
    START_US,
    Imu,
    ardupilot_parameters,
    logged,
    simulate,
    write_ardupilot_log,
    write_px4_log,
)


def ardupilot_correct(params: dict[str, float], instance: int, raw: np.ndarray) -> np.ndarray:
    """AP_InertialSensor_Backend::_rotate_and_correct_accel before the board rotation: accel -= INS_ACC*OFFS,
    then *= INS_ACC*SCAL per axis (no temperature calibration here)."""
    n = "" if instance == 0 else str(instance + 1)
    offset = np.array([params[f"INS_ACC{n}OFFS_{a}"] for a in "XYZ"])
    scale = np.array([params[f"INS_ACC{n}SCAL_{a}"] for a in "XYZ"])
    return (raw - offset) * scale


def px4_correct(params: dict[str, float], instance: int, raw: np.ndarray) -> np.ndarray:
    """calibration::Accelerometer::Correct before the rotation: (raw - CAL_ACCn_OFF) .* CAL_ACCn_SCALE."""
    offset = np.array([params[f"CAL_ACC{instance}_{a}OFF"] for a in "XYZ"])
    scale = np.array([params[f"CAL_ACC{instance}_{a}SCALE"] for a in "XYZ"])
    return (raw - offset) * scale


def worst_error_mg(corrected: np.ndarray, imu: Imu) -> float:
    true = (imu.raw - imu.truth.bias_mps2) @ imu.truth.matrix.T  # the truth applied to the same raw samples
    return float(np.max(np.linalg.norm(corrected - true, axis=1)) / MG)


def replay_and_export(log, tmp_path, target: str, instance: int, replay_args: list[str], capsys
                      ) -> tuple[dict[str, float], str, float]:
    """(exported parameters, replay's output, the loss export states in mg)."""
    calibration = tmp_path / f"{target}{instance}.yaml"
    assert main(["replay", str(log), *replay_args, "-o", str(calibration)]) == 0
    said = capsys.readouterr().out
    exported = tmp_path / f"{target}{instance}.param"
    assert main(["export", str(calibration), "--to", target, "--instance", str(instance), "--force",
                 "-o", str(exported)]) == 0
    stated = float(re.search(r"worst ([0-9.]+) mg", capsys.readouterr().out).group(1))
    return parse_parameter_text(exported.read_text(), str(exported)).values, said, stated


@pytest.mark.parametrize("old_style", [False, True], ids=["IMU with I", "IMU and IMU2"])
def test_ardupilot_export_corrects_the_raw_sensor(tmp_path, capsys, old_style):
    board = simulate(7)
    log = tmp_path / "00000042.BIN"
    write_ardupilot_log(log, board, old_style)
    for k, imu in enumerate(board.imus):
        params, said, stated = replay_and_export(log, tmp_path, "ardupilot", k, ["--instance", str(k)], capsys)
        error = worst_error_mg(ardupilot_correct(params, k, imu.raw), imu)
        assert error < 0.5, f"IMU {k}: {error:.2f} mg"
        assert stated < 0.5  # a diagonal truth: the autopilot holds it whole (sphere9 sees a little noise)
        assert "fitted to raw: DataFlash IMU instance" in said and "AHRS_ORIENTATION 2" in said
        assert "raw: " in load_calibration(tmp_path / f"ardupilot{k}.yaml").fitted_to


def test_px4_export_corrects_the_raw_sensor_from_combined_and_from_sensor_accel(tmp_path, capsys):
    board = simulate(8)
    log = tmp_path / "bench.ulg"
    write_px4_log(log, board)
    # sensor_combined (corrected by CAL_ACC0 and SENS_BOARD_ROT, undone), then IMU 1's own sensor_accel.
    for k, args in ((0, []), (1, ["--instance", "1"])):
        params, said, stated = replay_and_export(log, tmp_path, "px4", k, args, capsys)
        error = worst_error_mg(px4_correct(params, k, board.imus[k].raw), board.imus[k])
        assert error < 0.5, f"IMU {k}: {error:.2f} mg"
        assert stated < 0.5
        assert ("SENS_BOARD_ROT 2" in said) if k == 0 else (f"fitted to raw: sensor_accel instance 1 (px4 device "
                                                            f"{DEVICES[1]})" in said)


def test_a_misaligned_truth_is_within_the_stated_loss(tmp_path, capsys):
    board = simulate(9, misaligned=True)
    log = tmp_path / "misaligned.bin"
    write_ardupilot_log(log, board)
    params, _, stated = replay_and_export(log, tmp_path, "ardupilot", 1, ["--instance", "1", "--model", "sphere9"],
                                          capsys)
    error = worst_error_mg(ardupilot_correct(params, 1, board.imus[1].raw), board.imus[1])
    assert stated > 5  # ~1 deg of non-orthogonality the autopilot cannot hold
    assert error < stated + 0.5


def test_a_rotation_the_reader_does_not_know_is_one_line(tmp_path, capsys):
    board = simulate(7)
    log = tmp_path / "custom.bin"
    records = parameter_records(START_US - 1000, {**ardupilot_parameters(board), "AHRS_ORIENTATION": 101.0})
    accel, gyro = logged(board.imus[0])
    write_dataflash(log, FORMATS_4X, records + imu_records(board.t_us[:50], accel[:50], gyro[:50],
                                                           board.temperature[:50]))
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "AHRS_ORIENTATION = 101 is not a rotation" in err
    assert not out.exists()


def test_the_rotation_table_matches_the_autopilots_rotate():
    from accel_calibration.bag.logged_correction import rotation_matrix

    v = np.array([1.0, 2.0, 3.0])
    # rotate_3f / Vector3::rotate: YAW_90 (x, y) -> (-y, x); ROLL_180 (y, z) -> (-y, -z); PITCH_90 (x, z) -> (z, -x)
    np.testing.assert_allclose(rotation_matrix(2) @ v, [-2.0, 1.0, 3.0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(8) @ v, [1.0, -2.0, -3.0], atol=1e-12)
    np.testing.assert_allclose(rotation_matrix(24) @ v, [3.0, 2.0, -1.0], atol=1e-12)
    assert Rotation.from_matrix(rotation_matrix(17)).magnitude() > 0
