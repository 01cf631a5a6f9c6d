"""The dividing-head model of Gao et al. (2016): a MEMS accelerometer triad on an optical dividing head
whose tilt mechanism has errors of its own.

The head turns the sensor about its rotation axis to α and tilts that axis to β (a vernier sets β, so
its nominal value is off by Δβ). In units of g, with the specific force +1 on z when all angles are 0:

    A_i = diag(K) C Rx(α_i) Ry(β_i + Δβ_k) e_z + ∇

    C = [[ 1,           δθz,        -δθy ],
         [ -δθz + γ21,  1,           δθx ],
         [ δθy + γ31,  -δθx + γ32,   1   ]]

K: scale; ∇: bias (g); δθ: mounting misalignment of the triad on the head (rad); γ: non-orthogonality
of the axes (γ21, γ31, γ32, rad); Δβ_k: the tilt error at the k-th distinct β. At β = 90° every α
points the same nominal way, and Δβ there shows only as the α-harmonic of the two other axes.

In this package's convention a_raw = b + S a_true with S = diag(K) C and b = g ∇, so M = S^-1: the
correction takes the raw output to the head's frame (mounting misalignment included).

Numpy only; the fit that builds a Calibration from it is dividing_head_fit.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import CalibrationError

# Parameters before the tilt errors: K (3), ∇ (3), δθ (3), γ (3).
AXIS_PARAMETERS = 12
# Nominal β values closer than this (rad, ~0.2 arcsec) are one setting of the tilt mechanism.
SAME_TILT_RAD = 1e-6

# dC/dδθ and dC/dγ: which entry of C each angle moves, with its sign, as (row, column, sign).
_C_ENTRIES: tuple[tuple[tuple[int, int, float], ...], ...] = (
    ((1, 2, 1.0), (2, 1, -1.0)),  # δθx
    ((0, 2, -1.0), (2, 0, 1.0)),  # δθy
    ((0, 1, 1.0), (1, 0, -1.0)),  # δθz
    ((1, 0, 1.0),),  # γ21
    ((2, 0, 1.0),),  # γ31
    ((2, 1, 1.0),),  # γ32
)


def axes_matrix(angles_rad: np.ndarray) -> np.ndarray:
    """C from [δθx, δθy, δθz, γ21, γ31, γ32] (rad)."""
    c = np.eye(3)
    for angle, entries in zip(angles_rad.tolist(), _C_ENTRIES):
        for row, column, sign in entries:
            c[row, column] += sign * angle
    return c


def axes_angles(c: np.ndarray) -> np.ndarray:
    """[δθx, δθy, δθz, γ21, γ31, γ32] from a C of the model's form (the inverse of axes_matrix)."""
    return np.array([c[1, 2], -c[0, 2], c[0, 1], c[1, 0] + c[0, 1], c[2, 0] + c[0, 2], c[2, 1] + c[1, 2]])


def nominal_directions(alpha_rad: np.ndarray, theta_rad: np.ndarray) -> np.ndarray:
    """Rx(α) Ry(θ) e_z, (N, 3): the specific force's direction in the head's frame."""
    sin_t, cos_t = np.sin(theta_rad), np.cos(theta_rad)
    return np.column_stack([-sin_t, np.sin(alpha_rad) * cos_t, np.cos(alpha_rad) * cos_t])


def _direction_derivatives(alpha_rad: np.ndarray, theta_rad: np.ndarray) -> np.ndarray:
    """d/dθ of Rx(α) Ry(θ) e_z, (N, 3)."""
    sin_t, cos_t = np.sin(theta_rad), np.cos(theta_rad)
    return np.column_stack([-cos_t, -np.sin(alpha_rad) * sin_t, -np.cos(alpha_rad) * sin_t])


