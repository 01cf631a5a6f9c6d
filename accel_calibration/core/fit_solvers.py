"""The room-temperature solvers of fit(): the sphere models (six, sphere9: only |a| = g known) and the
reference models (the gravity direction of each pose known), by Gauss-Newton; the pose-weighted refit;
the parameters' 1-sigma; and the results that say why a fit could not be done."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from .calibration import Calibration, Quality
from .coverage import (
    CONDITION_LIMIT,
    SAME_DIRECTION_DEG,
    SigmaBounds,
    Uncertainty,
    angular_spread_deg,
    condition_and_inverse,
    describe_missing,
    missing_directions,
    next_orientation,
    scaled_condition_number,
)
from .fit_result import FitResult, Sigma
from .gauss_newton import LeastSquaresSolution, gauss_newton_stacked
from .models import SPHERE_MODELS, SphereModel, parameter_count, seed_sphere
from .pose_weights import MAX_REWEIGHTS, TAU_TOLERANCE, extra_variance, pose_weights, weighting_applies
from .units import MG

ONES3 = np.ones(3)


def uncertainty_of(model: str, bias: np.ndarray, matrix: np.ndarray, gravity: float, rows: np.ndarray,
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


def fit_without_temperature(accel: np.ndarray, model: str, gravity: float, temps: np.ndarray | None,
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


def numerical_failure(accel: np.ndarray, temps: np.ndarray | None, reason: str, *, model: str,
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


def no_degree_of_freedom(n: int, description: str, model: str, more: str = "orientation",
                          **fields: Any) -> FitResult:
    fields.setdefault("poses", n)
    return FitResult(False, f"{n} poses for the {description} leave no degree of freedom to judge the fit: "
                     f"hold at least one more {more}", model, **fields)


def broken_reason(broken: str, solution: LeastSquaresSolution) -> str:
    if solution.iterations == 0:  # the solver could not start: its message says why
        return solution.message
    return f"{broken} not finite after {solution.iterations} iterations"


def not_finite(**arrays: np.ndarray | None) -> str | None:
    """Name of the first array with a NaN or infinite entry (None when all are finite)."""
    for name, array in arrays.items():
        if array is not None and not np.isfinite(array).all():
            return name.replace("_", " ")
    return None


def quality_of(residuals_mg: np.ndarray, condition: float) -> Quality:
    return Quality(
        residual_rms_mg=math.sqrt(float(residuals_mg.dot(residuals_mg)) / len(residuals_mg)),
        residual_max_mg=float(np.abs(residuals_mg).max()),
        poses=len(residuals_mg),
        condition_number=float(condition),
    )


def standard_deviations(solution: LeastSquaresSolution, n: int) -> np.ndarray:
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
    bias0, matrix0, x0 = _sphere_start(model, accel, gravity, initial, start)
    directions = _start_directions(accel, accel_t, bias0, matrix0, name)
    if isinstance(directions, FitResult):
        return directions
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
    return _sphere_result(accel, model, gravity, solution, residuals_mg, missing, ref_temperature, frame_id)


def _sphere_start(model: SphereModel, accel: np.ndarray, gravity: float, initial: Calibration | None,
                  start: Calibration | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(b0, M0, x0): the point the solver starts from: `start` as it is, `initial` projected onto the
    model's form, else a seed from the poses."""
    if start is not None:
        return start.bias, start.matrix, model.pack(start.bias, start.matrix)
    if initial is not None:
        return initial.bias, initial.matrix, model.project(initial.bias, initial.matrix)
    bias0, matrix0 = seed_sphere(accel, gravity, cross_axis=model.name == "sphere9")
    # The seed's M is diagonal, or lower-triangular for sphere9, with a positive diagonal: already in
    # the model's form (what project's QR would return, without it).
    return bias0, matrix0, np.concatenate((bias0, matrix0.ravel()[model.flat_index]))


def _start_directions(accel: np.ndarray, accel_t: np.ndarray, bias0: np.ndarray, matrix0: np.ndarray,
                      name: str) -> np.ndarray | FitResult:
    """The poses' unit directions (N, 3) at the starting point, or the failure of a pose that has none."""
    n = len(accel)
    directions_t = np.dot(matrix0, accel_t - bias0[:, None])
    lengths = np.sqrt(np.dot(ONES3, directions_t * directions_t))
    if not lengths.min() > 0:  # NaN too
        row = int(np.flatnonzero(~(lengths > 0))[0])
        return FitResult(False, f"pose {row} reads {accel[row].tolist()}, exactly the starting estimate of the bias, "
                         "so it has no direction: drop it if it is a dropped or zeroed sample", name, poses=n)
    directions_t /= lengths
    if not math.isfinite(float(directions_t.sum())):  # unit vectors: the sum is finite unless an entry is not
        return numerical_failure(accel, None, "the starting point overflows", model=name)
    directions: np.ndarray = directions_t.T
    return directions


