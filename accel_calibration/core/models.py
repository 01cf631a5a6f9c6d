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
``dividing-head`` (Gao et al. 2016) is fitted from a dividing head's nominal angles with its tilt errors
(core/dividing_head.py); its calibration is a full M and b like reference12's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .lapack import dpocon as pocon
from .lapack import dposv as posv
from .units import AXES

SPHERE_MODELS = ("six", "sphere9")
REFERENCE_MODELS = ("reference12", "reference15")
MODELS = SPHERE_MODELS + REFERENCE_MODELS  # what fit() fits
# Fitted from a dividing head's angles (dividing_head_fit.py); its Calibration corrects like reference12's.
DIVIDING_HEAD = "dividing-head"
CALIBRATION_MODELS = MODELS + (DIVIDING_HEAD,)  # what a Calibration (and its file) may name

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
_ONES = np.ones(3)


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
        matrix.ravel()[_FLAT_INDEX[self.name]] = p[3:]
        return p[:3].copy(), matrix

    @property
    def _index(self) -> tuple[NDArray[np.int_], NDArray[np.int_]]:
        return _ENTRY_INDEX[self.name]

    @property
    def flat_index(self) -> NDArray[np.int_]:
        """Positions of the free entries in M's row-major ravel: p[3:] == M.ravel()[flat_index]."""
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
        """r_i = |M (a_i - b)| - g and its Jacobian (N x size), as views of `stacked`."""
        out = self.stacked(p, accel.T, gravity)
        return out[-1], out[:-1].T

    def stacked(self, p: np.ndarray, accel_t: np.ndarray, gravity: float) -> np.ndarray:
        """[J^T; r] as one (size + 1, N) array from the poses as columns (accel_t, 3 x N): what
        gauss_newton_stacked takes. Called every Gauss-Newton iteration: a handful of numpy calls on
        contiguous rows (axis-0 takes instead of column fancy-indexing, one output buffer)."""
        rows, cols = _ENTRY_INDEX[self.name]
        size = 3 + len(rows)
        matrix = np.zeros((3, 3))
        matrix.ravel()[_FLAT_INDEX[self.name]] = p[3:]
        # -v = b - a and -Mv, which give the derivatives below without negating M:
        # d|Mv|/db = -(Mv)^T M / |Mv| = M^T (-Mv) / |Mv|;  d|Mv|/dM_ij = (Mv)_i v_j / |Mv| = (-Mv)_i (-v)_j / |Mv|.
        negated = p[:3, None] - accel_t
        corrected = np.dot(matrix, negated)
        norm = np.sqrt(np.dot(_ONES, corrected * corrected))
        out = np.empty((size + 1, negated.shape[1]))
        np.dot(matrix.T, corrected, out=out[:3])
        np.multiply(corrected.take(rows, axis=0), negated.take(cols, axis=0), out=out[3:size])
        np.divide(out[:size], norm, out=out[:size])
        np.subtract(norm, gravity, out=out[size])
        return out

    def parameter_names(self) -> list[str]:
        return [f"b_{a}" for a in AXES] + [f"M_{AXES[i]}{AXES[j]}" for i, j in self.entries]


