"""Gauss-Newton sphere fit against scipy.optimize.least_squares on 24 poses, measured in the same run.

Both solve the same problem (sphere9, same analytic Jacobian, evaluated once per point; same start:
fit()'s own seed, the general ellipsoid through the poses; tight tolerances) and must land on the same
optimum; the figures are ratios of median times. The peer is least_squares with its default method
('trf', its default, what a user reaching for scipy gets) and with 'lm' (MINPACK), which is faster on a
problem this small. Target: the whole fit()
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


def evaluated_once(fun):
    """fun's (residuals, Jacobian) at the last point asked, so that least_squares' separate calls for the
    residuals and the Jacobian at one point cost one evaluation, as our solver's do."""
    last: dict = {}

    def at(p):
        key = p.tobytes()
        if key not in last:
            last.clear()
            last[key] = fun(p)
        return last[key]

    return at


def main() -> int:
    model = SphereModel("sphere9")
    ratios = {"trf": ([], []), "lm": ([], [])}  # per method: (solvers alone, whole fit)
    for seed in range(5):
        accel = problem(seed)
        x0 = model.project(*seed_sphere(accel, G, cross_axis=True))
        fun = lambda p, a=accel: model.residual_and_jacobian(p, a, G)  # noqa: E731
        accel_t = np.ascontiguousarray(accel.T)

        def ours(accel_t=accel_t, x0=x0):
            # What fit() runs: the same residuals and Jacobian, stacked as [J^T; r] (one product gives
            # J^T J, J^T r and r^T r).
            return gauss_newton_stacked(lambda p: model.stacked(p, accel_t, G), x0)

        def scipy_lsq(method, fun=fun, x0=x0):
            at = evaluated_once(fun)
            return least_squares(lambda p: at(p)[0], x0, jac=lambda p: at(p)[1], method=method,
                                 ftol=1e-12, xtol=1e-12, gtol=1e-15)

        a = ours()
        line = f"seed {seed}: gauss_newton ({a.iterations} it)"
        runs = [ours, lambda accel=accel: fit(accel)] + [lambda m=m: scipy_lsq(m) for m in ratios]
        t_ours, t_fit, *t_peers = median_us(*runs)
        line += f" {t_ours:6.1f} us | whole fit() {t_fit:6.1f} us"
        for (method, (solver, whole)), t_scipy in zip(ratios.items(), t_peers):
            b = scipy_lsq(method)
            assert np.max(np.abs(a.x - b.x)) < 1e-9, f"different optimum ({method})"
            # The whole fit with scipy in place of our solver (seed, checks and sigma are the same work).
            t_fit_scipy = t_fit - t_ours + t_scipy
            solver.append(t_scipy / t_ours)
            whole.append(t_fit_scipy / t_fit)
            line += (f" | least_squares {method} {t_scipy:6.1f} us ({b.nfev} evals): solvers {t_scipy / t_ours:4.1f}x, "
                     f"whole fit {t_fit_scipy / t_fit:3.1f}x")
        print(line)
    for method, (solver, whole) in ratios.items():
        print(f"whole fit() on 24 poses vs the same fit() with least_squares(method={method!r}): median "
              f"{np.median(whole):.1f}x (target >= 5x); the solvers alone: median {np.median(solver):.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
