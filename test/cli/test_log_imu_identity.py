"""Which IMU of an autopilot log a calibration is for: the file names its accelerometer's and gyro's device IDs
(replay writes them from the log), `check` and `replay --prior` pick the log's instance of that device or refuse
in one line, the gyro is paired with its accelerometer by device (a BMI088's gyro is a die of its own, with its
own ID), `export` writes CAL_GYROn_ID from the gyro's own ID, and --all-imus takes the instances the log has."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.cli.main import main
from accel_calibration.core.errors import DeprecatedInputWarning
from accel_calibration.io.autopilot_params import parse_parameter_text
from accel_calibration.io.calibration_file import load_calibration

from helpers.autopilot_logs import DEVICES, simulate, write_ardupilot_log, write_px4_log
from helpers.one_line import refused

GYRO_DEVICES = (2490378, 2555914)  # BMI088 gyro dies: IDs of their own
OTHER_DEVICE = 3735562


def gyro_bias_errors(board, out_dir) -> dict[int, float]:
    """Per IMU file of a --all-imus run: how far its gyro bias is from its own gyro's true bias, rad/s."""
    errors = {}
    for path in out_dir.iterdir():
        k = int(path.name[3])
        calibration = load_calibration(path)
        assert calibration.gyro_bias_radps is not None, path
        errors[k] = float(np.max(np.abs(calibration.gyro_bias_radps - board.imus[k].gyro_bias)))
    return errors


def test_all_imus_takes_instances_1_and_2_of_a_log_without_instance_0(tmp_path, capsys):
    board = simulate(21)
    log = tmp_path / "no_zero.ulg"
    write_px4_log(log, board, instances=(1, 2))
    out_dir = tmp_path / "cal"
    assert main(["replay", str(log), "--all-imus", "-o", str(out_dir)]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in out_dir.iterdir()) == [f"imu1_dev{DEVICES[0]}.yaml", f"imu2_dev{DEVICES[1]}.yaml"]
    for k, name in enumerate(sorted(p.name for p in out_dir.iterdir())):
        calibration = load_calibration(out_dir / name)
        assert calibration.accel_device_id == DEVICES[k]
        assert np.max(np.abs(calibration.bias - board.imus[k].truth.bias_mps2)) < 0.003  # m/s^2: 0.3 mg


def test_a_gyro_of_its_own_die_is_paired_by_device_and_exported_with_its_own_id(tmp_path, capsys):
    board = simulate(22)
    apart = abs(board.imus[0].gyro_bias - board.imus[1].gyro_bias).max()
    assert apart > 0.005  # rad/s: the two gyros told apart by their biases
    log = tmp_path / "bmi088.ulg"
    write_px4_log(log, board, gyro_devices=GYRO_DEVICES, gyro_instances=(1, 0))  # the gyros' uORB order swapped
    out_dir = tmp_path / "cal"
    assert main(["replay", str(log), "--all-imus", "-o", str(out_dir)]) == 0, capsys.readouterr().err
    errors = gyro_bias_errors(board, out_dir)
    assert max(errors.values()) < 0.1 * apart, errors
    for k in range(2):
        path = out_dir / f"imu{k}_dev{DEVICES[k]}.yaml"
        calibration = load_calibration(path)
        assert (calibration.accel_device_id, calibration.gyro_device_id) == (DEVICES[k], GYRO_DEVICES[k])
        exported = tmp_path / f"imu{k}.params"
        assert main(["export", str(path), "--to", "px4", "--instance", str(k), "-o", str(exported)]) == 0
        params = parse_parameter_text(exported.read_text(), str(exported)).values
        assert (params[f"CAL_ACC{k}_ID"], params[f"CAL_GYRO{k}_ID"]) == (DEVICES[k], GYRO_DEVICES[k])


def test_two_instances_of_one_device_id_each_keep_their_own_gyro(tmp_path, capsys):
    board = simulate(23)
    log = tmp_path / "one_id.ulg"
    write_px4_log(log, board, accel_devices=(DEVICES[0], DEVICES[0]))
    out_dir = tmp_path / "cal"
    assert main(["replay", str(log), "--all-imus", "-o", str(out_dir)]) == 0, capsys.readouterr().err
    apart = abs(board.imus[0].gyro_bias - board.imus[1].gyro_bias).max()
    errors = gyro_bias_errors(board, out_dir)
    assert max(errors.values()) < 0.1 * apart, errors


@pytest.fixture(scope="module")
def two_imu_log(tmp_path_factory):
    """A two-IMU ULog and IMU 1's calibration from it (replay --instance 1)."""
    folder = tmp_path_factory.mktemp("identity")
    log = folder / "two_imu.ulg"
    write_px4_log(log, simulate(24))
    imu1 = folder / "imu1.yaml"
    assert main(["replay", str(log), "--instance", "1", "-o", str(imu1)]) == 0
    return log, imu1


def test_check_without_instance_picks_the_instance_of_the_files_device_and_says_so(two_imu_log, capsys):
    log, imu1 = two_imu_log
    capsys.readouterr()
    assert main(["check", str(imu1), str(log)]) == 0
    out = capsys.readouterr().out
    assert f"sensor_accel instance 1 (device {DEVICES[1]})" in out, out
    assert out.splitlines()[0].startswith("holds:"), out