def _sphere_result(accel: np.ndarray, model: SphereModel, gravity: float, solution: LeastSquaresSolution,
                   residuals_mg: np.ndarray, missing: tuple[str, ...], ref_temperature: float | None,
                   frame_id: str) -> FitResult:
    """The solver's solution judged (finite, observable, converged, not mirrored) and, when it passes,
    the calibration with its sigma, uncertainty and the poses' leverages."""
    name, n = model.name, len(accel)
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
    failure = _sphere_failure(accel, model, gravity, solution, normal, condition, missing, common)
    if failure is not None:
        return failure
    if inverse is None:  # an infinite condition number fails the observability check above
        return numerical_failure(accel, None, "uncertainties not finite: the normal matrix is singular", **common)
    stds = np.sqrt(np.abs(inverse.diagonal()) * (2.0 * solution.cost / (n - model.size)))
    if not all(map(math.isfinite, stds.tolist())):
        return numerical_failure(accel, None, "uncertainties not finite: the normal matrix is singular", **common)
    bias, matrix = model.unpack(solution.x)
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
        quality=quality_of(residuals_mg, condition),
        frame_id=frame_id,
        reference_temperature_degc=ref_temperature,
    )
    return FitResult(True, solution.message, calibration=calibration, sigma=sigma, uncertainty=uncertainty,
                     leverage=leverage, **common)


def _sphere_failure(accel: np.ndarray, model: SphereModel, gravity: float, solution: LeastSquaresSolution,
                    normal: np.ndarray, condition: float, missing: tuple[str, ...],
                    common: dict[str, Any]) -> FitResult | None:
    """Why the solution is no calibration (not finite, unobservable, no degree of freedom, not converged,
    mirrored), in that order; None when it is one."""
    name, n = model.name, len(accel)
    # Overflow before observability: an infinite condition number from it says nothing about coverage.
    # Finite sums of squares (x, the cost, the normal matrix's diagonal) prove every entry finite at
    # once (the solver forms its normal matrix only at a point where they are); only otherwise is each
    # array checked to name the one that is not.
    x = solution.x
    finite = (math.isfinite(float(x.dot(x))) and math.isfinite(solution.cost)
              and (solution.normal is not None or math.isfinite(float(normal.trace()))))
    broken = None if finite else not_finite(parameters=x, residuals=solution.residuals, jacobian=solution.jacobian)
    if broken:
        return numerical_failure(accel, None, broken_reason(broken, solution), **common)
    # Observability first: a fit that wanders along an unobservable direction also fails to converge,
    # and "turn x down" helps the person more than "did not converge".
    if condition > CONDITION_LIMIT:
        # The normal matrix still says which orientation would pin down what is loose.
        bias_now, matrix_now = model.unpack(solution.x)
        uncertainty = uncertainty_of(name, bias_now, matrix_now, gravity, solution.jacobian, solution.residuals,
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
        return no_degree_of_freedom(n, f"{model.size} parameters of model {name}", **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    m00, m11, m22 = model.unpack(solution.x)[1].diagonal().tolist()
    if not m00 * m11 * m22 > 0:  # det(M): the sphere models' M is lower-triangular
        return FitResult(False, "fit converged to a mirrored solution; check the poses", **common)
    return None


def _fit_reference(accel: np.ndarray, directions: np.ndarray, name: str, gravity: float,
                   ref_temperature: float | None, frame_id: str, weights: np.ndarray | None = None) -> FitResult:
    """Forward model per axis j: a_raw_j = b_j + sum_k S_jk a_k (+ q_j a_j^2), linear least squares
    (weighted by `weights` of the poses, mean 1, when given: sigma from (X^T W X)^-1 times chi^2/dof)."""
    n = len(accel)
    true = gravity * directions
    quadratic = name == "reference15"
    missing = tuple(missing_directions(directions))
    axes = _reference_axes(accel, true, name, weights, missing)
    if isinstance(axes, FitResult):
        return axes
    coefficients, covariances, residual_raw, condition = axes
    bias = coefficients[:, 0]
    forward = coefficients[:, 1:4]
    q = coefficients[:, 4] if quadratic else None
    broken = not_finite(coefficients=coefficients, covariances=covariances)
    if broken:
        return numerical_failure(accel, None, f"{broken} not finite", model=name, condition_number=condition,
                                  missing_directions=missing)
    # Singular relative to its own rows (as Calibration checks): data in any units (counts, 1e-6 g) fit.
    row_size = np.linalg.norm(forward, axis=1)
    if not (np.all(row_size > 0) and abs(np.linalg.det(forward / row_size[:, None])) >= 1e-12):
        return numerical_failure(accel, None, "the fitted scale matrix is singular", model=name,
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
    broken = not_finite(matrix=matrix, uncertainties=stds, matrix_uncertainties=matrix_var)
    if broken:
        return numerical_failure(accel, None, f"{broken} not finite", model=name, condition_number=condition,
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
    if not_finite(residuals=residuals_mg):
        return numerical_failure(accel, None, "residuals not finite", model=name, condition_number=condition,
                                  missing_directions=missing)
    calibration = calibration.replace(quality=quality_of(residuals_mg, condition))
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


def _reference_axes(accel: np.ndarray, true: np.ndarray, name: str, weights: np.ndarray | None,
                    missing: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | FitResult:
    """Each axis' linear least squares: (coefficients (3, k), their covariances (3, k, k), the raw
    residuals (N, 3), the largest condition number), or why the directions do not determine them."""
    n = len(accel)
    quadratic = name == "reference15"
    k = 5 if quadratic else 4
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
            return no_degree_of_freedom(n, f"{k} parameters per axis of model {name}", name,
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
    return coefficients, covariances, residual_raw, condition
