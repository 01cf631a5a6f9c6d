"""The outlier layer of fit(): a pose whose residual stands out of the others' (studentized, leverage
taken into account, against a critical ratio for the poses' degrees of freedom) is left out and the
poses refitted without it, as long as the refit stays a fit; the result names what was left out."""
from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from .calibration import Calibration
from .coverage import (
    inverse_normal,
)
from .errors import CalibrationError
from .fit_result import FitResult, Outlier, OutlierOptions
from .models import SphereModel, parameter_count
from .units import AXES, MG

# The outlier test refits without at most this many candidates (largest first) per pose left out: a
# pose the model cannot do without (leverage near 1) looks like one until the refit without it fails.
OUTLIER_CANDIDATES = 3


def leave_out_outliers(fit_poses: Callable[[np.ndarray | None], FitResult], accel: np.ndarray,
                        temps: np.ndarray | None, ref: np.ndarray | None, options: OutlierOptions,
                        pose_sigma: np.ndarray | None) -> FitResult:
    """The fit of all poses, or, when a pose does not lie on the sphere (reference) with the rest, the fit
    without it, naming it. One pose at a time: candidates are poses whose linearised deleted residual
    r / (1 - h) exceeds the threshold, the largest standardised residual first; a candidate is left out
    only if the refit without it succeeds and the pose stands out against that refit (its deleted
    residual is beyond k_sigma in probability, judged with the refit's residual scale and degrees of
    freedom; see _stands_out). Two candidates that hide each other are tried together. Clean data:
    the first fit, untouched."""
    first = fit_poses(None)
    n = len(accel)
    budget = int(options.max_fraction * n)
    if options.threshold_mg <= 0 or budget < 1 or not first.success or first.calibration is None:
        return first
    if first.leverage is not None and len(first.leverage) == n:
        # Cheap bound first: the candidates' linearised deleted residuals from the fit's own residuals and
        # leverages. None near the threshold (margin far above rounding): clean data, the first fit stands.
        h = np.minimum(np.maximum(first.leverage, 0.0), 1.0 - 1e-9)  # np.clip's wrapper costs more
        if float((np.abs(first.residuals_mg) / (1.0 - h)).max()) < options.threshold_mg * (1.0 - 1e-6):
            return first
    keep = np.ones(n, dtype=bool)
    current = first

    def without(indices: list[int]) -> tuple[FitResult, np.ndarray] | None:
        trial_keep = keep.copy()
        trial_keep[indices] = False
        trial = fit_poses(trial_keep)
        if not trial.success or trial.calibration is None:
            return None  # the others alone do not determine the model: the poses stay
        if _stands_out(trial.calibration, trial_keep, indices, accel, temps, ref, options, pose_sigma):
            return trial, trial_keep
        return None

    try:
        while n - int(keep.sum()) < budget:
            assert current.calibration is not None  # only successful fits are kept
            residuals, leverage = residuals_and_leverage(current.calibration, keep, accel, temps, ref)
            kept = np.flatnonzero(keep)
            h = np.clip(leverage[kept], 0.0, 1.0 - 1e-9)
            estimate = np.abs(residuals[kept]) / (1.0 - h)
            standardised = np.abs(residuals[kept]) / np.sqrt(1.0 - h)
            order = [int(kept[i]) for i in np.argsort(-standardised)
                     if estimate[i] > options.threshold_mg][:OUTLIER_CANDIDATES]
            accepted = None
            for index in order:
                accepted = without([index])
                if accepted is not None:
                    break
            if accepted is None and len(order) >= 2 and n - int(keep.sum()) + 2 <= budget:
                accepted = without(order[:2])
            if accepted is None:
                break
            current, keep = accepted
    except (ArithmeticError, np.linalg.LinAlgError, CalibrationError, ValueError):
        pass  # wild numbers: keep what was established so far
    if keep.all():
        return first
    calibration = current.calibration
    assert calibration is not None
    left_out = np.flatnonzero(~keep)
    residuals = pose_residuals_mg(calibration, accel, temps, ref)
    corrected = calibration.apply(accel[left_out], None if temps is None else temps[left_out])
    off = "the sphere" if ref is None else "its reference direction"
    outliers = tuple(Outlier(int(i), float(residuals[i]), nearest_face(v), off) for i, v in zip(left_out, corrected))
    return replace(current, outliers=outliers)


