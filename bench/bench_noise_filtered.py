"""The white-noise density of low-pass-filtered noise against the simulated truth, per Butterworth cut-off
(none, 60, 20, 5 Hz) and rate (100, 250, 1000 Hz); the 95 % intervals' coverage over many seeds
(`--coverage`); our overlapping Allan deviation against allantools' oadev on the same arrays; and the real
logs in ../shared/data (PX4 sample.ulg, the imu_tk Xsens): sigma(1 s) beside the density.
Figures go to docs/noise.md. Run: .venv/bin/python bench/bench_noise_filtered.py [--coverage]"""
from __future__ import annotations

import gzip
import sys
from pathlib import Path

import numpy as np
from scipy.signal import butter, lfilter

from accel_calibration.core.allan import BIAS_INSTABILITY_FACTOR, fit_noise, overlapping_adev

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / "test" / "core")]
from test_noise_intervals import flicker  # noqa: E402

DENSITY, RECORD_S, SEEDS = 1e-3, 600.0, 5
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def filtered_white(rng: np.random.Generator, rate: float, cutoff: float | None, samples: int,
                   channels: int = 1) -> np.ndarray:
    x = DENSITY * np.sqrt(rate) * rng.standard_normal((samples, channels))
    if cutoff is None:
        return x
    b, a = butter(2, cutoff / (rate / 2.0))
    filtered: np.ndarray = lfilter(b, a, x, axis=0)
    return filtered


def density_grid() -> None:
    print(f"density of white noise {DENSITY:g} m/s^2/sqrt(Hz), {RECORD_S / 60:g} min, {SEEDS} seeds, "
          "2nd-order Butterworth")
    print(f"{'rate Hz':>8s} {'cut-off':>8s} {'mean error':>11s} {'worst error':>12s} {'interval held':>14s}")
    for rate in (100.0, 250.0, 1000.0):
        for cutoff in (None, 60.0, 20.0, 5.0):
            if cutoff is not None and cutoff >= 0.4 * rate:
                continue
            errors, held = [], 0
            for seed in range(SEEDS):
                x = filtered_white(np.random.default_rng(seed), rate, cutoff, int(RECORD_S * rate))
                tau, adev, relative = overlapping_adev(x, rate)
                white = fit_noise(tau, adev[:, 0], relative, RECORD_S).noise.white_density
                errors.append(white.value / DENSITY - 1)
                held += white.low <= DENSITY <= white.high
            worst = max(errors, key=abs)
            print(f"{rate:8g} {'none' if cutoff is None else f'{cutoff:g} Hz':>8s} {np.mean(errors):+10.1%} "
                  f"{worst:+11.1%} {held:>10d}/{SEEDS}")


def coverage(trials: int = 200) -> None:
    rate, seconds, walk = 100.0, 200.0, 1e-3
    print(f"coverage of the 95 % intervals, {trials} seeds, {seconds:g} s at {rate:g} Hz, white {DENSITY:g} + "
          f"random walk {walk:g}")
    for cutoff in (None, 20.0):
        rng = np.random.default_rng(100)
        samples = int(seconds * rate)
        x = filtered_white(rng, rate, cutoff, samples, trials)
        x += np.cumsum(walk * np.sqrt(1 / rate) * rng.standard_normal((samples, trials)), axis=0)
        tau, adev, relative = overlapping_adev(x, rate)
        fits = [fit_noise(tau, adev[:, t], relative, seconds).noise for t in range(trials)]
        density = np.mean([f.white_density.low <= DENSITY <= f.white_density.high for f in fits])
        held = np.mean([f.random_walk.resolved and f.random_walk.low <= walk <= f.random_walk.high for f in fits])
        absent = np.mean([not f.bias_instability.present for f in fits])
        print(f"  cut-off {'none' if cutoff is None else f'{cutoff:g} Hz'}: density held {density:.1%}, random walk "
              f"held {held:.1%}, bias instability 'not present' {absent:.1%}")


