"""accel-calib noise on awkward input: every output's place checked before any is written, a gap in the
stream (the longest unbroken stretch at the sample period's rate, said in one line), and channels with no
noise to measure (one line for that channel, the others' figures still printed), never a traceback."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from accel_calibration.cli.main import main

RATE_HZ = 100.0
ACCEL_DENSITY, GYRO_DENSITY = 2e-3, 2e-4


def write_csv(path, t_s: np.ndarray, accel: np.ndarray, gyro: np.ndarray, time_column: str = "t") -> None:
    with open(path, "w") as stream:
        stream.write(f"{time_column},ax,ay,az,gx,gy,gz\n")
        np.savetxt(stream, np.column_stack([t_s, accel, gyro]), delimiter=",", fmt="%.12g")


def still(seed: int, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    samples = int(seconds * RATE_HZ)
    accel = ACCEL_DENSITY * np.sqrt(RATE_HZ) * rng.standard_normal((samples, 3)) + [0.0, 0.0, 9.80665]
    gyro = GYRO_DENSITY * np.sqrt(RATE_HZ) * rng.standard_normal((samples, 3))
    return np.arange(samples) / RATE_HZ, accel, gyro


def test_a_missing_plot_directory_is_refused_before_the_kalibr_file_is_replaced(tmp_path, capsys):
    write_csv(tmp_path / "still.csv", *still(1, 60.0))
    kalibr = tmp_path / "imu.yaml"
    kalibr.write_text("kept: true\n")
    code = main(["noise", str(tmp_path / "still.csv"), "--whole", "--kalibr", str(kalibr),
                 "--plot", str(tmp_path / "missing" / "fig.png")])
    assert code == 1
    assert kalibr.read_text() == "kept: true\n"
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "--plot" in error and "does not exist" in error


@pytest.mark.parametrize("gap_s", [5.0, 36000.0])
def test_a_gap_leaves_the_longest_unbroken_stretch_at_the_sample_rate(tmp_path, capsys, gap_s):
    t, accel, gyro = still(2, 90.0)
    t = np.where(t >= 60.0, t + gap_s, t)  # 60 s, a gap, 30 s
    write_csv(tmp_path / "gap.csv", t, accel, gyro)
    assert main(["noise", str(tmp_path / "gap.csv"), "--whole", "--kalibr", str(tmp_path / "imu.yaml")]) == 0
    out = capsys.readouterr().out
    assert out.count("longest unbroken stretch") == 1 and "1 gap(s)" in out
    figures = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    assert figures["update_rate"] == pytest.approx(RATE_HZ, rel=1e-6)
    assert figures["accelerometer_noise_density"] == pytest.approx(ACCEL_DENSITY, rel=0.1)
    assert "6000 samples" in out  # the first 60 s


def test_a_constant_gyro_says_no_noise_while_the_accelerometer_figures_print(tmp_path, capsys):
    t, accel, gyro = still(3, 60.0)
    write_csv(tmp_path / "zero_gyro.csv", t, accel, np.zeros_like(gyro))
    assert main(["noise", str(tmp_path / "zero_gyro.csv"), "--whole"]) == 0
    out = capsys.readouterr().out
    assert "gyroscope: no noise measurable (constant or quantized)" in out
    assert out.count("[") >= 3  # the accelerometer's three densities with their intervals
    assert main(["noise", str(tmp_path / "zero_gyro.csv"), "--whole", "--kalibr", str(tmp_path / "imu.yaml")]) == 1
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "gyroscope" in error and not (tmp_path / "imu.yaml").exists()


def test_a_stepped_gyro_and_a_nanosecond_time_column_give_figures_or_one_line(tmp_path, capsys):
    t, accel, gyro = still(4, 60.0)
    stepped = np.round(gyro / 0.05) * 0.05  # quantized far coarser than its noise: mostly zeros
    write_csv(tmp_path / "stepped.csv", t, accel, stepped)
    write_csv(tmp_path / "ns.csv", np.round(t * 1e9), accel, gyro, time_column="t_ns")
    for name in ("stepped.csv", "ns.csv"):
        code = main(["noise", str(tmp_path / name), "--whole"])
        captured = capsys.readouterr()
        assert code in (0, 1) and "Traceback" not in captured.err
        assert code == 0 or captured.err.count("\n") == 1, captured.err
    assert code == 0 and "ay" not in captured.err


def test_the_fit_of_a_curve_spanning_many_decades_gives_figures_not_a_linear_algebra_error():
    """Two hours of slow turning taken as still (--whole): the curve rises by decades; the fit still
    answers (its columns are scaled) or says why in one line."""
    from accel_calibration.core.allan import fit_noise, overlapping_adev
    from accel_calibration.core.errors import CalibrationError

    rate, seconds = 50.0, 7200.0
    t = np.arange(int(rate * seconds)) / rate
    rng = np.random.default_rng(6)
    x = 9.80665 * np.sin(2 * np.pi * t / 600.0) + 1e-9 * rng.standard_normal(len(t))
    tau, adev, relative = overlapping_adev(x, rate)
    try:
        fit = fit_noise(tau, adev[:, 0], relative, seconds)
    except CalibrationError as error:
        assert "\n" not in str(error)
    else:
        assert np.isfinite(fit.noise.white_density.value)
