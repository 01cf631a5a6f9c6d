"""fit(): the one entry point from pose means to a Calibration, shared by the node, replay, CLI and notebooks.

Bad arguments raise CalibrationError (a ValueError). A fit that cannot be done from good
arguments -- too few poses, no degree of freedom left to judge the fit, poses that leave the model
unobservable, no convergence, overflow or a singular solution -- is reported in the result (success
False, message saying what is missing), never raised: finite poses of the right shape never raise.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .calibration import MG, STANDARD_GRAVITY, Calibration, Quality
from .coverage import (
    CONDITION_LIMIT,
    SAME_DIRECTION_DEG,
    angular_spread_deg,
    describe_missing,
    missing_directions,
    scaled_condition_number,
)
from .errors import CalibrationError
from .gauss_newton import LeastSquaresSolution, gauss_newton
from .models import MODELS, REFERENCE_MODELS, SPHERE_MODELS, SphereModel, parameter_count, seed_sphere
from .pose import Pose
from .temperature_models import (
    TEMPERATURE_MODELS,
    TemperatureModel,
    TemperatureOptions,
    ThermalSphereModel,
    fit_segmented_drift,
    temperature_span_problem,
)

AXES = "xyz"


@dataclass(frozen=True)
class Sigma:
    """One-sigma uncertainties, from the normal matrix and the residual variance."""

    bias: np.ndarray
    matrix: np.ndarray  # zero where the model fixes the entry
    quadratic: np.ndarray | None = None


@dataclass(frozen=True)
class FitResult:
    success: bool
    message: str
    model: str
    iterations: int = 0
    calibration: Calibration | None = None
    sigma: Sigma | None = None
    residuals_mg: np.ndarray = field(default_factory=lambda: np.zeros(0))
    cost: float = float("nan")
    condition_number: float = float("nan")
    missing_directions: tuple[str, ...] = ()
    poses: int = 0

    def summary(self) -> str:
        """A readable multi-line summary: parameters with +-sigma and residuals in mg."""
        lines = [f"model {self.model}: {'OK' if self.success else 'FAILED'} - {self.message}"]
        if self.calibration is None:
            return "\n".join(lines)
        c, s = self.calibration, self.sigma
        # fit() builds every result that has a calibration with its sigma and quality.
        assert s is not None and c.quality is not None
        lines.append(f"poses {self.poses}, iterations {self.iterations}, condition number {self.condition_number:.3g}")
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
                    lines.append(f"  bias drift dT^{k}: " + "  ".join(f"{v / 9.80665e-3:+.4g}" for v in row)
                                 + f" mg/degC^{k}")
                for k, row in enumerate(t.scale_coefficients, start=1):
                    lines.append(f"  scale drift dT^{k}: " + "  ".join(f"{v:+.3g}" for v in row) + f" /degC^{k}")
            else:
                width = t.segment_edges_degc[1] - t.segment_edges_degc[0]
                lines.append(f"  {len(t.segment_coefficients)} segments of {width:g} degC")
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
    if not np.all(np.isfinite(array)):
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
) -> FitResult:
    """Fit a calibration to static pose means.

    accel_mps2: N x 3 mean raw accelerations of static poses (or a list of Pose). Any consistent raw
    unit works (counts too); the corrected output is in m/s^2 scaled to `gravity`.
    reference: N x 3 directions of the gravity reaction in the sensor frame (reference models only).
    initial: warm start for the sphere models (e.g. the calibration in force).
    temperature_model: "none", "polynomial" or "segmented" (sphere models; needs temperature_degc);
    temperature_options: orders, segment width, minimum span, T_ref (TemperatureOptions).
    """
    accel, gravity, temps, ref = _check_arguments(accel_mps2, model, gravity, temperature_degc, reference, initial)
    if temperature_model not in TEMPERATURE_MODELS:
        raise CalibrationError(f"temperature_model must be one of {', '.join(TEMPERATURE_MODELS)}, "
                               f"got {temperature_model!r}")
    if temperature_model != "none":
        if temps is None:
            raise CalibrationError(f"temperature_model {temperature_model} needs temperature_degc (one per pose)")
        if model in REFERENCE_MODELS:
            raise CalibrationError("temperature models fit with the sphere models (six, sphere9)")
        options = temperature_options or TemperatureOptions(model=temperature_model)
        if options.model != temperature_model:
            options = TemperatureOptions(**{**options.__dict__, "model": temperature_model})
    else:
        options = None
    # The arguments are good: from here on every problem is the data's, reported in the result. Overflow
    # and the like are expected on wild data (and checked for), so numpy is not to warn about them.
    try:
        with np.errstate(all="ignore"):
            if options is not None:
                assert temps is not None  # checked above: a temperature model needs temperature_degc
                return _fit_with_temperature(accel, temps, model, gravity, options, initial, frame_id)
            return _fit_without_temperature(accel, model, gravity, temps, ref, initial, frame_id)
    except (ArithmeticError, np.linalg.LinAlgError, CalibrationError, ValueError) as error:
        text = error.args[-1] if error.args and isinstance(error.args[-1], str) else str(error)
        reason = text if isinstance(error, CalibrationError) else f"{type(error).__name__}: {text}"
        return _numerical_failure(accel, temps, reason, model=model)


# Beyond this, sums of squares of the poses (cost, normal matrix) overflow double precision.
LARGEST_VALUE = 1e150


def _fit_without_temperature(accel: np.ndarray, model: str, gravity: float, temps: np.ndarray | None,
                             ref: np.ndarray | None, initial: Calibration | None, frame_id: str) -> FitResult:
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
        return _fit_sphere(accel, model, gravity, initial, ref_temperature, frame_id)
    assert ref is not None  # _check_arguments requires reference directions for the reference models
    return _fit_reference(accel, ref, model, gravity, ref_temperature, frame_id)


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
        if array is not None and not np.all(np.isfinite(array)):
            return name.replace("_", " ")
    return None


def _quality(residuals_mg: np.ndarray, condition: float) -> Quality:
    return Quality(
        residual_rms_mg=float(np.sqrt(np.mean(residuals_mg**2))),
        residual_max_mg=float(np.max(np.abs(residuals_mg))),
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
                ref_temperature: float | None, frame_id: str) -> FitResult:
    model = SphereModel(name)
    n = len(accel)
    if initial is not None:
        bias0, matrix0 = initial.bias, initial.matrix
    else:
        bias0, matrix0 = seed_sphere(accel, gravity)
    directions = (accel - bias0) @ matrix0.T
    lengths = np.linalg.norm(directions, axis=1)
    if not np.all(lengths > 0):
        row = int(np.flatnonzero(~(lengths > 0))[0])
        return FitResult(False, f"pose {row} reads {accel[row].tolist()}, exactly the starting estimate of the bias, "
                         "so it has no direction: drop it if it is a dropped or zeroed sample", name, poses=n)
    directions /= lengths[:, None]
    if not np.all(np.isfinite(directions)):
        return _numerical_failure(accel, None, "the starting point overflows", model=name)
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
    solution = gauss_newton(
        lambda p: model.residual_and_jacobian(p, accel, gravity), model.project(bias0, matrix0)
    )
    condition = scaled_condition_number(solution.jacobian)
    residuals_mg = solution.residuals / MG
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
    broken = _not_finite(parameters=solution.x, residuals=solution.residuals, jacobian=solution.jacobian)
    if broken:
        return _numerical_failure(accel, None, _broken_reason(broken, solution), **common)
    # Observability first: a fit that wanders along an unobservable direction also fails to converge,
    # and "turn x down" helps the person more than "did not converge".
    if condition > CONDITION_LIMIT:
        return FitResult(
            False,
            f"poses do not constrain model {name} (condition number {condition:.3g} > {CONDITION_LIMIT:.0g}): "
            + describe_missing(list(missing)),
            **common,
        )
    if n <= model.size:
        return _no_degree_of_freedom(n, f"{model.size} parameters of model {name}", **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    bias, matrix = model.unpack(solution.x)
    if not np.linalg.det(matrix) > 0:
        return FitResult(False, "fit converged to a mirrored solution; check the poses", **common)
    stds = _standard_deviations(solution, n)
    if _not_finite(uncertainties=stds):
        return _numerical_failure(accel, None, "uncertainties not finite: the normal matrix is singular", **common)
    _, matrix_sigma = model.unpack(stds)
    sigma = Sigma(bias=stds[:3], matrix=matrix_sigma)
    calibration = Calibration(
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
    return FitResult(True, solution.message, calibration=calibration, sigma=sigma, **common)


def _fit_reference(accel: np.ndarray, directions: np.ndarray, name: str, gravity: float,
                   ref_temperature: float | None, frame_id: str) -> FitResult:
    """Forward model per axis j: a_raw_j = b_j + sum_k S_jk a_k (+ q_j a_j^2), linear least squares."""
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
        solution, *_ = np.linalg.lstsq(design, accel[:, j], rcond=None)
        coefficients[j] = solution
        residual_raw[:, j] = accel[:, j] - design @ solution
        dof = n - k
        variance = float(residual_raw[:, j] @ residual_raw[:, j]) / dof
        covariances[j] = variance * np.linalg.inv(design.T @ design)
    bias = coefficients[:, 0]
    forward = coefficients[:, 1:4]
    q = coefficients[:, 4] if quadratic else None
    broken = _not_finite(coefficients=coefficients, covariances=covariances)
    if broken:
        return _numerical_failure(accel, None, f"{broken} not finite", model=name, condition_number=condition,
                                  missing_directions=missing)
    if not abs(np.linalg.det(forward)) >= 1e-12 * np.power(max(1.0, float(np.abs(forward).max())), 3.0):
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
        cost=0.5 * float(np.sum(residual_raw**2)),
        condition_number=condition,
        missing_directions=missing,
        poses=n,
    )


def _fit_with_temperature(accel: np.ndarray, temps: np.ndarray, name: str, gravity: float,
                          options: TemperatureOptions, initial: Calibration | None, frame_id: str) -> FitResult:
    n = len(accel)
    if n < parameter_count(name):
        return FitResult(False, f"model {name} needs at least {parameter_count(name)} poses, got {n}", name, poses=n)
    problem = temperature_span_problem(temps, options)
    if problem is not None:
        return FitResult(False, problem, name, poses=n)
    reference_degc = options.reference_degc if options.reference_degc is not None else float(np.median(temps))
    span = (float(temps.min()), float(temps.max()))
    if options.model == "segmented":
        # Each segment needs several poses: more segments than poses means a corrupt temperature, and
        # would have fit_segmented_drift lay out (and loop over) that many segments.
        width = options.segment_width_degc
        segments = np.ceil(span[1] / width) - np.floor(span[0] / width)
        if not segments <= n:
            return FitResult(False, f"temperatures {span[0]:.4g}..{span[1]:.4g} degC span {segments:.3g} segments of "
                             f"{width:g} degC, more than the {n} poses can fill: check the temperatures for a corrupt "
                             "value", name, poses=n)
        # The seed's scheme: a room-temperature calibration from the poses near T_ref, then each
        # segment's drift against it.
        near = np.abs(temps - reference_degc) <= options.segment_width_degc / 2
        base = fit(accel[near], model=name, gravity=gravity, initial=initial, frame_id=frame_id)
        if not base.success or base.calibration is None:  # a successful fit always carries its calibration
            return FitResult(False, f"room-temperature calibration from the {int(near.sum())} poses within "
                             f"{options.segment_width_degc / 2:g} degC of {reference_degc:.1f} degC: {base.message}",
                             name, poses=n)
        try:
            edges, coefficients = fit_segmented_drift(accel, temps, base.calibration.bias,
                                                      base.calibration.matrix, gravity, options)
        except CalibrationError as error:
            return FitResult(False, str(error), name, poses=n)
        if _not_finite(segment_coefficients=coefficients):
            return _numerical_failure(accel, temps, "segment drift coefficients not finite", model=name)
        temperature = TemperatureModel("segmented", reference_degc, span, segment_edges_degc=edges,
                                       segment_coefficients=coefficients)
        calibration = base.calibration.replace(temperature=temperature, reference_temperature_degc=reference_degc)
        residuals_mg = (np.linalg.norm(calibration.apply(accel, temps), axis=1) - gravity) / MG
        if _not_finite(residuals=residuals_mg):
            return _numerical_failure(accel, temps, "residuals not finite", model=name)
        calibration = calibration.replace(quality=_quality(residuals_mg, base.condition_number))
        return FitResult(True, "segmented temperature model", name, iterations=base.iterations,
                         calibration=calibration, sigma=base.sigma, residuals_mg=residuals_mg,
                         cost=0.5 * float(np.sum((residuals_mg * MG) ** 2)), condition_number=base.condition_number,
                         missing_directions=base.missing_directions, poses=n)

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
