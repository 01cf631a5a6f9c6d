"""Is the model observable from these poses? Direction coverage, normal-matrix conditioning, and
the uncertainty of each parameter.

A sphere fit needs the gravity vector seen from well spread directions; when it is not, the fit
is refused with a message naming the directions that are missing, so a person knows how to turn
the vehicle next. Whether a fit is good enough to apply is judged by the sigma of each parameter
(bias, scale, misalignment) against its bound, not by which faces were seen; the orientation
advised next is the one whose pose would lower the largest sigma most (from the fit's normal
matrix with that pose added), spoken as faces: "turn x down", "turn x and y down (45 deg)".
"""
from __future__ import annotations

import enum
import itertools
import math
from dataclasses import dataclass

import numpy as np

from .lapack import dsyevd as syevd
from .models import SphereModel, matrix_entries
from .units import AXES, MG

# A pose "has x pointing down" when its measured specific force is within ~45 deg of -x
# (an accelerometer at rest reads +g upwards, so a_x ~ -g means the x axis points down).
FACE_COSINE = 0.7
# Above this, the Jacobi-scaled normal matrix is too ill-conditioned for the noise of real poses:
# parameter combinations are then set by noise, not by data. Six faces give ~10-50; poses in one
# hemisphere of one axis give 1e4-1e6.
CONDITION_LIMIT = 1e4
SAME_DIRECTION_DEG = 15.0


class Face(enum.Enum):
    """An axis pointing up or down: (axis index, sign of the specific force along it)."""

    X_UP = (0, 1)
    X_DOWN = (0, -1)
    Y_UP = (1, 1)
    Y_DOWN = (1, -1)
    Z_UP = (2, 1)
    Z_DOWN = (2, -1)

    @property
    def axis(self) -> int:
        return int(self.value[0])

    @property
    def sign(self) -> int:
        return int(self.value[1])

    @property
    def way(self) -> str:
        return "up" if self.sign > 0 else "down"

    def __str__(self) -> str:
        return f"{AXES[self.axis]} pointing {self.way}"

    @property
    def turn(self) -> str:
        """The advice that brings a pose to this face: 'turn x down'."""
        return f"turn {AXES[self.axis]} {self.way}"

    @property
    def direction(self) -> tuple[float, float, float]:
        """The unit specific force of a pose at this face."""
        unit = [0.0, 0.0, 0.0]
        unit[self.axis] = float(self.sign)
        return (unit[0], unit[1], unit[2])


def missing_faces(directions: np.ndarray) -> list[Face]:
    """Faces (x up, x down, ...) that no pose comes near. `directions` are unit vectors (N, 3) of
    the measured specific force."""
    highest, lowest = directions.max(axis=0).tolist(), directions.min(axis=0).tolist()
    missing = []
    for axis in range(3):
        if highest[axis] < FACE_COSINE:
            missing.append(Face((axis, 1)))
        if lowest[axis] > -FACE_COSINE:
            missing.append(Face((axis, -1)))
    return missing


def missing_directions(directions: np.ndarray) -> list[str]:
    """The missing faces (missing_faces), said: 'x pointing up', ..."""
    return [str(face) for face in missing_faces(directions)]


def angular_spread_deg(directions: np.ndarray) -> float:
    """Largest angle between any pose direction and the mean direction."""
    mean = directions.sum(axis=0) / len(directions)
    norm = math.sqrt(float(mean.dot(mean)))
    if norm < 1e-9:
        return 180.0
    # Scalar math on the one smallest cosine: this runs on every fit.
    return math.degrees(math.acos(min(max(float(directions.dot(mean / norm).min()), -1.0), 1.0)))


def scaled_condition_number(jacobian: np.ndarray) -> float:
    """Condition number of J^T J after Jacobi scaling (unit diagonal), so parameter units don't count."""
    return normal_condition_number(jacobian.T @ jacobian)


