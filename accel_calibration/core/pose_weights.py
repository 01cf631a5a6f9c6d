"""Weights for an efficient fit: each pose by the inverse variance of its mean, w_i = 1 / (s_i^2 + tau^2).

s_i is the pose mean's own noise (its samples' spread over sqrt(samples)); tau is one common extra error
per pose (what the sample noise does not explain: the sensor settling, a mount that is not quite the
same, slow drift), estimated from the residuals so that the weighted chi^2 equals its degrees of freedom
(the Paule-Mandel estimator of meta-analysis: the weighted fit and tau are iterated to agreement).
Without tau, weights from the sample count alone trust long poses far beyond what they deliver when the
poses scatter more than their samples allow. Numpy only.
"""
from __future__ import annotations

import numpy as np

# Paule-Mandel iterations (a weighted refit each). They stop when tau^2 moves less than this fraction of a
# typical pose's variance: the weights then move by as little, which moves the estimate by a negligible
# fraction of its sigma (chi^2/dof is 1 to about as much). One or two refits.
MAX_REWEIGHTS = 8
TAU_TOLERANCE = 1e-3


def weighting_applies(pose_sigma: np.ndarray | None) -> bool:
    """Weights change the fit only when every pose's own noise is known (> 0) and they differ: equal
    noise gives equal weights, today's fit exactly, which is then taken as it is."""
    if pose_sigma is None or len(pose_sigma) == 0:
        return False
    low, high = float(pose_sigma.min()), float(pose_sigma.max())
    return low > 0 and high > low


def extra_variance(squared_residuals: np.ndarray, pose_variance: np.ndarray, dof: int) -> float:
    """tau^2 >= 0 with sum_i R_i / (v_i + tau^2) = dof (R_i: pose i's sum of squared residual components,
    v_i its own variance per component); 0 when the poses scatter no more than their own noise allows.
    The left side falls monotonically with tau^2: Newton's method from below, safeguarded by bisection."""
    if dof < 1:
        return 0.0
    r = np.asarray(squared_residuals, dtype=float)
    v = np.asarray(pose_variance, dtype=float)

    def excess(tau2: float) -> float:
        return float(np.sum(r / (v + tau2))) - dof

    if excess(0.0) <= 0.0:
        return 0.0
    low, high = 0.0, float(r.sum()) / dof  # at high every term is below R_i / high: the sum is below dof
    tau2 = low
    for _ in range(100):
        value = excess(tau2)
        if abs(value) <= 1e-13 * dof:
            return tau2
        if value > 0:
            low = tau2
        else:
            high = tau2
        if high - low <= 1e-15 * high:
            break
        slope = -float(np.sum(r / (v + tau2) ** 2))
        step = tau2 - value / slope if slope < 0 else high
        tau2 = step if low < step < high else 0.5 * (low + high)
    return tau2


def pose_weights(pose_variance: np.ndarray, tau2: float) -> np.ndarray:
    """w_i = 1 / (v_i + tau^2), scaled to a mean of 1 (the scale cancels from the estimate and from sigma
    rescaled by chi^2/dof; at mean 1 a pose added to the normal matrix counts as a typical one)."""
    weights = 1.0 / (np.asarray(pose_variance, dtype=float) + tau2)
    scaled: np.ndarray = weights / weights.mean()
    return scaled
