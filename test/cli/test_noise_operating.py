"""The noise in operation: a simulated vehicle, still and then running with its own motion (below 5 Hz) and a
known vibration added to known sensor noise; `accel-calib noise --operating` prints the density in
operation within 10 % of the truth beside the static one with their ratio, and `--kalibr --noise operating`
writes it and says which figure it carries. The real PX4 log prints both."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from accel_calibration.cli.main import main
from accel_calibration.core.band_noise import band_density

RATE_HZ = 250.0
STILL_S, RUNNING_S = 120.0, 120.0
ACCEL_N, GYRO_N = 1e-3, 1e-4  # the sensor's white noise density
ACCEL_VIBRATION, GYRO_VIBRATION = 3e-3, 2e-4  # broadband vibration's density while running


def vehicle(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(accel, gyro) (samples, 3): still, then running: slow motion (0.3-2 Hz) + vibration + sensor noise."""
    still, running = int(STILL_S * RATE_HZ), int(RUNNING_S * RATE_HZ)
    samples = still + running
    t = np.arange(samples) / RATE_HZ
    accel = ACCEL_N * np.sqrt(RATE_HZ) * rng.standard_normal((samples, 3)) + [0.0, 0.0, 9.80665]
    gyro = GYRO_N * np.sqrt(RATE_HZ) * rng.standard_normal((samples, 3))
    moving = t >= STILL_S
    # the motion sets in over 2 s (a vehicle's rates do not jump), as the motors' vibration does at once
    onset = 0.5 - 0.5 * np.cos(np.pi * np.clip((t[moving] - STILL_S) / 2.0, 0.0, 1.0))
    for axis, (frequency, phase) in enumerate([(0.3, 0.1), (1.1, 1.0), (2.0, 2.0)]):
        accel[moving, axis] += 2.0 * onset * np.sin(2 * np.pi * frequency * t[moving] + phase)
        gyro[moving, axis] += 0.5 * onset * np.sin(2 * np.pi * frequency * 0.7 * t[moving] + phase)
    accel[moving] += ACCEL_VIBRATION * np.sqrt(RATE_HZ) * rng.standard_normal((running, 3))
    gyro[moving] += GYRO_VIBRATION * np.sqrt(RATE_HZ) * rng.standard_normal((running, 3))
    return accel, gyro


def test_the_band_density_of_white_noise_is_its_density_and_slow_motion_is_left_out():
    rng = np.random.default_rng(3)
    t = np.arange(int(60 * RATE_HZ)) / RATE_HZ
    white = ACCEL_N * np.sqrt(RATE_HZ) * rng.standard_normal((len(t), 3))
    moving = white + 3.0 * np.sin(2 * np.pi * 1.5 * t)[:, None]
    np.testing.assert_allclose(band_density(white, RATE_HZ), ACCEL_N, rtol=0.05)
    np.testing.assert_allclose(band_density(moving, RATE_HZ), ACCEL_N, rtol=0.05)


def test_noise_operating_is_within_10_percent_of_the_truth_and_kalibr_carries_it(tmp_path, capsys):
    accel, gyro = vehicle(np.random.default_rng(5))
    t = np.arange(len(accel)) / RATE_HZ
    with open(tmp_path / "flight.csv", "w") as stream:
        stream.write("t,ax,ay,az,gx,gy,gz\n")
        np.savetxt(stream, np.column_stack([t, accel, gyro]), delimiter=",", fmt="%.9g")
    assert main(["noise", str(tmp_path / "flight.csv"), "--operating", "--noise", "operating",
                 "--kalibr", str(tmp_path / "imu.yaml")]) == 0
    out = capsys.readouterr().out
    assert "in operation" in out and "ratio" in out
    text = (tmp_path / "imu.yaml").read_text()
    assert "noise densities in operation" in text
    figures = yaml.safe_load(text)
    assert figures["accelerometer_noise_density"] == pytest.approx(np.hypot(ACCEL_N, ACCEL_VIBRATION), rel=0.10)
    assert figures["gyroscope_noise_density"] == pytest.approx(np.hypot(GYRO_N, GYRO_VIBRATION), rel=0.10)
    # the export carries the figures and says which they are
    from accel_calibration.core.calibration import Calibration
    from accel_calibration.io.calibration_file import save_calibration

    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "openvins", "--noise", str(tmp_path / "imu.yaml"),
                 "-o", str(tmp_path / "chain.yaml")]) == 0
    chain = (tmp_path / "chain.yaml").read_text()
    assert "# noise densities in operation" in chain
    assert f"accelerometer_noise_density: {figures['accelerometer_noise_density']:.6e}" in chain
    ratios = [float(line.split("ratio")[1]) for line in out.splitlines() if line.startswith("  a")
              and "operating" in line]
    assert len(ratios) == 3
    assert all(r == pytest.approx(np.hypot(ACCEL_N, ACCEL_VIBRATION) / ACCEL_N, rel=0.10) for r in ratios)


def test_noise_operating_without_measuring_it_is_refused_in_one_line(tmp_path, capsys):
    (tmp_path / "x.csv").write_text("t,ax,ay,az\n0,0,0,9.8\n")
    assert main(["noise", str(tmp_path / "x.csv"), "--noise", "operating"]) == 1
    assert capsys.readouterr().err.count("\n") == 1


def test_the_px4_log_prints_both_figures(shared, capsys):
    assert main(["noise", str(shared("real/px4_ulog/sample.ulg")), "--operating"]) == 0
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if "operating" in line and "ratio" in line]
    assert len(lines) == 6, out
    assert all(float(line.split("ratio")[1]) > 0 for line in lines)
