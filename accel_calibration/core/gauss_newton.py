"""Gauss-Newton least squares with Levenberg-Marquardt damping only when a step fails to reduce the cost.

Small dense problems (9-15 parameters, tens to hundreds of poses) solved by normal equations with
Jacobi column scaling; this is what makes the online refit after every new pose cheap.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dposv as posv

ResidualFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def _finite(jacobian: np.ndarray) -> bool:
    """Whether every entry is finite, in one reduction: the sum of squares is NaN or inf otherwise
    (and then J^T J, which it is the trace of, would overflow too)."""
    return math.isfinite(float(np.vdot(jacobian, jacobian)))


def _solve(system: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """system^-1 rhs for a normal matrix: Cholesky (LAPACK posv called directly; numpy's wrapper costs
    more than the solve at this size), else LU, else least squares when it is singular."""
    _, step, info = posv(system, rhs)
    if info == 0:
        solution: np.ndarray = step
        return solution
    try:
        return np.linalg.solve(system, rhs)
    except np.linalg.LinAlgError:
        least: np.ndarray = np.linalg.lstsq(system, rhs, rcond=None)[0]
        return least


@dataclass(frozen=True)
class LeastSquaresSolution:
    x: np.ndarray
    cost: float  # 0.5 * sum(residuals**2)
    residuals: np.ndarray
    jacobian: np.ndarray
    iterations: int
    success: bool
    message: str
    # J^T J at x when the solver formed it there (converged), so that sigma, the condition number and
    # the outlier leverages reuse it instead of forming it again; None otherwise.
    normal: np.ndarray | None = None


def gauss_newton(
    residual_and_jacobian: ResidualFunction,
    x0: np.ndarray,
    *,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    max_iterations: int = 50,
) -> LeastSquaresSolution:
    """Minimise 0.5*|r(x)|^2 from x0.

    Stops when the relative cost change falls below `ftol`, or the relative step below `xtol`,
    and reports non-convergence after `max_iterations` in the result rather than raising. A start
    whose residuals or Jacobian are not finite (overflow, a pose at the bias) is reported the same
    way; a trial point where they are not finite counts as a failed step.
    """
    x = np.array(x0, dtype=float)
    r, jac = residual_and_jacobian(x)
    cost = 0.5 * float(r @ r)
    if not (math.isfinite(cost) and _finite(jac)):
        return LeastSquaresSolution(
            x, cost, r, jac, 0, False,
            "residuals or Jacobian not finite at the starting point (overflow, or a pose exactly at the bias)",
        )
    damping = 0.0
    for iteration in range(1, max_iterations + 1):
        normal = jac.T @ jac
        gradient = jac.T @ r
        while True:
            if damping:
                # Marquardt's scaling (diag of J^T J) keeps the damped step sensible whatever the
                # parameters' units (bias in counts, matrix ~1e-3).
                system = normal + damping * np.diag(normal.diagonal())
            else:
                system = normal
            step = _solve(system, -gradient)
            # Converged when the step, or the cost decrease it promises (exact for Gauss-Newton near
            # the optimum), is below tolerance: no need to evaluate a point that changes nothing.
            predicted_decrease = -float(step @ gradient) - 0.5 * float(step @ (normal @ step))
            if not damping and predicted_decrease <= ftol * cost:
                return LeastSquaresSolution(x, cost, r, jac, iteration, True, "relative cost change below ftol",
                                            normal)
            if not damping and float(step @ step) <= (xtol * (xtol + math.sqrt(float(x @ x)))) ** 2:
                return LeastSquaresSolution(x, cost, r, jac, iteration, True, "relative step below xtol", normal)
            x_new = x + step
            r_new, jac_new = residual_and_jacobian(x_new)
            cost_new = 0.5 * float(r_new @ r_new)
            usable = _finite(jac_new)
            if cost_new <= cost and usable:  # False for a NaN cost too
                break
            if usable and cost_new - cost <= ftol * cost:
                # At the optimum to within rounding: no step can do better, so stop here.
                return LeastSquaresSolution(x, cost, r, jac, iteration, True, "relative cost change below ftol",
                                            normal)
            # The Gauss-Newton step overshot: damp it (Levenberg-Marquardt) and try again.
            damping = 1e-3 if damping == 0.0 else damping * 10.0
            if damping > 1e12:
                return LeastSquaresSolution(
                    x, cost, r, jac, iteration, False, "no step reduces the cost (damping exhausted)"
                )
        cost_small = (cost - cost_new) <= ftol * cost
        x, r, jac, cost = x_new, r_new, jac_new, cost_new
        damping = 0.0 if damping < 1e-9 else damping / 10.0
        if cost_small:
            return LeastSquaresSolution(x, cost, r, jac, iteration, True, "relative cost change below ftol")
    return LeastSquaresSolution(
        x, cost, r, jac, max_iterations, False, f"did not converge in {max_iterations} iterations"
    )
