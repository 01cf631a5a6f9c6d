"""Is the model observable from these poses? Direction coverage and normal-matrix conditioning.

A sphere fit needs the gravity vector seen from well spread directions; when it is not, the fit
is refused with a message naming the directions that are missing, so a person knows how to turn
the vehicle next.
"""
from __future__ import annotations

import numpy as np

# A pose "has x pointing down" when its measured specific force is within ~45 deg of -x
# (an accelerometer at rest reads +g upwards, so a_x ~ -g means the x axis points down).
FACE_COSINE = 0.7
# Above this, the Jacobi-scaled normal matrix is too ill-conditioned for the noise of real poses:
# parameter combinations are then set by noise, not by data. Six faces give ~10-50; poses in one
# hemisphere of one axis give 1e4-1e6.
CONDITION_LIMIT = 1e4
SAME_DIRECTION_DEG = 15.0

def face_name(axis: int, sign: int) -> str:
    return f"{'xyz'[axis]} pointing {'up' if sign > 0 else 'down'}"


def missing_directions(directions: np.ndarray) -> list[str]:
    """Faces (x up, x down, ...) that no pose comes near. `directions` are unit vectors (N, 3) of
    the measured specific force."""
    highest, lowest = directions.max(axis=0), directions.min(axis=0)
    missing = []
    for axis in range(3):
        if highest[axis] < FACE_COSINE:
            missing.append(face_name(axis, +1))
        if lowest[axis] > -FACE_COSINE:
            missing.append(face_name(axis, -1))
    return missing


def angular_spread_deg(directions: np.ndarray) -> float:
    """Largest angle between any pose direction and the mean direction."""
    mean = directions.mean(axis=0)
    norm = np.linalg.norm(mean)
    if norm < 1e-9:
        return 180.0
    cosines = np.clip(directions @ (mean / norm), -1.0, 1.0)
    return float(np.degrees(np.arccos(cosines.min())))


def scaled_condition_number(jacobian: np.ndarray) -> float:
    """Condition number of J^T J after Jacobi scaling (unit diagonal), so parameter units don't count."""
    normal = jacobian.T @ jacobian
    diag = np.sqrt(normal.diagonal())
    if np.any(diag == 0) or not np.all(np.isfinite(normal)):
        return float("inf")
    eigenvalues = np.linalg.eigvalsh(normal / np.outer(diag, diag))  # symmetric: cheaper than an SVD
    return float(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else float("inf")


def describe_missing(missing: list[str]) -> str:
    if not missing:
        # Every face is covered, yet some parameter combination is not: the cross-axis terms need
        # poses where two axes both feel gravity.
        return "every face is covered but too few poses lie between the axes: add poses tilted about two axes"
    return "no pose with " + ", no pose with ".join(missing)
