"""The white-noise density of low-pass-filtered noise (every real IMU filters: a DLPF, PX4's integrator):
read where the Allan curve has the -1/2 slope, not from the short-tau points the filter pulls below the
white line. A grid of rates and Butterworth cut-offs, each within 10 % of the simulated density; a curve
without a white region says so instead of giving a density of 0."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import butter, lfilter

from accel_calibration.core.allan import fit_noise, overlapping_adev

DENSITY = 1e-3  # m/s^2/sqrt(Hz)
RECORD_S = 600.0


def filtered_white(rng: np.random.Generator, rate_hz: float, cutoff_hz: float | None, seconds: float) -> np.ndarray:
    """White noise of density DENSITY at `rate_hz` through a 2nd-order Butterworth low-pass (unit DC gain,
    so the density below the cut-off is unchanged)."""
    x = DENSITY * np.sqrt(rate_hz) * rng.standard_normal(int(seconds * rate_hz))
    if cutoff_hz is None:
        return x
    b, a = butter(2, cutoff_hz / (rate_hz / 2.0))
    return lfilter(b, a, x)


GRID = [(rate, cutoff) for rate in (100.0, 250.0, 1000.0) for cutoff in (None, 60.0, 20.0, 5.0)
        if cutoff is None or cutoff < 0.4 * rate]


@pytest.mark.parametrize("rate_hz,cutoff_hz", GRID)
def test_the_density_of_filtered_white_noise_is_within_10_percent(rate_hz, cutoff_hz):
    for seed in range(2):
        x = filtered_white(np.random.default_rng(seed), rate_hz, cutoff_hz, RECORD_S)
        tau, adev, relative = overlapping_adev(x, rate_hz)
        white = fit_noise(tau, adev[:, 0], relative, RECORD_S, replicates=0).noise.white_density
        assert white.resolved, (seed, white)
        assert abs(white.value / DENSITY - 1) < 0.10, (seed, white.value)


def test_a_curve_without_a_white_region_says_so_and_gives_no_zero():
    """A pure bias random walk (+1/2 slope everywhere): no white density to read."""
    rate = 100.0
    rng = np.random.default_rng(3)
    x = np.cumsum(1e-3 * np.sqrt(1 / rate) * rng.standard_normal(int(RECORD_S * rate)))
    tau, adev, relative = overlapping_adev(x, rate)
    white = fit_noise(tau, adev[:, 0], relative, RECORD_S).noise.white_density
    assert not white.resolved


def test_noise_kalibr_refuses_in_one_line_where_there_is_no_white_density(tmp_path, capsys):
    from accel_calibration.cli.main import main

    rate, seconds = 100.0, 120.0
    rng = np.random.default_rng(5)
    samples = int(seconds * rate)
    accel = np.cumsum(1e-3 * np.sqrt(1 / rate) * rng.standard_normal((samples, 3)), axis=0) + [0.0, 0.0, 9.80665]
    gyro = 2e-4 * np.sqrt(rate) * rng.standard_normal((samples, 3))
    t = np.arange(samples) / rate
    with open(tmp_path / "walk.csv", "w") as stream:
        stream.write("t,ax,ay,az,gx,gy,gz\n")
        np.savetxt(stream, np.column_stack([t, accel, gyro]), delimiter=",", fmt="%.9g")
    assert main(["noise", str(tmp_path / "walk.csv"), "--whole", "--kalibr", str(tmp_path / "imu.yaml")]) == 1
    captured = capsys.readouterr()
    assert "not resolved (no -1/2 slope)" in captured.out
    assert captured.err.count("\n") == 1 and "no white-noise region" in captured.err
    assert not (tmp_path / "imu.yaml").exists()


def test_noise_kalibr_writes_the_density_of_filtered_noise(tmp_path, capsys):
    """At 250 Hz through a 20 Hz Butterworth, imu.yaml had 1.2e-4 for 1e-3 (8x too low)."""
    import yaml

    from accel_calibration.cli.main import main

    rate, seconds = 250.0, 120.0
    rng = np.random.default_rng(12)
    columns = [filtered_white(rng, rate, 20.0, seconds) for _ in range(6)]
    data = np.column_stack(columns) + [0.0, 0.0, 9.80665, 0.0, 0.0, 0.0]
    with open(tmp_path / "dlpf.csv", "w") as stream:
        stream.write("t,ax,ay,az,gx,gy,gz\n")
        np.savetxt(stream, np.column_stack([np.arange(len(data)) / rate, data]), delimiter=",", fmt="%.9g")
    assert main(["noise", str(tmp_path / "dlpf.csv"), "--whole", "--kalibr", str(tmp_path / "imu.yaml")]) == 0
    figures = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    # The largest of three axes: at most ~+5 % above the truth by chance, never 8x below.
    assert figures["accelerometer_noise_density"] == pytest.approx(DENSITY, rel=0.1)
    assert figures["gyroscope_noise_density"] == pytest.approx(DENSITY, rel=0.1)


def test_the_px4_sample_density_is_the_plateau_not_the_filtered_short_taus(shared, capsys):
    """PX4 sample.ulg's still minute: sigma(1 s) is 1.2-1.9e-3 per axis; the density read 4.3-6.9e-4 from
    the filtered short taus. Now the plateau after them: at least 0.6 sigma(1 s) (sigma(1 s) carries the
    other noises already rising there, so it is an upper bound, not the density)."""
    from accel_calibration.bag.recording import open_recording
    from accel_calibration.cli.noise import channel_fits, still_stretch, unbroken_stretch

    recording = open_recording(str(shared("real/px4_ulog/sample.ulg")), None)
    first, last = still_stretch(recording.t_ns, recording.accel_mps2, recording.gyro_radps)
    within, beyond, rate, _ = unbroken_stretch(recording.t_ns[first:last])
    accel = recording.accel_mps2[first + within:first + beyond]
    fits = channel_fits(accel, rate, len(accel) / rate)
    assert fits is not None
    one_second = overlapping_adev(accel, rate, clusters=[int(round(rate))])[1][0]
    for fit, sigma_1s in zip(fits, one_second):
        assert fit.noise.white_density.present
        assert 0.6 * sigma_1s <= fit.noise.white_density.value <= 1.05 * sigma_1s, (fit.noise.white_density, sigma_1s)
