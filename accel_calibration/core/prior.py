"""A sphere fit with a prior: recalibration of a vehicle that cannot be turned through every orientation
(too large to turn upside down), from poses near level and the calibration in force.

The prior enters the least squares as a Gaussian pseudo-measurement of each parameter: mean the prior
calibration's b and M, 1-sigma its `uncertainty`. In units of the poses' noise s (one pose's residual
variance, estimated from the residuals) the cost is

    sum_i r_i(p)^2 + s^2 sum_k ((p_k - p0_k) / sigma0_k)^2,

so the normal matrix is J^T J + s^2 diag(1 / sigma0^2) and the posterior covariance s^2 (that)^-1: the
directions the poses observe are set by the poses, the rest stay at the prior with the prior's sigma.
s^2 is the poses' residual sum of squares over their degrees of freedom n - tr(J^T J H^-1) (the
parameters the prior determines cost the poses none), iterated with the fit until it settles.

The prior's sigma says how well b and M were known when it was fitted, not how far they moved since:
the bias is what drifts (turn-on, ageing, a knock; scale and misalignment are stable), and a bias that
moved 8 mg against a prior sure to 0.05 mg would be held back by it. So the bias's prior sigma is its
file sigma and `bias_drift_mps2` added in quadrature (Prior; default 10 mg, a MEMS part's drift over its
life); M keeps the file's sigma.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .calibration import Calibration
from .coverage import Uncertainty, condition_and_inverse, missing_directions
from .errors import CalibrationError
from .fit_result import FitResult, ParameterSource, Sigma
from .fit_solvers import LARGEST_VALUE, no_degree_of_freedom, not_finite, numerical_failure, quality_of
from .gauss_newton import LeastSquaresSolution, gauss_newton_stacked
from .models import SPHERE_MODELS, SphereModel
from .prior_evidence import PriorEvidence, prior_evidence
from .units import MG

# The poses' noise is re-estimated until it changes by less than this fraction (a few rounds).
NOISE_TOLERANCE = 1e-6
NOISE_ITERATIONS = 30
# The poses' noise never goes below this fraction of |a| (~0.1 ug): noise-free poses would otherwise
# weigh the prior out altogether.
NOISE_FLOOR = 1e-8
# Beyond this (Jacobi-scaled) condition number poses and prior together are numerically singular: a prior
# so loose it adds nothing where the poses see nothing. Below it the sigma gate judges the posterior.
SINGULAR_CONDITION = 1e12
# Poses and prior disagree when freeing the prior's bias lowers the poses' residuals beyond what the
# parameters it frees explain at this many Gaussian sigmas (an F test); the bias freed has this sigma.
CONFLICT_K_SIGMA = 4.0
FREE_BIAS_SIGMA_MPS2 = 10.0


DEFAULT_BIAS_DRIFT_MPS2 = 10.0 * MG


@dataclass(frozen=True)
class Prior:
    """A calibration to fit against (with its uncertainty) and how far its bias may have drifted since (1-sigma,
    raw units; added to its bias sigma in quadrature)."""

    calibration: Calibration
    bias_drift_mps2: float = DEFAULT_BIAS_DRIFT_MPS2

    def __post_init__(self) -> None:
        drift = self.bias_drift_mps2
        if isinstance(drift, bool) or not isinstance(drift, (int, float)) or not (math.isfinite(drift) and drift >= 0):
            raise CalibrationError(f"the prior's bias drift must be a number >= 0, got {drift!r}")


def prior_terms(given: Prior | Calibration, model: str, gravity: float) -> tuple[np.ndarray, np.ndarray]:
    """The prior's parameter vector and 1-sigma in `model`'s order (M rescaled to `gravity`, the bias's
    sigma widened by the drift); one-line CalibrationError when it cannot serve as this fit's prior."""
    if isinstance(given, Calibration):
        given = Prior(given)
    if not isinstance(given, Prior):
        raise CalibrationError("prior must be a Calibration (the calibration in force), a Prior or None")
    prior = given.calibration
    if model not in SPHERE_MODELS:
        raise CalibrationError(f"a prior enters the sphere models' fit ({', '.join(SPHERE_MODELS)}), not {model}")
    if prior.model != model:
        raise CalibrationError(f"the prior is model {prior.model} and the fit model {model}: fit with the prior's "
                               "model")
    if prior.bias_sigma is None or prior.matrix_sigma is None:
        raise CalibrationError("the prior has no uncertainty (1-sigma of b and M): without it the fit cannot "
                               "weigh the prior against the poses")
    if prior.temperature is not None or prior.quadratic is not None:
        raise CalibrationError("the prior has a temperature model: a fit with a prior fits b and M alone")
    sphere = SphereModel(model)
    outside = prior.matrix.copy()
    outside.ravel()[sphere.flat_index] = 0.0
    if np.abs(outside).max() > 1e-12 * np.abs(prior.matrix).max():
        raise CalibrationError(f"the prior's M is not of model {model}'s form (entries it fixes at 0 are not 0)")
    scale = gravity / prior.gravity  # M maps onto the fit's gravity
    values = sphere.pack(prior.bias, prior.matrix * scale)
    bias_sigma = np.sqrt(prior.bias_sigma**2 + given.bias_drift_mps2**2)
    sigma = sphere.pack(bias_sigma, prior.matrix_sigma * scale)
    for name, value in zip(sphere.parameter_names(), sigma.tolist()):
        if not (math.isfinite(value) and value > 0):
            raise CalibrationError(f"the prior's sigma of {name} is {value:g}: a prior needs a positive sigma "
                                   "per parameter")
    return values, sigma


