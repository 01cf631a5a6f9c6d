"""accel-calib noise: overlapping Allan deviation against its definition, the figures of simulated white
noise + random walk + a bias-instability (Gauss-Markov) process within 5 % (density) and 25 % (random
walk) in every one of 20 seeds, and the command end to end on a CSV stream (table, Kalibr file, figure,
refusal of a recording too short). The full 3 h at 200 Hz version is bench/bench_allan.py."""
from __future__ import annotations

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.signal import lfilter

from accel_calibration.cli.main import main
from accel_calibration.core.allan import fit_noise, overlapping_adev


def simulate(rng, samples: int, rate_hz: float, white: float, walk: float, gm_sigma: float, gm_tau_s: float,
             channels: int = 1) -> np.ndarray:
    """White noise of density `white`, a bias random walk of `walk`, and a first-order Gauss-Markov bias of
    std `gm_sigma` and correlation time `gm_tau_s` (the usual bias-instability model), (samples, channels)."""
    dt = 1.0 / rate_hz
    shape = (samples, channels)
    out = white * np.sqrt(rate_hz) * rng.standard_normal(shape)
    out += np.cumsum(walk * np.sqrt(dt) * rng.standard_normal(shape), axis=0)
    a = np.exp(-dt / gm_tau_s)
    out += lfilter([gm_sigma * np.sqrt(1 - a * a)], [1, -a], rng.standard_normal(shape), axis=0)
    return out


def test_overlapping_adev_matches_its_definition():
    rng = np.random.default_rng(1)
    y = rng.normal(size=1000)
    tau, adev, _ = overlapping_adev(y, 10.0, clusters=[1, 3, 7])
    for m, value in zip((1, 3, 7), adev[:, 0]):
        # sigma^2 = 1/(2 (N - 2m + 1) m^2) sum_j (sum_{i=j+m}^{j+2m-1} y_i - sum_{i=j}^{j+m-1} y_i)^2
        sums = [(y[j + m:j + 2 * m].sum() - y[j:j + m].sum()) ** 2 for j in range(len(y) - 2 * m + 1)]
        assert value == pytest.approx(np.sqrt(np.sum(sums) / (2 * m * m * (len(y) - 2 * m + 1))), rel=1e-10)
    np.testing.assert_allclose(tau, [0.1, 0.3, 0.7])


def test_figures_of_simulated_noise_in_every_one_of_20_seeds():
    """2 h at 100 Hz per seed (the 3 h at 200 Hz run is bench/bench_allan.py)."""
    rate, white, walk = 100.0, 1e-3, 3e-4
    for seed in range(20):
        x = simulate(np.random.default_rng(seed), int(2 * 3600 * rate), rate, white, walk, 5e-5, 20.0)
        tau, adev, relative = overlapping_adev(x, rate)
        noise = fit_noise(tau, adev[:, 0], relative, len(x) / rate, replicates=0).noise
        assert abs(noise.white_density.value / white - 1) < 0.05, seed
        assert abs(noise.random_walk.value / walk - 1) < 0.25, seed
        assert noise.random_walk.resolved and noise.white_density.low < noise.white_density.high


def _write_csv(path, data: np.ndarray, rate: float) -> None:
    t = np.arange(len(data)) / rate
    with open(path, "w") as stream:
        stream.write("t,ax,ay,az,gx,gy,gz\n")
        np.savetxt(stream, np.column_stack([t, data]), delimiter=",", fmt="%.9g")


def test_noise_command_on_a_csv_stream(tmp_path, capsys):
    rate = 100.0
    rng = np.random.default_rng(7)
    accel = simulate(rng, int(600 * rate), rate, 2e-3, 1e-4, 2e-5, 10.0, channels=3) + [0.0, 0.0, 9.80665]
    gyro = simulate(rng, int(600 * rate), rate, 2e-4, 2e-5, 1e-5, 10.0, channels=3)
    _write_csv(tmp_path / "still.csv", np.hstack([accel, gyro]), rate)
    assert main(["noise", str(tmp_path / "still.csv"), "--whole", "--kalibr", str(tmp_path / "imu.yaml"),
                 "--plot", str(tmp_path / "allan.png")]) == 0
    out = capsys.readouterr().out
    assert "accelerometer" in out and "gyroscope" in out and "written" in out
    figures = yaml.safe_load((tmp_path / "imu.yaml").read_text())
    assert figures["accelerometer_noise_density"] == pytest.approx(2e-3, rel=0.1)
    assert figures["gyroscope_noise_density"] == pytest.approx(2e-4, rel=0.1)
    assert figures["update_rate"] == pytest.approx(100.0, rel=1e-6)
    assert (tmp_path / "allan.png").read_bytes()[:4] == b"\x89PNG"
    # The figures feed the estimator exports.
    from accel_calibration.core.calibration import Calibration
    from accel_calibration.io.calibration_file import save_calibration

    save_calibration(Calibration.identity(), tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "openvins", "--noise", str(tmp_path / "imu.yaml"),
                 "-o", str(tmp_path / "chain.yaml")]) == 0


