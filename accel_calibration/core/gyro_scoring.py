"""How far a given gyro calibration carries each pose's gravity direction onto the next one's: the motion
residual |R_i^T u_i - u_{i+1}| of gyro_fit, for any matrix and bias (ours, a peer's, a candidate axis map),
so that two calibrations are scored on the same motions with the same bias model."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .errors import CalibrationError
from .gyro_fit import Motion, interpolated_bias
from .pose import Pose
from .rotation_integration import IntervalSet


def motion_residuals_mrad(poses: Sequence[Pose], motions: Sequence[Motion | None], directions: ArrayLike,
                          matrix: ArrayLike, bias_radps: ArrayLike | None = None) -> np.ndarray:
    """Per motion k (between poses k and k + 1): |R_k^T u_k - u_{k+1}| in mrad, R_k the rotation of
    w = matrix (w_raw - b) over motion k (NaN where it is None). `directions`: the poses' unit
    gravity directions (n, 3) in the frame `matrix` maps into. `bias_radps`: one constant bias (a
    calibration file's); None: interpolated between the poses' gyro means (gyro_fit's model)."""
    u = np.asarray(directions, dtype=float)
    m = np.asarray(matrix, dtype=float)
    if u.shape != (len(poses), 3) or m.shape != (3, 3) or len(motions) != len(poses) - 1:
        raise CalibrationError("need one direction per pose, a 3 x 3 matrix and one motion per pair of poses")
    kept = [k for k, motion in enumerate(motions) if motion is not None]
    result = np.full(len(motions), np.nan)
    if not kept:
        return result
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
    rotations = IntervalSet(stamps, rates, shares).rotations(m, np.zeros(3))
    index = np.array(kept)
    moved = np.einsum("kba,kb->ka", rotations, u[index])
    result[index] = np.linalg.norm(moved - u[index + 1], axis=1) * 1e3
    return result
