"""replay --all-imus: every IMU of an autopilot log in one run, one calibration file each named by
instance and device ID (its sensor_id makes export write the right CAL_ACCn_ID), and the rotation between
the IMUs from the poses they held together, with its 1 sigma and the axes observed."""
from __future__ import annotations

import re

import numpy as np
import pytest

from accel_calibration.bag.imu_alignment import relative_rotation
from accel_calibration.cli.main import main
from accel_calibration.io.autopilot_params import parse_parameter_text
from accel_calibration.io.calibration_file import load_calibration

from helpers.autopilot_logs import DEVICES, MG, simulate, write_ardupilot_log, write_px4_log

MOUNTING_MRAD = (4.0, -3.0, 6.0)  # IMU 1 turned from IMU 0 on the board


def said_rotation(out: str) -> tuple[np.ndarray, np.ndarray]:
    match = re.search(r"rotation IMU 0 -> IMU 1: (\S+) (\S+) (\S+) mrad about x y z \(1 sigma (\S+) (\S+) (\S+) mrad\)",
                      out)
    assert match, out
    values = [float(v) for v in match.groups()]
    return np.array(values[:3]), np.array(values[3:])


def test_every_imu_of_a_ulog_one_file_each_and_the_rotation_between_them(tmp_path, capsys):
    board = simulate(11, mounting_mrad=MOUNTING_MRAD)
    log = tmp_path / "bench.ulg"
    write_px4_log(log, board)
    out_dir = tmp_path / "cal"
    assert main(["replay", str(log), "--all-imus", "-o", str(out_dir)]) == 0
    out = capsys.readouterr().out
    names = sorted(p.name for p in out_dir.iterdir())
    assert names == [f"imu0_dev{DEVICES[0]}.yaml", f"imu1_dev{DEVICES[1]}.yaml"]
    for k in range(2):
        calibration = load_calibration(out_dir / names[k])
        assert calibration.sensor_id == f"px4 device {DEVICES[k]}"
        truth = board.imus[k].truth
        assert np.max(np.abs(calibration.bias - truth.bias_mps2)) < 0.3 * MG
        exported = tmp_path / f"imu{k}.params"
        assert main(["export", str(out_dir / names[k]), "--to", "px4", "--instance", str(k), "-o", str(exported)]) == 0
        params = parse_parameter_text(exported.read_text(), str(exported)).values
        assert params[f"CAL_ACC{k}_ID"] == DEVICES[k]
    angles, sigma = said_rotation(out)
    assert np.all(sigma < 0.5)  # mrad, from 14 distinct orientations
    assert np.all(np.abs(angles - MOUNTING_MRAD) < 3 * sigma), (angles, sigma)
    assert "all three axes observed" in out


def test_every_imu_of_an_older_dataflash_log(tmp_path, capsys):
    board = simulate(12, mounting_mrad=MOUNTING_MRAD)
    log = tmp_path / "00000007.BIN"
    write_ardupilot_log(log, board, old_style=True)
    out_dir = tmp_path / "cal"
    assert main(["replay", str(log), "--all-imus", "-o", str(out_dir)]) == 0
    out = capsys.readouterr().out
    assert sorted(p.name for p in out_dir.iterdir()) == ["imu0.yaml", "imu1.yaml"]  # no INS_ACC_ID logged
    angles, sigma = said_rotation(out)
    assert np.all(np.abs(angles - MOUNTING_MRAD) < 3 * sigma), (angles, sigma)


def test_options_that_do_not_fit_all_imus_are_one_line(tmp_path, capsys):
    csv = tmp_path / "samples.csv"
    csv.write_text("t,ax,ay,az\n0,0,0,9.8\n")
    for args in (["--instance", "1"], ["--report", str(tmp_path / "r.png")], []):
        assert main(["replay", str(csv), "--all-imus", *args, "-o", str(tmp_path / "out")]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("accel-calib: error: ")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("spread", [True, False], ids=["many orientations", "one orientation"])
def test_rotation_about_gravity_is_unobservable_from_one_pose(spread):
    rng = np.random.default_rng(3)
    truth = np.array([2.0, -1.0, 5.0]) * 1e-3
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_rotvec(truth).as_matrix()
    directions = rng.normal(size=(12, 3)) if spread else np.tile([0.0, 0.0, 1.0], (12, 1))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    noisy = directions @ turn.T + rng.normal(0.0, 2e-4, directions.shape)
    result = relative_rotation(directions, noisy / np.linalg.norm(noisy, axis=1, keepdims=True))
    if spread:
        assert result.unobserved is None
        assert np.all(np.abs(result.rotation_mrad - truth * 1e3) < 4 * result.sigma_mrad)
    else:  # z is gravity's axis: x and y are seen, z is not (and is left at zero, not guessed)
        np.testing.assert_allclose(np.abs(result.unobserved), [0, 0, 1], atol=1e-2)
        assert np.isnan(result.sigma_mrad[2]) and abs(result.rotation_mrad[2]) < 0.05
        assert np.all(np.abs(result.rotation_mrad[:2] - truth[:2] * 1e3) < 4 * result.sigma_mrad[:2])
        assert "not observed" in result.describe("IMU 0", "IMU 1")