def test_noise_refuses_a_recording_too_short_saying_how_long(tmp_path, capsys):
    rate = 100.0
    data = simulate(np.random.default_rng(2), int(10 * rate), rate, 2e-3, 0, 1e-9, 1.0, channels=6)
    data[:, 2] += 9.80665
    _write_csv(tmp_path / "short.csv", data, rate)
    assert main(["noise", str(tmp_path / "short.csv"), "--whole"]) == 1
    error = capsys.readouterr().err
    assert "lasts 10.0 s" in error and "at least 20 s" in error and "h" in error


def test_an_mcap_bag_and_a_csv_of_the_same_samples_give_the_same_figures(tmp_path, capsys):
    from helpers.imu_bags import write_imu_bag

    rate = 100.0
    rng = np.random.default_rng(11)
    samples = int(300 * rate)
    accel = simulate(rng, samples, rate, 2e-3, 1e-4, 2e-5, 10.0, channels=3) + [0.0, 0.0, 9.80665]
    gyro = simulate(rng, samples, rate, 2e-4, 2e-5, 1e-5, 10.0, channels=3)
    accel, gyro = np.round(accel, 9), np.round(gyro, 10)  # what the CSV's 9 significant digits keep
    _write_csv(tmp_path / "still.csv", np.hstack([accel, gyro]), rate)
    t_ns = 1_700_000_000_000_000_000 + (np.arange(samples) * 1e9 / rate).astype(np.int64)
    write_imu_bag(tmp_path / "still_bag", t_ns, accel, gyro, storage="mcap")
    figures = []
    for source in (tmp_path / "still.csv", tmp_path / "still_bag"):
        out = tmp_path / f"{source.name}.yaml"
        assert main(["noise", str(source), "--kalibr", str(out)]) == 0  # still stretch by the detector
        figures.append(yaml.safe_load(out.read_text()))
    printed = capsys.readouterr().out
    assert printed.count("min, ") == 2
    for name in ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density"):
        assert figures[0][name] == pytest.approx(figures[1][name], rel=1e-4), name


def test_the_still_stretch_joins_the_detectors_consecutive_poses_and_leaves_motion_out():
    from accel_calibration.cli.noise import still_stretch

    rate = 100.0
    rng = np.random.default_rng(4)
    moving = int(30 * rate)
    samples = moving + int(300 * rate)
    accel = rng.normal(scale=0.02, size=(samples, 3)) + [0.0, 0.0, 9.80665]
    angle = np.linspace(0, 6 * np.pi, moving)
    accel[:moving] = 9.80665 * np.column_stack([np.sin(angle), np.zeros(moving), np.cos(angle)])  # turning
    gyro = rng.normal(scale=0.003, size=(samples, 3))
    gyro[:moving, 1] = 6 * np.pi / 30
    t_ns = (np.arange(samples) * 1e9 / rate).astype(np.int64)
    first, last = still_stretch(t_ns, accel, gyro)
    assert moving <= first < moving + 3 * rate  # the stillness after the turning, not before
    assert last - first > 0.97 * (samples - moving)  # one stretch, not the detector's minute-long poses


@settings(max_examples=200, deadline=None)
@given(st.integers(3, 40), st.integers(0, 10_000))
def test_the_nonnegative_least_squares_is_scipys(rows, seed):
    """The Allan fit's 3-column NNLS (every subset tried, numpy only) gives scipy.optimize.nnls's
    solution: the same cost to 1e-9 relative, x >= 0."""
    from scipy.optimize import nnls

    from accel_calibration.core.allan import nonnegative_least_squares

    rng = np.random.default_rng(seed)
    a = rng.normal(size=(rows, 3)) * rng.uniform(0.01, 100, 3)
    b = rng.normal(size=rows) * 10 + a @ rng.normal(size=3)
    ours = nonnegative_least_squares(a, b)
    theirs, _ = nnls(a, b)
    assert np.all(ours >= 0)
    cost = lambda x: float(np.sum((a @ x - b) ** 2))  # noqa: E731
    assert cost(ours) <= cost(theirs) * (1 + 1e-9) + 1e-12
