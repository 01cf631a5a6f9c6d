"""fit_dividing_head(): a table of dividing-head positions (nominal α, β and the mean output) to a
Calibration of model `dividing-head`, by Gauss-Newton on the model of dividing_head.py with an analytic
Jacobian and a 1-sigma per parameter.

As with fit(): bad arguments raise CalibrationError; a table that cannot determine the model (a tilt
with fewer than three α, α that leave half the circle empty, fewer than three distinct tilts, an
ill-conditioned protocol) or a fit that does not converge is reported in the result, never raised.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration, Quality
from .coverage import CONDITION_LIMIT, normal_condition_number
from .dividing_head import AXIS_PARAMETERS, DividingHeadModel, DividingHeadTerms, axes_matrix
from .errors import CalibrationError
from .fit import FitResult, Sigma
from .gauss_newton import gauss_newton
from .models import DIVIDING_HEAD
from .units import MG, STANDARD_GRAVITY

# The α of one tilt must leave no gap wider than this of the circle: otherwise the α-harmonic that
# carries the tilt error (and at β = 90° all there is of it) is barely observable.
LARGEST_ALPHA_GAP_DEG = 180.0
MIN_ALPHAS = 3  # a constant and one harmonic (cos α, sin α) per axis
MIN_TILTS = 3  # two tilts leave each Δβ traded against the scales and biases (see docs/dividing_head.md)


def fit_dividing_head(alpha_rad: ArrayLike, beta_rad: ArrayLike, accel_mps2: ArrayLike, *,
                      gravity: float = STANDARD_GRAVITY, frame_id: str = "") -> FitResult:
    """Fit the 12 + k terms of Gao et al. (2016) to N positions of a dividing head.

    alpha_rad, beta_rad: (N,) nominal rotation and tilt of each position (rad); accel_mps2: (N, 3) mean
    raw output (m/s^2, or any raw unit in which `gravity` is 1 g). One tilt error Δβ per distinct β.
    The result's calibration has bias b = g ∇ and M = (diag(K) C)^-1, and its `dividing_head` terms.
    """
    alpha, beta, accel = _checked(alpha_rad, beta_rad, accel_mps2, gravity)
    model = DividingHeadModel.from_angles(alpha, beta)
    n = len(accel)
    problem = _protocol_problem(model)
    if problem is not None:
        return FitResult(False, problem, DIVIDING_HEAD, poses=n)
    measured_g = accel / gravity
    with np.errstate(all="ignore"):
        solution = gauss_newton(lambda p: model.residual_and_jacobian(p, measured_g), model.seed(measured_g))
        normal = solution.jacobian.T @ solution.jacobian
        condition = normal_condition_number(normal)
    residuals_g = solution.residuals.reshape(n, 3)
    residuals_mg = np.linalg.norm(residuals_g, axis=1) * gravity / MG
    common = dict(model=DIVIDING_HEAD, iterations=solution.iterations, residuals_mg=residuals_mg,
                  cost=solution.cost * gravity**2, condition_number=condition, poses=n)
    if not (np.all(np.isfinite(solution.x)) and math.isfinite(solution.cost) and np.all(np.isfinite(normal))):
        return FitResult(False, f"numerical failure fitting model {DIVIDING_HEAD} to {n} positions "
                         f"({solution.message}): check the table for a corrupt row", **common)
    if condition > CONDITION_LIMIT:
        return FitResult(False, f"the positions do not determine the {model.size} terms of the dividing head "
                         f"(condition number {condition:.3g} > {CONDITION_LIMIT:.0g}): spread α around the circle "
                         "and β over at least three well separated tilts (the paper: 0°, 45°, 90°)", **common)
    dof = 3 * n - model.size
    if dof < 1:
        return FitResult(False, f"{n} positions give {3 * n} readings for {model.size} terms: no degree of freedom "
                         "to judge the fit; add positions", **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    p = solution.x
    variance_g2 = 2.0 * solution.cost / dof
    covariance = variance_g2 * np.linalg.inv(normal)
    stds = np.sqrt(np.abs(covariance.diagonal()))
    forward = axes_matrix(p[6:12]) * p[:3, None]  # S = diag(K) C
    if not np.linalg.det(forward) > 0:
        return FitResult(False, "fit converged to a mirrored or singular scale matrix; check the table's signs "
                         "and units", **common)
    matrix = np.linalg.inv(forward)
    matrix_sigma = _matrix_sigma(p, matrix, covariance[:AXIS_PARAMETERS, :AXIS_PARAMETERS])
    bias = p[3:6] * gravity
    sigma = Sigma(bias=stds[3:6] * gravity, matrix=matrix_sigma)
    g_in_mg = gravity / MG
    terms = DividingHeadTerms(
        scale=tuple(p[:3]),
        bias_mg=tuple(p[3:6] * g_in_mg),
        mounting_mrad=tuple(p[6:9] * 1e3),
        nonorthogonality_mrad=tuple(p[9:12] * 1e3),
        tilt_error_mrad=tuple(p[AXIS_PARAMETERS:] * 1e3),
        tilt_deg=tuple(np.round(np.degrees(model.tilts_rad), 9)),
        sigma={"scale": tuple(stds[:3]), "bias_mg": tuple(stds[3:6] * g_in_mg),
               "mounting_mrad": tuple(stds[6:9] * 1e3), "nonorthogonality_mrad": tuple(stds[9:12] * 1e3),
               "tilt_error_mrad": tuple(stds[AXIS_PARAMETERS:] * 1e3)},
        residual_sigma_mg=math.sqrt(variance_g2) * g_in_mg,
    )
    quality = Quality(residual_rms_mg=math.sqrt(float(residuals_mg @ residuals_mg) / n),
                      residual_max_mg=float(residuals_mg.max()), poses=n, condition_number=condition)
    calibration = Calibration(bias=bias, matrix=matrix, model=DIVIDING_HEAD, gravity=gravity,
                              bias_sigma=sigma.bias, matrix_sigma=sigma.matrix, quality=quality,
                              frame_id=frame_id, dividing_head=terms)
    return FitResult(True, solution.message, calibration=calibration, sigma=sigma, **common)


def _checked(alpha_rad: ArrayLike, beta_rad: ArrayLike, accel_mps2: ArrayLike,
             gravity: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        accel = np.array(accel_mps2, dtype=float)
        alpha = np.array(alpha_rad, dtype=float)
        beta = np.array(beta_rad, dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError("alpha_rad, beta_rad and accel_mps2 must be numbers") from None
    if accel.ndim != 2 or accel.shape[1] != 3:
        raise CalibrationError(f"accel_mps2 must be an N x 3 array, got shape {accel.shape}")
    for name, angles in (("alpha_rad", alpha), ("beta_rad", beta)):
        if angles.shape != (len(accel),):
            raise CalibrationError(f"{name} must hold one angle per position ({len(accel)}), got shape {angles.shape}")
    for name, values in (("accel_mps2", accel), ("alpha_rad", alpha), ("beta_rad", beta)):
        if not np.all(np.isfinite(values)):
            raise CalibrationError(f"{name} has a non-finite value")
    if (isinstance(gravity, bool) or not isinstance(gravity, (int, float, np.floating)) or not np.isfinite(gravity)
            or gravity <= 0):
        raise CalibrationError(f"gravity must be a positive number of m/s^2, got {gravity!r}")
    return alpha, beta, accel


def _protocol_problem(model: DividingHeadModel) -> str | None:
    """What the positions lack to determine the model, in the words of the protocol; None when the
    protocol is complete (the condition number still judges the whole)."""
    tilts_deg = np.degrees(model.tilts_rad)
    for k, tilt in enumerate(tilts_deg.tolist()):
        alphas = np.unique(np.round(np.degrees(model.alpha_rad[model.tilt_index == k]) % 360.0, 9) % 360.0)
        if len(alphas) < MIN_ALPHAS:
            listed = ", ".join(f"{a:g}°" for a in alphas)
            return (f"tilt β = {tilt:g}° has {len(alphas)} distinct α ({listed}): hold at least {MIN_ALPHAS} α "
                    "around the circle at every tilt")
        gaps = np.diff(np.concatenate([alphas, [alphas[0] + 360.0]]))
        widest = float(gaps.max())
        if widest > LARGEST_ALPHA_GAP_DEG + 1e-9:
            return (f"at tilt β = {tilt:g}° the α leave {widest:g}° of the circle empty (more than half), so the "
                    "α-harmonic that shows the tilt error is not observable: turn the head around the whole circle")
    if len(tilts_deg) == 1:
        only = tilts_deg[0]
        if abs(only - 90.0) < 1e-6:
            return ("every position is at β = 90°: there the tilt error and the axes' scale and bias cannot be "
                    "separated; add positions at β = 0° and 45° (the paper's protocol)")
        return (f"every position is at β = {only:g}°: one tilt cannot separate its tilt error from the axes' scale "
                "and bias; add positions at two more β (the paper: 0°, 45°, 90°)")
    if len(tilts_deg) < MIN_TILTS:
        listed = ", ".join(f"{t:g}°" for t in tilts_deg)
        return (f"{len(tilts_deg)} tilts (β = {listed}) leave the tilt errors traded against the axes' scale and "
                f"bias: add positions at a third β (the paper: 0°, 45°, 90°)")
    return None


def _matrix_sigma(p: np.ndarray, matrix: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """1-sigma of M = (diag(K) C)^-1 by first-order propagation, dM = -M dS M, over K, δθ and γ."""
    base = axes_matrix(p[6:12])
    gradients = np.zeros((9, AXIS_PARAMETERS))
    for k in range(3):  # dS/dK_k: row k of C
        d_forward = np.zeros((3, 3))
        d_forward[k] = base[k]
        gradients[:, k] = (-matrix @ d_forward @ matrix).ravel()
    for k in range(6):  # dS/dangle: diag(K) dC/dangle
        unit = np.zeros(6)
        unit[k] = 1.0
        d_forward = (axes_matrix(unit) - np.eye(3)) * p[:3, None]
        gradients[:, 6 + k] = (-matrix @ d_forward @ matrix).ravel()
    variance = np.einsum("ij,jk,ik->i", gradients, covariance, gradients)
    sigma: np.ndarray = np.sqrt(np.abs(variance)).reshape(3, 3)
    return sigma
