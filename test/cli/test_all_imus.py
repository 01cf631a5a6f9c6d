"""replay --all-imus: every IMU of an autopilot log in one run, one calibration file each named by
instance and device ID (its sensor_id makes export write the right CAL_ACCn_ID), and the rotation between
the IMUs from the poses they held together, with its 1 sigma and the axes observed."""
from __future__ import annotations

import re
from pathlib import Path

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


# --- the files of one run are written as a set ---------------------------------------------------------

@pytest.fixture(scope="module")
def two_imu_log(tmp_path_factory):
    log = tmp_path_factory.mktemp("set") / "bench.ulg"
    write_px4_log(log, simulate(11, mounting_mrad=MOUNTING_MRAD))
    return log


def set_names():
    return [f"imu0_dev{DEVICES[0]}.yaml", f"imu1_dev{DEVICES[1]}.yaml"]


def earlier_set(out_dir):
    """The calibrations of an earlier run (identity, so they are told from this run's), and their bytes."""
    from accel_calibration.core.calibration import Calibration
    from accel_calibration.io.calibration_file import save_calibration

    out_dir.mkdir()
    for name in set_names():
        save_calibration(Calibration.identity(frame_id="earlier"), out_dir / name)
    return {name: (out_dir / name).read_bytes() for name in set_names()}


def test_a_file_there_that_is_no_calibration_is_refused_and_nothing_written(two_imu_log, tmp_path, capsys):
    out_dir = tmp_path / "cal"
    out_dir.mkdir()
    notes = out_dir / set_names()[1]
    notes.write_text("my notes on IMU 1\n")
    assert main(["replay", str(two_imu_log), "--all-imus", "-o", str(out_dir)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("accel-calib: error: ") and "not a calibration" in err, err
    assert notes.read_text() == "my notes on IMU 1\n"
    assert sorted(p.name for p in out_dir.iterdir()) == [set_names()[1]]


def test_what_is_replaced_is_listed_and_an_older_sets_leftover_named(two_imu_log, tmp_path, capsys):
    out_dir = tmp_path / "cal"
    earlier_set(out_dir)
    from accel_calibration.core.calibration import Calibration
    from accel_calibration.io.calibration_file import save_calibration

    save_calibration(Calibration.identity(frame_id="earlier"), out_dir / "imu2.yaml")  # a run with 3 IMUs
    assert main(["replay", str(two_imu_log), "--all-imus", "-o", str(out_dir)]) == 0
    out = capsys.readouterr().out
    for name in set_names():
        assert f"replaced {out_dir / name}" in out, out
        assert load_calibration(out_dir / name).frame_id != "earlier"
    assert re.search(rf"not of this run.*{re.escape(str(out_dir / 'imu2.yaml'))}", out), out
    assert load_calibration(out_dir / "imu2.yaml").frame_id == "earlier"  # named, never removed


@pytest.mark.parametrize("fails_at", ["write", "rename"])
def test_a_failure_on_the_second_file_leaves_the_whole_earlier_set(two_imu_log, tmp_path, capsys, monkeypatch,
                                                                    fails_at):
    import os

    from accel_calibration.io import output_paths

    out_dir = tmp_path / "cal"
    before = earlier_set(out_dir)
    real = {"write": os.fsync, "rename": os.replace}[fails_at]

    def second_fails(*args):  # the disk full at IMU 1's file: its data (fsync), or its rename into place
        path = os.readlink(f"/proc/self/fd/{args[0]}") if fails_at == "write" else str(args[1])
        if set_names()[1] in Path(path).name:
            raise OSError(28, "No space left on device")
        return real(*args)

    monkeypatch.setattr(output_paths.os, {"write": "fsync", "rename": "replace"}[fails_at], second_fails)
    assert main(["replay", str(two_imu_log), "--all-imus", "-o", str(out_dir)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left" in err and "as they were" in err, err
    assert {p.name: p.read_bytes() for p in out_dir.iterdir()} == before  # no temp file left either
