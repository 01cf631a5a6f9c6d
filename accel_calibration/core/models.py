"""The error models: how raw accelerometer output relates to the true specific force.

Convention everywhere: a_true = M (a_raw - b), with b the output at zero input (m/s^2 or the raw
units of the data) and M unitless (or raw-units -> m/s^2).

Sphere models fit without knowing orientations (|a_true| = g at every static pose):
- ``six``: diagonal M and b (6 parameters), the seed paper's model.
- ``sphere9``: lower-triangular M and b (9). The sensor x axis is the reference and the sensor y
  axis lies in the true x-y plane, which removes the unobservable rotation so the fit is unique.
Reference models fit poses with known gravity directions by linear least squares, in the forward
direction a_raw = b + S a_true (+ q * a_true^2), S = M^-1, because the noise lives in a_raw:
- ``reference12``: full S and b.
- ``reference15``: reference12 plus a per-axis quadratic term q (Song & Qin 2009's six-position model).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

SPHERE_MODELS = ("six", "sphere9")
REFERENCE_MODELS = ("reference12", "reference15")
MODELS = SPHERE_MODELS + REFERENCE_MODELS
AXES = "xyz"

# Free entries of M for each sphere model, as (row, column).
_MATRIX_ENTRIES = {
    "six": ((0, 0), (1, 1), (2, 2)),
    "sphere9": ((0, 0), (1, 0), (1, 1), (2, 0), (2, 1), (2, 2)),
}


_ENTRY_INDEX: dict[str, tuple[NDArray[np.int_], NDArray[np.int_]]] = {
    name: (np.array([i for i, _ in entries]), np.array([j for _, j in entries]))
    for name, entries in _MATRIX_ENTRIES.items()
}


_FLAT_INDEX: dict[str, NDArray[np.int_]] = {name: rows * 3 + cols for name, (rows, cols) in _ENTRY_INDEX.items()}


def parameter_count(model: str) -> int:
    return {"six": 6, "sphere9": 9, "reference12": 12, "reference15": 15}[model]


def matrix_entries(model: str) -> tuple[tuple[int, int], ...]:
    """Entries of M a model estimates (all nine for the reference models)."""
    if model in _MATRIX_ENTRIES:
        return _MATRIX_ENTRIES[model]
    return tuple((i, j) for i in range(3) for j in range(3))


@dataclass(frozen=True)
class SphereModel:
    """Parameter vector p = [b_x, b_y, b_z, free entries of M in row-major order]."""

    name: str

    @property
    def entries(self) -> tuple[tuple[int, int], ...]:
        return _MATRIX_ENTRIES[self.name]

    @property
    def size(self) -> int:
        return 3 + len(self.entries)

    def pack(self, bias: np.ndarray, matrix: np.ndarray) -> np.ndarray:
        return np.concatenate([bias, [matrix[i, j] for i, j in self.entries]])

    def unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        matrix = np.zeros((3, 3))
        rows, cols = self._index
        matrix[rows, cols] = p[3:]
        return p[:3].copy(), matrix

    @property
    def _index(self) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
        return _ENTRY_INDEX[self.name]

    @property
    def _flat_index(self) -> NDArray[np.int_]:
        return _FLAT_INDEX[self.name]

    def project(self, bias: np.ndarray, matrix: np.ndarray) -> np.ndarray:
        """Closest parameter vector for a warm start from any calibration: M is brought to this
        model's form by a rotation (QR), which leaves |M v| unchanged."""
        if self.name == "six":
            return self.pack(bias, np.diag(np.linalg.norm(matrix, axis=0)))
        # M = Q R with R upper-triangular; |M v| = |R v|. We need lower-triangular L with |L v| = |M v|:
        # M^T M = L^T L, i.e. a Cholesky-like factor. Reverse axes to turn QR's upper form into lower.
        flip = np.eye(3)[::-1]
        _, upper = np.linalg.qr(matrix @ flip)
        lower = flip @ upper @ flip
        lower = np.diag(np.sign(np.diag(lower))) @ lower
        return self.pack(bias, lower)

    def residual_and_jacobian(self, p: np.ndarray, accel: np.ndarray,
                              gravity: float) -> tuple[np.ndarray, np.ndarray]:
        """r_i = |M (a_i - b)| - g and its Jacobian (N x size). Called every Gauss-Newton iteration:
        kept to a handful of vectorised numpy calls."""
        rows, cols = self._index
        matrix: np.ndarray = np.zeros(9)
        matrix[self._flat_index] = p[3:]
        matrix = matrix.reshape(3, 3)
        centred = accel - p[:3]
        corrected = centred @ matrix.T
        norm = np.sqrt((corrected * corrected).sum(axis=1))
        jac = np.empty((len(accel), self.size))
        # d|Mv|/db = -(Mv)^T M / |Mv|;  d|Mv|/dM_ij = (Mv)_i v_j / |Mv| for the free entries (i, j).
        np.matmul(corrected, -matrix, out=jac[:, :3])
        np.multiply(corrected[:, rows], centred[:, cols], out=jac[:, 3:])
        jac /= norm[:, None]
        return norm - gravity, jac

    def parameter_names(self) -> list[str]:
        return [f"b_{a}" for a in AXES] + [f"M_{AXES[i]}{AXES[j]}" for i, j in self.entries]


