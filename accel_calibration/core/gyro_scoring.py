"""How far a given gyro calibration carries each pose's gravity direction onto the next one's: the motion
residual |R_i^T u_i - u_{i+1}| of gyro_fit, for any matrix and bias (ours, a peer's, a candidate axis map),
so that two calibrations are scored on the same motions with the same bias model."""
from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from .errors import CalibrationError
from .pose import Pose
from .rotation_integration import IntervalSet


class GyroSamples(Protocol):
    """What scoring needs of a motion (gyro_fit.Motion has it): stamps (n,) ns and raw rates (n, 3)."""

    @property
    def stamps_ns(self) -> np.ndarray: ...

    @property
    def gyro_radps(self) -> np.ndarray: ...


def interpolated_bias(poses: Sequence[Pose], k: int, stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bias during motion k as gyro_fit takes it: linear in time between the gyro means of poses k and
    k + 1 (their mid-times); (bias per sample (n, 3), the later pose's share per sample (n,))."""
    before = 0.5 * (poses[k].start_ns + poses[k].end_ns)
    after = 0.5 * (poses[k + 1].start_ns + poses[k + 1].end_ns)
    share = np.clip((stamps_ns - before) / (after - before), 0.0, 1.0)
    earlier, later = (np.asarray(p.gyro_radps, dtype=float) for p in (poses[k], poses[k + 1]))
    return (1.0 - share)[:, None] * earlier + share[:, None] * later, share


def motion_intervals(poses: Sequence[Pose], motions: Sequence[GyroSamples | None], kept: Sequence[int],
                     bias_radps: ArrayLike | None = None) -> IntervalSet:
    """The sample intervals of motions[k] for k in `kept` (none of them None), the bias taken off: one
    constant `bias_radps`, or (None) interpolated between the poses' gyro means."""
    stamps, rates, shares = [], [], []
    for k in kept:
        motion = motions[k]
        assert motion is not None
        t = np.asarray(motion.stamps_ns, dtype=np.int64)
        raw = np.asarray(motion.gyro_radps, dtype=float)
        bias, share = interpolated_bias(poses, k, t)
        if bias_radps is not None:
            bias = np.broadcast_to(np.asarray(bias_radps, dtype=float), raw.shape)
        stamps.append(t)
        rates.append(raw - bias)
        shares.append(share)
    return IntervalSet(stamps, rates, shares)


def motion_rotations(poses: Sequence[Pose], motions: Sequence[GyroSamples | None], matrix: ArrayLike,
                     bias_radps: ArrayLike | None = None) -> tuple[list[int], np.ndarray]:
    """(indices k of the motions given, not None; their rotations R_k (K, 3, 3) of w = matrix (w_raw - b)),
    the bias as in motion_residuals_mrad."""
    kept = [k for k, motion in enumerate(motions) if motion is not None]
    if not kept:
        return kept, np.zeros((0, 3, 3))
    intervals = motion_intervals(poses, motions, kept, bias_radps)
    return kept, intervals.rotations(np.asarray(matrix, dtype=float), np.zeros(3))


def motion_residuals_mrad(poses: Sequence[Pose], motions: Sequence[GyroSamples | None], directions: ArrayLike,
                          matrix: ArrayLike, bias_radps: ArrayLike | None = None) -> np.ndarray:
    """Per motion k (between poses k and k + 1): |R_k^T u_k - u_{k+1}| in mrad, R_k the rotation of
    w = matrix (w_raw - b) over motion k (NaN where it is None). `directions`: the poses' unit
    gravity directions (n, 3) in the frame `matrix` maps into. `bias_radps`: one constant bias (a
    calibration file's); None: interpolated between the poses' gyro means (gyro_fit's model)."""
    u = np.asarray(directions, dtype=float)
    m = np.asarray(matrix, dtype=float)
    if u.shape != (len(poses), 3) or m.shape != (3, 3) or len(motions) != len(poses) - 1:
        raise CalibrationError("need one direction per pose, a 3 x 3 matrix and one motion per pair of poses")
    result = np.full(len(motions), np.nan)
    kept, rotations = motion_rotations(poses, motions, m, bias_radps)
    if not kept:
        return result
    index = np.array(kept)
    moved = np.einsum("kba,kb->ka", rotations, u[index])
    result[index] = np.linalg.norm(moved - u[index + 1], axis=1) * 1e3
    return result
