"""fit(): the one entry point from pose means to a Calibration, shared by the node, replay, CLI and notebooks.

Bad arguments raise CalibrationError (a ValueError). A fit that cannot be done from good
arguments -- too few poses, no degree of freedom left to judge the fit, poses that leave the model
unobservable, no convergence, overflow or a singular solution -- is reported in the result (success
False, message saying what is missing), never raised: finite poses of the right shape never raise.
"""
from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration
from .errors import CalibrationError
from .fit_outliers import leave_out_outliers, sphere_rows
from .fit_result import DEFAULT_OUTLIER_OPTIONS, FitResult, Outlier, OutlierOptions, Sigma
from .fit_solvers import fit_without_temperature, numerical_failure, uncertainty_of
from .fit_temperature import fit_with_temperature
from .models import MODELS, REFERENCE_MODELS, SPHERE_MODELS
from .pose import Pose
from .prior import Prior, fit_sphere_with_prior, prior_noise_floor, prior_terms
from .temperature_models import (
    TEMPERATURE_MODELS,
    TemperatureOptions,
)
from .units import AXES, MG, STANDARD_GRAVITY

# The result types live in fit_result.py, the outlier layer in fit_outliers.py, the solvers in fit_solvers.py
# and fit_temperature.py; what callers import from here stays here.
__all__ = ["AXES", "FitResult", "Outlier", "OutlierOptions", "Sigma", "fit", "pose_mean_sigma"]


