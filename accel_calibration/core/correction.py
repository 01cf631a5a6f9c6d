"""The one correction: what the node publishes for a message and what a corrected copy of a recording
holds come from `Correction.apply` / `apply_gyro` / `covariance_for` (the node calls them on one
message's floats, a copy on a group's arrays) and `correct_samples` (which Correction is in force for
each sample: the same temperature rule as the node's).

The arithmetic is elementwise in a fixed order (products and sums of floats, never BLAS: `@`, dot and
matmul round differently by CPU kernel and matrix size), so a sample's corrected value is the same bit
for bit whether it is corrected alone, in a group of any size, or on any CPU.

A Correction is built from a Calibration at one temperature (polynomial bias and scale drift folded
into M and b, a warm-up's spline drift into b and the gyro bias; the segmented model's drift of the
raw output as its (l, m, n) per axis at that temperature), with the reference15 quadratic term, the
gyro bias and the REP-145 covariance; rebuilt when the calibration, the measured noise or the
temperature (by TEMPERATURE_STEP_DEGC) changes and swapped whole, so a message is corrected by one
consistent set.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple, TypeVar

import numpy as np

from .calibration import Calibration

Floats3 = tuple[float, float, float]
Floats9 = tuple[float, float, float, float, float, float, float, float, float]
Value = TypeVar("Value", float, np.ndarray)  # one message's component, or a group's column

# The correction follows the filtered temperature once it has moved this far from where the correction
# was evaluated (~1 ug of drift for 20 ug/degC sensors): per-message work stays a 3x3 product.
TEMPERATURE_STEP_DEGC = 0.05
# ...rounded to this many decimals (1 mdegC) first: the filter's last bits differ between one reading at a
# time (the node) and a whole recording (a copy), and must never decide a step.
TEMPERATURE_DECIMALS = 3


def rep145_covariance(matrix: np.ndarray, noise_var_per_axis: float | None, bias_sigma: np.ndarray | None,
                      matrix_sigma: np.ndarray | None, gravity: float) -> np.ndarray | None:
    """linear_acceleration_covariance (REP-145) of a corrected sample, (3, 3) in (m/s^2)^2: the sensor's
    measured white noise carried through M, plus the calibration's own uncertainty at |a| = g (bias
    sigma through M; each row of M's sigma acting on a g-sized input spread over three axes).
    None when neither is known."""
    if noise_var_per_axis is None and (bias_sigma is None or matrix_sigma is None):
        return None
    cov = np.zeros((3, 3))
    if noise_var_per_axis is not None:
        m = np.asarray(matrix, dtype=float)
        cov += float(noise_var_per_axis) * np.einsum("ik,jk->ij", m, m)
    if bias_sigma is not None and matrix_sigma is not None:
        m2 = np.asarray(matrix, dtype=float) ** 2
        cov += np.diag((m2 * np.asarray(bias_sigma) ** 2).sum(axis=1)
                       + (np.asarray(matrix_sigma) ** 2).sum(axis=1) * gravity * gravity / 3)
    return cov


@dataclass(frozen=True)
class Correction:
    """a_true = M (a_raw - b), then the reference15 quadratic inverted by fixed-point iteration, then the
    segmented model's drift l a_raw^2 + m a_raw + n per axis added (the paper's eq. 5);
    w_true = M_g (w_raw - b_g) (M_g once the gyro is calibrated, else the bias alone).

    Covariance (REP-145): `covariance` when the sensor's noise is measured (noise through M plus the
    calibration's own uncertainty); until then `calibration_covariance` (the calibration's part alone) is
    added to what the driver reported, never put in its place: a filter must not be told the sensor is
    quieter than its driver says."""

    matrix: Floats9  # row-major M at `temperature_degc`
    bias: Floats3
    quadratic: Floats3 | None = None
    gyro_bias_radps: Floats3 | None = None
    covariance: Floats9 | None = None  # noise measured: the whole covariance of a corrected sample
    temperature_degc: float | None = None  # where the temperature terms were evaluated
    temperature_clamped: bool = False  # outside the calibrated range: evaluated at its edge
    drift: Floats9 | None = None  # segmented: l_x, l_y, l_z (s^2/m), m_x, m_y, m_z (1), n_x, n_y, n_z (m/s^2)
    calibration_covariance: Floats9 | None = None  # the calibration's own part, added to the driver's
    gyro_matrix: Floats9 | None = None  # row-major M_g
    # angular_velocity_covariance, as the acceleration's: the whole constant part once the gyro's noise is
    # measured (noise through M_g, plus the bias sigma through M_g), else the calibration's constant part
    # alone; plus, per sample, each row of M_g's sigma acting on the bias-free raw rate (diagonal).
    gyro_covariance: Floats9 | None = None
    gyro_calibration_covariance: Floats9 | None = None
    gyro_matrix_variance: Floats9 | None = None  # M_g's sigma squared, row-major

    @classmethod
    def _gyro_terms(cls, calibration: Calibration | None, noise_var: float | None) -> dict[str, Floats9 | None]:
        matrix = np.eye(3) if calibration is None or calibration.gyro_matrix is None else calibration.gyro_matrix
        quality = None if calibration is None else calibration.gyro_quality
        own = None
        if quality is not None and quality.bias_sigma_radps is not None:
            own = np.einsum("ik,k,jk->ij", matrix, np.asarray(quality.bias_sigma_radps) ** 2, matrix)
        elif quality is not None:
            own = np.zeros((3, 3))
        whole = None
        if noise_var is not None:
            whole = float(noise_var) * np.einsum("ik,jk->ij", matrix, matrix) + (0.0 if own is None else own)
        return {
            "gyro_matrix": None if calibration is None or calibration.gyro_matrix is None
            else _floats9(calibration.gyro_matrix),
            "gyro_covariance": None if whole is None else _floats9(whole),
            "gyro_calibration_covariance": None if own is None else _floats9(own),
            "gyro_matrix_variance": None if quality is None else _floats9(np.asarray(quality.matrix_sigma) ** 2),
        }

    @classmethod
    def build(cls, calibration: Calibration | None, temperature_degc: float | None = None,
              noise_var_per_axis: float | None = None, gyro_noise_var_per_axis: float | None = None
              ) -> Correction | None:
        """None when there is nothing to apply and no covariance to report. The noise variances are per
        axis, (m/s^2)^2 and (rad/s)^2, as measured at the still poses (None: not yet, and then the noise
        the calibration was made with, when it says, so a restart's covariance starts from it)."""
        if calibration is not None and calibration.noise is not None:
            if noise_var_per_axis is None:
                noise_var_per_axis = calibration.noise.accel_var
            if gyro_noise_var_per_axis is None:
                gyro_noise_var_per_axis = calibration.noise.gyro_var
        gyro = cls._gyro_terms(calibration, gyro_noise_var_per_axis)
        if calibration is None:
            cov = rep145_covariance(np.eye(3), noise_var_per_axis, None, None, 0.0)
            if cov is None and gyro["gyro_covariance"] is None:
                return None
            identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
            return cls(identity, (0.0, 0.0, 0.0), covariance=None if cov is None else _floats9(cov),
                       gyro_covariance=gyro["gyro_covariance"])
        terms = calibration.terms_at(temperature_degc)
        clamped = bool(temperature_degc is not None and calibration.temperature is not None
                       and calibration.temperature_clamped(temperature_degc))
        cov = rep145_covariance(calibration.matrix, noise_var_per_axis, calibration.bias_sigma,
                                calibration.matrix_sigma, calibration.gravity)
        own = rep145_covariance(calibration.matrix, None, calibration.bias_sigma, calibration.matrix_sigma,
                                calibration.gravity)
        return cls(
            matrix=_floats9(terms[:9]),
            bias=_floats3(terms[9:12]),
            quadratic=None if calibration.quadratic is None else _floats3(calibration.quadratic),
            gyro_bias_radps=_floats3_or_none(calibration.gyro_bias_at(temperature_degc)),
            covariance=None if cov is None or noise_var_per_axis is None else _floats9(cov),
            temperature_degc=temperature_degc if calibration.temperature is not None else None,
            temperature_clamped=clamped,
            drift=_floats9_or_none(calibration.drift_terms_at(temperature_degc)),
            calibration_covariance=None if own is None else _floats9(own),
            **gyro,
        )

    def apply(self, ax: Value, ay: Value, az: Value) -> tuple[Value, Value, Value]:
        """Corrected acceleration of one sample (floats: ~1 us) or of a group (equal-length arrays), with
        the same operations in the same order either way."""
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

    def apply_gyro(self, gx: Value, gy: Value, gz: Value) -> tuple[Value, Value, Value]:
        """Corrected angular rate: the gyro bias taken off, then M_g (raw passes through without either)."""
        if self.gyro_bias_radps is not None:
            g0, g1, g2 = self.gyro_bias_radps
            gx, gy, gz = gx - g0, gy - g1, gz - g2
        if self.gyro_matrix is None:
            return gx, gy, gz
        m00, m01, m02, m10, m11, m12, m20, m21, m22 = self.gyro_matrix
        return (m00 * gx + m01 * gy + m02 * gz, m10 * gx + m11 * gy + m12 * gz, m20 * gx + m21 * gy + m22 * gz)

    def angular_covariance_for(self, driver: np.ndarray, raw_radps: np.ndarray) -> np.ndarray:
        """angular_velocity_covariance of corrected samples from what the driver reported ((9,) or (N, 9))
        and the raw rates ((3,) or (N, 3)): as covariance_for, plus M_g's own uncertainty at each rate.
        Elementwise, so one sample alone and in a group agree bit for bit."""
        driver = np.asarray(driver, dtype=float)
        if self.gyro_covariance is None and self.gyro_calibration_covariance is None:
            return driver
        rate_part = np.zeros(driver.shape)
        if self.gyro_matrix_variance is not None:
            raw = np.asarray(raw_radps, dtype=float)
            u0, u1, u2 = raw[..., 0], raw[..., 1], raw[..., 2]
            if self.gyro_bias_radps is not None:
                b0, b1, b2 = self.gyro_bias_radps
                u0, u1, u2 = u0 - b0, u1 - b1, u2 - b2
            s = self.gyro_matrix_variance
            for row, column in ((0, 0), (1, 4), (2, 8)):
                rate_part[..., column] = s[3 * row] * u0 * u0 + s[3 * row + 1] * u1 * u1 + s[3 * row + 2] * u2 * u2
        if self.gyro_covariance is not None:
            return np.asarray(self.gyro_covariance) + rate_part
        known = (driver[..., :1] >= 0) & np.any(driver != 0, axis=-1, keepdims=True)
        own = np.asarray(self.gyro_calibration_covariance)
        return np.where(known, driver + own + rate_part, driver)

    @cached_property
    def _covariance_rows(self) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """The constant parts as arrays, made once per Correction (it is swapped whole, never changed)."""
        def row(values: Floats9 | None) -> np.ndarray | None:
            return None if values is None else np.array(values, dtype=float)

        return (row(self.covariance), row(self.calibration_covariance), row(self.gyro_covariance),
                row(self.gyro_calibration_covariance))

    def covariance_into(self, driver: np.ndarray) -> None:
        """covariance_for one message, written over its own (9,) array: the stream's path, about a
        microsecond where covariance_for makes new arrays (~12 us). The same values bit for bit."""
        whole, own, _, _ = self._covariance_rows
        if whole is not None:
            driver[:] = whole
        elif own is not None and driver[0] >= 0 and driver.any():
            driver += own

    def angular_covariance_into(self, driver: np.ndarray, gx: float, gy: float, gz: float) -> None:
        """angular_covariance_for one message's raw rates, written over its own (9,) array."""
        _, _, whole, own = self._covariance_rows
        if whole is None and own is None:
            return
        if whole is not None:
            driver[:] = whole
        elif driver[0] >= 0 and driver.any():
            driver += own
        else:
            return  # unknown: stays so
        s = self.gyro_matrix_variance
        if s is not None:
            if self.gyro_bias_radps is not None:
                b0, b1, b2 = self.gyro_bias_radps
                gx, gy, gz = gx - b0, gy - b1, gz - b2
            driver[0] += s[0] * gx * gx + s[1] * gy * gy + s[2] * gz * gz
            driver[4] += s[3] * gx * gx + s[4] * gy * gy + s[5] * gz * gz
            driver[8] += s[6] * gx * gx + s[7] * gy * gy + s[8] * gz * gz

    def covariance_for(self, driver: np.ndarray) -> np.ndarray:
        """linear_acceleration_covariance of corrected samples, from what the driver reported ((9,) or
        (N, 9)): the measured one, else the driver's plus the calibration's own part. What the driver
        says is unknown (all zeros) or absent (first element -1), REP-145, stays so until the noise is
        measured: the calibration's part alone would claim a sensor thousands of times quieter than it is."""
        driver = np.asarray(driver, dtype=float)
        if self.covariance is not None:
            return np.broadcast_to(np.asarray(self.covariance), driver.shape).copy()
        if self.calibration_covariance is None:
            return driver
        known = (driver[..., :1] >= 0) & np.any(driver != 0, axis=-1, keepdims=True)
        return np.where(known, driver + np.asarray(self.calibration_covariance), driver)


def correction_temperatures(filtered_degc: np.ndarray, held_degc: float | None = None) -> np.ndarray:
    """The temperature the correction is evaluated at after each filtered reading (in arrival order): it
    follows the filtered value (rounded to TEMPERATURE_DECIMALS) once that has moved TEMPERATURE_STEP_DEGC
    from where it was evaluated
    (`held_degc`: where it was before the first). The node calls it one reading at a time, a corrected
    copy with the whole recording's: the same rule gives the same temperatures."""
    out = np.empty(len(filtered_degc))
    held = held_degc
    rounded = np.round(np.asarray(filtered_degc, dtype=float), TEMPERATURE_DECIMALS)
    for index, value in enumerate(rounded.tolist()):
        if held is None or abs(value - held) >= TEMPERATURE_STEP_DEGC:
            held = value
        out[index] = held
    return out


class CorrectedSamples(NamedTuple):
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray
    covariance: np.ndarray | None  # linear_acceleration_covariance (N, 9), None when none was given
    angular_covariance: np.ndarray | None  # angular_velocity_covariance (N, 9), None when none was given
    corrected: np.ndarray  # which rows were corrected (finite acceleration)


def correct_samples(calibration: Calibration, t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray,
                    covariance: np.ndarray | None = None,
                    temperatures: tuple[np.ndarray, np.ndarray] | None = None,
                    noise_var_per_axis: float | None = None, angular_covariance: np.ndarray | None = None,
                    gyro_noise_var_per_axis: float | None = None) -> CorrectedSamples:
    """What the node publishes for these samples, as arrays. `temperatures`: the filtered readings in arrival
    order (stamps ns, degC), as TemperatureFilter.take gives them; each sample is corrected at the
    correction temperature of the latest reading stamped at or before it (the node's latest reading),
    the reference temperature before the first. A sample whose acceleration is not finite passes
    unchanged, as the node passes it on."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    accel = np.array(accel_mps2, dtype=float).reshape(-1, 3)
    gyro = np.array(gyro_radps, dtype=float).reshape(-1, 3)
    cov = None if covariance is None else np.array(covariance, dtype=float).reshape(-1, 9)
    angular = None if angular_covariance is None else np.array(angular_covariance, dtype=float).reshape(-1, 9)
    finite = np.all(np.isfinite(accel), axis=1)
    reading = np.full(len(t), -1)
    held = np.zeros(0)
    if temperatures is not None and calibration.temperature is not None and len(temperatures[0]):
        stamps, filtered = temperatures
        held = correction_temperatures(np.asarray(filtered, dtype=float))
        reading = np.searchsorted(np.asarray(stamps, dtype=np.int64), t, side="right") - 1
    # One Correction per distinct correction temperature (few: it moves in 0.05 degC steps).
    keys = np.where(reading >= 0, held[np.clip(reading, 0, None)] if len(held) else 0.0, np.nan)
    groups: dict[float | None, np.ndarray] = {}
    if np.all(np.isnan(keys)):
        groups[None] = np.flatnonzero(finite)
    else:
        for value in np.unique(keys[finite & ~np.isnan(keys)]).tolist():
            groups[value] = np.flatnonzero(finite & (keys == value))
        groups[None] = np.flatnonzero(finite & np.isnan(keys))
    for temperature, rows in groups.items():
        if not len(rows):
            continue
        correction = Correction.build(calibration, temperature, noise_var_per_axis, gyro_noise_var_per_axis)
        assert correction is not None  # a calibration always gives one
        a, g = accel[rows], gyro[rows]
        accel[rows] = np.column_stack(correction.apply(a[:, 0], a[:, 1], a[:, 2]))
        gyro[rows] = np.column_stack(correction.apply_gyro(g[:, 0], g[:, 1], g[:, 2]))
        if cov is not None:
            cov[rows] = correction.covariance_for(cov[rows])
        if angular is not None:
            angular[rows] = correction.angular_covariance_for(angular[rows], g)
    return CorrectedSamples(accel, gyro, cov, angular, finite)


def correct_rows(calibration: Calibration, accel_mps2: np.ndarray,
                 temperature_degc: np.ndarray | None = None) -> np.ndarray:
    """Rows that are samples of their own (a table's rows, pose means), corrected as the node corrects a
    message: each by the Correction at its own temperature rounded to TEMPERATURE_DECIMALS (no filter and
    no step: the rows are not a stream), at the reference temperature without one. (N, 3); a row that is
    not finite passes unchanged."""
    accel = np.array(accel_mps2, dtype=float).reshape(-1, 3)
    finite = np.all(np.isfinite(accel), axis=1)
    if temperature_degc is None or calibration.temperature is None:
        keys = np.full(len(accel), np.nan)
    else:
        keys = np.round(np.asarray(temperature_degc, dtype=float).reshape(-1), TEMPERATURE_DECIMALS)
    for value in np.unique(keys[finite]).tolist():
        rows = np.flatnonzero(finite & ((keys == value) | (np.isnan(keys) & np.isnan(value))))
        correction = Correction.build(calibration, None if np.isnan(value) else value)
        assert correction is not None  # a calibration always gives one
        a = accel[rows]
        accel[rows] = np.column_stack(correction.apply(a[:, 0], a[:, 1], a[:, 2]))
    return accel


def _floats3(values: object) -> Floats3:
    a, b, c = (float(v) for v in np.asarray(values, dtype=float).ravel())
    return a, b, c


def _floats3_or_none(values: object) -> Floats3 | None:
    return None if values is None else _floats3(values)


def _floats9_or_none(values: object) -> Floats9 | None:
    return None if values is None else _floats9(values)


def _floats9(values: object) -> Floats9:
    flat = [float(v) for v in np.asarray(values, dtype=float).ravel()]
    return (flat[0], flat[1], flat[2], flat[3], flat[4], flat[5], flat[6], flat[7], flat[8])