def prior_noise_floor(given: Prior | Calibration, pose_sigma: np.ndarray | None) -> float:
    """One pose's noise the test of the prior never goes below (raw units; 0: none known): the larger of
    the poses' own (rms of their means' sigma) and the prior's fit residual rms (how closely this sensor's
    poses lie on a sphere, misfit included)."""
    prior = given.calibration if isinstance(given, Prior) else given
    own = float(np.sqrt(np.mean(np.square(pose_sigma)))) if pose_sigma is not None and len(pose_sigma) else 0.0
    fitted = prior.quality.residual_rms_mg * MG if prior.quality is not None else 0.0
    floor = max(own, fitted)
    return floor if math.isfinite(floor) else 0.0


def _solve(model: SphereModel, accel_t: np.ndarray, gravity: float, prior_values: np.ndarray,
           prior_weight: np.ndarray, start: np.ndarray) -> LeastSquaresSolution:
    """Gauss-Newton on the poses' residuals with the prior's rows after them: prior_weight_k (p_k - p0_k),
    prior_weight = s / sigma0 (the poses' noise over the prior's sigma)."""
    n, size = accel_t.shape[1], model.size

    def stacked(p: np.ndarray) -> np.ndarray:
        out = np.zeros((size + 1, n + size))
        out[:, :n] = model.stacked(p, accel_t, gravity)
        out[np.arange(size), n + np.arange(size)] = prior_weight
        out[size, n:] = prior_weight * (p - prior_values)
        return out

    return gauss_newton_stacked(stacked, start)


@dataclass(frozen=True)
class _Settled:
    """The last solve once the poses' noise settled: the solution, H, its condition number and inverse, s^2
    and the poses' degrees of freedom n - tr(J^T J H^-1) (NaN when the loop stopped before forming them)."""

    solution: LeastSquaresSolution
    normal: np.ndarray
    condition: float
    inverse: np.ndarray | None
    variance: float
    dof: float

    @property
    def pose_residual_squares(self) -> float:
        residuals = self.solution.residuals[:-len(self.normal)]
        return float(residuals @ residuals)


