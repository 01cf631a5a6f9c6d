"""Overlapping Allan deviation of still IMU samples and the noise figures estimators ask for.

sigma^2(tau) = 1 / (2 tau^2 (N - 2m)) sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2, tau = m tau0, with
theta the running integral of the samples (IEEE Std 952, the overlapping estimator): one cumulative sum,
then the second differences per tau, a cache-sized block at a time.

The figures, per axis: the whole curve fitted at once (core/allan_model.py), sigma^2 = 3 Q^2 / tau^2 +
N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3 + R^2 tau^2 / 2 (IEEE Std 952 annex C), from where the curve first
has the -1/2 slope (white_region_start): every real IMU low-pass filters (a DLPF, an autopilot's
integrator), which pulls the short-tau points below the white line.
- white noise density N, read as sigma at tau = 1 s of its -1/2 line. Units: m/s^2/sqrt(Hz), rad/s/sqrt(Hz)
  -- Kalibr's *_noise_density.
- random walk K, sigma at tau = 3 s of its +1/2 line. Units: m/s^3/sqrt(Hz), rad/s^2/sqrt(Hz) -- Kalibr's
  *_random_walk.
- bias instability B: the flat floor / sqrt(2 ln 2 / pi) (= 0.664).
Intervals (95 %) by simulation of the fit itself (test inversion, allan_model.py); a term the record does
not resolve is reported with its 95 % upper bound (`resolved` False, `value` the bound, `estimate` the fit).
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
    n = len(values)
    tau0 = 1.0 / rate_hz
    m = octave_taus(n, tau0) if clusters is None else np.asarray(clusters, dtype=np.int64)
    m = m[(m >= 1) & (2 * m < n)]
    # The running integral (phase, in sample periods: tau0 enters at the end), of the samples less their
    # mean: keeps theta small, so the second differences lose no digits to a 9.8 m/s^2 offset. One channel
    # at a time in one row reused (a fresh (C, N) array cost more in page faults than all the arithmetic on
    # it), its mean from that row (numpy's mean down the columns of (N, 6) cost a tenth of the whole), a
    # non-finite sample found by that mean; the second differences a block of columns at a time in one
    # scratch buffer that stays in cache (no full-length temporaries).
    channels = values.shape[1]
    theta = np.zeros(n + 1)
    column = theta[1:]
    scratch, firsts = np.empty(_BLOCK), np.empty(2 * _BLOCK)
    sums = np.zeros((len(m), channels))
    sizes = m.tolist()
    for channel in range(channels):
        np.copyto(column, values[:, channel])
        mean = float(column.sum()) / n
        if not math.isfinite(mean):
            raise CalibrationError("samples must be finite")
        column -= mean
        np.cumsum(column, out=column)
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
    adev = np.sqrt(sums / (2.0 * (m.astype(float) ** 2 * (n + 1 - 2 * m)))[:, None])
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
    """One noise figure with its 95 % interval; `resolved` False: the recording does not resolve it and
    `value` (= `high`) is an upper bound that holds 95 % of the time (`needs_s`: the still recording a
    +-25 % figure would need, when known; `estimate`: the fitted value, below the bound); `present` False:
    the curve shows no such term (no -1/2 slope; no bias instability beyond what chance gives)."""

    value: float
    low: float
    high: float
    resolved: bool = True
    at_tau_s: float | None = None
    needs_s: float | None = None
    present: bool = True
    estimate: float | None = None


@dataclass(frozen=True)
class AxisNoise:
    white_density: Figure  # N: sigma^2 = N^2 / tau, read as sigma at tau = 1 s
    random_walk: Figure  # K: sigma^2 = K^2 tau / 3, i.e. sigma at tau = 3 s
    bias_instability: Figure  # B: the flat sigma^2 = (2 ln 2 / pi) B^2, at_tau_s where it carries most
    quantization: float = 0.0  # Q (sigma^2 = 3 Q^2 / tau^2), 0 unless the curve asks for it
    rate_ramp: float = 0.0  # R (sigma^2 = R^2 tau^2 / 2), 0 unless the curve asks for it


@dataclass(frozen=True)
class NoiseFit:
    """The Allan curve of one channel and the model fitted to it."""

    tau_s: np.ndarray
    adev: np.ndarray
    relative_error: np.ndarray
    noise: AxisNoise
    floor: float  # C: the flat part of sigma^2
    white_from_tau_s: float | None = None  # where the fit starts (None: no -1/2 region)
    coefficients: np.ndarray | None = None  # (Q^2 or the filter's deficit, N^2, C, K^2, R^2) of sigma^2
    terms: tuple[str, ...] = ()  # the terms the fit carries; "filter": a low-pass filter's deficit (-3/tau^2)


REPLICATES = 400


def fit_noise(tau_s: np.ndarray, adev: np.ndarray, relative_error: np.ndarray, duration_s: float,
              target_relative: float = 0.25, tau0_s: float | None = None,
              replicates: int = REPLICATES) -> NoiseFit:
    """The figures of one channel's Allan curve, the whole model fitted at once (core/allan_model.py);
    `tau0_s` the sample period (default: the first tau, as octave_taus starts at one sample); `replicates`
    0: intervals from the fit's covariance (the points taken as independent), no simulation."""
    from .allan_model import TERMS, design_columns, equivalent_dof, select_terms, simulation_for

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
    variance = sigma[used] ** 2
    clusters = np.maximum(np.rint(tau[used] / period).astype(np.int64), 1)
    columns, dof = design_columns(tau[used], filtered), equivalent_dof(clusters, samples)
    if not np.all(np.isfinite(columns * variance.max())):
        raise CalibrationError("the Allan curve has values out of floating-point range: no fit")
    try:
        chosen, coefficients = select_terms(variance, columns, dof, filtered)
    except np.linalg.LinAlgError as error:
        raise CalibrationError(f"the Allan curve could not be fitted ({error}): is the stretch still?") from None
    simulation = (simulation_for(clusters, period, samples, replicates, filtered)
                  if replicates > 0 and coefficients[1] > 0 else None)
    intervals = (_simulated_intervals(simulation, variance, coefficients, chosen, filtered) if simulation is not None
                 else _covariance_intervals(variance, coefficients, chosen, columns, dof))
    model = columns @ coefficients
    white = _white_figure(coefficients[1], intervals[1], present=start is not None, filtered=filtered)
    walk = _walk_figure(coefficients, intervals[3], tau[used], duration_s, target_relative)
    bias = _bias_figure(coefficients[2], intervals[2], tau[used], model)
    noise = AxisNoise(white_density=white, random_walk=walk, bias_instability=bias,
                      quantization=0.0 if filtered else math.sqrt(coefficients[0]),
                      rate_ramp=math.sqrt(coefficients[4]))
    return NoiseFit(tau_s=tau, adev=sigma, relative_error=relative, noise=noise, floor=float(coefficients[2]),
                    white_from_tau_s=None if start is None else float(tau[start]), coefficients=coefficients,
                    terms=tuple("filter" if filtered and j == 0 else TERMS[j] for j in chosen))