def floor_coverage(trials: int = 50, chunk: int = 25) -> None:
    """Bias instability over a flicker floor: how often it is found, and how often its interval holds."""
    rate, floor = 100.0, 2e-4
    truth = floor / BIAS_INSTABILITY_FACTOR
    for seconds in (1800.0, 3600.0):
        samples, figures = int(seconds * rate), []
        for start in range(0, trials, chunk):
            rng = np.random.default_rng(200 + start)
            x = DENSITY * np.sqrt(rate) * rng.standard_normal((samples, chunk)) + flicker(rng, samples, rate, floor,
                                                                                           chunk)
            tau, adev, relative = overlapping_adev(x, rate)
            figures += [fit_noise(tau, adev[:, t], relative, seconds).noise.bias_instability for t in range(chunk)]
        present = [f for f in figures if f.present]
        held = np.mean([f.low <= truth <= f.high for f in present]) if present else float("nan")
        print(f"  flicker floor 2e-4 under white {DENSITY:g}, {seconds / 60:g} min at {rate:g} Hz, {trials} seeds: "
              f"found {len(present) / trials:.0%}, its interval held {held:.1%} of those")


def against_allantools() -> None:
    try:
        import allantools
    except ModuleNotFoundError:
        print("allantools not installed: comparison skipped")
        return
    rate, samples = 250.0, 150_000
    rng = np.random.default_rng(3)
    data = np.column_stack([filtered_white(rng, rate, None, samples)[:, 0] + 9.80665,
                            filtered_white(rng, rate, 20.0, samples)[:, 0],
                            np.cumsum(1e-4 * rng.standard_normal(samples))])
    tau, ours, _ = overlapping_adev(data, rate)
    worst = 0.0
    for channel in range(data.shape[1]):
        _, theirs, _, _ = allantools.oadev(data[:, channel], rate=rate, data_type="freq", taus=tau)
        worst = max(worst, float(np.max(np.abs(ours[:, channel] / theirs - 1))))
    print(f"allantools {allantools.__version__} oadev, 3 channels x {samples} samples, {len(tau)} octave taus: "
          f"largest relative difference {worst:.1e}")


def real_logs() -> None:
    from accel_calibration.bag.recording import open_recording
    from accel_calibration.cli.noise import still_stretch, unbroken_stretch

    sources = []
    ulog = SHARED / "real" / "px4_ulog" / "sample.ulg"
    if ulog.exists():
        recording = open_recording(str(ulog), None)
        sources.append(("PX4 sample.ulg accel", recording.t_ns, recording.accel_mps2, recording.gyro_radps))
    xsens = SHARED / "real" / "imu_tk" / "xsens_acc.txt.gz"
    if xsens.exists():
        counts = np.loadtxt(gzip.open(xsens))
        # Unsigned counts about 32768, 4057 counts/g, local g 9.81744 m/s^2 (docs/efficient_fit.md)
        accel = (counts[:, 1:] - 32768.0) * 9.81744 / 4057.0
        sources.append(("imu_tk Xsens accel", (counts[:, 0] * 1e9).astype(np.int64), accel, None))
    for name, t_ns, accel, gyro in sources:
        first, last = still_stretch(t_ns, accel, gyro)
        within, beyond, rate, _ = unbroken_stretch(t_ns[first:last])
        values = accel[first + within:first + beyond]
        seconds = len(values) / rate
        tau, adev, relative = overlapping_adev(values, rate)
        one_s = overlapping_adev(values, rate, clusters=[int(round(rate))])[1][0]
        densities = [fit_noise(tau, adev[:, axis], relative, seconds, tau0_s=1 / rate).noise.white_density.value
                     for axis in range(3)]
        print(f"{name}: {seconds:.0f} s still at {rate:.0f} Hz; sigma(1 s) "
              + ", ".join(f"{v:.2e}" for v in one_s) + "; density " + ", ".join(f"{v:.2e}" for v in densities))


def main() -> int:
    against_allantools()
    density_grid()
    if "--coverage" in sys.argv:
        coverage()
        floor_coverage()
    real_logs()
    return 0


if __name__ == "__main__":
    sys.exit(main())
