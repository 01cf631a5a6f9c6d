"""The Allan variance fitted whole (white noise, bias instability and random walk together): each term within
10 % of the simulated truth in the median over seeds, its 95 % interval holding the truth, a term simulated
absent not reported, and a random walk the record does not resolve bounded from above, never under-stated
(also in Kalibr's imu.yaml). The Monte Carlo over more seeds, ranges and filters is bench/bench_noise_model.py."""
from __future__ import annotations

import numpy as np
import pytest
import yaml

from accel_calibration.core.allan import BIAS_INSTABILITY_FACTOR, fit_noise, overlapping_adev

from helpers.noise_processes import flicker

RATE_HZ, RECORD_S = 50.0, 4 * 3600.0
DENSITY, FLOOR_ADEV, WALK = 1e-3, 2e-4, 5e-5  # white meets the floor at 25 s, the walk rises over it from ~50 s
INSTABILITY = FLOOR_ADEV / BIAS_INSTABILITY_FACTOR
SEEDS = 12


def parts(seed: int, channels: int = SEEDS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(white noise, flicker floor, random walk) of the truth above, one channel per simulated sensor."""
    rng = np.random.default_rng(seed)
    samples = int(RECORD_S * RATE_HZ)
    white = DENSITY * np.sqrt(RATE_HZ) * rng.standard_normal((samples, channels))
    walk = np.cumsum(WALK * np.sqrt(1.0 / RATE_HZ) * rng.standard_normal((samples, channels)), axis=0)
    return white, flicker(rng, samples, RATE_HZ, FLOOR_ADEV, channels), walk


def figures(values: np.ndarray) -> list:
    tau, adev, relative = overlapping_adev(values, RATE_HZ)
    return [fit_noise(tau, adev[:, c], relative, RECORD_S, tau0_s=1.0 / RATE_HZ).noise for c in range(adev.shape[1])]


@pytest.fixture(scope="module")
def all_three():
    white, floor, walk = parts(42)
    return figures(white + floor + walk)


def test_each_term_is_within_10_percent_in_the_median_with_all_three_present(all_three):
    """Read off the curve one term at a time, bias instability came out 12-27 % high where the random walk's
    rise reached the floor (the minimum / 0.664 carries the walk's share)."""
    for name, truth in (("white_density", DENSITY), ("bias_instability", INSTABILITY), ("random_walk", WALK)):
        found = [getattr(f, name) for f in all_three]
        assert all(f.resolved for f in found), name
        error = np.median([abs(f.value / truth - 1.0) for f in found])
        assert error <= 0.10, (name, error)


def test_the_intervals_hold_the_truth_with_all_three_present(all_three):
    for name, truth in (("white_density", DENSITY), ("bias_instability", INSTABILITY), ("random_walk", WALK)):
        held = sum(getattr(f, name).low <= truth <= getattr(f, name).high for f in all_three)
        assert held >= SEEDS - 1, (name, held)


def test_an_absent_random_walk_or_bias_instability_is_not_reported():
    white, floor, walk = parts(43)
    without_walk = figures(white + floor)
    without_floor = figures(white + walk)
    assert sum(f.random_walk.resolved for f in without_walk) <= 1
    assert sum(f.bias_instability.present for f in without_floor) <= 1
    # and the terms that are there still are
    assert all(f.bias_instability.resolved for f in without_walk)
    assert all(f.random_walk.resolved for f in without_floor)


def test_an_unresolved_random_walk_is_an_upper_bound_above_the_truth():
    """A walk a fifth of the one above: its +1/2 rise stays under the floor over most of the record. Its
    bound was below the truth in 11 of 27 such cases."""
    white, floor, walk = parts(44)
    weak = WALK / 5.0
    found = [f.random_walk for f in figures(white + floor + walk / 5.0)]
    held = sum((f.low <= weak <= f.high) if f.resolved else weak <= f.high for f in found)
    assert held >= SEEDS - 1, [(f.resolved, f.low, f.value, f.high) for f in found]
    unresolved = [f for f in found if not f.resolved]
    assert len(unresolved) >= SEEDS // 2
    assert all(f.value == f.high and f.estimate is not None and f.estimate <= f.high for f in unresolved)


def test_noise_kalibr_writes_the_walks_upper_bound_when_it_is_not_resolved_and_says_so(tmp_path, capsys):
    from accel_calibration.cli.main import main

    rate, seconds = 50.0, 1200.0
    rng = np.random.default_rng(8)
    samples = int(rate * seconds)
    gyro_walk = 2e-6  # under the white noise of 2e-4 over all of 20 min: not resolvable
    gyro = 2e-4 * np.sqrt(rate) * rng.standard_normal((samples, 3))
    gyro += np.cumsum(gyro_walk * np.sqrt(1 / rate) * rng.standard_normal((samples, 3)), axis=0)
    accel = 2e-3 * np.sqrt(rate) * rng.standard_normal((samples, 3)) + [0.0, 0.0, 9.80665]
    with open(tmp_path / "still.csv", "w") as stream:
        stream.write("t,ax,ay,az,gx,gy,gz\n")
        np.savetxt(stream, np.column_stack([np.arange(samples) / rate, accel, gyro]), delimiter=",", fmt="%.9g")
    assert main(["noise", str(tmp_path / "still.csv"), "--whole", "--kalibr", str(tmp_path / "imu.yaml")]) == 0
    out = capsys.readouterr().out
    assert "not resolved" in out and "95 % upper bound" in out
    text = (tmp_path / "imu.yaml").read_text()
    assert "95 % upper bound" in text
    assert yaml.safe_load(text)["gyroscope_random_walk"] >= gyro_walk