def _stands_out(calibration: Calibration, keep: np.ndarray, indices: list[int], accel: np.ndarray,
                temps: np.ndarray | None, ref: np.ndarray | None, options: OutlierOptions,
                pose_sigma: np.ndarray | None) -> bool:
    """Whether each pose left out (`indices`) is an outlier against the fit of the poses `keep`: its
    residual d exceeds threshold_mg, and d^2 / (m s^2 (1 + h)) exceeds the F(m, dof) quantile with the
    tail probability of k_sigma Gaussian sigmas. s^2: the fit's residual variance over its degrees of
    freedom (floored at the poses' own noise), h: the growth of the pose's prediction variance, m: 1 on
    the sphere, 3 with a reference direction (a residual vector). With few degrees of freedom s is
    poorly known and the quantile is correspondingly large."""
    residuals, leverage = residuals_and_leverage(calibration, keep, accel, temps, ref)
    components = 1 if ref is None else 3
    temperature = calibration.temperature
    extra = 0 if temperature is None else (temperature.bias_coefficients.size + temperature.scale_coefficients.size
                                           + temperature.segment_coefficients.size)
    if ref is None:
        unknowns = parameter_count(calibration.model) + extra
    else:  # per axis: bias, a row of S (and q), and the axis' share of the temperature terms
        unknowns = (5 if calibration.quadratic is not None else 4) + extra // 3
    dof = int(keep.sum()) - unknowns
    if dof < 1:
        return False
    variance = float(residuals[keep] @ residuals[keep]) / (components * dof)
    if pose_sigma is not None:
        gain = float(np.mean(np.linalg.norm(calibration.matrix, axis=1)))
        variance = max(variance, (float(np.median(pose_sigma[keep])) * gain / MG) ** 2)
    critical = critical_ratio(options.k_sigma, components, components * dof)
    for index in indices:
        d = abs(float(residuals[index]))
        spread = components * variance * (1.0 + max(float(leverage[index]), 0.0))
        if not (d > options.threshold_mg and d * d > critical * spread):
            return False
    return True


@functools.lru_cache(maxsize=256)
def critical_ratio(k_sigma: float, components: int, dof: int) -> float:
    """F(components, dof) quantile with the upper tail probability of k_sigma Gaussian sigmas (two-sided)."""
    # Imported here: scipy.stats costs ~0.5 s at import, and only a fit with an outlier candidate needs it.
    from scipy.special import erfc
    from scipy.stats import f as f_distribution

    return float(f_distribution.ppf(1.0 - erfc(k_sigma / np.sqrt(2.0)), components, dof))


def residuals_and_leverage(calibration: Calibration, keep: np.ndarray, accel: np.ndarray,
                            temps: np.ndarray | None, ref: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Against one fit (of the poses `keep`): every pose's residual (mg) and leverage x (X_k^T X_k)^-1 x^T
    with X_k the design (Jacobian) rows of the poses kept: for a pose kept its leverage, for a pose
    left out how much its prediction's variance exceeds one pose's. The reference models' per-axis
    designs differ (reference15): the largest."""
    residuals = pose_residuals_mg(calibration, accel, temps, ref)
    if ref is None:
        designs = [sphere_rows(calibration, accel, temps)]
    else:
        true = calibration.gravity * ref
        base = np.column_stack([np.ones(len(ref)), true])
        designs = [np.column_stack([base, true[:, j] ** 2]) for j in range(3)] \
            if calibration.quadratic is not None else [base]
    leverage = np.zeros(len(accel))
    for design in designs:
        inverse = inverse_normal(design[keep].T @ design[keep])
        leverage = np.maximum(leverage, np.einsum("ij,jk,ik->i", design, inverse, design))
    return residuals, leverage


def pose_residuals_mg(calibration: Calibration, accel: np.ndarray, temps: np.ndarray | None,
                       ref: np.ndarray | None) -> np.ndarray:
    """Each pose's residual against a calibration: |a| - g on the sphere, |a - g ref| with a reference."""
    corrected = calibration.apply(accel, temps)
    if ref is None:
        result: np.ndarray = (np.linalg.norm(corrected, axis=1) - calibration.gravity) / MG
    else:
        result = np.linalg.norm(corrected - calibration.gravity * ref, axis=1) / MG
    return result


def sphere_rows(calibration: Calibration, accel: np.ndarray, temps: np.ndarray | None) -> np.ndarray:
    """Jacobian rows of the sphere residuals at a calibration's b and M, one per pose. With a temperature
    model, of the poses corrected to the reference temperature (the temperature terms left out)."""
    model = SphereModel(calibration.model)
    c = calibration
    if c.temperature is not None and temps is not None:
        accel = c.bias + np.linalg.solve(c.matrix, c.apply(accel, temps).T).T
    _, rows = model.residual_and_jacobian(model.pack(c.bias, c.matrix), accel, c.gravity)
    return rows


def nearest_face(corrected: np.ndarray) -> str:
    axis = int(np.argmax(np.abs(corrected)))
    return f"{AXES[axis]} {'up' if corrected[axis] > 0 else 'down'}"