def _settle(model: SphereModel, accel_t: np.ndarray, gravity: float, prior_values: np.ndarray,
            prior_sigma: np.ndarray, typical: float) -> _Settled:
    """Fit and re-estimate the poses' noise s^2 = residual sum of squares / (n - tr(J^T J H^-1)) until it
    settles, each solve from the last; stops early where a solve is not usable (the caller judges it).
    typical: the poses' |a|, which sets the first guess of s (~0.1 mg) and its floor."""
    n = accel_t.shape[1]
    floor = (NOISE_FLOOR * typical) ** 2
    variance, x, dof = (1e-4 * typical) ** 2, prior_values, float("nan")
    for _ in range(NOISE_ITERATIONS):
        solution = _solve(model, accel_t, gravity, prior_values, math.sqrt(variance) / prior_sigma, x)
        jacobian = solution.jacobian
        normal = solution.normal if solution.normal is not None else jacobian.T @ jacobian
        condition, inverse = condition_and_inverse(normal)
        broken = not_finite(parameters=solution.x, residuals=solution.residuals, jacobian=jacobian)
        if broken or inverse is None or condition > SINGULAR_CONDITION or not solution.success:
            break
        poses_normal = jacobian[:n].T @ jacobian[:n]
        dof = n - float(np.sum(poses_normal * inverse))  # n - tr(J^T J H^-1): H and its inverse are symmetric
        if dof < 1.0:
            break
        pose_residuals = solution.residuals[:n]
        settled = max(float(pose_residuals @ pose_residuals) / dof, floor)
        if abs(settled - variance) <= NOISE_TOLERANCE * variance:
            break
        variance, x = settled, solution.x
    return _Settled(solution, normal, condition, inverse, variance, dof)


def fit_sphere_with_prior(accel: np.ndarray, name: str, gravity: float, prior_values: np.ndarray,
                          prior_sigma: np.ndarray, ref_temperature: float | None, frame_id: str,
                          noise_floor: float = 0.0) -> FitResult:
    """The sphere fit of `accel` with the prior (prior_terms) as pseudo-measurements; a failed result
    says why. The poses' noise s is estimated with the fit (module docstring); the test of the prior
    against the poses (core/prior_evidence.py) never takes it below noise_floor (prior_noise_floor)."""
    model = SphereModel(name)
    n = len(accel)
    if n < 2:
        return FitResult(False, f"a fit with a prior needs at least 2 poses, got {n}", name, poses=n)
    if float(np.abs(accel).max()) > LARGEST_VALUE:
        return numerical_failure(accel, None, f"values beyond {LARGEST_VALUE:.0e} overflow the fit", model=name)
    accel_t = np.ascontiguousarray(accel.T)
    typical = float(np.median(np.linalg.norm(accel, axis=1)))
    settled = _settle(model, accel_t, gravity, prior_values, prior_sigma, typical)
    if settled.dof < 1.0:
        return no_degree_of_freedom(n, f"{model.size} parameters of model {name} and the prior", name,
                                    condition_number=settled.condition)
    evidence = prior_evidence(model, accel, gravity, prior_values, prior_sigma, settled.variance, noise_floor)
    result = _result(accel, model, gravity, settled, prior_sigma, ref_temperature, frame_id, evidence)
    # A moved bias first (its own test says by how much each axis moved), then the rest of what the poses see.
    moved = result.success and _conflict(model, accel_t, gravity, prior_values, prior_sigma, typical, settled)
    conflict = moved or evidence.refusal
    if conflict:
        return FitResult(False, conflict, name, condition_number=result.condition_number, poses=n,
                         residuals_mg=result.residuals_mg, missing_directions=result.missing_directions)
    return result


