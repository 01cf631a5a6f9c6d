"""Overlapping Allan deviation of still IMU samples and the noise figures estimators ask for.

sigma^2(tau) = 1 / (2 tau^2 (N - 2m)) sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2, tau = m tau0, with
theta the running integral of the samples (IEEE Std 952, the overlapping estimator): one cumulative sum,
then the second differences per tau, a cache-sized block at a time.

The figures, per axis, from the three regions of the log-log curve (IEEE Std 952 annex C):
- white noise density N (the -1/2 slope, sigma = N / sqrt(tau)): the -1/2 line read at tau = 1 s.
  Units: m/s^2/sqrt(Hz) (accelerometer), rad/s/sqrt(Hz) (gyroscope) -- Kalibr's *_noise_density.
- random walk K (the +1/2 slope, sigma = K sqrt(tau / 3)): the +1/2 line read at tau = 3 s.
  Units: m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz) -- Kalibr's *_random_walk.
- bias instability B: the curve's minimum / sqrt(2 ln 2 / pi) (= 0.664), at the tau of the minimum; "not
  present" unless the fitted flat floor carries half of sigma^2 somewhere and exceeds what white noise +
  random walk alone fit as a floor (99th percentile of the bootstrap below).
The lines are fitted together with a flat floor (sigma^2 = N^2 / tau + C + K^2 tau / 3, non-negative least
squares on sigma^2 weighted by the model's relative errors 1 / sqrt(2 (N / m - 1))) from where the curve
first has the -1/2 slope (white_region_start): every real IMU low-pass filters (a DLPF, an autopilot's
integrator), which pulls the short-tau points below the white line, and those points carry most weight.
Intervals (95 %): a parametric bootstrap of the whole fit (white noise + random walk simulated from the
fitted lines at the same cluster sizes), so the overlapping points' correlation and the few degrees of
freedom at long tau are in them; bias instability's from chi^2 with the overlapping estimator's
equivalent degrees of freedom. A figure the recording cannot resolve (its line never dominates) is
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
    # Columns scaled to unit norm (the solution unscaled at the end): the Allan fit's 1/tau, 1 and tau
    # columns span many decades, and unscaled the SVD of lstsq could fail to converge.
    scale = _column_scale(a)
    a = a / scale
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
    unscaled: np.ndarray = best / scale
    return unscaled


def _column_scale(matrix: np.ndarray) -> np.ndarray:
    norms = np.sqrt(np.einsum("ij,ij->j", matrix, matrix))
    if not np.all(np.isfinite(norms)):
        raise CalibrationError("the Allan curve has values out of floating-point range: no fit")
    return np.where(norms > 0, norms, 1.0)


BIAS_INSTABILITY_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)  # 0.664
MIN_CLUSTERS = 9  # the longest tau keeps >= 9 independent clusters (point error <= 25 %)
Z95 = 1.959964
_BLOCK = 1 << 15  # samples per block of the second differences: 256 kB, in L2
_DOT = 8192  # OpenBLAS starts threads for a dot product of more than 10,000 (CPU time, not speed)


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
    # differences lose no digits to a 9.8 m/s^2 offset. One channel at a time in one row reused (a fresh
    # (C, N) array cost more in page faults than all the arithmetic on it), and the second differences a
    # block of columns at a time in one scratch buffer that stays in cache (no full-length temporaries).
    channels = values.shape[1]
    mean = values.mean(axis=0)
    theta = np.zeros(n + 1)
    scratch, firsts = np.empty(_BLOCK), np.empty(2 * _BLOCK)
    sums = np.zeros((len(m), channels))
    sizes = m.tolist()
    for channel in range(channels):
        np.subtract(values[:, channel], mean[channel], out=theta[1:])
        np.cumsum(theta[1:], out=theta[1:])
        theta *= tau0
        for row, size in enumerate(sizes):
            length = n + 1 - 2 * size
            total = 0.0
            for start in range(0, length, _BLOCK):
                stop = min(start + _BLOCK, length)
                second = scratch[:stop - start]
                if size <= _BLOCK:  # first differences (cluster sums) once, then theirs: two passes
                    first = firsts[:stop - start + size]
                    np.subtract(theta[start + size:stop + 2 * size], theta[start:stop + size], out=first)
                    np.subtract(first[size:], first[:stop - start], out=second)
                else:  # a cluster longer than the block: three passes, no longer first differences
                    np.subtract(theta[start + 2 * size:stop + 2 * size], theta[start + size:stop + size], out=second)
                    second -= theta[start + size:stop + size]
                    second += theta[start:stop]
                for part in range(0, stop - start, _DOT):  # BLAS's dot, in parts it runs in one thread
                    piece = second[part:part + _DOT]
                    total += float(np.dot(piece, piece))
            sums[row, channel] = total
    tau = m * tau0
    adev = np.sqrt(sums / (2.0 * (tau * tau * (n + 1 - 2 * m)))[:, None])
    relative = 1.0 / np.sqrt(2.0 * np.maximum(n / m - 1.0, 1.0))
    return m * tau0, adev, relative


SLOPE_TOLERANCE = 0.08  # the white region: local log-log slope within -1/2 +- this
MIN_WHITE_POINTS = 3  # a white line needs this many taus from the region's start on
FILTER_DEFICIT = 0.05  # what the filter may still take off the density there: added to its interval's top
FILTER_SKIP_OCTAVES = 2  # leaves ~3 % of the filter's deficit (one octave left ~5 %: intervals held less)


def white_region_start(tau_s: np.ndarray, adev: np.ndarray) -> tuple[int | None, bool]:
    """(index of the first tau to read the white line from, or None when the curve has no -1/2 region;
    whether a filter's flatter stretch came before it).

    Low-pass-filtered white noise (a DLPF, an autopilot's integrator) sits below its -1/2 line at taus
    within a few correlation times of the filter, where the curve is flatter or rising; quantization sits
    above it (slope -1). The white region starts where the local slope first lies within -1/2 +-
    SLOPE_TOLERANCE; after a flatter stretch (a filter) FILTER_SKIP_OCTAVES more are skipped, because the
    deficit there, 1 - sigma sqrt(tau) / N ~ (slope + 1/2), is still ~10 % and halves with each octave."""
    slopes = np.diff(np.log(adev)) / np.diff(np.log(tau_s))
    for index, slope in enumerate(slopes.tolist()):
        if abs(slope + 0.5) <= SLOPE_TOLERANCE:
            filtered = index > 0 and bool(np.any(slopes[:index] > -0.5 + SLOPE_TOLERANCE))
            start = index + FILTER_SKIP_OCTAVES if filtered else index
            return (start if len(tau_s) - start >= MIN_WHITE_POINTS else None), filtered
    return None, False


@dataclass(frozen=True)
class Figure:
    """One noise figure with its 95 % interval; `resolved` False: the recording does not show its region
    and `value` is an upper bound (`needs_s`: the still recording a +-25 % figure would need, when known);
    `present` False: the curve has no such region at all (no -1/2 slope, no flat floor), nothing to read."""

    value: float
    low: float
    high: float
    resolved: bool = True
    at_tau_s: float | None = None
    needs_s: float | None = None
    present: bool = True


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
    white_from_tau_s: float | None = None  # where the white line was read from (None: no -1/2 region)


def _fit_lines(tau: np.ndarray, variance: np.ndarray,
               relative_error: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N^2, C, K^2), their covariance and the model of sigma^2 = N^2 / tau + C + K^2 tau / 3 by weighted
    non-negative least squares, each equation weighted by 1 / its standard error: first as measured, then
    as the first fit's model says (a point's own value in its weight favours the points that fell low)."""
    design = np.column_stack([1.0 / tau, np.ones_like(tau), tau / 3.0])
    level = variance
    for _ in range(2):
        weight = 1.0 / (2.0 * relative_error * level)  # sigma^2's relative error is twice sigma's
        weighted = design * weight[:, None]
        solution = nonnegative_least_squares(weighted, variance * weight)
        model = design @ solution
        level = np.where(model > 0, model, variance)
    # Scaled by the fit's own scatter when worse than the stated errors (chi^2 per degree of freedom > 1).
    chi2 = float(np.sum(((variance - model) * weight) ** 2)) / max(len(tau) - 3, 1)
    return solution, np.linalg.pinv(weighted.T @ weighted) * max(chi2, 1.0), model


BOOTSTRAP_REPLICATES = 100
BOOTSTRAP_MAX_SAMPLES = 1 << 13  # longer records are simulated decimated (taus of >= the decimation only)
FLOOR_QUANTILE = 0.99  # a flat floor is present when C exceeds this quantile of C fitted to no-floor noise


def nonnegative_least_squares_many(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """nonnegative_least_squares for many right-hand sides (T, R) at once: (columns, R)."""
    a, b = np.asarray(matrix, dtype=float), np.asarray(rhs, dtype=float)
    scale = _column_scale(a)
    a = a / scale
    columns = a.shape[1]
    best, best_cost = np.zeros((columns, b.shape[1])), np.einsum("tr,tr->r", b, b)
    for mask in range(1, 1 << columns):
        chosen = [j for j in range(columns) if mask >> j & 1]
        x = np.linalg.pinv(a[:, chosen]) @ b
        full = np.zeros_like(best)
        full[chosen] = x
        residual = a @ full - b
        cost = np.einsum("tr,tr->r", residual, residual)
        better = np.all(x >= 0, axis=0) & (cost < best_cost)
        best[:, better], best_cost[better] = full[:, better], cost[better]
    unscaled: np.ndarray = best / scale[:, None]
    return unscaled


def bootstrap_lines(white2: float, walk2: float, clusters: np.ndarray, tau0_s: float, samples: int,
                    replicates: int = BOOTSTRAP_REPLICATES, seed: int = 0) -> np.ndarray | None:
    """(replicates, 3): (N^2, C, K^2) fitted to white noise + random walk simulated from the fitted lines
    (no floor), at the same cluster sizes and record length: the spread of the fit itself, with the
    overlapping points' correlation and their few degrees of freedom at long tau included (treating the
    points as independent gave random-walk intervals that held the truth in 23 of 32 cases).
    A long record is simulated at a decimated rate (cluster sizes below the decimation left out: they
    carry nothing of the random walk). The replicates are weighted by the simulated model's errors (one
    solve for all). None when fewer than 3 cluster sizes remain."""
    decimation = 1
    while samples // decimation > BOOTSTRAP_MAX_SAMPLES:
        decimation *= 2
    kept = clusters[(clusters >= decimation) & (clusters % decimation == 0)] // decimation
    length = samples // decimation
    kept = kept[2 * kept < length]
    if len(kept) < 3:
        return None
    dt = decimation * tau0_s
    rng = np.random.default_rng(seed)
    simulated = np.sqrt(white2 / dt) * rng.standard_normal((length, replicates))
    simulated += np.cumsum(np.sqrt(walk2 * dt) * rng.standard_normal((length, replicates)), axis=0)
    tau, adev, relative = overlapping_adev(simulated, 1.0 / dt, clusters=kept)
    design = np.column_stack([1.0 / tau, np.ones_like(tau), tau / 3.0])
    weight = 1.0 / (2.0 * relative * (design @ np.array([white2, 0.0, walk2])))
    return nonnegative_least_squares_many(design * weight[:, None], adev**2 * weight[:, None]).T


def _scale_interval(value: float, ratios: np.ndarray) -> tuple[float, float]:
    """95 % interval of a scale figure from bootstrap ratios (estimate / truth), the ratio as pivot."""
    upper, lower = (float(q) for q in np.quantile(ratios, [0.975, 0.025]))
    return value / upper if upper > 0 else 0.0, value / lower if lower > 0 else math.inf


def _chi2_quantile(probability: float, dof: float) -> float:
    """Wilson-Hilferty's chi^2 quantile (within ~1 % for dof >= 3; scipy.stats costs a second to import)."""
    z = {0.025: -Z95, 0.975: Z95}[probability]
    return dof * (1.0 - 2.0 / (9.0 * dof) + z * math.sqrt(2.0 / (9.0 * dof))) ** 3


def _bias_instability(tau: np.ndarray, sigma: np.ndarray, floor: float, model: np.ndarray, samples: int,
                      tau0_s: float, null_floors: np.ndarray | None) -> Figure:
    """min sigma / 0.664 with a chi^2 interval (flicker-noise equivalent degrees of freedom of the
    overlapping estimator, 5 N^2 / (4 m (N + 3 m))); not present unless the fitted flat floor carries at
    least half of sigma^2 somewhere and exceeds what white noise + random walk alone fit as a floor."""
    lowest = int(np.argmin(sigma))
    instability = float(sigma[lowest]) / BIAS_INSTABILITY_FACTOR
    m = max(float(tau[lowest]) / tau0_s, 1.0)
    dof = max(5.0 * samples**2 / (4.0 * m * (samples + 3.0 * m)), 1.0)
    low = instability * math.sqrt(dof / _chi2_quantile(0.975, dof))
    high = instability * math.sqrt(dof / max(_chi2_quantile(0.025, dof), 1e-12))
    dominant = bool(np.any(floor >= 0.5 * model))
    beyond_null = null_floors is None or floor > float(np.quantile(null_floors, FLOOR_QUANTILE))
    inner = lowest not in (0, len(sigma) - 1)
    present = dominant and beyond_null
    return Figure(value=instability, low=low, high=high, resolved=inner and present,
                  at_tau_s=float(tau[lowest]), present=present)


def fit_noise(tau_s: np.ndarray, adev: np.ndarray, relative_error: np.ndarray, duration_s: float,
              target_relative: float = 0.25, tau0_s: float | None = None,
              replicates: int = BOOTSTRAP_REPLICATES) -> NoiseFit:
    """The figures of one channel's Allan curve (see the module text); `tau0_s` the sample period
    (default: the first tau, as octave_taus starts at one sample); `replicates` 0: the intervals from the
    fit's covariance alone (the points taken as independent), no bootstrap."""
    tau = np.asarray(tau_s, dtype=float)
    sigma = np.asarray(adev, dtype=float)
    relative = np.asarray(relative_error, dtype=float)
    if len(tau) < 3:
        raise CalibrationError(f"an Allan curve needs at least 3 taus, got {len(tau)}: record longer")
    if not np.all(sigma > 0):
        raise CalibrationError("the Allan deviation is 0 at some tau: no noise measurable (constant or quantized "
                               "samples)")
    if not (np.all(np.isfinite(sigma)) and np.all(np.isfinite(tau)) and np.all(tau > 0)):
        raise CalibrationError("the Allan curve must be finite, at taus > 0")
    period = float(tau[0]) if tau0_s is None else float(tau0_s)
    samples = int(round(duration_s / period)) + 1
    start, filtered = white_region_start(tau, sigma)
    used = slice(0 if start is None else start, None)
    try:
        solution, covariance, model = _fit_lines(tau[used], sigma[used] ** 2, relative[used])
    except np.linalg.LinAlgError as error:
        raise CalibrationError(f"the Allan curve could not be fitted ({error}): is the stretch still?") from None
    white2, floor, walk2 = (float(v) for v in solution)
    clusters = np.rint(tau[used] / period).astype(np.int64)
    boot = (bootstrap_lines(white2, walk2, clusters, period, samples, replicates)
            if white2 > 0 and replicates > 0 else None)
    white = _white_figure(white2, covariance, boot, present=start is not None, filtered=filtered)
    walk = _walk_figure(walk2, floor, white2, tau[used], model, covariance, boot, duration_s, target_relative)
    bias = _bias_instability(tau[used], sigma[used], floor, model, samples, period,
                             None if boot is None else boot[:, 1])
    return NoiseFit(tau_s=tau, adev=sigma, relative_error=relative,
                    noise=AxisNoise(white_density=white, random_walk=walk, bias_instability=bias), floor=floor,
                    white_from_tau_s=None if start is None else float(tau[start]))


def _analytic_interval(value2: float, variance: float) -> tuple[float, float]:
    spread = Z95 * math.sqrt(max(variance, 0.0))
    return math.sqrt(max(value2 - spread, 0.0)), math.sqrt(value2 + spread)


def _white_figure(white2: float, covariance: np.ndarray, boot: np.ndarray | None, present: bool,
                  filtered: bool) -> Figure:
    value = math.sqrt(max(white2, 0.0))
    if not present or value == 0.0:
        return Figure(value=value, low=0.0, high=math.inf, resolved=False, at_tau_s=1.0, present=False)
    if boot is None:
        low, high = _analytic_interval(white2, float(covariance[0, 0]))
    else:
        low, high = _scale_interval(value, np.sqrt(np.maximum(boot[:, 0], 0.0)) / value)
    if filtered:  # the bootstrap knows nothing of the filter's remaining deficit, which only lowers the value
        high /= 1.0 - FILTER_DEFICIT
    return Figure(value=value, low=low, high=high, resolved=low > 0, at_tau_s=1.0)


def _walk_figure(walk2: float, floor: float, white2: float, tau: np.ndarray, model: np.ndarray,
                 covariance: np.ndarray, boot: np.ndarray | None, duration_s: float,
                 target_relative: float) -> Figure:
    """K with its interval; resolved where the +1/2 line carries at least half of sigma^2 at some tau,
    else an upper bound with the still recording a +-target figure would need."""
    value = math.sqrt(max(walk2, 0.0))
    dominant = bool(np.any(walk2 * tau / 3.0 >= 0.5 * model)) and value > 0
    if dominant and boot is not None:
        low, high = _scale_interval(value, np.sqrt(np.maximum(boot[:, 2], 0.0)) / value)
    else:
        low, high = _analytic_interval(walk2, float(covariance[2, 2]))
    if dominant and low > 0 and math.isfinite(high):
        return Figure(value=value, low=low, high=high, at_tau_s=3.0)
    # The +1/2 line would need to dominate: where it would cross the rest, from its upper bound, and
    # N / m clusters there for the target error: 1 / sqrt(2 (T / tau - 1)) <= target.
    bound = _analytic_interval(walk2, float(covariance[2, 2]))[1]
    rest = white2 / tau + floor
    crossing = float(3.0 * max(float(np.min(rest)), 1e-300) / max(bound**2, 1e-300))
    needs = crossing * (1.0 + 1.0 / (2.0 * target_relative**2))
    return Figure(value=bound, low=0.0, high=bound, resolved=False, at_tau_s=3.0,
                  needs_s=max(needs, duration_s * 2.0))


def required_duration_s(tau_s: float, target_relative: float = 0.25) -> float:
    """Recording length for a point at tau to have relative error `target_relative`: T = tau (1 + 1/(2 e^2))."""
    return tau_s * (1.0 + 1.0 / (2.0 * target_relative**2))
