"""Gauss-Newton sphere fit against scipy.optimize.least_squares on 24 poses, measured in the same run.

Both solve the same problem (sphere9, same analytic Jacobian, same start: fit()'s own seed, the general
ellipsoid through the poses; tight tolerances) and must land on the same optimum; the figures are ratios
of median times. Target (issue 13): the whole fit()
>= 5x faster than the same fit() with least_squares as its solver; the solver alone is printed too.
"""
import sys
import timeit

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from accel_calibration import fit
from accel_calibration.core.gauss_newton import gauss_newton_stacked
from accel_calibration.core.models import SphereModel, seed_sphere

G = 9.80665


def problem(seed):
    rng = np.random.default_rng(seed)
    directions = Rotation.random(24, random_state=rng).apply([0.0, 0.0, 1.0])
    directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    matrix = np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3)))
    bias = rng.normal(0, 0.3, 3)
    return (G * directions) @ np.linalg.inv(matrix).T + bias + rng.normal(0, 0.002, (24, 3))


def median_us(*stmts, number=200, repeat=7):
    """Median time per call of each statement, in us. The statements take turns within each repeat, so
    that load from other processes on a shared machine weighs on all of them alike."""
    times = [[] for _ in stmts]
    for _ in range(repeat):
        for stmt, kept in zip(stmts, times):
            kept.append(timeit.timeit(stmt, number=number))
    return [float(np.median(kept)) / number * 1e6 for kept in times]


def main() -> int:
    model = SphereModel("sphere9")
    ratios_solver, ratios_fit, ratios_alone = [], [], []
    for seed in range(5):
        accel = problem(seed)
        x0 = model.project(*seed_sphere(accel, G, cross_axis=True))
        fun = lambda p, a=accel: model.residual_and_jacobian(p, a, G)  # noqa: E731
        accel_t = np.ascontiguousarray(accel.T)

        def ours(accel_t=accel_t, x0=x0):
            # What fit() runs: the same residuals and Jacobian, stacked as [J^T; r] (one product gives
            # J^T J, J^T r and r^T r).
            return gauss_newton_stacked(lambda p: model.stacked(p, accel_t, G), x0)

        def scipy_lsq(fun=fun, x0=x0):
            return least_squares(lambda p: fun(p)[0], x0, jac=lambda p: fun(p)[1], ftol=1e-12, xtol=1e-12, gtol=1e-15)

        a, b = ours(), scipy_lsq()
        assert np.max(np.abs(a.x - b.x)) < 1e-9, "different optimum"
        t_ours, t_scipy, t_fit = median_us(ours, scipy_lsq, lambda accel=accel: fit(accel))
        # The whole fit with scipy in place of our solver (seed, checks and sigma are the same work).
        t_fit_scipy = t_fit - t_ours + t_scipy
        ratios_solver.append(t_scipy / t_ours)
        ratios_fit.append(t_fit_scipy / t_fit)
        ratios_alone.append(t_scipy / t_fit)
        print(f"seed {seed}: gauss_newton {t_ours:7.1f} us ({a.iterations} it) | least_squares {t_scipy:7.1f} us "
              f"({b.nfev} evals) | ratio {t_scipy / t_ours:4.1f}x | whole fit() {t_fit:6.1f} us "
              f"(with scipy: {t_fit_scipy / t_fit:3.1f}x slower; least_squares alone {t_scipy / t_fit:3.1f}x fit())")
    print(f"whole fit() on 24 poses vs the same fit() with scipy.optimize.least_squares: median "
          f"{np.median(ratios_fit):.1f}x (target >= 5x); the solvers alone: median {np.median(ratios_solver):.1f}x; "
          f"least_squares alone vs the whole fit(): median {np.median(ratios_alone):.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