Interval = tuple[float, float, bool]  # (low, high, resolved) of a variance coefficient; unresolved: high one-sided


def _simulated_intervals(simulation: object, variance: np.ndarray, coefficients: np.ndarray,
                         chosen: list[int], filtered: bool) -> dict[int, Interval]:
    """White noise's interval from the simulated fits' ratio to the truth (a scale pivot: white noise is
    always resolved where the curve has its slope); bias instability's and random walk's by test inversion."""
    from .allan_model import Simulation, fit_batch, term_interval

    assert isinstance(simulation, Simulation)
    # quantization: below the simulation's shortest tau; a filter's deficit: fitted there as in the data
    simulated_terms = chosen if filtered else [j for j in chosen if j != 0]
    part = fit_batch(variance[simulation.kept][None, :], simulation.columns[:, simulated_terms],
                     simulation.dof[:, simulated_terms])[0]
    statistic = np.zeros(len(coefficients))
    statistic[simulated_terms] = part
    intervals: dict[int, Interval] = {}
    white = float(coefficients[1])
    if statistic[1] > 0:
        ratios = simulation.fitted(statistic, simulated_terms)[:, 1] / statistic[1]
        upper, lower = (float(q) for q in np.quantile(ratios, [0.975, 0.025]))
        intervals[1] = (white / upper if upper > 0 else 0.0, white / lower if lower > 0 else math.inf, True)
    else:
        intervals[1] = (0.0, math.inf, False)
    for term in (2, 3):
        found = term_interval(simulation, variance[simulation.kept], statistic, simulated_terms, term,
                              float(coefficients[term]))
        intervals[term] = (found.low, found.high, found.resolved)
    return intervals


