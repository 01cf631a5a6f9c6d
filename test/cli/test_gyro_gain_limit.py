"""The gyro's gain has one limit with one name, `gyro.scale_min` / `gyro.scale_max`: the fit's gate and the
check every reader makes of a file (core/plausibility) take the same band, so raising it lets imu_tk's Xsens
recording, read at the nominal 6258 counts per rad/s (31 % off), calibrate its gyro. And the count of
"distinct" poses a refusal gives is the count of directions held, not of holds kept apart."""
from __future__ import annotations

import gzip
import re

import numpy as np
import pytest
from conftest import shared_path

from accel_calibration.core.calibration import Calibration
from accel_calibration.core.plausibility import plausibility_refusal
from accel_calibration.core.refusal import Gate
from accel_calibration.io.calibration_file import load_calibration
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up

from helpers.one_line import assert_one_error_line, run_main

G_XSENS = 9.81744  # the authors' local g


@pytest.fixture(scope="module")
def xsens_csv(tmp_path_factory):
    """imu_tk's Xsens recording as a CSV: accelerometer counts, the gyro at the nominal 6258 counts per rad/s."""
    acc = np.loadtxt(gzip.open(shared_path("real/imu_tk/xsens_acc.txt.gz")))
    gyr = np.loadtxt(gzip.open(shared_path("real/imu_tk/xsens_gyro.txt.gz")))
    gyro = (gyr[:, 1:] - 32768.0) / 6258.0
    rows = [f"{float(t)!r},{a[0]:.0f},{a[1]:.0f},{a[2]:.0f},{float(g[0])!r},{float(g[1])!r},{float(g[2])!r}"
            for t, a, g in zip(acc[:, 0], acc[:, 1:] - 32768.0, gyro)]
    path = tmp_path_factory.mktemp("xsens") / "xsens.csv"
    path.write_text("t,ax,ay,az,gx,gy,gz\n" + "\n".join(rows) + "\n")
    return path


def replay_xsens(path, output, *parameters):
    return run_main(["replay", path, "--units", "counts", "--counts-per-g", "4060", "-p", f"gravity:={G_XSENS}",
                     *parameters, "-o", output])


def test_raising_gyro_scale_max_calibrates_the_xsens_gyro_at_its_nominal_scale(xsens_csv, tmp_path):
    output = tmp_path / "xsens.yaml"
    code, err = replay_xsens(xsens_csv, output)
    assert code == 0, err
    assert load_calibration(output).gyro_matrix is None  # gains 1.31: beyond the default 1.1, kept at its bias
    code, err = replay_xsens(xsens_csv, output, "-p", "gyro.scale_max:=1.4")
    assert code == 0, err
    gains = np.linalg.norm(load_calibration(output).gyro_matrix, axis=1)
    np.testing.assert_allclose(gains, 1.31, atol=0.01)


def test_a_readers_gyro_gain_limit_is_the_gates_and_named_so():
    calibration = Calibration.identity().replace(gyro_bias_radps=np.zeros(3), gyro_matrix=np.eye(3) * 1.2)
    refusal = plausibility_refusal(calibration)
    assert refusal is not None and refusal.gate is Gate.PLAUSIBILITY, refusal
    assert "gyro.scale_max" in refusal.text and "0.9..1.1" in refusal.text, refusal
    assert plausibility_refusal(calibration, gyro_scale_band=(0.9, 1.4)) is None


def test_the_distinct_poses_said_are_the_directions_held(tmp_path):
    """4 directions, each held 4 times at tilts 1 deg apart (17 mg: the store keeps such holds apart), a turn
    to another direction between any two holds."""
    ups = [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]
    rotations = []
    for tilt in range(4):
        for up in ups:
            direction = np.asarray(up) + np.radians(1.0 * tilt) * np.roll(up, 1)
            rotations.append(rotation_with_up(direction / np.linalg.norm(direction)))
    s = SyntheticImu(SensorErrors(noise_mps2=0.02, gyro_noise_radps=0.002), rotations, dwell_s=2.5, move_s=0.8,
                     rate_hz=100.0, seed=2).samples()
    recording = tmp_path / "four.csv"
    rows = [f"{t},{','.join(repr(float(v)) for v in a)}" for t, a in zip(s.t_ns, s.accel_raw)]
    recording.write_text("t_ns,ax,ay,az\n" + "\n".join(rows) + "\n")
    code, err = run_main(["replay", recording, "-o", tmp_path / "cal.yaml"])
    assert_one_error_line(code, err)
    found = re.search(r"found (\d+) static poses \((\d+) distinct directions?\)", err)
    assert found, err
    assert int(found.group(1)) >= 12 and int(found.group(2)) == 4, err


def test_readers_at_the_default_limit_take_such_a_file_with_its_gyro_bias_only(xsens_csv, tmp_path, capsys):
    """export (like apply and report) has no parameters: it reads the file at the default gyro.scale_max, as
    replay at the default keeps the gyro's bias only, and says so in one line; the node, with the raised
    parameter, takes the matrix too."""
    from accel_calibration.cli.main import main
    from accel_calibration.io.autopilot_params import parse_parameter_text

    calibration = tmp_path / "xsens.yaml"
    assert replay_xsens(xsens_csv, calibration, "-p", "gyro.scale_max:=1.4")[0] == 0
    exported = tmp_path / "xsens.params"
    assert main(["export", str(calibration), "--to", "px4", "--force", "-o", str(exported)]) == 0  # 12 mg misaligned
    captured = capsys.readouterr()
    assert "gyro matrix not used" in captured.err and "gyro.scale_max" in captured.err, captured.err
    assert captured.err.count("\n") == 1
    params = parse_parameter_text(exported.read_text(), str(exported)).values
    bias = load_calibration(calibration).gyro_bias_radps
    np.testing.assert_allclose([params[f"CAL_GYRO0_{a}OFF"] for a in "XYZ"], bias, atol=1e-6)