def seed_sphere(accel: np.ndarray, gravity: float) -> tuple[np.ndarray, np.ndarray]:
    """Starting bias and diagonal matrix from an algebraic axis-aligned ellipsoid fit.

    Solves A x^2 + B y^2 + C z^2 + D x + E y + F z = 1 linearly on normalised data, which copes with
    raw counts far from zero (e.g. unsigned 16-bit output centred on 32768). Falls back to zero bias
    and a common scale when the poses do not define an ellipsoid (or their magnitudes overflow).
    """
    centre = accel.mean(axis=0)
    spread = float(np.abs(accel - centre).max()) or 1.0
    typical = float(np.median(np.linalg.norm(accel, axis=1)))
    fallback = np.zeros(3), np.eye(3) * gravity / (typical if np.isfinite(typical) and typical > 0 else 1.0)
    if not np.isfinite(spread):
        return fallback
    x = (accel - centre) / spread
    design = np.hstack([x**2, x])
    if len(accel) >= 6:
        coeffs, *_ = np.linalg.lstsq(design, np.ones(len(accel)), rcond=None)
        quad, lin = coeffs[:3], coeffs[3:]
        if np.all(quad > 0):
            offset = -lin / (2 * quad)
            level = 1.0 + float(np.sum(quad * offset**2))
            if level > 0:
                radii = np.sqrt(level / quad) * spread
                bias = centre + offset * spread
                # Plausible only if the axes' scales agree within 50 % (MEMS parts are within a few %)
                # and the poses span more than a sliver of it; a cluster of alike poses fits any quadric.
                plausible = (
                    np.all(np.isfinite(radii))
                    and np.all(np.isfinite(bias))
                    and radii.max() < 1.5 * radii.min()
                    and 2 * spread > 0.2 * radii.mean()
                )
                if plausible:
                    return bias, np.diag(gravity / radii)
    return fallback


def apply_forward_inverse(raw: np.ndarray, bias: np.ndarray, matrix: np.ndarray,
                          quadratic: np.ndarray | None) -> np.ndarray:
    """Invert a_raw = b + S a + q*a^2 for a (S = M^-1). Fixed-point iteration from the linear answer;
    q*a is ~1e-3 so three iterations reach 1e-9 relative."""
    linear: np.ndarray = (raw - bias) @ matrix.T
    if quadratic is None:
        return linear
    corrected = linear
    for _ in range(4):
        corrected = linear - (quadratic * corrected**2) @ matrix.T
    return corrected
