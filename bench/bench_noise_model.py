"""The Allan variance fitted whole against the simulated truth with white noise, bias instability (flicker) and
random walk all present: per tau-range (the record's length: its longest tau is a ninth of it) and low-pass
cut-off, the median error of N, B and K over seeds and how often their 95 % intervals (or, unresolved, the
upper bound) held the truth; and beside ours, on the same arrays, allantools' oadev read the usual way (N
from the point whose slope is nearest -1/2, K nearest +1/2, B = the minimum / 0.664).
Targets: median error <= 10 % for each term, coverage >= 90 % for each. Figures go to docs/noise.md.
Run: .venv/bin/python bench/bench_noise_model.py [--seeds 40] [--hours 2,4,8] [--cutoffs none,10]"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.signal import butter, lfilter

sys.path[:0] = [str(Path(__file__).resolve().parents[1] / "test" / "core")]
from test_noise_intervals import flicker  # noqa: E402

from accel_calibration.core.allan import BIAS_INSTABILITY_FACTOR, fit_noise, overlapping_adev  # noqa: E402

RATE_HZ = 50.0
DENSITY, FLOOR_ADEV, WALK = 1e-3, 2e-4, 5e-5  # white meets the floor at 25 s, the walk rises over it from ~50 s
TRUTH = {"N": DENSITY, "B": FLOOR_ADEV / BIAS_INSTABILITY_FACTOR, "K": WALK}
CHUNK = 10  # seeds simulated at a time (memory)
MEDIAN_TARGET, COVERAGE_TARGET = 0.10, 0.90


def simulate(seed: int, samples: int, channels: int, cutoff_hz: float | None) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = DENSITY * np.sqrt(RATE_HZ) * rng.standard_normal((samples, channels))
    x += flicker(rng, samples, RATE_HZ, FLOOR_ADEV, channels)
    x += np.cumsum(WALK * np.sqrt(1.0 / RATE_HZ) * rng.standard_normal((samples, channels)), axis=0)
    if cutoff_hz is None:
        return x
    b, a = butter(2, cutoff_hz / (RATE_HZ / 2.0))
    filtered: np.ndarray = lfilter(b, a, x, axis=0)
    return filtered


def slope_readings(tau: np.ndarray, adev: np.ndarray) -> dict[str, float]:
    """The usual reading of an Allan curve (allan_variance_ros, imu_utils, MATLAB's example): N from the
    point before the minimum whose local slope is nearest -1/2, K from the one after it nearest +1/2 (a
    filter's rise at short tau is not taken for the walk), B the minimum / 0.664."""
    slopes = np.diff(np.log(adev)) / np.diff(np.log(tau))
    lowest = int(np.argmin(adev))
    white = int(np.argmin(np.abs(slopes[:max(lowest, 1)] + 0.5)))
    walk = lowest + int(np.argmin(np.abs(slopes[lowest:] - 0.5))) + 1 if lowest < len(slopes) else len(tau) - 1
    return {"N": float(adev[white] * np.sqrt(tau[white])), "K": float(adev[walk] * np.sqrt(3.0 / tau[walk])),
            "B": float(np.min(adev) / BIAS_INSTABILITY_FACTOR)}


def ours(noise) -> dict[str, tuple[float, bool]]:
    """Per term: (value, whether the reported statement held the truth: the interval, or the upper bound)."""
    out = {}
    for key, figure in (("N", noise.white_density), ("B", noise.bias_instability), ("K", noise.random_walk)):
        truth = TRUTH[key]
        held = figure.low <= truth <= figure.high if figure.resolved else truth <= figure.high
        out[key] = (figure.value if figure.resolved else (figure.estimate or 0.0), held, figure.resolved)
    return out


def run_case(hours: float, cutoff_hz: float | None, seeds: int, allantools) -> str:
    samples = int(hours * 3600 * RATE_HZ)
    rows: list[dict] = []
    theirs: list[dict[str, float]] = []
    started = time.process_time()
    for first in range(0, seeds, CHUNK):
        count = min(CHUNK, seeds - first)
        x = simulate(1000 + first, samples, count, cutoff_hz)
        tau, adev, relative = overlapping_adev(x, RATE_HZ)
        rows += [ours(fit_noise(tau, adev[:, c], relative, hours * 3600, tau0_s=1 / RATE_HZ).noise)
                 for c in range(count)]
        if allantools is not None:
            for c in range(count):
                their_tau, their_adev, _, _ = allantools.oadev(x[:, c], rate=RATE_HZ, data_type="freq", taus=tau)
                theirs.append(slope_readings(np.asarray(their_tau), np.asarray(their_adev)))
    cpu = time.process_time() - started
    parts = []
    for key in ("N", "B", "K"):
        error = np.median([abs(r[key][0] / TRUTH[key] - 1) for r in rows])
        coverage = np.mean([r[key][1] for r in rows])
        resolved = sum(r[key][2] for r in rows)
        text = f"{key} {error:5.1%} {coverage:6.1%} {resolved:3d}"
        if theirs:
            text += f" | {np.median([abs(t[key] / TRUTH[key] - 1) for t in theirs]):6.1%}"
        parts.append(text)
    met = all(np.median([abs(r[k][0] / TRUTH[k] - 1) for r in rows]) <= MEDIAN_TARGET
              and np.mean([r[k][1] for r in rows]) >= COVERAGE_TARGET for k in TRUTH)
    cut = "none" if cutoff_hz is None else f"{cutoff_hz:g} Hz"
    return (f"{hours:4g} h {hours * 3600 / 9:6.0f} s {cut:>7s}  " + "  ".join(parts)
            + f"  {'meets' if met else 'misses'}  ({cpu:.0f} s CPU)")


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", type=int, default=40)
    parser.add_argument("--hours", default="2,4,8")
    parser.add_argument("--cutoffs", default="none,10")
    args = parser.parse_args()
    try:
        import allantools
    except ModuleNotFoundError:
        allantools = None
        print("allantools not installed: its readings skipped")
    print(f"white {DENSITY:g}, flicker floor (Allan deviation) {FLOOR_ADEV:g} (B {TRUTH['B']:.3g}), random walk "
          f"{WALK:g}, {RATE_HZ:g} Hz, {args.seeds} seeds, 2nd-order Butterworth low-pass")
    print("record  max tau  cut-off  per term: ours median |error|, coverage of the 95 % statement (interval or "
          "upper bound), resolved of seeds | allantools oadev read by slope: median |error|")
    for hours in (float(h) for h in args.hours.split(",")):
        for cutoff in args.cutoffs.split(","):
            print(run_case(hours, None if cutoff == "none" else float(cutoff), args.seeds, allantools), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