def normal_condition_number(normal: np.ndarray) -> float:
    """scaled_condition_number from the normal matrix J^T J itself (when the caller has it already)."""
    diag = np.sqrt(normal.diagonal())
    if np.any(diag == 0) or not np.all(np.isfinite(normal)):
        return float("inf")
    eigenvalues = np.linalg.eigvalsh(normal / np.outer(diag, diag))  # symmetric: cheaper than an SVD
    return float(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else float("inf")


def condition_and_inverse(normal: np.ndarray) -> tuple[float, np.ndarray | None]:
    """normal_condition_number and the inverse of the normal matrix from one eigendecomposition of the
    Jacobi-scaled matrix (what a fit needs for its observability check, sigma and leverages). The
    inverse is None where the condition number is infinite."""
    diag = np.sqrt(normal.diagonal())
    outer = diag[:, None] * diag
    scaled = normal / outer
    # A zero or non-finite diagonal, or a non-finite entry: the scaled entries of a normal matrix lie
    # within +-1, so their sum is finite exactly when they all are (one reduction instead of two).
    if not (diag.min() > 0 and math.isfinite(float(scaled.sum()))):
        return float("inf"), None
    # LAPACK's syevd directly (what numpy's eigh calls): on a 9 x 9 matrix numpy's wrapper costs more
    # than the decomposition, and this runs on every fit.
    eigenvalues, vectors, info = syevd(scaled, lower=1)
    smallest, largest = float(eigenvalues[0]), float(eigenvalues[-1])
    if info != 0 or not smallest > 0:
        return float("inf"), None
    inverse: np.ndarray = np.dot(vectors / eigenvalues, vectors.T) / outer
    return largest / smallest, inverse


def describe_missing(missing: list[str]) -> str:
    if not missing:
        # Every face is covered, yet some parameter combination is not: the cross-axis terms need
        # poses where two axes both feel gravity.
        return "every face is covered but too few poses lie between the axes: add poses tilted about two axes"
    return "no pose with " + ", no pose with ".join(missing)


# ------------------------------------------------------------------ observability by uncertainty


@dataclass(frozen=True)
class SigmaBounds:
    """Largest 1-sigma the sigma gate accepts for each kind of parameter. Scale and misalignment are
    relative to the gain of their row of M, so the bounds hold in any raw unit. The defaults cost
    alike at 1 g: 5 mg of bias, 5000 ppm of scale and 5 mrad of misalignment are each ~5 mg."""

    bias_mg: float = 5.0
    scale_ppm: float = 5000.0
    misalignment_mrad: float = 5.0


@dataclass(frozen=True)
class ParameterSigma:
    """One parameter's 1-sigma in the unit people quote it in, and its bound."""

    name: str  # "bias x", "scale y", "misalignment zx" (M_zx: how much of x leaks into z)
    sigma: float
    unit: str  # mg, ppm, mrad
    bound: float

    @property
    def ratio(self) -> float:
        return self.sigma / self.bound

    def __str__(self) -> str:
        return f"{self.name} uncertainty {self.sigma:.3g} {self.unit} above {self.bound:g} {self.unit}"


def parameter_sigmas(model: str, bias_sigma: np.ndarray, matrix_sigma: np.ndarray, matrix: np.ndarray,
                     bounds: SigmaBounds) -> list[ParameterSigma]:
    """Every estimated parameter's sigma against its bound: bias in mg (raw units / 1 mg, as SI input
    gives), scale in ppm and misalignment in mrad of the gain of their row of M."""
    gains = np.linalg.norm(matrix, axis=1)
    out = [ParameterSigma(f"bias {AXES[i]}", float(bias_sigma[i]) / MG, "mg", bounds.bias_mg) for i in range(3)]
    for i, j in matrix_entries(model):
        relative = float(matrix_sigma[i, j]) / float(gains[i])
        if i == j:
            out.append(ParameterSigma(f"scale {AXES[i]}", relative * 1e6, "ppm", bounds.scale_ppm))
        else:
            out.append(ParameterSigma(f"misalignment {AXES[i]}{AXES[j]}", relative * 1e3, "mrad",
                                      bounds.misalignment_mrad))
    return out


def worst(sigmas: list[ParameterSigma]) -> ParameterSigma:
    """The parameter with the largest sigma against its bound (a NaN sigma counts as largest)."""
    return max(sigmas, key=lambda s: s.ratio if s.ratio == s.ratio else float("inf"))


@dataclass(frozen=True)
class Uncertainty:
    """A sphere fit at its solution: the parameters [b, free entries of M], the normal matrix J^T J of
    the residuals |M (a - b)| - g over the poses, and the residual variance of one pose (raw units^2,
    NaN with no degree of freedom). Covariance = variance x (J^T J)^-1. With a temperature model, J
    is that of the poses corrected to the reference temperature (the temperature terms left out)."""

    model: str  # six or sphere9
    bias: np.ndarray
    matrix: np.ndarray
    gravity: float
    normal: np.ndarray
    variance: float

    def sigma(self) -> tuple[np.ndarray, np.ndarray]:
        """(bias sigma (3,), matrix sigma (3, 3), zero where the model fixes the entry)."""
        stds = np.sqrt(np.abs(np.diag(inverse_normal(self.normal))) * self.variance)
        matrix = np.zeros((3, 3))
        for k, (i, j) in enumerate(matrix_entries(self.model)):
            matrix[i, j] = stds[3 + k]
        return stds[:3], matrix

    def scale(self, bounds: SigmaBounds) -> np.ndarray:
        """Each parameter's bound in its own unit (raw units for b, M's units for M)."""
        gains = np.linalg.norm(self.matrix, axis=1)
        entries = [bounds.bias_mg * MG] * 3
        for i, j in matrix_entries(self.model):
            entries.append(gains[i] * (bounds.scale_ppm * 1e-6 if i == j else bounds.misalignment_mrad * 1e-3))
        return np.array(entries)


def inverse_normal(normals: np.ndarray) -> np.ndarray:
    """Inverse of a normal matrix J^T J (or of a stack of them), Jacobi-scaled first (their entries span many decades:
    bias in m/s^2 or counts, M unitless); a singular one gives its pseudo-inverse."""
    diag = np.sqrt(np.abs(np.diagonal(normals, axis1=-2, axis2=-1)))
    diag = np.where(diag > 0, diag, 1.0)
    scaled = normals / (diag[..., :, None] * diag[..., None, :])
    try:
        inverse = np.linalg.inv(scaled)
    except np.linalg.LinAlgError:
        inverse = np.linalg.pinv(scaled, hermitian=True)
    result: np.ndarray = inverse / (diag[..., :, None] * diag[..., None, :])
    return result


def _candidate_directions() -> np.ndarray:
    """The 26 orientations a person can be told: 6 faces, 12 edges (two axes 45 deg down or up),
    8 corners (three axes 35 deg), faces first so that a tie goes to the simplest to say."""
    steps = [np.array(v, dtype=float) for v in itertools.product((-1, 0, 1), repeat=3) if any(v)]
    steps.sort(key=lambda v: int(np.count_nonzero(v)))
    return np.array([v / np.linalg.norm(v) for v in steps])


CANDIDATE_DIRECTIONS = _candidate_directions()  # unit vectors of the specific force (up) in the sensor frame


def orientation_advice(direction: np.ndarray) -> str:
    """What to tell a person for a specific-force direction (the sensor axes that point up have a
    positive component): its nearest candidate, e.g. "turn z down", "turn x up and y down (45 deg)",
    "turn x, y and z down (35 deg)"."""
    nearest = CANDIDATE_DIRECTIONS[int(np.argmax(CANDIDATE_DIRECTIONS @ np.asarray(direction, dtype=float)))]
    groups: dict[str, list[str]] = {}
    for axis in range(3):
        if nearest[axis] != 0:
            groups.setdefault("up" if nearest[axis] > 0 else "down", []).append(AXES[axis])

    def axes(names: list[str]) -> str:
        return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]

    text = "turn " + " and ".join(f"{axes(names)} {way}" for way, names in groups.items())
    count = int(np.count_nonzero(nearest))
    return text if count == 1 else f"{text} ({45 if count == 2 else 35} deg)"


