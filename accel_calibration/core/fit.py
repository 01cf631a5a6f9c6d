"""fit(): the one entry point from pose means to a Calibration, shared by the node, replay, CLI and notebooks.

Bad arguments raise CalibrationError (a ValueError). A fit that cannot be done from good
arguments -- too few poses, no degree of freedom left to judge the fit, poses that leave the model
unobservable, no convergence, overflow or a singular solution -- is reported in the result (success
False, message saying what is missing), never raised: finite poses of the right shape never raise.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration, Quality
from .coverage import (
    CONDITION_LIMIT,
    SAME_DIRECTION_DEG,
    SigmaBounds,
    Uncertainty,
    angular_spread_deg,
    condition_and_inverse,
    describe_missing,
    inverse_normal,
    missing_directions,
    next_orientation,
    scaled_condition_number,
)
from .errors import CalibrationError
from .gauss_newton import LeastSquaresSolution, gauss_newton, gauss_newton_stacked
from .models import MODELS, REFERENCE_MODELS, SPHERE_MODELS, SphereModel, parameter_count, seed_sphere
from .pose import Pose
from .pose_weights import MAX_REWEIGHTS, TAU_TOLERANCE, extra_variance, pose_weights, weighting_applies
from .temperature_models import (
    TEMPERATURE_MODELS,
    TemperatureModel,
    TemperatureOptions,
    ThermalSphereModel,
    blend_weights,
    describe_needs,
    known_blended_drift,
    known_segment_drift,
    room_temperature_poses,
    segment_bounds,
    segment_keys,
    segment_needs,
    sphere_blended_drift,
    sphere_segment_drift,
    temperature_span_problem,
)
from .units import MG, STANDARD_GRAVITY

AXES = "xyz"
_ONES3 = np.ones(3)


@dataclass(frozen=True)
class Sigma:
    """One-sigma uncertainties, from the normal matrix and the residual variance."""

    bias: np.ndarray
    matrix: np.ndarray  # zero where the model fixes the entry
    quadratic: np.ndarray | None = None


@dataclass(frozen=True)
class OutlierOptions:
    """When fit() leaves a pose out as an outlier: its residual against the fit of the other poses (its
    deleted residual) exceeds `threshold_mg` and is as improbable as `k_sigma` Gaussian sigmas given
    the spread those poses predict for it (their residual scatter, floored at the poses' own noise,
    with their degrees of freedom and the pose's leverage). At most `max_fraction` of the poses are
    left out, one at a time, and a pose only when the others still determine the model with a degree
    of freedom. threshold_mg 0 turns it off."""

    threshold_mg: float = 5.0  # well above the few-mg residuals of a clean MEMS session
    k_sigma: float = 5.0
    max_fraction: float = 0.2

    def __post_init__(self) -> None:
        for name, low in (("threshold_mg", 0.0), ("k_sigma", 1.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < low:
                raise CalibrationError(f"outlier {name} must be a number >= {low:g}, got {value!r}")
        if not (isinstance(self.max_fraction, (int, float)) and 0.0 <= self.max_fraction <= 0.5):
            raise CalibrationError(f"outlier max_fraction must be within 0..0.5, got {self.max_fraction!r}")


_DEFAULT_OUTLIER_OPTIONS = OutlierOptions()  # frozen: one instance serves every fit that gives none


@dataclass(frozen=True)
class Outlier:
    """A pose fit() left out: it does not lie on the sphere (or its reference direction) with the rest."""

    index: int  # into the poses given to fit()
    residual_mg: float  # against the fit of the other poses: |a| - g (sphere), |a - g ref| (reference)
    orientation: str  # the face it is nearest, e.g. "x down"
    off: str = "the sphere"

    def describe(self, number: int | None = None) -> str:
        """`number`: how the caller counts its poses (default: the index into fit()'s input)."""
        return (f"pose {self.index if number is None else number} ({self.orientation}, "
                f"{abs(self.residual_mg):.1f} mg off {self.off}) left out as an outlier")


@dataclass(frozen=True)
class FitResult:
    success: bool
    message: str
    model: str
    iterations: int = 0
    calibration: Calibration | None = None
    sigma: Sigma | None = None
    residuals_mg: np.ndarray = field(default_factory=lambda: np.zeros(0))  # of the poses fitted
    cost: float = float("nan")
    condition_number: float = float("nan")
    missing_directions: tuple[str, ...] = ()
    poses: int = 0  # fitted (outliers not counted)
    outliers: tuple[Outlier, ...] = ()  # poses left out, by their index into the input
    uncertainty: Uncertainty | None = None  # sphere models: what the sigma gate and its advice use
    # Leverage of each pose fitted (sphere fits without a temperature model): lets the outlier test
    # see at once that no pose can be one, without forming the Jacobian and its inverse again.
    leverage: np.ndarray | None = field(default=None, repr=False, compare=False)
    # Poses weighted by 1 / (s_i^2 + tau^2) (their own noise given, unequal): tau, the common extra error
    # per pose estimated so that chi^2/dof = 1 (raw units); None for an unweighted fit.
    pose_extra_sigma: float | None = None

    @property
    def outlier_indices(self) -> tuple[int, ...]:
        return tuple(o.index for o in self.outliers)

    def summary(self) -> str:
        """A readable multi-line summary: parameters with +-sigma and residuals in mg."""
        lines = [f"model {self.model}: {'OK' if self.success else 'FAILED'} - {self.message}"]
        lines += [o.describe() for o in self.outliers]
        if self.calibration is None:
            return "\n".join(lines)
        c, s = self.calibration, self.sigma
        # fit() builds every result that has a calibration with its sigma and quality.
        assert s is not None and c.quality is not None
        left_out = f" (and {len(self.outliers)} left out)" if self.outliers else ""
        lines.append(f"poses {self.poses}{left_out}, iterations {self.iterations}, "
                     f"condition number {self.condition_number:.3g}")
        if self.pose_extra_sigma is not None:
            lines.append("poses weighted by their own noise and a common extra error of "
                         f"{self.pose_extra_sigma / MG:.3f} mg per pose (1 / (s_i^2 + tau^2))")
        lines.append(
            "bias b (raw units; m/s^2 for SI input):  "
            + "  ".join(f"{AXES[i]} {c.bias[i]:+.6g} ± {s.bias[i]:.2g}" for i in range(3))
        )
        lines.append("matrix M (a_true = M (a_raw - b)), ± 1 sigma:")
        for i in range(3):
            lines.append(
                "  [" + "  ".join(f"{c.matrix[i, j]:+.7g} ± {s.matrix[i, j]:.2g}" for j in range(3)) + "]"
            )
        if c.quadratic is not None:
            assert s.quadratic is not None  # reference15 reports the quadratic term's sigma with it
            lines.append(
                "quadratic q (s^2/m): "
                + "  ".join(f"{AXES[i]} {c.quadratic[i]:+.4g} ± {s.quadratic[i]:.2g}" for i in range(3))
            )
        lines.append(
            f"residuals: rms {c.quality.residual_rms_mg:.3f} mg, max {c.quality.residual_max_mg:.3f} mg"
        )
        if c.temperature is not None:
            t = c.temperature
            lines.append(f"temperature model {t.kind}: T_ref {t.reference_degc:.1f} degC, calibrated range "
                         f"{t.range_degc[0]:.1f}..{t.range_degc[1]:.1f} degC")
            if t.kind == "polynomial":
                for k, row in enumerate(t.bias_coefficients, start=1):
                    lines.append(f"  bias drift dT^{k}: " + "  ".join(f"{v / MG:+.4g}" for v in row)
                                 + f" mg/degC^{k}")
                for k, row in enumerate(t.scale_coefficients, start=1):
                    lines.append(f"  scale drift dT^{k}: " + "  ".join(f"{v:+.3g}" for v in row) + f" /degC^{k}")
            else:
                lines.append(f"  {len(t.segment_coefficients)} segments, "
                             + ("blended between the temperatures they were learned at" if t.segment_blend
                                else "the one holding the temperature picked")
                             + "; drift l a^2 + m a + n per axis (a raw m/s^2): l mg/g^2, m ppm, n mg")
                for (lo, hi), at, poses, (quad, lin, offset) in zip(
                        t.segment_bounds_degc, t.segment_temperatures_degc, t.segment_poses, t.segment_coefficients):
                    lines.append(f"  {lo:g}..{hi:g} degC (at {at:.1f}, {poses} poses): l "
                                 + " ".join(f"{v * STANDARD_GRAVITY**2 / MG:+.3g}" for v in quad) + "  m "
                                 + " ".join(f"{v * 1e6:+.0f}" for v in lin) + "  n "
                                 + " ".join(f"{v / MG:+.2f}" for v in offset))
        if self.missing_directions:
            lines.append("not covered (fit still observable): " + ", ".join(self.missing_directions))
        return "\n".join(lines)


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
    """
    if pose_sigma_mps2 is None and isinstance(accel_mps2, (list, tuple)) and accel_mps2 \
            and all(isinstance(p, Pose) for p in accel_mps2):
        pose_sigma_mps2 = pose_mean_sigma(accel_mps2)
    accel, gravity, temps, ref = _check_arguments(accel_mps2, model, gravity, temperature_degc, reference, initial)
    outlier_options = _DEFAULT_OUTLIER_OPTIONS if outlier_options is None else outlier_options
    if not isinstance(outlier_options, OutlierOptions):
        raise CalibrationError("outlier_options must be an OutlierOptions or None")
    pose_sigma = None
    if pose_sigma_mps2 is not None:
        try:
            pose_sigma = np.array(pose_sigma_mps2, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            pose_sigma = np.zeros(0)
        if pose_sigma.shape != (len(accel),) or not np.all(np.isfinite(pose_sigma)) or np.any(pose_sigma < 0):
            raise CalibrationError(f"pose_sigma_mps2 must be {len(accel)} finite numbers >= 0 (one per pose)")
    if temperature_model not in TEMPERATURE_MODELS:
        raise CalibrationError(f"temperature_model must be one of {', '.join(TEMPERATURE_MODELS)}, "
                               f"got {temperature_model!r}")
    if temperature_model != "none":
        if temps is None:
            raise CalibrationError(f"temperature_model {temperature_model} needs temperature_degc (one per pose)")
        if model in REFERENCE_MODELS and temperature_model == "polynomial":
            raise CalibrationError("the polynomial temperature model fits with the sphere models (six, sphere9); "
                                   "with reference directions use the segmented one")
        options = temperature_options or TemperatureOptions(model=temperature_model)
        if options.model != temperature_model:
            options = TemperatureOptions(**{**options.__dict__, "model": temperature_model})
    else:
        options = None
    # The arguments are good: from here on every problem is the data's, reported in the result. Overflow
    # and the like are expected on wild data (and checked for), so numpy is not to warn about them.
    def fit_poses(keep: np.ndarray | None) -> FitResult:
        """The fit of the poses kept (all when None): what the outlier test compares against."""
        a = accel if keep is None else accel[keep]
        t = temps if temps is None or keep is None else temps[keep]
        r = ref if ref is None or keep is None else ref[keep]
        s = pose_sigma if pose_sigma is None or keep is None else pose_sigma[keep]
        if options is not None:
            assert t is not None  # checked above: a temperature model needs temperature_degc
            result = _fit_with_temperature(a, t, model, gravity, options, initial, frame_id, r)
        else:
            result = _fit_without_temperature(a, model, gravity, t, r, initial, frame_id, s)
        return _with_uncertainty(result, a, t, gravity)

    try:
        with np.errstate(all="ignore"):
            return _leave_out_outliers(fit_poses, accel, temps, ref, gravity, outlier_options, pose_sigma)
    except (ArithmeticError, np.linalg.LinAlgError, CalibrationError, ValueError) as error:
        text = error.args[-1] if error.args and isinstance(error.args[-1], str) else str(error)
        reason = text if isinstance(error, CalibrationError) else f"{type(error).__name__}: {text}"
        return _numerical_failure(accel, temps, reason, model=model)


def pose_mean_sigma(poses: Sequence[Pose]) -> np.ndarray:
    """1-sigma noise of each pose's mean (raw units): the rms over axes of its samples' spread over
    sqrt(samples); 0 where a pose carries no usable covariance."""
    out = np.zeros(len(poses))
    for i, pose in enumerate(poses):
        with np.errstate(all="ignore"):
            value = float(np.sqrt(np.trace(np.asarray(pose.accel_cov, dtype=float)) / 3.0 / max(int(pose.samples), 1)))
        out[i] = value if np.isfinite(value) else 0.0
    return out


# The outlier test refits without at most this many candidates (largest first) per pose left out: a
# pose the model cannot do without (leverage near 1) looks like one until the refit without it fails.
OUTLIER_CANDIDATES = 3


def _leave_out_outliers(fit_poses: Callable[[np.ndarray | None], FitResult], accel: np.ndarray,
                        temps: np.ndarray | None, ref: np.ndarray | None, gravity: float, options: OutlierOptions,
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
            residuals, leverage = _residuals_and_leverage(current.calibration, keep, accel, temps, ref)
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
    residuals = _pose_residuals_mg(calibration, accel, temps, ref)
    corrected = calibration.apply(accel[left_out], None if temps is None else temps[left_out])
    off = "the sphere" if ref is None else "its reference direction"
    outliers = tuple(Outlier(int(i), float(residuals[i]), _nearest_face(v), off) for i, v in zip(left_out, corrected))
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
    residuals, leverage = _residuals_and_leverage(calibration, keep, accel, temps, ref)
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
    critical = _critical_ratio(options.k_sigma, components, components * dof)
    for index in indices:
        d = abs(float(residuals[index]))
        spread = components * variance * (1.0 + max(float(leverage[index]), 0.0))
        if not (d > options.threshold_mg and d * d > critical * spread):
            return False
    return True


@functools.lru_cache(maxsize=256)
def _critical_ratio(k_sigma: float, components: int, dof: int) -> float:
    """F(components, dof) quantile with the upper tail probability of k_sigma Gaussian sigmas (two-sided)."""
    # Imported here: scipy.stats costs ~0.5 s at import, and only a fit with an outlier candidate needs it.
    from scipy.special import erfc
    from scipy.stats import f as f_distribution

    return float(f_distribution.ppf(1.0 - erfc(k_sigma / np.sqrt(2.0)), components, dof))


def _residuals_and_leverage(calibration: Calibration, keep: np.ndarray, accel: np.ndarray,
                            temps: np.ndarray | None, ref: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Against one fit (of the poses `keep`): every pose's residual (mg) and leverage x (X_k^T X_k)^-1 x^T
    with X_k the design (Jacobian) rows of the poses kept: for a pose kept its leverage, for a pose
    left out how much its prediction's variance exceeds one pose's. The reference models' per-axis
    designs differ (reference15): the largest."""
    residuals = _pose_residuals_mg(calibration, accel, temps, ref)
    if ref is None:
        designs = [_sphere_rows(calibration, accel, temps)]
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


def _pose_residuals_mg(calibration: Calibration, accel: np.ndarray, temps: np.ndarray | None,
                       ref: np.ndarray | None) -> np.ndarray:
    """Each pose's residual against a calibration: |a| - g on the sphere, |a - g ref| with a reference."""
    corrected = calibration.apply(accel, temps)
    if ref is None:
        result: np.ndarray = (np.linalg.norm(corrected, axis=1) - calibration.gravity) / MG
    else:
        result = np.linalg.norm(corrected - calibration.gravity * ref, axis=1) / MG
    return result


def _sphere_rows(calibration: Calibration, accel: np.ndarray, temps: np.ndarray | None) -> np.ndarray:
    """Jacobian rows of the sphere residuals at a calibration's b and M, one per pose. With a temperature
    model, of the poses corrected to the reference temperature (the temperature terms left out)."""
    model = SphereModel(calibration.model)
    c = calibration
    if c.temperature is not None and temps is not None:
        accel = c.bias + np.linalg.solve(c.matrix, c.apply(accel, temps).T).T
    _, rows = model.residual_and_jacobian(model.pack(c.bias, c.matrix), accel, c.gravity)
    return rows


def _nearest_face(corrected: np.ndarray) -> str:
    axis = int(np.argmax(np.abs(corrected)))
    return f"{AXES[axis]} {'up' if corrected[axis] > 0 else 'down'}"


def _with_uncertainty(result: FitResult, accel: np.ndarray, temps: np.ndarray | None, gravity: float) -> FitResult:
    """A sphere fit with its Uncertainty (normal matrix at the solution, residual variance): what the
    sigma gate's advice adds a candidate pose to."""
    c = result.calibration
    if result.uncertainty is not None or c is None or c.model not in SPHERE_MODELS:
        return result
    rows = _sphere_rows(c, accel, temps)
    extra = 0 if c.temperature is None else 3 * (len(c.temperature.bias_coefficients)
                                                   + len(c.temperature.scale_coefficients))
    return replace(result, uncertainty=_uncertainty(c.model, c.bias, c.matrix, gravity, rows,
                                                    result.residuals_mg * MG, rows.shape[1] + extra))


def _uncertainty(model: str, bias: np.ndarray, matrix: np.ndarray, gravity: float, rows: np.ndarray,
                 residuals: np.ndarray, size: int, normal: np.ndarray | None = None) -> Uncertainty | None:
    """`normal`: rows^T rows when the caller has it already."""
    dof = len(residuals) - size
    variance = float(residuals @ residuals) / dof if dof > 0 else float("nan")
    if normal is None:
        normal = rows.T @ rows
    if not np.isfinite(normal).all():
        return None
    return Uncertainty(model, bias, matrix, gravity, normal, variance)


# Beyond this, sums of squares of the poses (cost, normal matrix) overflow double precision.
LARGEST_VALUE = 1e150


def _fit_without_temperature(accel: np.ndarray, model: str, gravity: float, temps: np.ndarray | None,
                             ref: np.ndarray | None, initial: Calibration | None, frame_id: str,
                             pose_sigma: np.ndarray | None = None) -> FitResult:
    n = len(accel)
    # Reference models are separate linear fits per axis (4 or 5 unknowns each), sphere models one joint fit.
    size = {"reference12": 4, "reference15": 5}.get(model, parameter_count(model))
    if n < size:
        return FitResult(False, f"model {model} needs at least {size} poses, got {n}", model, poses=n)
    largest = float(np.abs(accel).max())
    if largest > LARGEST_VALUE:
        row = int(np.argmax(np.abs(accel).max(axis=1)))
        return FitResult(False, f"pose {row} reads {accel[row].tolist()}: values beyond {LARGEST_VALUE:.0e} overflow "
                         "the fit; drop the corrupt pose or give the data in smaller units", model, poses=n)
    ref_temperature = None if temps is None else float(temps.mean())
    if model in SPHERE_MODELS:
        first = _fit_sphere(accel, model, gravity, initial, ref_temperature, frame_id)
        if not weighting_applies(pose_sigma) or first.calibration is None:
            return first
        assert pose_sigma is not None
        return _reweighted(first, pose_sigma, n - parameter_count(model), lambda w, start: _fit_sphere(
            accel, model, gravity, None, ref_temperature, frame_id, weights=w, start=start))
    assert ref is not None  # _check_arguments requires reference directions for the reference models
    first = _fit_reference(accel, ref, model, gravity, ref_temperature, frame_id)
    if not weighting_applies(pose_sigma) or first.calibration is None:
        return first
    assert pose_sigma is not None
    return _reweighted(first, pose_sigma, 3 * (n - size), lambda w, _: _fit_reference(
        accel, ref, model, gravity, ref_temperature, frame_id, weights=w))


def _reweighted(first: FitResult, pose_sigma: np.ndarray, dof: int,
                fit_with: Callable[[np.ndarray, Calibration], FitResult]) -> FitResult:
    """The fit with each pose weighted by 1 / (s_i^2 + tau^2), from the unweighted one (`first`): tau^2 from
    its residuals so that chi^2 = dof, then the weighted refit, its residuals, tau^2 again, until tau^2
    settles (Paule-Mandel). Residuals are compared in raw units: the corrected ones (mg; a reference fit's
    are the norm of the pose's three, dof counting all three) over the correction's gain. A weighted refit
    that fails leaves the unweighted fit."""
    variance = pose_sigma * pose_sigma
    current, tau2 = first, -1.0
    for _ in range(MAX_REWEIGHTS):
        calibration = current.calibration
        assert calibration is not None  # only successful fits are reweighted
        # rms of M's row norms: what pose_mean_sigma's trace / 3 of isotropic noise becomes through M.
        gain = math.sqrt(float(np.sum(calibration.matrix**2)) / 3.0)
        squared = (current.residuals_mg * (MG / gain)) ** 2
        new_tau2 = extra_variance(squared, variance, dof)
        if abs(new_tau2 - tau2) <= TAU_TOLERANCE * (new_tau2 + float(np.median(variance))):
            break
        tau2 = new_tau2
        weighted = fit_with(pose_weights(variance, tau2), calibration)
        if not weighted.success or weighted.calibration is None:
            return first
        current = replace(weighted, pose_extra_sigma=math.sqrt(tau2))
    return current


def _numerical_failure(accel: np.ndarray, temps: np.ndarray | None, reason: str, *, model: str,
                       **fields: Any) -> FitResult:
    """A failed result for a fit that broke down numerically, naming the pose most likely to blame."""
    n = len(accel)
    message = f"numerical failure fitting model {model} to {n} poses ({reason})"
    if n:
        row = int(np.argmax(np.abs(accel).max(axis=1)))
        message += f": check the poses for a corrupt or outlying one (the largest is pose {row}, {accel[row].tolist()})"
        if temps is not None:
            message += f" and the temperatures ({float(temps.min()):.4g}..{float(temps.max()):.4g} degC)"
    fields.setdefault("poses", n)
    return FitResult(False, message, model, **fields)


def _no_degree_of_freedom(n: int, description: str, model: str, more: str = "orientation",
                          **fields: Any) -> FitResult:
    fields.setdefault("poses", n)
    return FitResult(False, f"{n} poses for the {description} leave no degree of freedom to judge the fit: "
                     f"hold at least one more {more}", model, **fields)


def _broken_reason(broken: str, solution: LeastSquaresSolution) -> str:
    if solution.iterations == 0:  # the solver could not start: its message says why
        return solution.message
    return f"{broken} not finite after {solution.iterations} iterations"


def _not_finite(**arrays: np.ndarray | None) -> str | None:
    """Name of the first array with a NaN or infinite entry (None when all are finite)."""
    for name, array in arrays.items():
        if array is not None and not np.isfinite(array).all():
            return name.replace("_", " ")
    return None


def _quality(residuals_mg: np.ndarray, condition: float) -> Quality:
    return Quality(
        residual_rms_mg=math.sqrt(float(residuals_mg.dot(residuals_mg)) / len(residuals_mg)),
        residual_max_mg=float(np.abs(residuals_mg).max()),
        poses=len(residuals_mg),
        condition_number=float(condition),
    )


def _standard_deviations(solution: LeastSquaresSolution, n: int) -> np.ndarray:
    """1-sigma of each parameter: residual variance (cost over the degrees of freedom) times the
    inverse Gauss-Newton normal matrix. NaN when there are no degrees of freedom left."""
    size = len(solution.x)
    dof = n - size
    variance = 2.0 * solution.cost / dof if dof > 0 else float("nan")
    try:
        covariance = variance * np.linalg.inv(solution.jacobian.T @ solution.jacobian)
    except np.linalg.LinAlgError:
        covariance = np.full((size, size), np.nan)
    stds: np.ndarray = np.sqrt(np.abs(np.diag(covariance)))
    return stds


def _fit_sphere(accel: np.ndarray, name: str, gravity: float, initial: Calibration | None,
                ref_temperature: float | None, frame_id: str, weights: np.ndarray | None = None,
                start: Calibration | None = None) -> FitResult:
    """weights: of each pose's residual (mean 1), or None: each pose alike. start: a fit of this model to
    these poses to start from as it is (M already in the model's form: no projection)."""
    model = SphereModel(name)
    n = len(accel)
    # The poses as rows of x, y and z: what the residual function and the direction checks work on
    # (whole contiguous rows instead of strided columns).
    accel_t = np.ascontiguousarray(accel.T)
    if start is not None:
        bias0, matrix0 = start.bias, start.matrix
        x0 = model.pack(bias0, matrix0)
    elif initial is not None:
        bias0, matrix0 = initial.bias, initial.matrix
        x0 = model.project(bias0, matrix0)
    else:
        bias0, matrix0 = seed_sphere(accel, gravity, cross_axis=name == "sphere9")
        # The seed's M is diagonal, or lower-triangular for sphere9, with a positive diagonal: already in
        # the model's form (what project's QR would return, without it).
        x0 = np.concatenate((bias0, matrix0.ravel()[model.flat_index]))
    directions_t = np.dot(matrix0, accel_t - bias0[:, None])
    lengths = np.sqrt(np.dot(_ONES3, directions_t * directions_t))
    if not lengths.min() > 0:  # NaN too
        row = int(np.flatnonzero(~(lengths > 0))[0])
        return FitResult(False, f"pose {row} reads {accel[row].tolist()}, exactly the starting estimate of the bias, "
                         "so it has no direction: drop it if it is a dropped or zeroed sample", name, poses=n)
    directions_t /= lengths
    if not math.isfinite(float(directions_t.sum())):  # unit vectors: the sum is finite unless an entry is not
        return _numerical_failure(accel, None, "the starting point overflows", model=name)
    directions = directions_t.T
    missing = tuple(missing_directions(directions))
    spread = angular_spread_deg(directions)
    if spread < SAME_DIRECTION_DEG:
        return FitResult(
            False,
            f"all {n} poses point the same way (within {spread:.1f} deg): "
            f"turn the sensor ({describe_missing(list(missing))})",
            name,
            missing_directions=missing,
            poses=n,
        )
    if weights is None:
        solution = gauss_newton_stacked(lambda p: model.stacked(p, accel_t, gravity), x0)
        residuals_mg = solution.residuals / MG
    else:
        # Rows of J and r scaled by sqrt(w): the solver minimises sum w r^2, and its normal matrix, cost and
        # leverages are the weighted ones, so sigma below is (J^T W J)^-1 times chi^2/dof.
        root = np.sqrt(weights)
        solution = gauss_newton_stacked(lambda p: model.stacked(p, accel_t, gravity) * root, x0)
        residuals_mg = solution.residuals / root / MG
    # One normal matrix (the solver's, when it formed it at the solution) for the condition number,
    # sigma, the uncertainty and the outlier leverages.
    jacobian = solution.jacobian
    normal = solution.normal if solution.normal is not None else jacobian.T @ jacobian
    condition, inverse = condition_and_inverse(normal)
    common: dict[str, Any] = dict(
        model=name,
        iterations=solution.iterations,
        residuals_mg=residuals_mg,
        cost=solution.cost,
        condition_number=condition,
        missing_directions=missing,
        poses=n,
    )
    # Overflow before observability: an infinite condition number from it says nothing about coverage.
    # Finite sums of squares (x, the cost, the normal matrix's diagonal) prove every entry finite at
    # once (the solver forms its normal matrix only at a point where they are); only otherwise is each
    # array checked to name the one that is not.
    x = solution.x
    finite = (math.isfinite(float(x.dot(x))) and math.isfinite(solution.cost)
              and (solution.normal is not None or math.isfinite(float(normal.trace()))))
    broken = None if finite else _not_finite(parameters=x, residuals=solution.residuals, jacobian=jacobian)
    if broken:
        return _numerical_failure(accel, None, _broken_reason(broken, solution), **common)
    # Observability first: a fit that wanders along an unobservable direction also fails to converge,
    # and "turn x down" helps the person more than "did not converge".
    if condition > CONDITION_LIMIT:
        # The normal matrix still says which orientation would pin down what is loose.
        bias_now, matrix_now = model.unpack(solution.x)
        uncertainty = _uncertainty(name, bias_now, matrix_now, gravity, solution.jacobian, solution.residuals,
                                   model.size)
        advice = None if uncertainty is None else next_orientation(uncertainty, SigmaBounds())
        return FitResult(
            False,
            f"poses do not constrain model {name} (condition number {condition:.3g} > {CONDITION_LIMIT:.0g}): "
            + describe_missing(list(missing)) + ("" if advice is None else f"; {advice.text} would help most"),
            uncertainty=uncertainty,
            **common,
        )
    if n <= model.size:
        return _no_degree_of_freedom(n, f"{model.size} parameters of model {name}", **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    bias, matrix = model.unpack(solution.x)
    m00, m11, m22 = matrix.diagonal().tolist()
    if not m00 * m11 * m22 > 0:  # det(M): the sphere models' M is lower-triangular
        return FitResult(False, "fit converged to a mirrored solution; check the poses", **common)
    if inverse is None:  # an infinite condition number fails the observability check above
        return _numerical_failure(accel, None, "uncertainties not finite: the normal matrix is singular", **common)
    stds = np.sqrt(np.abs(inverse.diagonal()) * (2.0 * solution.cost / (n - model.size)))
    if not all(map(math.isfinite, stds.tolist())):
        return _numerical_failure(accel, None, "uncertainties not finite: the normal matrix is singular", **common)
    _, matrix_sigma = model.unpack(stds)
    sigma = Sigma(bias=stds[:3], matrix=matrix_sigma)
    residuals = solution.residuals
    # The normal matrix is finite (checked above): the Uncertainty needs no further test.
    uncertainty = Uncertainty(name, bias, matrix, gravity, normal, float(residuals.dot(residuals)) / (n - model.size))
    # Leverage h_i = J_i (J^T J)^-1 J_i^T of each pose, from the solver's J^T (rows of parameters).
    jacobian_t = jacobian.T
    leverage = np.einsum("ji,ji->i", np.dot(inverse, jacobian_t), jacobian_t)
    # Every array here was just computed and found finite (x, stds): validated once.
    calibration = Calibration.from_fit(
        bias=bias,
        matrix=matrix,
        model=name,
        gravity=gravity,
        bias_sigma=sigma.bias,
        matrix_sigma=sigma.matrix,
        quality=_quality(residuals_mg, condition),
        frame_id=frame_id,
        reference_temperature_degc=ref_temperature,
    )
    return FitResult(True, solution.message, calibration=calibration, sigma=sigma, uncertainty=uncertainty,
                     leverage=leverage, **common)


def _fit_reference(accel: np.ndarray, directions: np.ndarray, name: str, gravity: float,
                   ref_temperature: float | None, frame_id: str, weights: np.ndarray | None = None) -> FitResult:
    """Forward model per axis j: a_raw_j = b_j + sum_k S_jk a_k (+ q_j a_j^2), linear least squares
    (weighted by `weights` of the poses, mean 1, when given: sigma from (X^T W X)^-1 times chi^2/dof)."""
    n = len(accel)
    true = gravity * directions
    quadratic = name == "reference15"
    k = 5 if quadratic else 4
    missing = tuple(missing_directions(directions))
    coefficients = np.zeros((3, k))
    covariances = np.zeros((3, k, k))
    residual_raw = np.zeros((n, 3))
    condition = 0.0
    for j in range(3):
        columns = [np.ones(n), true[:, 0], true[:, 1], true[:, 2]]
        if quadratic:
            columns.append(true[:, j] ** 2)
        design = np.column_stack(columns)
        condition = max(condition, scaled_condition_number(design))
        if not np.isfinite(condition) or condition > 1e10 or np.linalg.matrix_rank(design) < k:
            return FitResult(
                False,
                f"reference directions do not determine model {name}: " + describe_missing(list(missing)),
                name,
                condition_number=condition,
                missing_directions=missing,
                poses=n,
            )
        if n <= k:
            return _no_degree_of_freedom(n, f"{k} parameters per axis of model {name}", name,
                                         condition_number=condition, missing_directions=missing)
        dof = n - k
        if weights is None:
            solution, *_ = np.linalg.lstsq(design, accel[:, j], rcond=None)
            coefficients[j] = solution
            residual_raw[:, j] = accel[:, j] - design @ solution
            variance = float(residual_raw[:, j] @ residual_raw[:, j]) / dof
            covariances[j] = variance * np.linalg.inv(design.T @ design)
        else:
            root = np.sqrt(weights)
            solution, *_ = np.linalg.lstsq(design * root[:, None], accel[:, j] * root, rcond=None)
            coefficients[j] = solution
            residual_raw[:, j] = accel[:, j] - design @ solution
            variance = float(weights @ residual_raw[:, j] ** 2) / dof
            covariances[j] = variance * np.linalg.inv((design * weights[:, None]).T @ design)
    bias = coefficients[:, 0]
    forward = coefficients[:, 1:4]
    q = coefficients[:, 4] if quadratic else None
    broken = _not_finite(coefficients=coefficients, covariances=covariances)
    if broken:
        return _numerical_failure(accel, None, f"{broken} not finite", model=name, condition_number=condition,
                                  missing_directions=missing)
    # Singular relative to its own rows (as Calibration checks): data in any units (counts, 1e-6 g) fit.
    row_size = np.linalg.norm(forward, axis=1)
    if not (np.all(row_size > 0) and abs(np.linalg.det(forward / row_size[:, None])) >= 1e-12):
        return _numerical_failure(accel, None, "the fitted scale matrix is singular", model=name,
                                  condition_number=condition, missing_directions=missing)
    matrix = np.linalg.inv(forward)
    # sigma of M = S^-1 by first-order propagation: dM = -M dS M; rows of S are independent fits.
    matrix_var = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            for j in range(3):
                grad = -matrix[a, j] * matrix[:, b]  # d M_ab / d S_jk for k = 0..2
                matrix_var[a, b] += grad @ covariances[j, 1:4, 1:4] @ grad
    stds = np.sqrt(np.abs(np.array([np.diag(c) for c in covariances])))
    broken = _not_finite(matrix=matrix, uncertainties=stds, matrix_uncertainties=matrix_var)
    if broken:
        return _numerical_failure(accel, None, f"{broken} not finite", model=name, condition_number=condition,
                                  missing_directions=missing)
    sigma = Sigma(bias=stds[:, 0], matrix=np.sqrt(matrix_var), quadratic=stds[:, 4] if quadratic else None)
    calibration = Calibration(
        bias=bias,
        matrix=matrix,
        model=name,
        gravity=gravity,
        quadratic=q,
        bias_sigma=sigma.bias,
        matrix_sigma=sigma.matrix,
        quality=None,
        frame_id=frame_id,
        reference_temperature_degc=ref_temperature,
    )
    errors = calibration.apply(accel) - true
    residuals_mg = np.linalg.norm(errors, axis=1) / MG
    if _not_finite(residuals=residuals_mg):
        return _numerical_failure(accel, None, "residuals not finite", model=name, condition_number=condition,
                                  missing_directions=missing)
    calibration = calibration.replace(quality=_quality(residuals_mg, condition))
    return FitResult(
        True,
        "linear least squares",
        name,
        iterations=1,
        calibration=calibration,
        sigma=sigma,
        residuals_mg=residuals_mg,
        cost=0.5 * float(np.sum(residual_raw**2) if weights is None else weights @ np.sum(residual_raw**2, axis=1)),
        condition_number=condition,
        missing_directions=missing,
        poses=n,
    )


def _fit_segmented(accel: np.ndarray, temps: np.ndarray, ref: np.ndarray | None, name: str, gravity: float,
                   options: TemperatureOptions, initial: Calibration | None, frame_id: str) -> FitResult:
    """The seed paper's segmented model: the room-temperature calibration from the poses near T_ref (else
    near the temperature most poses share), then per segment the drift (l, m, n) of each axis against it:
    observed directly with known orientations (a linear fit per axis), on the sphere without."""
    n = len(accel)
    width = options.segment_width_degc
    low_degc, high_degc = float(temps.min()), float(temps.max())
    # Each segment needs several poses: more segments than poses means a corrupt temperature, and
    # would have the loop below lay out that many segments.
    spanned = segment_keys(np.array([high_degc]), width)[0] - segment_keys(np.array([low_degc]), width)[0] + 1
    if not spanned <= n:
        return FitResult(False, f"temperatures {low_degc:.4g}..{high_degc:.4g} degC span {spanned:.3g} segments of "
                         f"{width:g} degC, more than the {n} poses can fill: check the temperatures for a corrupt "
                         "value", name, poses=n)
    keys = segment_keys(temps, width)
    occupied = np.unique(keys)
    in_base = room_temperature_poses(temps, options)
    band = f"within {width / 4:g} degC of " + (f"{options.reference_degc:g} degC" if options.reference_degc is not None
                                                 else "the room temperature")
    if not in_base.any():
        return FitResult(False, f"no poses {band}: hold the room-temperature poses there, or give another "
                         "reference temperature", name, poses=n)
    reference_degc = float(temps[in_base].mean())
    base_key = float(segment_keys(np.array([reference_degc]), width)[0])
    base = fit(accel[in_base], model=name, gravity=gravity, reference=None if ref is None else ref[in_base],
               initial=initial, frame_id=frame_id)
    if not base.success or base.calibration is None:  # a successful fit always carries its calibration
        return FitResult(False, f"room-temperature calibration from the {int(in_base.sum())} poses at "
                         f"{reference_degc:.1f} degC: {base.message}", name, poses=n,
                         missing_directions=base.missing_directions)
    room = base.calibration
    corrected = room.apply(accel)
    known = ref is not None
    if known:
        assert ref is not None
        directions, true = ref, gravity * ref
    else:
        directions, true = corrected / np.linalg.norm(corrected, axis=1)[:, None], None
    bounds, anchors, coefficients, learned_poses, refused = [], [], [], [], []
    learned = np.zeros(n, dtype=bool)
    for key in occupied:
        inside = keys == key
        lo, hi = segment_bounds(float(key), width)
        here = f"segment {lo:g}..{hi:g} degC ({int(inside.sum())} poses at {float(temps[inside].mean()):.1f} degC)"
        needs = segment_needs(directions[inside], known, options.min_poses_per_segment)
        if key == base_key and (needs or (not known and in_base[inside].all())):
            # The room-temperature calibration stands for its own segment: no drift against itself (on the
            # sphere, poses spent on the calibration have none left to show; with known orientations the
            # quadratic is kept when determined).
            q = np.zeros((3, 3))
        elif needs:
            refused.append(f"{here} cannot be determined: hold {describe_needs(needs)}")
            continue
        elif true is not None:
            q, _ = known_segment_drift(accel[inside], true[inside] - corrected[inside])
        else:
            solution = sphere_segment_drift(accel[inside], corrected[inside], gravity)
            if not solution.success or _not_finite(drift=solution.x):
                refused.append(f"{here}: its drift fit failed ({solution.message})")
                continue
            q = solution.x.reshape(3, 3)
        bounds.append((lo, hi))
        anchors.append(float(temps[inside].mean()))
        coefficients.append(q)
        learned_poses.append(int(inside.sum()))
        learned |= inside
    if refused and options.every_segment:
        return FitResult(False, "; ".join(refused), name, poses=n, missing_directions=base.missing_directions)
    if options.segment_blend and len(bounds) > 1:
        # Each segment alone is the paper's fit, and the least squares of the picked model. The blended one
        # is fitted as applied: every pose at its own temperature, between its neighbouring segments (the
        # same answer when each segment's poses share one temperature).
        weights = blend_weights(temps[learned], np.array(anchors))
        if true is not None:
            coefficients = list(known_blended_drift(accel[learned], (true - corrected)[learned], weights))
        else:
            free = np.array([not (q == 0).all() for q in coefficients])  # the room segment's drift stays zero
            solution = sphere_blended_drift(accel[learned], corrected[learned], gravity, weights,
                                            np.array(coefficients), free)
            if not solution.success or _not_finite(drift=solution.x):
                return FitResult(False, f"the blended segment fit failed ({solution.message}); "
                                 "fit with segment_blend off", name, poses=n)
            joint = np.array(coefficients)
            joint[free] = solution.x.reshape(-1, 3, 3)
            coefficients = list(joint)
    if _not_finite(segment_coefficients=np.array(coefficients)):
        return _numerical_failure(accel, temps, "segment drift coefficients not finite", model=name)
    temperature = TemperatureModel(
        "segmented", reference_degc, (float(temps[learned].min()), float(temps[learned].max())),
        segment_bounds_degc=np.array(bounds), segment_temperatures_degc=np.array(anchors),
        segment_coefficients=np.array(coefficients),
        segment_poses=tuple(learned_poses), segment_blend=options.segment_blend)
    calibration = room.replace(temperature=temperature, reference_temperature_degc=temperature.reference_degc)
    # Judged on the poses the model describes; those of a segment not learned yet are reported, not fitted.
    fitted = calibration.apply(accel[learned], temps[learned])
    if true is not None:
        residuals_mg = np.linalg.norm(fitted - true[learned], axis=1) / MG
    else:
        residuals_mg = (np.linalg.norm(fitted, axis=1) - gravity) / MG
    if _not_finite(residuals=residuals_mg):
        return _numerical_failure(accel, temps, "residuals not finite", model=name)
    calibration = calibration.replace(quality=_quality(residuals_mg, base.condition_number))
    message = (f"segmented temperature model: {len(bounds)} segment{'s' if len(bounds) > 1 else ''} learned "
               f"({', '.join(temperature.segment_names())}; room temperature {reference_degc:.1f} degC)")
    if refused:
        message += "; not yet: " + "; ".join(refused)
    return FitResult(True, message, name, iterations=base.iterations, calibration=calibration, sigma=base.sigma,
                     residuals_mg=residuals_mg, cost=0.5 * float(np.sum((residuals_mg * MG) ** 2)),
                     condition_number=base.condition_number, missing_directions=base.missing_directions, poses=n)


def _fit_with_temperature(accel: np.ndarray, temps: np.ndarray, name: str, gravity: float,
                          options: TemperatureOptions, initial: Calibration | None, frame_id: str,
                          ref: np.ndarray | None = None) -> FitResult:
    n = len(accel)
    size = {"reference12": 4, "reference15": 5}.get(name, parameter_count(name))
    if n < size:
        return FitResult(False, f"model {name} needs at least {size} poses, got {n}", name, poses=n)
    problem = temperature_span_problem(temps, options)
    if problem is not None:
        return FitResult(False, problem, name, poses=n)
    if options.model == "segmented":
        return _fit_segmented(accel, temps, ref, name, gravity, options, initial, frame_id)
    reference_degc = options.reference_degc if options.reference_degc is not None else float(np.median(temps))
    span = (float(temps.min()), float(temps.max()))

    # Polynomial: bias and scale drift jointly with M and b, started from the temperature-blind fit.
    model = ThermalSphereModel(SphereModel(name), options.bias_order, options.scale_order, reference_degc)
    described = (f"model {name} with a polynomial temperature model (bias order {options.bias_order}, "
                 f"scale order {options.scale_order})")
    if n < model.size:
        return FitResult(False, f"{described} needs at least {model.size} poses, got {n}", name, poses=n)
    base = fit(accel, model=name, gravity=gravity, initial=initial, frame_id=frame_id)
    if not base.success or base.calibration is None:  # a successful fit always carries its calibration
        return FitResult(False, base.message, name, poses=n, missing_directions=base.missing_directions)
    solution = gauss_newton(lambda p: model.residual_and_jacobian(p, accel, temps, gravity),
                            model.pack(base.calibration.bias, base.calibration.matrix))
    condition = scaled_condition_number(solution.jacobian)
    residuals_mg = solution.residuals / MG
    common: dict[str, Any] = dict(model=name, iterations=solution.iterations, residuals_mg=residuals_mg,
                                  cost=solution.cost, condition_number=condition,
                                  missing_directions=base.missing_directions, poses=n)
    broken = _not_finite(parameters=solution.x, residuals=solution.residuals, jacobian=solution.jacobian)
    if broken:
        return _numerical_failure(accel, temps, _broken_reason(broken, solution), **common)
    if condition > CONDITION_LIMIT * 100:  # temperature terms are smaller and more correlated by nature
        return FitResult(False, f"poses do not separate the temperature terms (condition number {condition:.3g}): "
                         "hold several orientations at each temperature", **common)
    if n <= model.size:
        return _no_degree_of_freedom(n, f"{model.size} parameters of {described}", more="pose", **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    bias, matrix, c, d = model.unpack(solution.x)
    if not np.linalg.det(matrix) > 0:
        return FitResult(False, "fit converged to a mirrored solution; check the poses", **common)
    stds = _standard_deviations(solution, n)
    if _not_finite(uncertainties=stds):
        return _numerical_failure(accel, temps, "uncertainties not finite: the normal matrix is singular", **common)
    _, matrix_sigma = model.base.unpack(stds[: model.base.size])
    sigma = Sigma(bias=stds[:3], matrix=matrix_sigma)
    temperature = TemperatureModel("polynomial", reference_degc, span, bias_coefficients=c, scale_coefficients=d)
    _, scale = temperature.bias_and_scale(np.linspace(span[0], span[1], 101))
    if not np.all(scale > 0):
        return FitResult(False, "the fitted scale drift reaches zero within the calibrated temperature range "
                         f"{span[0]:.4g}..{span[1]:.4g} degC: check the temperatures, or fit with a lower scale order",
                         **common)
    calibration = Calibration(
        bias=bias, matrix=matrix, model=name, gravity=gravity, bias_sigma=sigma.bias, matrix_sigma=sigma.matrix,
        quality=_quality(residuals_mg, condition), frame_id=frame_id, reference_temperature_degc=reference_degc,
        temperature=temperature,
    )
    return FitResult(True, solution.message, calibration=calibration, sigma=sigma, **common)
