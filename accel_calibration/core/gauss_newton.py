"""Gauss-Newton least squares with Levenberg-Marquardt damping only when a step fails to reduce the cost.

Small dense problems (9-15 parameters, tens to hundreds of poses) solved by normal equations with
Jacobi column scaling; this is what makes the online refit after every new pose cheap.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .lapack import dposv as posv

ResidualFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
# x -> [J^T; r], (size + 1, N): the Jacobian transposed with the residuals as its last row.
StackedFunction = Callable[[np.ndarray], np.ndarray]


def _solve(system: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, bool]:
    """system^-1 rhs for a normal matrix: Cholesky (LAPACK posv called directly; numpy's wrapper costs
    more than the solve at this size), else LU, else least squares when it is singular; and whether
    the solution is exact (not least squares)."""
    _, step, info = posv(system, rhs)
    if info == 0:
        solution: np.ndarray = step
        return solution, True
    try:
        return np.linalg.solve(system, rhs), True
    except np.linalg.LinAlgError:
        least: np.ndarray = np.linalg.lstsq(system, rhs, rcond=None)[0]
        return least, False


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

    def stacked(x: np.ndarray) -> np.ndarray:
        r, jac = residual_and_jacobian(x)
        out = np.empty((jac.shape[1] + 1, len(r)))
        out[:-1] = jac.T
        out[-1] = r
        return out

    return gauss_newton_stacked(stacked, x0, ftol=ftol, xtol=xtol, max_iterations=max_iterations)


def gauss_newton_stacked(
    stacked: StackedFunction,
    x0: np.ndarray,
    *,
    ftol: float = 1e-12,
    xtol: float = 1e-12,
    max_iterations: int = 50,
) -> LeastSquaresSolution:
    """gauss_newton() for a problem that gives its Jacobian and residuals stacked as one (size + 1, N)
    array S = [J^T; r]: then S S^T is [[J^T J, J^T r], [r^T J, r^T r]], the normal matrix, the gradient
    and twice the cost from one product, which at 9 parameters and tens of poses is most of the work."""
    x = np.array(x0, dtype=float)
    size = len(x)
    s = stacked(x)
    r = s[size]
    if not math.isfinite(float(np.vdot(s, s))):  # the residuals' and the Jacobian's sum of squares
        return LeastSquaresSolution(
            x, 0.5 * float(r @ r), r, s[:size].T, 0, False,
            "residuals or Jacobian not finite at the starting point (overflow, or a pose exactly at the bias)",
        )
    product = np.dot(s, s.T)
    cost = 0.5 * float(product[size, size])
    damping = 0.0
    for iteration in range(1, max_iterations + 1):
        normal = product[:size, :size]
        gradient = product[:size, size]
        while True:
            if damping:
                # Marquardt's scaling (diag of J^T J) keeps the damped step sensible whatever the
                # parameters' units (bias in counts, matrix ~1e-3).
                system = normal + damping * np.diag(normal.diagonal())
            else:
                system = normal
            step, exact = _solve(system, -gradient)
            if not damping:
                # Converged when the step, or the cost decrease it promises (exact for Gauss-Newton near
                # the optimum), is below tolerance: no need to evaluate a point that changes nothing.
                # -g.s - s.N.s/2, which is -g.s/2 when N s = -g was solved exactly.
                along = float(step.dot(gradient))
                predicted_decrease = (-0.5 * along if exact
                                      else -along - 0.5 * float(step.dot(normal.dot(step))))
                if predicted_decrease <= ftol * cost:
                    return _solution(x, cost, s, iteration, True, "relative cost change below ftol", normal)
                if float(step.dot(step)) <= (xtol * (xtol + math.sqrt(float(x.dot(x))))) ** 2:
                    return _solution(x, cost, s, iteration, True, "relative step below xtol", normal)
            x_new = x + step
            s_new = stacked(x_new)
            product_new = np.dot(s_new, s_new.T)
            cost_new = 0.5 * float(product_new[size, size])
            # The trial point is usable when its Jacobian is finite; when only its residuals are not,
            # its cost is not finite and the tests below reject it all the same.
            usable = math.isfinite(float(np.vdot(s_new, s_new)))
            if cost_new <= cost and usable:  # False for a NaN cost too
                break
            if usable and cost_new - cost <= ftol * cost:
                # At the optimum to within rounding: no step can do better, so stop here.
                return _solution(x, cost, s, iteration, True, "relative cost change below ftol", normal)
            # The Gauss-Newton step overshot: damp it (Levenberg-Marquardt) and try again.
            damping = 1e-3 if damping == 0.0 else damping * 10.0
            if damping > 1e12:
                return _solution(x, cost, s, iteration, False, "no step reduces the cost (damping exhausted)")
        cost_small = (cost - cost_new) <= ftol * cost
        x, s, product, cost = x_new, s_new, product_new, cost_new
        damping = 0.0 if damping < 1e-9 else damping / 10.0
        if cost_small:
            return _solution(x, cost, s, iteration, True, "relative cost change below ftol", product[:size, :size])
    return _solution(x, cost, s, max_iterations, False, f"did not converge in {max_iterations} iterations")


def _solution(x: np.ndarray, cost: float, s: np.ndarray, iterations: int, success: bool, message: str,
              normal: np.ndarray | None = None) -> LeastSquaresSolution:
    size = len(x)
    return LeastSquaresSolution(x, cost, s[size], s[:size].T, iterations, success, message, normal)
