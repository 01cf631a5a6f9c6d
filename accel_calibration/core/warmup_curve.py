"""A bias curve over temperature: a natural cubic spline through values at evenly spaced knots, held
flat outside its knots (never extrapolated). Fitted to per-temperature bin means, every bin weighted
alike (weight by temperature, not by time: the slow end of a warm-up does not dominate), the number of
knots chosen by leave-one-out cross-validation over the bins, each recording with its own constant
offset (its turn-on bias). A natural cubic spline is linear in its knot values, so the fit is one
linear least squares and its covariance gives the curve's sigma at any temperature."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .errors import CalibrationError

MIN_KNOTS = 2
MAX_KNOTS = 16
BINS_PER_KNOT = 3  # at least this many bins per unknown of the curve


def spline_basis(knots_degc: np.ndarray, degc: ArrayLike) -> np.ndarray:
    """(N, K): the natural cubic spline through the knots, per unit knot value, at `degc` clamped to the
    knots' span (flat outside it)."""
    knots = np.asarray(knots_degc, dtype=float)
    at = np.clip(np.asarray(degc, dtype=float).reshape(-1), knots[0], knots[-1])
    if len(knots) == 2:  # a line: CubicSpline's natural ends need three knots
        share = (at - knots[0]) / (knots[1] - knots[0])
        return np.column_stack([1.0 - share, share])
    from scipy.interpolate import CubicSpline  # here: scipy.interpolate brings scipy.linalg, which start-up avoids

    basis: np.ndarray = CubicSpline(knots, np.eye(len(knots)), bc_type="natural")(at)
    return basis


@dataclass(frozen=True, eq=False)
class BiasCurve:
    """One sensor's bias drift against temperature, per axis, zero at the reference temperature:
    values at the knots (K, 3) of a natural cubic spline, with their covariance per axis (3, K, K)."""

    knots_degc: np.ndarray  # (K,) increasing; the first and last are the usable range
    values: np.ndarray  # (K, 3) drift at each knot, per axis
    covariance: np.ndarray  # (3, K, K) of each axis's knot values

    def __post_init__(self) -> None:
        knots = np.asarray(self.knots_degc, dtype=float)
        values = np.asarray(self.values, dtype=float)
        if knots.ndim != 1 or len(knots) < MIN_KNOTS or np.any(np.diff(knots) <= 0) or not np.all(np.isfinite(knots)):
            raise CalibrationError("a bias curve needs at least 2 increasing finite knot temperatures")
        if values.shape != (len(knots), 3) or not np.all(np.isfinite(values)):
            raise CalibrationError(f"a bias curve's values must be {len(knots)} rows of 3 finite numbers")
        object.__setattr__(self, "knots_degc", knots)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "covariance", np.asarray(self.covariance, dtype=float).reshape(3, len(knots),
                                                                                               len(knots)))

    @property
    def range_degc(self) -> tuple[float, float]:
        return float(self.knots_degc[0]), float(self.knots_degc[-1])

    def at(self, degc: ArrayLike) -> np.ndarray:
        """(N, 3) drift at each temperature; flat outside the range."""
        result: np.ndarray = spline_basis(self.knots_degc, degc) @ self.values
        return result

    def sigma_at(self, degc: ArrayLike) -> np.ndarray:
        """(N, 3) one sigma of the drift at each temperature (of the fit; flat outside the range)."""
        basis = spline_basis(self.knots_degc, degc)
        variance = np.einsum("nk,akl,nl->na", basis, self.covariance, basis)
        result: np.ndarray = np.sqrt(np.maximum(variance, 0.0))
        return result


@dataclass(frozen=True)
class CurveFit:
    """What `fit_bias_curve` returns: the curve (zero at the reference), each run's offset (its bias at
    the reference temperature, (R, 3)), the bins' rms residual per axis and the cross-validation score."""

    curve: BiasCurve
    offsets: np.ndarray
    residual_rms: np.ndarray
    cv_score: float


def _design(knots: np.ndarray, degc: np.ndarray, runs: np.ndarray, run_count: int) -> np.ndarray:
    """Spline columns and one offset column per run but the first (the spline carries the first's)."""
    offsets = (runs[:, None] == np.arange(1, run_count)[None, :]).astype(float)
    return np.hstack([spline_basis(knots, degc), offsets])


