"""The rotation between two IMUs of one vehicle, from the poses both held at the same time: each pose's
gravity direction in each IMU's calibrated axes, and the rotation that best maps one set onto the other
(Wahba's problem, solved by Gauss-Newton from the identity: redundant IMUs are nominally aligned).

Gravity at one pose fixes two of the three angles: a rotation about gravity leaves it unchanged. Only
poses of several distinct orientations observe all three; the result says which axes were observed and
gives the least rotation about the others (no guess)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..core.calibration import Calibration
from ..core.pose import Pose

MIN_OVERLAP = 0.5  # of the shorter pose: two IMUs' still intervals of the same holding
OBSERVED_FRACTION = 0.05  # an axis is observed where the information is at least this share of the poses'


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _exp(rotation_vector: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    matrix: np.ndarray = Rotation.from_rotvec(rotation_vector).as_matrix()
    return matrix


@dataclass(frozen=True)
class RelativeRotation:
    """`matrix` maps directions in the reference IMU's calibrated axes to the other's: u_other = R u_ref."""

    matrix: np.ndarray
    rotation_mrad: np.ndarray  # R's rotation vector, mrad, in the reference's axes
    sigma_mrad: np.ndarray  # 1 sigma per reference axis; NaN about an axis not observed
    poses: int  # common poses used
    residual_mrad: float  # rms angle between u_other and R u_ref
    unobserved: np.ndarray | None  # the axis no pose observed a rotation about (a unit vector), if any

    def describe(self, reference: str, other: str) -> str:
        angles = " ".join(f"{v:+.2f}" for v in self.rotation_mrad)
        sigma = " ".join("n/a" if np.isnan(s) else f"{s:.2f}" for s in self.sigma_mrad)
        text = (f"rotation {reference} -> {other}: {angles} mrad about x y z (1 sigma {sigma} mrad), "
                f"{self.poses} common poses, residual {self.residual_mrad:.2f} mrad rms")
        if self.unobserved is None:
            return text + "; all three axes observed"
        axis = " ".join(f"{v:+.2f}" for v in self.unobserved)
        return (text + f"; rotation about ({axis}) not observed (gravity in too few distinct directions: "
                "hold the vehicle in several orientations)")


def common_directions(poses_a: Sequence[Pose], calibration_a: Calibration, poses_b: Sequence[Pose],
                      calibration_b: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Unit gravity directions (n, 3) in each IMU's calibrated axes of the poses both held at once (still
    intervals overlapping by at least half the shorter one)."""
    first, second = [], []
    for a in poses_a:
        for b in poses_b:
            overlap = min(a.end_ns, b.end_ns) - max(a.start_ns, b.start_ns)
            if overlap > MIN_OVERLAP * min(a.end_ns - a.start_ns, b.end_ns - b.start_ns) and overlap > 0:
                first.append(calibration_a.apply(a.accel_mps2, a.temperature_degc))
                second.append(calibration_b.apply(b.accel_mps2, b.temperature_degc))
                break
    if not first:
        return np.zeros((0, 3)), np.zeros((0, 3))
    ua, ub = np.array(first), np.array(second)
    return ua / np.linalg.norm(ua, axis=1, keepdims=True), ub / np.linalg.norm(ub, axis=1, keepdims=True)


def frame_sigma_mrad(calibration: Calibration) -> float:
    """How well a calibration fixes its own axes: the 1 sigma of M's off-diagonal terms (a tilt of the
    calibrated frame, mrad), the largest; 0 where the calibration keeps none."""
    if calibration.matrix_sigma is None:
        return 0.0
    off = ~np.eye(3, dtype=bool)
    return float(np.max(np.asarray(calibration.matrix_sigma)[off] / np.abs(np.diag(calibration.matrix)).min())) * 1e3


def relative_rotation(ua: np.ndarray, ub: np.ndarray, frame_sigma: float = 0.0) -> RelativeRotation | None:
    """The rotation R with ub ~ R ua (least squares), its 1 sigma from the residuals and `frame_sigma`
    (mrad: how well the two calibrations fix their axes, added in quadrature), the axis not observed;
    None without two common poses."""
    n = len(ua)
    if n < 2:
        return None
    matrix = np.eye(3)
    information = np.zeros((3, 3))
    for _ in range(8):  # Gauss-Newton on R <- exp(d) R; converges in 2-3 steps for small angles
        predicted = ua @ matrix.T
        residual = (ub - predicted).ravel()
        jacobian = np.vstack([-_skew(v) for v in predicted])
        information = jacobian.T @ jacobian
        step = np.linalg.lstsq(jacobian, residual, rcond=1e-6)[0]  # least norm about an unobserved axis
        matrix = _exp(step) @ matrix
        if np.linalg.norm(step) < 1e-12:
            break
    residual = ub - ua @ matrix.T
    values, vectors = np.linalg.eigh(information)
    observed = values > OBSERVED_FRACTION * n
    dof = max(2 * n - int(observed.sum()), 1)
    variance = float(np.sum(residual**2)) / dof
    inverse = sum(np.outer(vectors[:, k], vectors[:, k]) / values[k] for k in range(3) if observed[k])
    sigma = np.hypot(np.sqrt(variance * np.diag(np.asarray(inverse))) * 1e3, frame_sigma)
    unobserved = None if observed.all() else vectors[:, int(np.argmin(values))]
    if unobserved is not None:
        sigma = np.where(np.abs(unobserved) > 0.1, np.nan, sigma)  # an axis with a share of the blind one
    from scipy.spatial.transform import Rotation

    rotation_vector = Rotation.from_matrix(matrix).as_rotvec()
    angles = np.linalg.norm(residual, axis=1)
    return RelativeRotation(matrix, rotation_vector * 1e3, sigma, n, float(np.sqrt(np.mean(angles**2)) * 1e3),
                            None if unobserved is None else unobserved * np.sign(unobserved[np.argmax(
                                np.abs(unobserved))]))