@dataclass(frozen=True)
class DividingHeadModel:
    """The model over one table of positions. Parameter vector p (units of g and rad):
    [Kx, Ky, Kz, ∇x, ∇y, ∇z, δθx, δθy, δθz, γ21, γ31, γ32, Δβ_0 .. Δβ_(k-1)], Δβ in increasing β."""

    alpha_rad: np.ndarray  # (N,) nominal rotation of the head
    beta_rad: np.ndarray  # (N,) nominal tilt
    tilt_index: np.ndarray  # (N,) which distinct β each position has
    tilts_rad: np.ndarray  # (k,) the distinct β, increasing

    @classmethod
    def from_angles(cls, alpha_rad: np.ndarray, beta_rad: np.ndarray) -> DividingHeadModel:
        order = np.argsort(beta_rad, kind="stable")
        tilts: list[float] = []
        index = np.zeros(len(beta_rad), dtype=int)
        for i in order.tolist():
            if not tilts or beta_rad[i] - tilts[-1] > SAME_TILT_RAD:
                tilts.append(float(beta_rad[i]))
            index[i] = len(tilts) - 1
        return cls(np.asarray(alpha_rad, dtype=float), np.asarray(beta_rad, dtype=float), index, np.array(tilts))

    @property
    def size(self) -> int:
        return AXIS_PARAMETERS + len(self.tilts_rad)

    def predict(self, p: np.ndarray) -> np.ndarray:
        """A_i (N, 3), units of g."""
        theta = self.beta_rad + p[AXIS_PARAMETERS:][self.tilt_index]
        direction = nominal_directions(self.alpha_rad, theta)
        predicted: np.ndarray = direction @ axes_matrix(p[6:12]).T * p[:3] + p[3:6]
        return predicted

    def residual_and_jacobian(self, p: np.ndarray, measured_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """r = A(p) - measured, raveled position by position (x, y, z of each), and dr/dp (3N, size)."""
        n = len(self.alpha_rad)
        scale = p[:3]
        c = axes_matrix(p[6:12])
        theta = self.beta_rad + p[AXIS_PARAMETERS:][self.tilt_index]
        v = nominal_directions(self.alpha_rad, theta)
        aligned = v @ c.T  # C v
        residual = (aligned * scale + p[3:6] - measured_g).ravel()
        jacobian = np.zeros((n, 3, self.size))
        for axis in range(3):
            jacobian[:, axis, axis] = aligned[:, axis]  # dA/dK
            jacobian[:, axis, 3 + axis] = 1.0  # dA/d∇
        for k, entries in enumerate(_C_ENTRIES):  # dA/dδθ, dA/dγ: K ⊙ (dC/dangle v)
            for row, column, sign in entries:
                jacobian[:, row, 6 + k] += sign * scale[row] * v[:, column]
        turned = _direction_derivatives(self.alpha_rad, theta) @ c.T * scale  # dA/dθ
        jacobian[np.arange(n), :, AXIS_PARAMETERS + self.tilt_index] = turned
        return residual, jacobian.reshape(3 * n, self.size)

    def seed(self, measured_g: np.ndarray) -> np.ndarray:
        """A starting point: the linear fit A = ∇ + S v of the nominal directions (all Δβ = 0), with
        S = diag(K) C split into the model's terms. The errors are mrad and per mille: Gauss-Newton
        converges from here in a few iterations."""
        v = nominal_directions(self.alpha_rad, self.beta_rad)
        design = np.column_stack([np.ones(len(v)), v])
        coefficients = np.linalg.lstsq(design, measured_g, rcond=None)[0]  # (4, 3): rows ∇, S^T
        bias = coefficients[0]
        forward = coefficients[1:].T
        scale = forward.diagonal().copy()
        if not np.all(np.isfinite(scale)) or np.any(scale == 0):
            return np.concatenate([np.ones(3), np.zeros(9 + len(self.tilts_rad))])
        angles = axes_angles(forward / scale[:, None])
        return np.concatenate([scale, bias, angles, np.zeros(len(self.tilts_rad))])


@dataclass(frozen=True)
class DividingHeadTerms:
    """The fitted terms in the paper's words, each with its 1-sigma (what a calibration file's
    `dividing_head:` block holds). Angles in mrad, bias in mg (1 mg = 9.80665e-3 m/s^2)."""

    scale: tuple[float, float, float]  # Kx, Ky, Kz
    bias_mg: tuple[float, float, float]
    mounting_mrad: tuple[float, float, float]  # δθx, δθy, δθz
    nonorthogonality_mrad: tuple[float, float, float]  # γ21, γ31, γ32
    tilt_error_mrad: tuple[float, ...]  # Δβ per distinct β, increasing β
    tilt_deg: tuple[float, ...]  # the distinct nominal β
    sigma: dict[str, tuple[float, ...]]  # 1-sigma of each of the five above, same keys and lengths
    residual_sigma_mg: float  # the noise of one axis of one position mean, from the residuals and their dof

    VALUES = ("scale", "bias_mg", "mounting_mrad", "nonorthogonality_mrad", "tilt_error_mrad")

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in (*self.VALUES, "tilt_deg"):
            set_(self, name, _finite_tuple(getattr(self, name), f"dividing_head.{name}"))
        for name in ("scale", "bias_mg", "mounting_mrad", "nonorthogonality_mrad"):
            if len(getattr(self, name)) != 3:
                raise CalibrationError(f"dividing_head.{name} must hold 3 numbers, got {len(getattr(self, name))}")
        if len(self.tilt_error_mrad) != len(self.tilt_deg) or not self.tilt_deg:
            raise CalibrationError("dividing_head.tilt_error_mrad must hold one number per tilt_deg (at least one)")
        if not isinstance(self.sigma, dict) or set(self.sigma) != set(self.VALUES):
            raise CalibrationError(f"dividing_head.sigma must have the keys {', '.join(self.VALUES)}")
        sigma = {}
        for name in self.VALUES:
            values = _finite_tuple(self.sigma[name], f"dividing_head.sigma.{name}")
            if len(values) != len(getattr(self, name)) or any(v < 0 for v in values):
                raise CalibrationError(f"dividing_head.sigma.{name} must hold {len(getattr(self, name))} "
                                       "numbers >= 0")
            sigma[name] = values
        set_(self, "sigma", sigma)
        if not (isinstance(self.residual_sigma_mg, (int, float)) and math.isfinite(self.residual_sigma_mg)
                and self.residual_sigma_mg >= 0):
            raise CalibrationError(f"dividing_head.residual_sigma_mg must be a number >= 0, "
                                   f"got {self.residual_sigma_mg!r:.40}")
        set_(self, "residual_sigma_mg", float(self.residual_sigma_mg))

    def describe(self) -> str:
        """The table `accel-calib fit --model dividing-head` prints."""
        def row(label: str, name: str, names: tuple[str, ...], digits: int) -> str:
            values, sigmas = getattr(self, name), self.sigma[name]
            return f"  {label:28s}" + "   ".join(f"{n} {v:+.{digits}f} ± {s:.{digits}f}"
                                               for n, v, s in zip(names, values, sigmas))

        tilts = tuple(f"β {b:g}°:" for b in self.tilt_deg)
        return "\n".join([
            "dividing head (Gao et al. 2016), ± 1 sigma:",
            row("scale K", "scale", ("x", "y", "z"), 6),
            row("bias ∇ (mg)", "bias_mg", ("x", "y", "z"), 3),
            row("mounting δθ (mrad)", "mounting_mrad", ("x", "y", "z"), 3),
            row("non-orthogonality γ (mrad)", "nonorthogonality_mrad", ("21", "31", "32"), 3),
            row("tilt error Δβ (mrad)", "tilt_error_mrad", tilts, 3),
            f"  noise of one axis of one position mean: {self.residual_sigma_mg:.3f} mg (from the residuals)",
        ])

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, DividingHeadTerms):
            return NotImplemented
        return all(getattr(self, f) == getattr(other, f) for f in
                   (*self.VALUES, "tilt_deg", "sigma", "residual_sigma_mg"))

    __hash__ = None  # type: ignore[assignment]


def _finite_tuple(values: object, name: str) -> tuple[float, ...]:
    try:
        array = np.array(values, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be a list of numbers, got {values!r:.60}") from None
    if isinstance(values, (str, bytes)) or not np.all(np.isfinite(array)):
        raise CalibrationError(f"{name} must be a list of finite numbers, got {values!r:.60}")
    return tuple(float(v) for v in array)