def _loo_score(design: np.ndarray, means: np.ndarray, scale: np.ndarray) -> float:
    """Sum over bins and axes of the leave-one-out residual squared, each axis in units of its typical
    bin error (so accelerometer and gyro, or quiet and noisy axes, count alike)."""
    q, _ = np.linalg.qr(design)
    leverage = np.einsum("ij,ij->i", q, q)
    if np.any(leverage > 1 - 1e-9):
        return float("inf")
    residual = means - q @ (q.T @ means)
    return float(np.sum((residual / (1 - leverage)[:, None] / scale) ** 2))


def fit_bias_curve(degc: np.ndarray, means: np.ndarray, errors: np.ndarray, runs: np.ndarray,
                   reference_degc: float) -> CurveFit:
    """Bins at temperatures `degc` (B,) with means (B, 3), standard errors (B, 3) and the run each came
    from (B,) ints 0..R-1: the curve over their range with the knot count cross-validation prefers."""
    run_count = int(runs.max()) + 1
    low, high = float(degc.min()), float(degc.max())
    scale = np.maximum(np.median(errors, axis=0), 1e-300)
    most = max(MIN_KNOTS, min(MAX_KNOTS, len(degc) // BINS_PER_KNOT - (run_count - 1)))
    best: tuple[float, np.ndarray] | None = None
    for count in range(MIN_KNOTS, most + 1):
        knots = np.linspace(low, high, count)
        score = _loo_score(_design(knots, degc, runs, run_count), means, scale)
        if best is None or score < best[0]:
            best = (score, knots)
    if best is None or not np.isfinite(best[0]):
        raise CalibrationError(f"{len(degc)} temperature bins cannot determine a curve")
    score, knots = best
    design = _design(knots, degc, runs, run_count)
    solution, *_ = np.linalg.lstsq(design, means, rcond=None)
    residual = means - design @ solution
    dof = max(len(degc) - design.shape[1], 1)
    # Sigma of the knot values from the scatter about the fit (which holds the bins' own noise and any
    # misfit), never below what the bins' standard errors say.
    variance = np.maximum(np.sum(residual**2, axis=0) / dof, np.mean(errors**2, axis=0))
    inverse = np.linalg.pinv(design.T @ design)
    k = len(knots)
    values = solution[:k]
    offsets = np.vstack([np.zeros((1, 3)), solution[k:]])
    # Zero at the reference: the drift there moves into every run's offset.
    at_reference = spline_basis(knots, [reference_degc]) @ values
    values = values - at_reference
    offsets = offsets + at_reference
    shift = np.eye(k) - spline_basis(knots, [reference_degc])  # values' = shift @ values (row broadcast)
    covariance = np.stack([shift @ inverse[:k, :k] @ shift.T * v for v in variance])
    return CurveFit(BiasCurve(knots, values, covariance), offsets, np.sqrt(np.mean(residual**2, axis=0)), score)


def misfit(degc: np.ndarray, means: np.ndarray, errors: np.ndarray, runs: np.ndarray,
           knot_spacing_degc: float = 1.0) -> tuple[float, int]:
    """Chi-square of the bins about a curve with a knot every `knot_spacing_degc` (at most one per two
    bins), each bin in its own standard errors: a curve that rich follows any smooth drift, so what is
    left is disagreement between bins at one temperature (two heating histories that do not agree).
    With its degrees of freedom (what the chi-square is when the bins agree but for their noise)."""
    run_count = int(runs.max()) + 1
    low, high = float(degc.min()), float(degc.max())
    count = max(MIN_KNOTS, min(int(np.ceil((high - low) / knot_spacing_degc)) + 1, len(degc) // 2 - (run_count - 1)))
    design = _design(np.linspace(low, high, count), degc, runs, run_count)
    solution, *_ = np.linalg.lstsq(design, means, rcond=None)
    chi_square = float(np.sum(((means - design @ solution) / np.maximum(errors, 1e-300)) ** 2))
    return chi_square, max(means.size - design.shape[1] * means.shape[1], 1)