@dataclass(frozen=True)
class NextOrientation:
    """The orientation whose pose would lower the largest bound-normalised sigma most."""

    direction: np.ndarray  # unit specific force in the sensor frame
    text: str  # "turn z up"
    worst_after: float  # largest sigma / bound with that pose added (NaN when the variance is unknown)


def next_orientation(uncertainty: Uncertainty, bounds: SigmaBounds) -> NextOrientation | None:
    """Add one pose at each candidate orientation to the fit's normal matrix (the pose reads exactly g
    there, with the fit's residual variance) and keep the one that leaves the largest sigma / bound
    smallest. None when the fit's numbers do not allow it (not finite)."""
    u = uncertainty
    model = SphereModel(u.model)
    try:
        raw = u.bias + np.linalg.solve(u.matrix, u.gravity * CANDIDATE_DIRECTIONS.T).T
    except np.linalg.LinAlgError:
        return None
    _, rows = model.residual_and_jacobian(model.pack(u.bias, u.matrix), raw, u.gravity)
    normals = u.normal[None] + rows[:, :, None] * rows[:, None, :]
    if not (np.all(np.isfinite(normals)) and np.all(np.isfinite(u.scale(bounds)))):
        return None
    unit_variances = np.abs(np.diagonal(inverse_normal(normals), axis1=1, axis2=2))
    worst_unit = np.max(np.sqrt(unit_variances) / u.scale(bounds), axis=1)  # ranking needs no variance
    best = int(np.argmin(worst_unit))
    direction = CANDIDATE_DIRECTIONS[best]
    variance = u.variance if np.isfinite(u.variance) else float("nan")
    return NextOrientation(direction, orientation_advice(direction), float(worst_unit[best] * np.sqrt(variance)))