def _as_points(accel: ArrayLike | Sequence[Pose], name: str) -> np.ndarray:
    try:
        array = np.array(accel, dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be an N x 3 array of numbers") from None
    if array.ndim != 2 or array.shape[1] != 3:
        raise CalibrationError(f"{name} must be an N x 3 array, got shape {array.shape}")
    if not np.isfinite(array).all():
        bad = int(np.flatnonzero(~np.all(np.isfinite(array), axis=1))[0])
        raise CalibrationError(f"{name} has a non-finite value (row {bad})")
    return array


def _check_arguments(accel_mps2: ArrayLike | Sequence[Pose], model: str, gravity: float,
                     temperature_degc: ArrayLike | None, reference: ArrayLike | None, initial: Calibration | None
                     ) -> tuple[np.ndarray, float, np.ndarray | None, np.ndarray | None]:
    if isinstance(accel_mps2, (list, tuple)) and accel_mps2 and isinstance(accel_mps2[0], Pose):
        poses: Sequence[Pose] = accel_mps2
        accel_mps2 = [p.accel_mps2 for p in poses]
        if temperature_degc is None and all(p.temperature_degc is not None for p in poses):
            temperature_degc = [p.temperature_degc for p in poses if p.temperature_degc is not None]
    accel = _as_points(accel_mps2, "accel_mps2")
    if model not in MODELS:
        raise CalibrationError(f"model must be one of {', '.join(MODELS)}, got {model!r}")
    if (isinstance(gravity, bool) or not isinstance(gravity, (int, float, np.floating)) or not np.isfinite(gravity)
            or gravity <= 0):
        raise CalibrationError(f"gravity must be a positive number of m/s^2, got {gravity!r}")
    temps = None
    if temperature_degc is not None:
        temps = np.array(temperature_degc, dtype=float).reshape(-1)
        if temps.shape != (len(accel),):
            raise CalibrationError(f"temperature_degc must have one value per pose ({len(accel)}), got {temps.shape}")
        if not np.all(np.isfinite(temps)):
            raise CalibrationError("temperature_degc has a non-finite value")
    ref = None
    if model in REFERENCE_MODELS:
        if reference is None:
            raise CalibrationError(f"model {model} needs reference gravity directions (reference=N x 3)")
        ref = _as_points(reference, "reference")
        if ref.shape != accel.shape:
            raise CalibrationError(f"reference must have one row per pose ({len(accel)}), got {len(ref)}")
        peak = np.abs(ref).max(axis=1, initial=0.0)
        if np.any(peak == 0):
            raise CalibrationError(f"reference row {int(np.flatnonzero(peak == 0)[0])} is zero: give a direction")
        with np.errstate(over="ignore", under="ignore"):
            norms = np.linalg.norm(ref, axis=1)
        odd = ~np.isfinite(norms) | (norms < 1e-150)  # the squares overflow or underflow: scale the row first
        if np.any(odd):
            ref[odd] /= peak[odd, None]
            norms[odd] = np.linalg.norm(ref[odd], axis=1)
        ref = ref / norms[:, None]
    elif reference is not None:
        raise CalibrationError(f"model {model} fits without reference directions; use reference12/reference15")
    if initial is not None and not isinstance(initial, Calibration):
        raise CalibrationError("initial must be a Calibration (warm start) or None")
    return accel, float(gravity), temps, ref


def fit(
    accel_mps2: ArrayLike | Sequence[Pose],
    *,
    model: str = "sphere9",
    gravity: float = STANDARD_GRAVITY,
    temperature_degc: ArrayLike | None = None,
    reference: ArrayLike | None = None,
    initial: Calibration | None = None,
    frame_id: str = "",
    temperature_model: str = "none",
    temperature_options: TemperatureOptions | None = None,
    outlier_options: OutlierOptions | None = None,
    pose_sigma_mps2: ArrayLike | None = None,
    prior: Calibration | Prior | None = None,
) -> FitResult:
    """Fit a calibration to static pose means.

    accel_mps2: N x 3 mean raw accelerations of static poses (or a list of Pose). Any consistent raw
    unit works (counts too); the corrected output is in m/s^2 scaled to `gravity`.
    reference: N x 3 directions of the gravity reaction in the sensor frame (reference models only).
    initial: warm start for the sphere models (e.g. the calibration in force).
    temperature_model: "none", "polynomial" (sphere models) or "segmented" (any model; with the reference
    models each segment's drift is observed directly); needs temperature_degc;
    temperature_options: orders, segment width, minimum span, T_ref, blend (TemperatureOptions).
    outlier_options: when a pose off the sphere is left out (OutlierOptions; default on, threshold 5 mg);
    the result names it (`outliers`) and is then the fit of the other poses.
    pose_sigma_mps2: 1-sigma noise of each pose mean (N, raw units; per axis); taken from the poses' covariance
    and sample count when Pose objects are given. When every pose has one and they differ, the sphere and
    reference fits (without a temperature model) weight pose i by 1 / (s_i^2 + tau^2), tau the common extra
    error estimated so that chi^2/dof = 1, and report sigma from (J^T W J)^-1 rescaled by chi^2/dof; equal
    ones give the unweighted fit exactly. Also the floor under the outlier test's scale.
    prior: a sphere calibration with its uncertainty (the one in force), or a Prior (bias drift allowed since):
    Gaussian pseudo-measurements of b and M, for poses that cannot reach every orientation (core/prior.py);
    poses weighted alike; the result's parameter_sources say what came from the poses, what from the prior.
    """
    if pose_sigma_mps2 is None and isinstance(accel_mps2, (list, tuple)) and accel_mps2 \
            and all(isinstance(p, Pose) for p in accel_mps2):
        pose_sigma_mps2 = pose_mean_sigma(accel_mps2)
    accel, gravity, temps, ref = _check_arguments(accel_mps2, model, gravity, temperature_degc, reference, initial)
    outlier_options = DEFAULT_OUTLIER_OPTIONS if outlier_options is None else outlier_options
    if not isinstance(outlier_options, OutlierOptions):
        raise CalibrationError("outlier_options must be an OutlierOptions or None")
    pose_sigma = None if pose_sigma_mps2 is None else _checked_pose_sigma(pose_sigma_mps2, len(accel))
    options = _checked_temperature_options(temperature_model, temperature_options, temps, model)
    if prior is not None and options is not None:
        raise CalibrationError("a fit with a prior fits without a temperature model")
    prior_values = None if prior is None else prior_terms(prior, model, gravity)
    # The arguments are good: from here on every problem is the data's, reported in the result. Overflow
    # and the like are expected on wild data (and checked for), so numpy is not to warn about them.
    def fit_poses(keep: np.ndarray | None) -> FitResult:
        """The fit of the poses kept (all when None): what the outlier test compares against."""
        a = accel if keep is None else accel[keep]
        t = temps if temps is None or keep is None else temps[keep]
        r = ref if ref is None or keep is None else ref[keep]
        s = pose_sigma if pose_sigma is None or keep is None else pose_sigma[keep]
        if prior_values is not None:
            assert prior is not None  # prior_values come from it
            result = fit_sphere_with_prior(a, model, gravity, *prior_values,
                                           None if t is None else float(t.mean()), frame_id,
                                           prior_noise_floor(prior, s))
        elif options is not None:
            assert t is not None  # checked above: a temperature model needs temperature_degc
            # The room-temperature fit inside takes the caller's outlier test and pose noise, as this one does.
            base_fit = functools.partial(fit, outlier_options=outlier_options)
            result = fit_with_temperature(a, t, model, gravity, options, initial, frame_id, r, base_fit=base_fit,
                                          pose_sigma=s)
        else:
            result = fit_without_temperature(a, model, gravity, t, r, initial, frame_id, s)
        return _with_uncertainty(result, a, t, gravity)

    try:
        with np.errstate(all="ignore"):
            return leave_out_outliers(fit_poses, accel, temps, ref, outlier_options, pose_sigma)
    except (ArithmeticError, np.linalg.LinAlgError, CalibrationError, ValueError) as error:
        text = error.args[-1] if error.args and isinstance(error.args[-1], str) else str(error)
        reason = text if isinstance(error, CalibrationError) else f"{type(error).__name__}: {text}"
        return numerical_failure(accel, temps, reason, model=model)


def _checked_temperature_options(temperature_model: str, temperature_options: TemperatureOptions | None,
                                 temps: np.ndarray | None, model: str) -> TemperatureOptions | None:
    if temperature_model not in TEMPERATURE_MODELS:
        raise CalibrationError(f"temperature_model must be one of {', '.join(TEMPERATURE_MODELS)}, "
                               f"got {temperature_model!r}")
    if temperature_model == "none":
        return None
    if temps is None:
        raise CalibrationError(f"temperature_model {temperature_model} needs temperature_degc (one per pose)")
    if model in REFERENCE_MODELS and temperature_model == "polynomial":
        raise CalibrationError("the polynomial temperature model fits with the sphere models (six, sphere9); "
                               "with reference directions use the segmented one")
    options = temperature_options or TemperatureOptions(model=temperature_model)
    if options.model != temperature_model:
        options = TemperatureOptions(**{**options.__dict__, "model": temperature_model})
    return options


def _checked_pose_sigma(pose_sigma_mps2: ArrayLike, count: int) -> np.ndarray:
    try:
        pose_sigma = np.array(pose_sigma_mps2, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        pose_sigma = np.zeros(0)
    if pose_sigma.shape != (count,) or not np.all(np.isfinite(pose_sigma)) or np.any(pose_sigma < 0):
        raise CalibrationError(f"pose_sigma_mps2 must be {count} finite numbers >= 0 (one per pose)")
    return pose_sigma


def pose_mean_sigma(poses: Sequence[Pose]) -> np.ndarray:
    """1-sigma noise of each pose's mean (raw units): the rms over axes of its samples' spread over
    sqrt(samples); 0 where a pose carries no usable covariance."""
    out = np.zeros(len(poses))
    for i, pose in enumerate(poses):
        with np.errstate(all="ignore"):
            value = float(np.sqrt(np.trace(np.asarray(pose.accel_cov, dtype=float)) / 3.0 / max(int(pose.samples), 1)))
        out[i] = value if np.isfinite(value) else 0.0
    return out


def _with_uncertainty(result: FitResult, accel: np.ndarray, temps: np.ndarray | None, gravity: float) -> FitResult:
    """A sphere fit with its Uncertainty (normal matrix at the solution, residual variance): what the
    sigma gate's advice adds a candidate pose to."""
    c = result.calibration
    if result.uncertainty is not None or c is None or c.model not in SPHERE_MODELS:
        return result
    rows = sphere_rows(c, accel, temps)
    extra = 0 if c.temperature is None else 3 * (len(c.temperature.bias_coefficients)
                                                   + len(c.temperature.scale_coefficients))
    return replace(result, uncertainty=uncertainty_of(c.model, c.bias, c.matrix, gravity, rows,
                                                    result.residuals_mg * MG, rows.shape[1] + extra))