def seed_sphere(accel: np.ndarray, gravity: float, *, cross_axis: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Starting bias and matrix from an algebraic ellipsoid fit.

    Solves A x^2 + B y^2 + C z^2 + D x + E y + F z = 1 linearly on normalised data, which copes with
    raw counts far from zero (e.g. unsigned 16-bit output centred on 32768), and gives a diagonal M.
    cross_axis: first try the general ellipsoid (xy, xz, yz terms too), which gives a lower-triangular M
    (sphere9's form) within noise of sphere9's optimum, so that Gauss-Newton needs two iterations instead
    of four; when the poses do not pin the cross terms down, the axis-aligned fit as before. Falls back
    to zero bias and a common scale when the poses do not define an ellipsoid (or their magnitudes
    overflow).
    """
    n = len(accel)
    centre = accel.sum(axis=0) / n  # accel.mean(axis=0) without its wrapper
    centred = accel - centre
    spread = float(np.abs(centred).max()) or 1.0
    if math.isfinite(spread) and n >= 6:
        x = centred / spread
        if cross_axis and n >= 9:
            general = _general_ellipsoid_seed(x, centre, spread, gravity)
            if general is not None:
                return general
        coeffs = _ellipsoid_coefficients(x)
        quad, lin = coeffs[:3], coeffs[3:]
        if quad[0] > 0 and quad[1] > 0 and quad[2] > 0:
            # Scalar arithmetic on three numbers: the same IEEE operations numpy would do, for less.
            offset = [-b / (2 * a) for a, b in zip(quad, lin)]
            level = 1.0 + (quad[0] * offset[0] * offset[0] + quad[1] * offset[1] * offset[1]
                           + quad[2] * offset[2] * offset[2])
            if level > 0:
                radii = [math.sqrt(level / a) * spread for a in quad]
                bias = [c + o * spread for c, o in zip(centre.tolist(), offset)]
                if _plausible(radii, bias, spread):
                    matrix = np.zeros((3, 3))
                    matrix.ravel()[::4] = [gravity / r for r in radii]  # the diagonal
                    return np.array(bias), matrix
    typical = float(np.median(np.linalg.norm(accel, axis=1)))
    return np.zeros(3), np.eye(3) * gravity / (typical if np.isfinite(typical) and typical > 0 else 1.0)


def _plausible(radii: list[float], bias: list[float], spread: float) -> bool:
    """A seed's ellipsoid is plausible only if it is finite, the axes' scales (radii, in the data's units)
    agree within 50 % (MEMS parts are within a few %) and the poses span more than a sliver of it (a
    cluster of alike poses fits any quadric)."""
    return (all(map(math.isfinite, radii)) and all(map(math.isfinite, bias))
            and max(radii) < 1.5 * min(radii) and 2 * spread > 0.2 * ((radii[0] + radii[1] + radii[2]) / 3))


# Below this reciprocal condition (a 1-norm estimate) of its normal equations the general ellipsoid is
# left for the axis-aligned one: the cross terms are then set by a handful of poses, or by none.
SEED_RCOND = 1e-6


def _general_ellipsoid_seed(x: np.ndarray, centre: np.ndarray, spread: float,
                            gravity: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Bias and lower-triangular M with |M (a - b)| = g on the general ellipsoid x^T A x + l^T x = 1
    through the normalised poses x = (a - centre) / spread (least squares, normal equations by Cholesky),
    or None when the poses do not determine it (reciprocal condition <= SEED_RCOND: poses only at the
    faces, in a plane) or it is no plausible sensor (not an ellipsoid, axes' scales 50 % apart)."""
    n = len(x)
    x_t = x.T
    design = np.empty((10, n))  # rows: x^2, y^2, z^2, xy, xz, yz, x, y, z, 1
    np.multiply(x_t, x_t, out=design[:3])
    np.multiply(x_t[0], x_t[1:], out=design[3:5])
    np.multiply(x_t[1], x_t[2], out=design[5])
    design[6:9] = x_t
    design[9] = 1.0
    c = _normal_solution(np.dot(design, design.T), 9, SEED_RCOND)  # [D^T D, D^T 1] in one product
    if c is None:
        return None
    # A = [[c0, c3/2, c4/2], [c3/2, c1, c5/2], [c4/2, c5/2, c2]], l = c[6:]. Scalar arithmetic on a 3 x 3
    # matrix: numpy's per-call cost would exceed the work many times over.
    a01, a02, a12 = 0.5 * c[3], 0.5 * c[4], 0.5 * c[5]
    # Lower-triangular L with L^T L = A (Cholesky from the last axis), which is sphere9's form of M.
    if not c[2] > 0:
        return None
    l22 = math.sqrt(c[2])
    l21, l20 = a12 / l22, a02 / l22
    rest = c[1] - l21 * l21
    if not rest > 0:
        return None
    l11 = math.sqrt(rest)
    l10 = (a01 - l20 * l21) / l11
    rest = c[0] - l10 * l10 - l20 * l20
    if not rest > 0:
        return None
    l00 = math.sqrt(rest)
    # Centre o = -A^-1 l / 2 by two triangular solves: w = L^-T l, o = -L^-1 w / 2; and
    # (x - o)^T A (x - o) = 1 + o^T A o = 1 + |w|^2 / 4.
    w2 = c[8] / l22
    w1 = (c[7] - l21 * w2) / l11
    w0 = (c[6] - l10 * w1 - l20 * w2) / l00
    o0 = w0 / l00
    o1 = (w1 - l10 * o0) / l11
    o2 = (w2 - l20 * o0 - l21 * o1) / l22
    level = 1.0 + 0.25 * (w0 * w0 + w1 * w1 + w2 * w2)
    factor_g = gravity / (spread * math.sqrt(level))
    diagonal = (l00 * factor_g, l11 * factor_g, l22 * factor_g)
    bias = [centre_i - 0.5 * o_i * spread for centre_i, o_i in zip(centre.tolist(), (o0, o1, o2))]
    if not _plausible([gravity / d for d in diagonal], bias, spread):  # M's diagonal for the axes' scales
        return None
    matrix = np.array([[diagonal[0], 0.0, 0.0],
                       [l10 * factor_g, diagonal[1], 0.0],
                       [l20 * factor_g, l21 * factor_g, diagonal[2]]])
    return np.array(bias), matrix


def _ellipsoid_coefficients(x: np.ndarray) -> list[float]:
    """Least-squares solution of [x^2, x] c = 1 (N >= 6 rows). Normal equations by Cholesky when they
    are well conditioned (reciprocal condition > 1e-3; normalised poses spread over the sphere give ~0.2,
    and then they agree with the SVD solution to rounding), else numpy's SVD least squares as before
    (poses in a hemisphere or a plane, where the two could part)."""
    n = len(x)
    design = np.empty((n, 7))
    np.multiply(x, x, out=design[:, :3])
    design[:, 3:6] = x
    design[:, 6] = 1.0
    coefficients = _normal_solution(design.T @ design, 6, 1e-3)  # [D^T D, D^T 1] in one product
    if coefficients is not None:
        return coefficients
    least: list[float] = np.linalg.lstsq(design[:, :6], np.ones(n), rcond=None)[0].tolist()
    return least


def _normal_solution(normal: np.ndarray, size: int, least_rcond: float) -> list[float] | None:
    """The solution c of normal[:size, :size] c = normal[:size, size] (normal equations with the right-hand
    side as their last column) by Cholesky, or None when the matrix is not positive definite or its
    reciprocal condition (LAPACK's 1-norm estimate) is not above `least_rcond`."""
    factor, solution, info = posv(normal[:size, :size], normal[:size, size])
    if info != 0:
        return None
    # 1-norm bound for pocon: |A_ij| <= max diagonal for a positive definite A (conservative by <= size x).
    rcond, info = pocon(factor, size * float(normal.diagonal()[:size].max()))
    if info != 0 or not rcond > least_rcond:
        return None
    coefficients: list[float] = solution.tolist()
    return coefficients


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