def _conflict(model: SphereModel, accel_t: np.ndarray, gravity: float, prior_values: np.ndarray,
              prior_sigma: np.ndarray, typical: float, settled: _Settled) -> str | None:
    """Whether the poses contradict the prior's bias, said plainly (None when not): with the bias freed the
    poses' residual sum of squares falls by more than the q parameters it frees explain (F(q, dof) at
    CONFLICT_K_SIGMA). Else a bias that moved beyond its drift allowance would be taken for pose noise."""
    from .fit_outliers import critical_ratio  # scipy.stats, imported only when a fit has a prior

    free_sigma = prior_sigma.copy()
    free_sigma[:3] = np.maximum(free_sigma[:3], FREE_BIAS_SIGMA_MPS2)
    free = _settle(model, accel_t, gravity, prior_values, free_sigma, typical)
    freed = settled.dof - free.dof
    if not (free.dof >= 1.0 and freed >= 0.5 and free.solution.success):
        return None  # the prior's bias is as loose as free already, or the poses alone cannot say
    held, loose = settled.pose_residual_squares, free.pose_residual_squares
    ratio = ((held - loose) / freed) / (loose / free.dof) if loose > 0 else math.inf
    if not ratio > critical_ratio(CONFLICT_K_SIGMA, max(1, round(freed)), max(1, round(free.dof))):
        return None
    moved = ", ".join(f"{v:+.2f}" for v in (free.solution.x[:3] - prior_values[:3]) / MG)
    n = accel_t.shape[1]
    return (f"the poses disagree with the prior: with its bias freed the bias moves ({moved}) mg and the poses' "
            f"residual falls from {math.sqrt(held / n) / MG:.3g} to {math.sqrt(loose / n) / MG:.3g} mg rms; the bias "
            "moved beyond the prior's drift allowance (raise it) or the prior is not this sensor's")


def _result(accel: np.ndarray, model: SphereModel, gravity: float, settled: _Settled, prior_sigma: np.ndarray,
            ref_temperature: float | None, frame_id: str, evidence: PriorEvidence) -> FitResult:
    """The FitResult of the last solve: posterior sigma s^2 H^-1, the Uncertainty of poses and prior
    (what the sigma gate's advice adds a pose to) and each parameter's share from the poses."""
    n, name = len(accel), model.name
    solution, normal, condition = settled.solution, settled.normal, settled.condition
    inverse, variance = settled.inverse, settled.variance
    bias, matrix = model.unpack(solution.x)
    residuals_mg = solution.residuals[:n] / MG
    directions = (matrix @ (accel - bias).T).T
    missing = tuple(missing_directions(directions / np.linalg.norm(directions, axis=1)[:, None]))
    common: dict[str, Any] = dict(model=name, iterations=solution.iterations, residuals_mg=residuals_mg,
                                  cost=solution.cost, condition_number=condition, missing_directions=missing, poses=n)
    broken = not_finite(parameters=solution.x, residuals=solution.residuals, jacobian=solution.jacobian)
    if broken:
        return numerical_failure(accel, None, f"{broken} not finite", **common)
    if inverse is None or condition > SINGULAR_CONDITION:
        return FitResult(False, f"poses and prior do not determine model {name} (condition number "
                         f"{condition:.3g}): the prior's sigma are too large to hold what the poses do not see",
                         **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    m00, m11, m22 = matrix.diagonal().tolist()
    if not m00 * m11 * m22 > 0:
        return FitResult(False, "fit converged to a mirrored solution; check the poses and the prior", **common)
    stds = np.sqrt(np.abs(inverse.diagonal()) * variance)
    _, matrix_sigma = model.unpack(stds)
    sigma = Sigma(bias=stds[:3], matrix=matrix_sigma)
    jacobian_t = solution.jacobian[:n].T
    leverage = np.einsum("ji,ji->i", np.dot(inverse, jacobian_t), jacobian_t)
    calibration = Calibration.from_fit(bias=bias, matrix=matrix, model=name, gravity=gravity,
                                       bias_sigma=sigma.bias, matrix_sigma=sigma.matrix,
                                       quality=quality_of(residuals_mg, condition), frame_id=frame_id,
                                       reference_temperature_degc=ref_temperature)
    sources = tuple(ParameterSource(label, float(s), float(s0))
                    for label, s, s0 in zip(model.parameter_names(), stds.tolist(), prior_sigma.tolist()))
    sources = tuple(dataclasses.replace(source, note=evidence.note(k, source.source))
                    for k, source in enumerate(sources))
    message = (f"{solution.message}; with the prior, the poses' noise {math.sqrt(variance) / MG:.3g} mg "
               "estimated from their residuals")
    return FitResult(True, message, calibration=calibration, sigma=sigma,
                     uncertainty=Uncertainty(name, bias, matrix, gravity, normal, variance),
                     leverage=leverage, parameter_sources=sources, **common)