def _covariance_intervals(variance: np.ndarray, coefficients: np.ndarray, chosen: list[int], columns: np.ndarray,
                          dof: np.ndarray) -> dict[int, Interval]:
    """Intervals from the weighted fit's covariance (points independent, scaled by the misfit when worse
    than the stated errors): for short records and replicates=0."""
    from .allan_model import variance_sd, weighted_misfit

    sd = variance_sd(coefficients[None, :], columns, dof)[0]
    weighted = columns[:, chosen] / np.maximum(sd, 1e-300)[:, None]
    chi2 = weighted_misfit(variance, coefficients, columns, dof) / max(len(variance) - len(chosen), 1)
    covariance = np.linalg.pinv(weighted.T @ weighted) * max(chi2, 1.0)
    intervals: dict[int, Interval] = {}
    for term in (1, 2, 3):
        spread = Z95 * math.sqrt(max(float(covariance[chosen.index(term), chosen.index(term)]), 0.0))
        value = float(coefficients[term])
        resolved = value - spread > 0
        intervals[term] = ((value - spread, value + spread, True) if resolved
                           else (0.0, value + 0.8 * spread, False))  # one-sided 95 %: 1.645 / 1.96
    return intervals


def _white_figure(white2: float, interval: Interval, present: bool, filtered: bool) -> Figure:
    value = math.sqrt(max(white2, 0.0))
    if not present or value == 0.0:
        return Figure(value=value, low=0.0, high=math.inf, resolved=False, at_tau_s=1.0, present=False)
    low, high = math.sqrt(max(interval[0], 0.0)), math.sqrt(interval[1])
    if filtered:  # the simulation knows nothing of the filter's remaining deficit, which only lowers the value
        high /= 1.0 - FILTER_DEFICIT
    return Figure(value=value, low=low, high=high, resolved=low > 0, at_tau_s=1.0)


def _walk_figure(coefficients: np.ndarray, interval: Interval, tau: np.ndarray, duration_s: float,
                 target_relative: float) -> Figure:
    """K with its interval; not resolved: its 95 % upper bound, with the still recording a +-target figure
    would need (where the bound's +1/2 line would cross the rest of the model, and N / m clusters there:
    1 / sqrt(2 (T / tau - 1)) <= target)."""
    value = math.sqrt(max(float(coefficients[3]), 0.0))
    low, high, resolved = interval
    if resolved:
        return Figure(value=value, low=math.sqrt(low), high=math.sqrt(high), at_tau_s=3.0)
    bound = math.sqrt(max(high, 0.0))
    white2, floor = float(coefficients[1]), float(coefficients[2])
    rest = white2 / tau + floor
    crossing = float(3.0 * max(float(np.min(rest)), 1e-300) / max(bound**2, 1e-300))
    needs = crossing * (1.0 + 1.0 / (2.0 * target_relative**2))
    return Figure(value=bound, low=0.0, high=bound, resolved=False, at_tau_s=3.0,
                  needs_s=max(needs, duration_s * 2.0), estimate=value)


def _bias_figure(floor: float, interval: Interval, tau: np.ndarray, model: np.ndarray) -> Figure:
    """B = sqrt(C) / 0.664 with its interval, at the tau where the floor carries most of sigma^2; not
    resolved: not present, with its 95 % upper bound."""
    value = math.sqrt(max(floor, 0.0)) / BIAS_INSTABILITY_FACTOR
    low, high, resolved = interval
    at_tau = float(tau[int(np.argmax(floor / np.maximum(model, 1e-300)))])
    scale = 1.0 / BIAS_INSTABILITY_FACTOR
    if resolved:
        return Figure(value=value, low=math.sqrt(low) * scale, high=math.sqrt(high) * scale, at_tau_s=at_tau)
    bound = math.sqrt(max(high, 0.0)) * scale
    return Figure(value=bound, low=0.0, high=bound, resolved=False, at_tau_s=at_tau, present=False, estimate=value)


def required_duration_s(tau_s: float, target_relative: float = 0.25) -> float:
    """Recording length for a point at tau to have relative error `target_relative`: T = tau (1 + 1/(2 e^2))."""
    return tau_s * (1.0 + 1.0 / (2.0 * target_relative**2))
