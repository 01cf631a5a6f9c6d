"""Whatever `accel-calib` writes, `apply` reads: a replay whose gyro part the readers would refuse as
implausible writes the accelerometer calibration alone and says in one line that the gyro was left out."""
from __future__ import annotations

import contextlib
import io

import numpy as np

from accel_calibration import load_calibration
from accel_calibration.cli.main import main

from helpers.session_streams import stream


def write_samples_csv(path, samples, gyro_offset):
    gyro = samples.gyro_raw + gyro_offset
    rows = np.column_stack([samples.t_ns, samples.accel_raw, gyro])
    lines = ["t_ns,ax,ay,az,gx,gy,gz"] + [f"{int(r[0])}," + ",".join(f"{v!r}" for v in r[1:]) for r in rows.tolist()]
    path.write_text("\n".join(lines) + "\n")


def run(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in args])
    return code, out.getvalue(), err.getvalue()


def test_replay_leaves_an_implausible_gyro_out_and_apply_takes_the_file(tmp_path):
    _, samples = stream(seed=3)
    recording, cal = tmp_path / "imu.csv", tmp_path / "cal.yaml"
    write_samples_csv(recording, samples, np.array([2.0, 0.0, 0.0]))
    code, out, err = run(["replay", recording, "-o", cal])
    assert code == 0, err
    said = [line for line in out.splitlines() if "gyro left out" in line]
    assert len(said) == 1 and "gyro bias" in said[0], out
    calibration = load_calibration(cal)
    assert calibration.gyro_bias_radps is None and calibration.gyro_matrix is None
    table = tmp_path / "in.csv"
    table.write_text("ax,ay,az\n0.1,0.2,9.8\n")
    code, _, err = run(["apply", "-c", cal, table, tmp_path / "out.csv"])
    assert code == 0 and err == "", err
