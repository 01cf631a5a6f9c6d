"""Overlapping Allan deviation of still IMU samples and the noise figures estimators ask for.

sigma^2(tau) = 1 / (2 tau^2 (N - 2m)) sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2, tau = m tau0, with
theta the running integral of the samples (IEEE Std 952, the overlapping estimator): one cumulative sum,
then one strided second difference per tau, all channels at once.

The figures, per axis, from the three regions of the log-log curve (IEEE Std 952 annex C):
- white noise density N (the -1/2 slope, sigma = N / sqrt(tau)): the -1/2 line read at tau = 1 s.
  Units: m/s^2/sqrt(Hz) (accelerometer), rad/s/sqrt(Hz) (gyroscope) -- Kalibr's *_noise_density.
- random walk K (the +1/2 slope, sigma = K sqrt(tau / 3)): the +1/2 line read at tau = 3 s.
  Units: m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz) -- Kalibr's *_random_walk.
- bias instability B: the curve's minimum / sqrt(2 ln 2 / pi) (= 0.664), at the tau of the minimum.
The two lines are fitted together with a flat floor (sigma^2 = N^2 / tau + C + K^2 tau / 3, weighted
non-negative least squares on sigma^2), so each is read where it dominates without picking points by
hand. Each point's relative 1-sigma error is 1 / sqrt(2 (N / m - 1)) (IEEE 952's cluster count; the
overlapping estimator does better, so the intervals are conservative); a figure's interval is the fit's
95 % interval under those errors. A figure the recording cannot resolve (its line never dominates) is
reported as an upper bound with the recording length its +-25 % would need.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .errors import CalibrationError


def nonnegative_least_squares(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """min |A x - b| subject to x >= 0, for a few columns, exactly: the optimum is the least-squares
    solution on some subset of the columns (the others at 0, KKT), so every subset is tried and the best
    feasible kept. scipy.optimize.nnls gives the same; importing scipy.optimize costs 0.75 s, a seventh
    of the noise command on a 3-hour recording."""
    a, b = np.asarray(matrix, dtype=float), np.asarray(rhs, dtype=float)
    columns = a.shape[1]
    best, best_cost = np.zeros(columns), float(b @ b)
    for mask in range(1, 1 << columns):
        chosen = [j for j in range(columns) if mask >> j & 1]
        x, *_ = np.linalg.lstsq(a[:, chosen], b, rcond=None)
        if np.any(x < 0):
            continue
        full = np.zeros(columns)
        full[chosen] = x
        residual = a @ full - b
        cost = float(residual @ residual)
        if cost < best_cost:
            best, best_cost = full, cost
    return best


BIAS_INSTABILITY_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.664
MIN_CLUSTERS = 9  # the longest tau keeps >= 9 independent clusters (point error <= 25 %)
Z95 = 1.959964


def octave_taus(samples: int, tau0_s: float, min_clusters: int = MIN_CLUSTERS) -> np.ndarray:
    """Cluster sizes m = 1, 2, 4, ... up to samples / min_clusters, as an int array."""
    largest = samples // min_clusters
    if largest < 1:
        return np.zeros(0, dtype=np.int64)
    return 2 ** np.arange(int(math.log2(largest)) + 1, dtype=np.int64)


def overlapping_adev(samples: ArrayLike, rate_hz: float,
                     clusters: ArrayLike | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(tau_s (T,), adev (T, C), relative 1-sigma error (T,)) of samples (N,) or (N, C) at `rate_hz`,
    at octave cluster sizes unless `clusters` (sample counts) are given."""
    values = np.asarray(samples, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    if values.ndim != 2 or len(values) < 3:
        raise CalibrationError(f"Allan deviation needs at least 3 samples per channel, got shape {values.shape}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise CalibrationError(f"rate must be a positive number of Hz, got {rate_hz!r}")
    if not np.all(np.isfinite(values)):
        raise CalibrationError("samples must be finite")
    n = len(values)
    tau0 = 1.0 / rate_hz
    m = octave_taus(n, tau0) if clusters is None else np.asarray(clusters, dtype=np.int64)
    m = m[(m >= 1) & (2 * m < n)]
    # The running integral (phase), of the samples less their mean: keeps theta small, so the second
    # differences lose no digits to a 9.8 m/s^2 offset.
    # One contiguous row per channel, and one scratch buffer reused for every tau (no temporaries).
    theta = np.zeros((values.shape[1], n + 1))
    np.cumsum((values - values.mean(axis=0)).T, axis=1, out=theta[:, 1:])
    theta *= tau0
    adev = np.empty((len(m), values.shape[1]))
    scratch = np.empty((values.shape[1], n))
    for row, size in enumerate(m.tolist()):
        length = n + 1 - 2 * size
        second = scratch[:, :length]
        np.subtract(theta[:, 2 * size:], theta[:, size:-size], out=second)
        second -= theta[:, size:-size]
        second += theta[:, :-2 * size]
        tau = size * tau0
        adev[row] = np.sqrt(np.einsum("ij,ij->i", second, second) / (2.0 * tau * tau * length))
    relative = 1.0 / np.sqrt(2.0 * np.maximum(n / m - 1.0, 1.0))
    return m * tau0, adev, relative


@dataclass(frozen=True)
class Figure:
    """One noise figure with its 95 % interval; `resolved` False: the recording does not show its region
    and `value` is an upper bound (`needs_s`: the still recording a +-25 % figure would need, when known)."""

    value: float
    low: float
    high: float
    resolved: bool = True
    at_tau_s: float | None = None
    needs_s: float | None = None


@dataclass(frozen=True)
class AxisNoise:
    white_density: Figure  # sigma at tau = 1 s on the -1/2 line
    random_walk: Figure  # K of the +1/2 line sigma = K sqrt(tau / 3), i.e. its value at tau = 3 s
    bias_instability: Figure  # min sigma / 0.664, at_tau_s the minimum's tau


@dataclass(frozen=True)
class NoiseFit:
    """The Allan curve of one channel and the lines fitted to it."""

    tau_s: np.ndarray
    adev: np.ndarray
    relative_error: np.ndarray
    noise: AxisNoise
    floor: float  # C: the flat part of sigma^2


def fit_noise(tau_s: np.ndarray, adev: np.ndarray, relative_error: np.ndarray, duration_s: float,
              target_relative: float = 0.25) -> NoiseFit:
    """The figures of one channel's Allan curve (see the module text)."""
    tau = np.asarray(tau_s, dtype=float)
    sigma = np.asarray(adev, dtype=float)
    if len(tau) < 3:
        raise CalibrationError(f"an Allan curve needs at least 3 taus, got {len(tau)}: record longer")
    variance = sigma**2
    # sigma^2's relative error is twice sigma's; weight each equation by 1 / its standard error.
    weight = 1.0 / (2.0 * relative_error * variance)
    design = np.column_stack([1.0 / tau, np.ones_like(tau), tau / 3.0])
    solution = nonnegative_least_squares(design * weight[:, None], variance * weight)
    white2, floor, walk2 = (float(v) for v in solution)
    covariance = np.linalg.pinv((design * weight[:, None]).T @ (design * weight[:, None]))
    model = design @ solution
    # Scale by the fit's own scatter when worse than the stated errors (chi^2 per degree of freedom > 1).
    dof = max(len(tau) - 3, 1)
    chi2 = float(np.sum(((variance - model) * weight) ** 2)) / dof
    covariance = covariance * max(chi2, 1.0)

    def figure(index: int, value2: float, read_tau: float, share_of: np.ndarray) -> Figure:
        spread = Z95 * math.sqrt(max(float(covariance[index, index]), 0.0))
        value = math.sqrt(max(value2, 0.0))
        low = math.sqrt(max(value2 - spread, 0.0))
        high = math.sqrt(value2 + spread)
        # Resolved where this term carries at least half of sigma^2 at some tau of the curve.
        resolved = bool(np.any(share_of >= 0.5 * model)) and value2 > 0 and low > 0
        return Figure(value=value, low=low, high=high, resolved=resolved, at_tau_s=read_tau)

    white = figure(0, white2, 1.0, white2 / tau)
    walk = figure(2, walk2, 3.0, walk2 * tau / 3.0)
    if not walk.resolved:
        # The +1/2 line would need to dominate: where it would cross the rest, from its upper bound, and
        # N / m clusters there for the target error: 1 / sqrt(2 (T / tau - 1)) <= target.
        bound2 = max(walk.high**2, 1e-300)
        rest = white2 / tau + floor
        crossing = float(3.0 * max(float(np.min(rest)), 1e-300) / bound2)
        needs = crossing * (1.0 + 1.0 / (2.0 * target_relative**2))
        walk = Figure(value=walk.high, low=0.0, high=walk.high, resolved=False, at_tau_s=3.0,
                      needs_s=max(needs, duration_s * 2.0))
    lowest = int(np.argmin(sigma))
    instability = sigma[lowest] / BIAS_INSTABILITY_FACTOR
    error = Z95 * relative_error[lowest]
    inner = lowest not in (0, len(sigma) - 1)
    bias = Figure(value=float(instability), low=float(instability * max(1.0 - error, 0.0)),
                  high=float(instability * (1.0 + error)), resolved=inner, at_tau_s=float(tau[lowest]))
    return NoiseFit(tau_s=tau, adev=sigma, relative_error=np.asarray(relative_error, dtype=float),
                    noise=AxisNoise(white_density=white, random_walk=walk, bias_instability=bias), floor=floor)


def required_duration_s(tau_s: float, target_relative: float = 0.25) -> float:
    """Recording length for a point at tau to have relative error `target_relative`: T = tau (1 + 1/(2 e^2))."""
    return tau_s * (1.0 + 1.0 / (2.0 * target_relative**2))
