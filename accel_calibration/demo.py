"""`make demo`: calibrate a badly calibrated MPU-6050-class accelerometer and show before/after errors."""
from __future__ import annotations

import sys

import numpy as np
from scipy.spatial.transform import Rotation

from . import MG, STANDARD_GRAVITY, fit


def main() -> int:
    rng = np.random.default_rng(2026)
    bias = np.array([0.35, -0.42, 0.51])  # m/s^2: 36..52 mg
    matrix = np.array([[1.021, 0.0, 0.0], [0.012, 0.984, 0.0], [-0.009, 0.015, 1.017]])
    directions = Rotation.random(24, random_state=rng).apply([0.0, 0.0, 1.0])
    directions[:6] = np.vstack([np.eye(3), -np.eye(3)])
    # Pose means over ~2 s at 200 Hz of 4 mg noise: ~0.2 mg per axis.
    raw = (STANDARD_GRAVITY * directions) @ np.linalg.inv(matrix).T + bias + rng.normal(0, 0.2 * MG, (24, 3))
    print(f"simulated sensor: {len(raw)} static poses, bias {np.round(bias, 3)} m/s^2")
    result = fit(raw)
    print(result.summary())
    if not result.success:
        return 1
    fresh = Rotation.random(500, random_state=rng).apply([0.0, 0.0, STANDARD_GRAVITY])
    raw_fresh = fresh @ np.linalg.inv(matrix).T + bias
    before = np.linalg.norm(raw_fresh - fresh, axis=1) / MG
    after = np.linalg.norm(result.calibration.apply(raw_fresh) - fresh, axis=1) / MG
    print(f"error at 500 fresh orientations: before {before.mean():.1f} mg mean / {before.max():.1f} mg max, "
          f"after {after.mean():.3f} mg mean / {after.max():.3f} mg max")
    return 0


if __name__ == "__main__":
    sys.exit(main())
