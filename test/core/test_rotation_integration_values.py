"""rotation_integration's vectorised products give the values of the plain stacked matmul they replace."""
from __future__ import annotations

import numpy as np

from accel_calibration.core import rotation_integration as ri


def _interval_set(rng: np.random.Generator) -> ri.IntervalSet:
    stamps, rates, shares = [], [], []
    start = 0
    for samples in (2, 17, 1500, 3001):
        t = start + np.arange(samples, dtype=np.int64) * 1_000_000
        start = int(t[-1]) + 10**9
        stamps.append(t)
        rates.append(0.8 * rng.standard_normal((samples, 3)))
        shares.append(np.linspace(0.0, 1.0, samples))
    return ri.IntervalSet(stamps, rates, shares)


def _reference(intervals: ri.IntervalSet, matrix: np.ndarray, bias: np.ndarray) -> np.ndarray:
    """The per-motion sums as computed before: (N, 3, 3) @ (N, 3, 3), then weights^T factors per motion."""
    mean, cross = intervals._rates(bias)
    theta = intervals.rotation_vectors(matrix, bias)
    running, _ = intervals._running(theta)
    weights = (ri.quaternion_to_matrix(running) @ ri.right_jacobian(theta)).reshape(-1, 9)
    factors = np.concatenate([intervals.dt_s[:, None] * mean, intervals.coning_weight[:, None] * cross,
                              intervals._fixed_factors], axis=1)
    return np.stack([weights[s:e + 1].T @ factors[s:e + 1] for s, e in zip(intervals.first, intervals.last)])


def test_frames_times_jacobians_is_the_stacked_matmul():
    rng = np.random.default_rng(3)
    frames, jacobians = rng.standard_normal((1000, 3, 3)), rng.standard_normal((1000, 3, 3))
    rows = ri._frames_times_jacobians(frames.reshape(-1, 9).T.copy(), jacobians.reshape(-1, 9).T.copy())
    np.testing.assert_allclose(rows, (frames @ jacobians).reshape(-1, 9).T, rtol=0, atol=1e-14)


def test_matrix_and_jacobian_rows_are_the_stacked_forms():
    rng = np.random.default_rng(5)
    q, theta = rng.standard_normal((500, 4)), 0.05 * rng.standard_normal((500, 3))
    assert np.array_equal(ri._matrix_rows(q).T.reshape(-1, 3, 3), ri.quaternion_to_matrix(q))
    assert np.array_equal(ri._jacobian_rows(theta).T.reshape(-1, 3, 3), ri.right_jacobian(theta))


def test_rotations_and_derivatives_keep_their_values(monkeypatch):
    rng = np.random.default_rng(4)
    intervals = _interval_set(rng)
    matrix = np.eye(3) + 0.02 * rng.standard_normal((3, 3))
    bias = np.array([1e-3, -2e-3, 5e-4])
    captured = {}
    original = np.stack

    def spy(arrays, *args, **kwargs):  # the per-motion sums, as rotations_and_derivatives stacks them
        result = original(arrays, *args, **kwargs)
        if result.ndim == 3 and result.shape[1:] == (9, 12):
            captured["sums"] = result
        return result

    monkeypatch.setattr(ri.np, "stack", spy)
    intervals.rotations_and_derivatives(matrix, bias, with_bias=True)
    monkeypatch.setattr(ri.np, "stack", original)
    reference = _reference(intervals, matrix, bias)
    np.testing.assert_allclose(captured["sums"], reference, rtol=1e-12, atol=1e-12 * np.abs(reference).max())