def test_check_refuses_another_device_in_one_line(two_imu_log, tmp_path, capsys):
    log, imu1 = two_imu_log
    refused(capsys, ["check", imu1, log, "--instance", "0"], str(DEVICES[0]), str(DEVICES[1]), "--instance 1")
    stranger = tmp_path / "stranger.yaml"
    text = imu1.read_text().replace(str(DEVICES[1]), str(OTHER_DEVICE))
    stranger.write_text(text)
    refused(capsys, ["check", stranger, log], str(OTHER_DEVICE), f"{DEVICES[0]} (instance 0)",
            f"{DEVICES[1]} (instance 1)")


def test_an_older_file_naming_its_device_in_sensor_id_only_is_matched_too(two_imu_log, tmp_path, capsys):
    log, imu1 = two_imu_log
    older = tmp_path / "older.yaml"
    older.write_text("".join(line for line in imu1.read_text().splitlines(keepends=True)
                             if "device_id:" not in line))
    with pytest.warns(DeprecatedInputWarning, match="sensor_id only"):
        assert load_calibration(older).accel_device_id == DEVICES[1]
    assert main(["check", str(older), str(log)]) == 0
    said = capsys.readouterr()
    assert f"sensor_accel instance 1 (device {DEVICES[1]})" in said.out
    assert said.err.startswith("accel-calib: warning: ") and f"accel_device_id: {DEVICES[1]}" in said.err


def test_replay_prior_of_another_device_is_refused_or_its_instance_picked(two_imu_log, tmp_path, capsys):
    log, imu1 = two_imu_log
    refused(capsys, ["replay", log, "--instance", "0", "--prior", imu1, "-o", tmp_path / "new.yaml"],
            "--prior", str(DEVICES[1]), str(DEVICES[0]))
    assert main(["replay", str(log), "--prior", str(imu1), "-o", str(tmp_path / "new.yaml")]) == 0
    assert f"sensor_accel instance 1 (device {DEVICES[1]})" in capsys.readouterr().out
    assert load_calibration(tmp_path / "new.yaml").accel_device_id == DEVICES[1]


def test_export_refuses_a_device_id_other_than_the_files(two_imu_log, tmp_path, capsys):
    _, imu1 = two_imu_log
    refused(capsys, ["export", imu1, "--to", "px4", "--device-id", str(DEVICES[0])], str(DEVICES[0]),
            str(DEVICES[1]))


def test_all_imus_with_a_prior_puts_it_on_its_own_device_only(two_imu_log, tmp_path, capsys):
    log, imu1 = two_imu_log
    capsys.readouterr()
    out_dir = tmp_path / "cal"
    assert main(["replay", str(log), "--all-imus", "--prior", str(imu1), "-o", str(out_dir)]) == 0, \
        capsys.readouterr().err
    out = capsys.readouterr().out
    assert f"IMU 0 (device {DEVICES[0]}): fitted without --prior" in out, out
    assert sorted(p.name for p in out_dir.iterdir()) == [f"imu0_dev{DEVICES[0]}.yaml", f"imu1_dev{DEVICES[1]}.yaml"]
    stranger = tmp_path / "stranger.yaml"
    stranger.write_text(imu1.read_text().replace(str(DEVICES[1]), str(OTHER_DEVICE)))
    refused(capsys, ["replay", log, "--all-imus", "--prior", stranger, "-o", tmp_path / "other"], str(OTHER_DEVICE))


def test_check_picks_the_dataflash_instance_of_the_files_device(tmp_path, capsys):
    log = tmp_path / "00000009.BIN"
    write_ardupilot_log(log, simulate(25), devices=DEVICES)
    imu1 = tmp_path / "imu1.yaml"
    assert main(["replay", str(log), "--instance", "1", "-o", str(imu1)]) == 0
    assert load_calibration(imu1).accel_device_id == DEVICES[1]
    capsys.readouterr()
    assert main(["check", str(imu1), str(log)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("holds:") and f"IMU instance 1 (device {DEVICES[1]})" in out, out
    refused(capsys, ["check", imu1, log, "--instance", "0"], str(DEVICES[0]), "--instance 1")


def test_export_says_when_the_gyro_id_is_the_accelerometers_by_assumption(two_imu_log, tmp_path, capsys):
    _, imu1 = two_imu_log
    older = tmp_path / "older.yaml"
    older.write_text("".join(line for line in imu1.read_text().splitlines(keepends=True) if "device_id:" not in line))
    capsys.readouterr()
    assert main(["export", str(older), "--to", "px4", "--instance", "1", "-o", str(tmp_path / "p.params")]) == 0
    out = capsys.readouterr().out
    assert f"CAL_GYRO1_ID = {DEVICES[1]}, the accelerometer's" in out, out
    assert main(["export", str(imu1), "--to", "px4", "--instance", "1", "-o", str(tmp_path / "q.params")]) == 0
    assert "the accelerometer's" not in capsys.readouterr().out
