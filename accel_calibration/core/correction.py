"""The correction in force, as one immutable value of plain floats: what per-message code applies.

Built from a Calibration at one temperature (polynomial bias and scale drift folded into M and b; the
segmented model's drift of the raw output as its (l, m, n) per axis at that temperature), with the
reference15 quadratic term, the gyro bias and the REP-145 covariance; rebuilt when the calibration
or the temperature changes and swapped whole, so a message is corrected by one consistent set.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .calibration import Calibration

Floats3 = tuple[float, float, float]
Floats9 = tuple[float, float, float, float, float, float, float, float, float]


def rep145_covariance(matrix: np.ndarray, noise_var_per_axis: float | None, bias_sigma: np.ndarray | None,
                      matrix_sigma: np.ndarray | None, gravity: float) -> np.ndarray | None:
    """linear_acceleration_covariance (REP-145) of a corrected sample, (3, 3) in (m/s^2)^2: the sensor's
    measured white noise carried through M, plus the calibration's own uncertainty at |a| = g (bias
    sigma through M; each row of M's sigma acting on a g-sized input spread over three axes).
    None when neither is known (the driver's covariance is then kept)."""
    if noise_var_per_axis is None and (bias_sigma is None or matrix_sigma is None):
        return None
    cov = np.zeros((3, 3))
    if noise_var_per_axis is not None:
        cov += float(noise_var_per_axis) * (matrix @ matrix.T)
    if bias_sigma is not None and matrix_sigma is not None:
        cov += np.diag((matrix**2) @ bias_sigma**2 + (matrix_sigma**2).sum(axis=1) * gravity * gravity / 3)
    return cov


@dataclass(frozen=True)
class Correction:
    """a_true = M (a_raw - b), then the reference15 quadratic inverted by fixed-point iteration, then the
    segmented model's drift l a_raw^2 + m a_raw + n per axis added (the paper's eq. 5)."""

    matrix: Floats9  # row-major M at `temperature_degc`
    bias: Floats3
    quadratic: Floats3 | None = None
    gyro_bias_radps: Floats3 | None = None
    covariance: Floats9 | None = None
    temperature_degc: float | None = None  # where the temperature terms were evaluated
    temperature_clamped: bool = False  # outside the calibrated range: evaluated at its edge
    drift: Floats9 | None = None  # segmented: l_x, l_y, l_z (s^2/m), m_x, m_y, m_z (1), n_x, n_y, n_z (m/s^2)

    @classmethod
    def build(cls, calibration: Calibration | None, temperature_degc: float | None = None,
              noise_var_per_axis: float | None = None) -> Correction | None:
        """None when there is nothing to apply and no covariance to report."""
        if calibration is None:
            cov = rep145_covariance(np.eye(3), noise_var_per_axis, None, None, 0.0)
            if cov is None:
                return None
            identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
            return cls(identity, (0.0, 0.0, 0.0), covariance=_floats9(cov))
        terms = calibration.terms_at(temperature_degc)
        clamped = bool(temperature_degc is not None and calibration.temperature is not None
                       and calibration.temperature_clamped(temperature_degc))
        cov = rep145_covariance(calibration.matrix, noise_var_per_axis, calibration.bias_sigma,
                                calibration.matrix_sigma, calibration.gravity)
        return cls(
            matrix=_floats9(terms[:9]),
            bias=_floats3(terms[9:12]),
            quadratic=None if calibration.quadratic is None else _floats3(calibration.quadratic),
            gyro_bias_radps=None if calibration.gyro_bias_radps is None else _floats3(calibration.gyro_bias_radps),
            covariance=None if cov is None else _floats9(cov),
            temperature_degc=temperature_degc if calibration.temperature is not None else None,
            temperature_clamped=clamped,
            drift=_floats9_or_none(calibration.drift_terms_at(temperature_degc)),
        )

    def apply(self, ax: float, ay: float, az: float) -> Floats3:
        """One sample in plain floats (~1 us; numpy per 3-vector costs more than it saves)."""
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = self.matrix
        b0, b1, b2 = self.bias
        x, y, z = ax - b0, ay - b1, az - b2
        lx = m00 * x + m01 * y + m02 * z
        ly = m10 * x + m11 * y + m12 * z
        lz = m20 * x + m21 * y + m22 * z
        if self.quadratic is not None:
            # a_raw = b + M^-1 a + q a^2: a = M (a_raw - b) - M (q a^2); q a ~ 1e-3, four steps reach 1e-12.
            q0, q1, q2 = self.quadratic
            cx, cy, cz = lx, ly, lz
            for _ in range(4):
                px, py, pz = q0 * cx * cx, q1 * cy * cy, q2 * cz * cz
                cx = lx - (m00 * px + m01 * py + m02 * pz)
                cy = ly - (m10 * px + m11 * py + m12 * pz)
                cz = lz - (m20 * px + m21 * py + m22 * pz)
            lx, ly, lz = cx, cy, cz
        if self.drift is None:
            return lx, ly, lz
        l0, l1, l2, s0, s1, s2, n0, n1, n2 = self.drift
        return (lx + (l0 * ax + s0) * ax + n0, ly + (l1 * ay + s1) * ay + n1, lz + (l2 * az + s2) * az + n2)


def _floats3(values: object) -> Floats3:
    a, b, c = (float(v) for v in np.asarray(values, dtype=float).ravel())
    return a, b, c


def _floats9_or_none(values: object) -> Floats9 | None:
    return None if values is None else _floats9(values)


def _floats9(values: object) -> Floats9:
    flat = [float(v) for v in np.asarray(values, dtype=float).ravel()]
    return (flat[0], flat[1], flat[2], flat[3], flat[4], flat[5], flat[6], flat[7], flat[8])
