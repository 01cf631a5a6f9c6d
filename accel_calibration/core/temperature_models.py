"""Temperature compensation: how the sensor's output drifts with temperature, fitted from the static poses.

Two models, both carried by a Calibration and applied with the current temperature:

- ``polynomial`` (default): b(T) = b + sum_k c_k dT^k (k = 1..bias_order <= 3) and a per-axis scale
  drift 1 + sum_k d_k dT^k (k = 1..scale_order <= 2), dT = T - T_ref, fitted jointly with M and b by
  the same Gauss-Newton on the sphere constraint, using each pose's mean temperature:
      a_true = M ((a_raw - b(T)) / (1 + s(T)))          (per-axis division)
  The autopilots (ArduPilot, PX4) fit bias only; MEMS scale factors drift too (~1e-4/degC), which at
  1 g is ~1 mg per 10 degC: scale_order=0 gives their model, for comparison.
- ``segmented``: the seed paper's model as published (Gui Yi, eqs. 4-5; restated in
  ../shared/data/literature/README.md). The range is cut into segments of `segment_width_degc`
  (centred on multiples of the width: -20, -10, 0, ... for 10 degC, so a chamber's set points sit at
  segment centres). In each segment the drift of each axis is a quadratic of that axis's *measured*
  (raw) acceleration, on top of the room-temperature calibration:
      sigma_i = l_i a_raw_i^2 + m_i a_raw_i + n_i          (l in s^2/m, m unitless, n in m/s^2)
      a_true  = M (a_raw - b) + sigma                       (the paper's a_true = k a + D + sigma)
  One temperature per segment suffices; what a segment needs is orientations. With known orientations
  each pose's drift is observed directly and each axis of each segment is a 3-unknown linear least
  squares (each axis seen up, down and level, as six faces give). Without them the nine coefficients
  are fitted on the sphere constraint |M (a_raw - b) + sigma| = g, which sees only the drift along
  gravity: six faces cannot separate l from n there, a pose tilted about 45 deg per axis can.
  At run time the paper picks the segment holding the temperature (`segment_blend=False`); by default
  the coefficients are interpolated linearly between the temperatures the neighbouring segments were
  learned at, so the output has no step at a segment edge and follows the drift between set points.

- ``spline`` (from a warm-up, core/warmup.py): the bias drift of the accelerometer and of the gyro, a
  natural cubic spline through values at knots, zero at T_ref, flat outside the knots (never
  extrapolated): a_true = M (a_raw - b - drift(T)), w_true = G (w_raw - b_g - gyro_drift(T)).

All store T_ref and the calibrated range; outside it the temperature is clamped to the edge and
the clamp is reported. A temperature fit is refused, with the reason, when the poses' temperature
span is under `min_span_degc` (10 by default); a segment is refused only when its orientations cannot
determine it, naming the axis and the orientation it needs.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .coverage import CONDITION_LIMIT, scaled_condition_number
from .errors import CalibrationError
from .gauss_newton import LeastSquaresSolution, gauss_newton
from .units import AXES
from .warmup_curve import spline_basis

if TYPE_CHECKING:
    from .models import SphereModel

TEMPERATURE_MODELS = ("none", "polynomial", "segmented")  # what a fit of poses may be asked for
TEMPERATURE_KINDS = ("polynomial", "segmented", "spline")  # what a calibration may hold (spline: a warm-up's)
# The orientations a segment's advice is phrased in, as the cosine between an axis and the measured
# gravity reaction: "x pointing up" within ~32 deg of vertical, "x level" within ~17 deg of horizontal,
# "x tilted about 45 deg" in between (what separates l from n on the sphere).
POINTING_COSINE = 0.85
LEVEL_COSINE = 0.3
TILTED_COSINES = (0.35, 0.85)
# Unknowns of one segment: per axis (l, m, n), one linear problem per axis with known orientations,
# one nine-unknown problem on the sphere.
KNOWN_UNKNOWNS, SPHERE_UNKNOWNS = 3, 9


@dataclass(frozen=True)
class TemperatureOptions:
    """Settings of a temperature fit (validated here, so the CLI, node and API share the checks)."""

    model: str = "polynomial"
    bias_order: int = 2
    scale_order: int = 1
    segment_width_degc: float = 10.0
    min_span_degc: float = 10.0
    reference_degc: float | None = None  # T_ref; None = the poses' median (segmented: its fullest segment)
    # Fewest poses a segment is learned from; 0 = the fewest that determine it with a degree of freedom
    # left to judge it (4 with known orientations, 10 on the sphere).
    min_poses_per_segment: int = 0
    segment_blend: bool = True  # False: the paper's pick of the segment holding the temperature
    # True (offline fits): a segment its poses cannot determine refuses the fit. False (the online
    # session): learn the segments the poses determine and say what the others still need.
    every_segment: bool = True

    def __post_init__(self) -> None:
        if self.model not in TEMPERATURE_MODELS:
            raise CalibrationError(f"temperature model must be one of {', '.join(TEMPERATURE_MODELS)}, "
                                   f"got {self.model!r}")
        if not (isinstance(self.bias_order, int) and 0 <= self.bias_order <= 3):
            raise CalibrationError(f"bias_order must be 0..3, got {self.bias_order!r}")
        if not (isinstance(self.scale_order, int) and 0 <= self.scale_order <= 2):
            raise CalibrationError(f"scale_order must be 0..2, got {self.scale_order!r}")
        if not (self.segment_width_degc > 0 and self.min_span_degc >= 0):
            raise CalibrationError("segment_width_degc must be positive and min_span_degc not negative")
        if not (isinstance(self.min_poses_per_segment, int) and not isinstance(self.min_poses_per_segment, bool)
                and self.min_poses_per_segment >= 0):
            raise CalibrationError(f"min_poses_per_segment must be a non-negative integer, "
                                   f"got {self.min_poses_per_segment!r}")
        for name in ("segment_blend", "every_segment"):
            if not isinstance(getattr(self, name), bool):
                raise CalibrationError(f"{name} must be true or false, got {getattr(self, name)!r}")


def _frozen_array(values: ArrayLike, shape: tuple[int, ...], name: str) -> np.ndarray:
    try:
        array = np.array(values, dtype=float).reshape(shape)
    except (TypeError, ValueError):
        raise CalibrationError(f"temperature {name} must be numbers of shape {shape}") from None
    if not np.all(np.isfinite(array)):
        raise CalibrationError(f"temperature {name} must be finite")
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class TemperatureModel:
    """The temperature block of a calibration."""

    kind: str  # "polynomial" or "segmented"
    reference_degc: float
    range_degc: tuple[float, float]  # calibrated range; outside it the temperature is clamped
    bias_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # polynomial: c_k rows
    scale_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # polynomial: d_k rows
    # segmented, K segments in increasing temperature:
    segment_bounds_degc: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (K, 2) low, high
    segment_temperatures_degc: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (K,) learned at
    segment_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))  # (K, (l, m, n), axis)
    segment_poses: tuple[int, ...] = ()  # poses each segment was learned from
    segment_blend: bool = True  # interpolate between segments (False: pick the segment holding T)
    # spline (from a warm-up): the raw output's bias drift at the knots, zero at the reference, a natural
    # cubic spline between them, flat outside them (the range); the gyro's likewise, or no rows.
    spline_knots_degc: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (K,) increasing
    spline_bias: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (K, 3) m/s^2
    spline_gyro_knots_degc: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (J,) over the same range
    spline_gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (J, 3) rad/s, or none

    def __post_init__(self) -> None:
        if self.kind not in TEMPERATURE_KINDS:
            raise CalibrationError(f"temperature model kind must be one of {', '.join(TEMPERATURE_KINDS)}, "
                                   f"got {self.kind!r}")
        set_ = object.__setattr__
        self._check_spline()
        for name in ("bias_coefficients", "scale_coefficients"):
            array = _frozen_array(getattr(self, name), (-1, 3), name)
            if len(array) > 3:
                raise CalibrationError(f"temperature {name} must be up to 3 rows of 3 finite numbers")
            set_(self, name, array)
        bounds = _frozen_array(self.segment_bounds_degc, (-1, 2), "segment bounds")
        count = len(bounds)
        temperatures = _frozen_array(self.segment_temperatures_degc, (-1,), "segment temperatures")
        coefficients = _frozen_array(self.segment_coefficients, (-1, 3, 3), "segment coefficients")
        poses = tuple(self.segment_poses)
        if any(isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 0 for p in poses):
            raise CalibrationError("temperature segment poses must be non-negative integers")
        if len(temperatures) != count or len(coefficients) != count or len(poses) not in (0, count):
            raise CalibrationError(f"temperature segments: {count} bounds, {len(temperatures)} temperatures, "
                                   f"{len(coefficients)} coefficient sets and {len(poses)} pose counts must agree")
        if self.kind == "segmented":
            if count == 0:
                raise CalibrationError("segmented temperature model needs at least one segment")
            if (np.any(bounds[:, 1] <= bounds[:, 0]) or np.any(bounds[1:, 0] < bounds[:-1, 1])
                    or np.any(temperatures < bounds[:, 0]) or np.any(temperatures > bounds[:, 1])):
                raise CalibrationError("temperature segments must be in increasing order, not overlapping, each "
                                       "learned at a temperature within its bounds")
        if not isinstance(self.segment_blend, bool):
            raise CalibrationError(f"temperature segment_blend must be true or false, got {self.segment_blend!r}")
        set_(self, "segment_bounds_degc", bounds)
        set_(self, "segment_temperatures_degc", temperatures)
        set_(self, "segment_coefficients", coefficients)
        set_(self, "segment_poses", tuple(int(p) for p in poses) or (0,) * count)
        lo, hi = (float(v) for v in self.range_degc)
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi and np.isfinite(self.reference_degc)):
            raise CalibrationError(f"temperature range must be finite with low <= high, got {self.range_degc!r}")
        set_(self, "range_degc", (lo, hi))
        set_(self, "reference_degc", float(self.reference_degc))

    def _check_spline(self) -> None:
        """The spline's arrays: K >= 2 increasing knots spanning the range, K rows of bias (and of gyro
        bias, or none); empty for the other kinds."""
        set_ = object.__setattr__
        knots = _frozen_array(self.spline_knots_degc, (-1,), "spline knots")
        bias = _frozen_array(self.spline_bias, (-1, 3), "spline bias")
        gyro_knots = _frozen_array(self.spline_gyro_knots_degc, (-1,), "spline gyro knots")
        gyro = _frozen_array(self.spline_gyro_bias, (-1, 3), "spline gyro bias")
        if self.kind != "spline":
            if len(knots) or len(bias) or len(gyro_knots) or len(gyro):
                raise CalibrationError(f"spline knots and biases belong to the spline model, not {self.kind}")
        else:
            ends = tuple(float(v) for v in self.range_degc)
            for name, where, values in (("", knots, bias), ("gyro ", gyro_knots, gyro)):
                if name and not len(where) and not len(values):
                    continue  # no gyro part
                if len(where) < 2 or np.any(np.diff(where) <= 0) or len(values) != len(where):
                    raise CalibrationError(f"spline temperature model: {name}knots must be at least 2, increasing, "
                                           f"with a {name}bias row each (got {len(where)} knots, {len(values)} rows)")
                if (float(where[0]), float(where[-1])) != ends:
                    raise CalibrationError(f"spline temperature model: its range is its first and last {name}knot")
        set_(self, "spline_knots_degc", knots)
        set_(self, "spline_bias", bias)
        set_(self, "spline_gyro_knots_degc", gyro_knots)
        set_(self, "spline_gyro_bias", gyro)

    def gyro_drift(self, temperature_degc: ArrayLike) -> np.ndarray:
        """(N, 3) drift of the raw gyro's bias at each temperature, rad/s, w_true = G (w_raw - b_g - drift);
        zeros for a model without a gyro part. Flat outside the range."""
        t = np.atleast_1d(np.asarray(temperature_degc, dtype=float))
        if not len(self.spline_gyro_bias):
            return np.zeros((len(t), 3))
        drift: np.ndarray = spline_basis(self.spline_gyro_knots_degc, t) @ self.spline_gyro_bias
        return drift

    @property
    def has_gyro(self) -> bool:
        return bool(len(self.spline_gyro_bias))

    def clamp(self, temperature_degc: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(temperature clamped to the calibrated range, mask of the values that were clamped)."""
        t = np.asarray(temperature_degc, dtype=float)
        lo, hi = self.range_degc
        return np.clip(t, lo, hi), (t < lo) | (t > hi)

    def bias_and_scale(self, temperature_degc: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample additive drift of the raw output (N, 3) and scale divisor (N, 3), with
        a_true = M ((a_raw - b - drift) / scale). Exact for the polynomial model; for the segmented one
        its bias and scale part (n, m) as if M were the identity, for plots (apply() is exact)."""
        t, _ = self.clamp(np.atleast_1d(temperature_degc))
        if self.kind == "spline":
            spline: np.ndarray = spline_basis(self.spline_knots_degc, t) @ self.spline_bias
            return spline, np.ones((len(t), 3))
        if self.kind == "segmented":
            terms = self.segment_terms(t)
            gain = 1.0 + terms[:, 1]
            return -terms[:, 2] / gain, 1.0 / gain
        dt = (t - self.reference_degc)[:, None]
        drift = np.zeros((len(t), 3))
        for k, row in enumerate(self.bias_coefficients, start=1):
            drift += row * dt**k
        scale = np.ones((len(t), 3))
        for k, row in enumerate(self.scale_coefficients, start=1):
            scale += row * dt**k
        return drift, scale

    def segment_terms(self, temperature_degc: ArrayLike) -> np.ndarray:
        """Segmented: the (l, m, n) rows per axis in force at each temperature, (N, 3, 3), after clamping.
        Blended: linear in temperature between the temperatures neighbouring segments were learned at
        (`blend_weights`); picked: the segment whose bounds hold the temperature, or the nearest learned
        one where no segment was learned."""
        t, _ = self.clamp(np.atleast_1d(np.asarray(temperature_degc, dtype=float)))
        anchors, coefficients = self.segment_temperatures_degc, self.segment_coefficients
        if self.segment_blend and len(anchors) > 1:
            blended: np.ndarray = blend_weights(t, anchors) @ coefficients.reshape(len(anchors), 9)
            return blended.reshape(-1, 3, 3)
        index = np.argmin(np.abs(t[:, None] - anchors[None, :]), axis=1)
        low, high = self.segment_bounds_degc[:, 0], self.segment_bounds_degc[:, 1]
        holder = np.searchsorted(low, t, side="right") - 1
        inside = (holder >= 0) & (t < high[np.clip(holder, 0, None)])
        index[inside] = holder[inside]
        picked: np.ndarray = coefficients[index]
        return picked

    def segment_drift(self, raw: np.ndarray, temperature_degc: ArrayLike) -> np.ndarray:
        """sigma (N, 3) added to the room-temperature correction: l a_raw^2 + m a_raw + n per axis."""
        terms = self.segment_terms(temperature_degc)
        drift: np.ndarray = terms[:, 0] * raw * raw + terms[:, 1] * raw + terms[:, 2]
        return drift

    def segment_names(self) -> list[str]:
        return [f"{lo:g}..{hi:g} degC" for lo, hi in self.segment_bounds_degc]


def temperature_span_problem(temperatures: np.ndarray, options: TemperatureOptions) -> str | None:
    """Why these pose temperatures cannot carry a temperature model (None when they can)."""
    lo, hi = float(np.min(temperatures)), float(np.max(temperatures))
    if hi - lo < options.min_span_degc:
        return (
            f"temperature span {hi - lo:.1f} degC ({lo:.1f}..{hi:.1f} degC) is under {options.min_span_degc:g} degC: "
            "hold poses while the sensor warms up or cools down to fit a temperature model"
        )
    return None


class ThermalSphereModel:
    """Sphere residuals with the polynomial temperature model, for the Gauss-Newton solver.

    p = [b (3), free entries of M (lower-triangular, 6), c_1..c_nb (3 each), d_1..d_ns (3 each)]
    """

    def __init__(self, base: SphereModel, bias_order: int, scale_order: int, reference_degc: float) -> None:
        self.base = base  # SphereModel
        self.bias_order, self.scale_order = bias_order, scale_order
        self.reference_degc = reference_degc
        self.size = base.size + 3 * (bias_order + scale_order)

    def pack(self, bias: np.ndarray, matrix: np.ndarray, bias_coefficients: np.ndarray | None = None,
             scale_coefficients: np.ndarray | None = None) -> np.ndarray:
        c = np.zeros((self.bias_order, 3)) if bias_coefficients is None else bias_coefficients
        d = np.zeros((self.scale_order, 3)) if scale_coefficients is None else scale_coefficients
        return np.concatenate([self.base.pack(bias, matrix), np.ravel(c), np.ravel(d)])

    def unpack(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        bias, matrix = self.base.unpack(p[: self.base.size])
        rest = p[self.base.size:]
        c = rest[: 3 * self.bias_order].reshape(self.bias_order, 3)
        d = rest[3 * self.bias_order:].reshape(self.scale_order, 3)
        return bias, matrix, c, d

    def residual_and_jacobian(self, p: np.ndarray, accel: np.ndarray, temperature: np.ndarray,
                              gravity: float) -> tuple[np.ndarray, np.ndarray]:
        bias, matrix, c, d = self.unpack(p)
        dt = (temperature - self.reference_degc)[:, None]
        powers_b = [dt**k for k in range(1, self.bias_order + 1)]
        powers_s = [dt**k for k in range(1, self.scale_order + 1)]
        drift = bias + sum((row * pw for row, pw in zip(c, powers_b)), np.zeros((len(accel), 3)))
        scale = 1.0 + sum((row * pw for row, pw in zip(d, powers_s)), np.zeros((len(accel), 3)))
        centred = accel - drift
        w = centred / scale
        y = w @ matrix.T
        norm = np.sqrt((y * y).sum(axis=1))
        e = y / norm[:, None]
        em = e @ matrix  # d|Mw|/dw
        jac = np.empty((len(accel), self.size))
        db = -em / scale
        jac[:, :3] = db
        rows, cols = self.base._index
        jac[:, 3:self.base.size] = e[:, rows] * w[:, cols]
        column = self.base.size
        for pw in powers_b:
            jac[:, column:column + 3] = db * pw
            column += 3
        for pw in powers_s:
            jac[:, column:column + 3] = -em * w / scale * pw
            column += 3
        return norm - gravity, jac


# ---------------------------------------------------------------------------------- segmented model
def segment_keys(temperatures: np.ndarray, width: float) -> np.ndarray:
    """Index of the segment holding each temperature (float, so a corrupt 1e300 cannot overflow):
    segment k spans [(k - 1/2) w, (k + 1/2) w), centred on k w."""
    keys: np.ndarray = np.floor(np.asarray(temperatures, dtype=float) / width + 0.5)
    return keys


def segment_bounds(key: float, width: float) -> tuple[float, float]:
    return (key - 0.5) * width, (key + 0.5) * width


def room_temperature_poses(temperatures: np.ndarray, options: TemperatureOptions) -> np.ndarray:
    """Mask of the poses the room-temperature calibration is fitted to: those within a quarter segment
    of T_ref (one chamber set point, never two: poses 9 degC apart are not one sphere). Without a
    T_ref, the band holding the most poses, the one nearest the median temperature on a tie."""
    temps = np.asarray(temperatures, dtype=float)
    half = options.segment_width_degc / 4
    if options.reference_degc is not None:
        mask: np.ndarray = np.abs(temps - options.reference_degc) <= half
        return mask
    ordered = np.sort(temps)
    counts = np.searchsorted(ordered, temps + half, side="right") - np.searchsorted(ordered, temps - half)
    candidates = temps[counts == counts.max()]
    centre = float(candidates[np.argmin(np.abs(candidates - np.median(temps)))])
    around: np.ndarray = np.abs(temps - centre) <= half
    return around


def segment_unknowns(known_orientations: bool) -> int:
    return KNOWN_UNKNOWNS if known_orientations else SPHERE_UNKNOWNS


def fewest_segment_poses(known_orientations: bool, min_poses_per_segment: int = 0) -> int:
    return max(segment_unknowns(known_orientations) + 1, min_poses_per_segment)


def _design(directions: np.ndarray, axis: int | None) -> np.ndarray:
    """Known orientations, one axis: columns a^2, a, 1. Sphere: d|a + sigma|/d(l, m, n) = e_i a_i^2,
    e_i a_i, e_i for every axis (in units of g, which Jacobi scaling makes irrelevant)."""
    if axis is not None:
        a = directions[:, axis]
        return np.column_stack([a * a, a, np.ones(len(a))])
    return np.hstack([directions**3, directions**2, directions])


def _weak_axes(directions: np.ndarray, known_orientations: bool) -> list[int]:
    """Axes whose coefficients the poses leave undetermined (scaled normal matrix beyond CONDITION_LIMIT)."""
    if known_orientations:
        return [axis for axis in range(3)
                if not scaled_condition_number(_design(directions, axis)) <= CONDITION_LIMIT]
    jacobian = _design(directions, None)
    normal = jacobian.T @ jacobian
    diag = np.sqrt(normal.diagonal())
    if np.any(diag == 0):  # a column of zeros: every pose has that axis level, so it is undetermined
        return sorted({int(j) % 3 for j in np.flatnonzero(diag == 0)})
    eigenvalues, vectors = np.linalg.eigh(normal / np.outer(diag, diag))
    weak = eigenvalues <= eigenvalues[-1] / CONDITION_LIMIT
    if not weak.any():
        return []
    # An axis is undetermined when it takes part in a direction of parameter space the poses do not see.
    share = (vectors[:, weak] ** 2).reshape(3, 3, -1).sum(axis=0)  # (axis, weak direction)
    return [axis for axis in range(3) if np.any(share[axis] > 0.2)]


def segment_needs(directions: np.ndarray, known_orientations: bool, min_poses_per_segment: int = 0) -> list[str]:
    """What a segment's poses still lack to determine its (l, m, n) per axis, as poses to hold
    ("x tilted about 45 deg", "z pointing down", "3 more poses"); [] when they determine it.
    `directions`: unit vectors of the gravity reaction per pose (known, or measured)."""
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    fewest = fewest_segment_poses(known_orientations, min_poses_per_segment)
    needs: list[str] = []
    for axis in _weak_axes(d, known_orientations) if len(d) else range(3):
        c = d[:, axis]
        name = AXES[axis]
        missing = []
        if not np.any(c >= POINTING_COSINE):
            missing.append(f"{name} pointing up")
        if not np.any(c <= -POINTING_COSINE):
            missing.append(f"{name} pointing down")
        if known_orientations and not np.any(np.abs(c) <= LEVEL_COSINE):
            missing.append(f"{name} level")
        if not known_orientations and not np.any((np.abs(c) >= TILTED_COSINES[0]) & (np.abs(c) <= TILTED_COSINES[1])):
            missing.append(f"{name} tilted about 45 deg")
        needs.extend(missing or [f"{name} at another angle"])
    if len(d) < fewest:
        more = fewest - len(d)
        needs.append(f"{more} more pose{'s' if more > 1 else ''}")
    return needs


def describe_needs(needs: list[str]) -> str:
    """'a pose with x tilted about 45 deg, a pose with z pointing down, 2 more poses'."""
    parts = [need if need[0].isdigit() else f"a pose with {need}" for need in needs]
    return ", ".join(parts)


def known_segment_drift(raw: np.ndarray, observed_drift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Known orientations: per axis, least squares of the observed drift (true minus room-temperature
    corrected, (N, 3)) on a_raw^2, a_raw, 1. Returns ((l, m, n) x axis (3, 3), residuals (N, 3))."""
    coefficients = np.zeros((3, 3))
    residuals = np.zeros_like(observed_drift)
    for axis in range(3):
        design = _design(raw, axis)
        solution, *_ = np.linalg.lstsq(design, observed_drift[:, axis], rcond=None)
        coefficients[:, axis] = solution
        residuals[:, axis] = observed_drift[:, axis] - design @ solution
    return coefficients, residuals


def sphere_segment_drift(raw: np.ndarray, corrected: np.ndarray, gravity: float) -> LeastSquaresSolution:
    """Orientation-free: the nine coefficients (x = l, m, n rows flattened) by Gauss-Newton on
    |corrected + sigma(raw)| = g, with the room-temperature correction held fixed."""
    square = raw * raw

    def residual_and_jacobian(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        quad, lin, offset = q[:3], q[3:6], q[6:]  # the paper's l, m, n
        y = corrected + quad * square + lin * raw + offset
        norm = np.sqrt((y * y).sum(axis=1))
        e = y / norm[:, None]
        return norm - gravity, np.hstack([e * square, e * raw, e])

    return gauss_newton(residual_and_jacobian, np.zeros(9))


def blend_weights(temperatures: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """(N, K): how much of each segment's coefficients the blended model applies at each temperature:
    linear between the neighbouring anchors (the temperatures the segments were learned at), and
    continued along the end pair beyond the first and last anchor (at most half a segment: the caller
    clamps to the calibrated range), so the drift's trend carries on rather than flattening there."""
    t = np.asarray(temperatures, dtype=float).reshape(-1)
    count = len(anchors)
    weights = np.zeros((len(t), count))
    if count == 1:
        weights[:, 0] = 1.0
        return weights
    right = np.clip(np.searchsorted(anchors, t, side="right"), 1, count - 1)
    left = right - 1
    fraction = (t - anchors[left]) / (anchors[right] - anchors[left])
    rows = np.arange(len(t))
    weights[rows, left] = 1.0 - fraction
    weights[rows, right] += fraction
    return weights


def known_blended_drift(raw: np.ndarray, observed_drift: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Known orientations, blended: every segment's (l, m, n) at once, per axis a linear least squares of
    the observed drift on the blend weights times a_raw^2, a_raw, 1: the blended model as it is applied,
    fitted to every pose at its own temperature. Returns (K, 3, 3)."""
    count = weights.shape[1]
    coefficients = np.zeros((count, 3, 3))
    for axis in range(3):
        a = raw[:, axis:axis + 1]
        design = np.hstack([weights * a * a, weights * a, weights])
        solution, *_ = np.linalg.lstsq(design, observed_drift[:, axis], rcond=None)
        coefficients[:, :, axis] = solution.reshape(3, count).T
    return coefficients


def sphere_blended_drift(raw: np.ndarray, corrected: np.ndarray, gravity: float, weights: np.ndarray,
                         start: np.ndarray, free: np.ndarray) -> LeastSquaresSolution:
    """Orientation-free, blended: the (l, m, n) of the `free` segments at once by Gauss-Newton on
    |corrected + sum_k w_k sigma_k(raw)| = g (the others held at `start`); x = the free segments'
    (l, m, n) rows flattened in turn, started from `start`."""
    square = raw * raw
    fixed = weights[:, ~free]
    held = start[~free]
    fixed_drift = (np.einsum("pk,kj->pj", fixed, held[:, 0]) * square + np.einsum("pk,kj->pj", fixed, held[:, 1]) * raw
                   + fixed @ held[:, 2])
    w = weights[:, free]

    def residual_and_jacobian(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = x.reshape(-1, 3, 3)
        drift = (w @ q[:, 0]) * square + (w @ q[:, 1]) * raw + w @ q[:, 2]
        y = corrected + fixed_drift + drift
        norm = np.sqrt((y * y).sum(axis=1))
        e = y / norm[:, None]
        blocks = [np.hstack([w[:, k:k + 1] * e * square, w[:, k:k + 1] * e * raw, w[:, k:k + 1] * e])
                  for k in range(w.shape[1])]
        return norm - gravity, np.hstack(blocks)

    return gauss_newton(residual_and_jacobian, start[free].ravel())


def segment_status(temperatures: np.ndarray, directions: np.ndarray, options: TemperatureOptions,
                   learned: TemperatureModel | None) -> str:
    """For diagnostics: which segments are learned, and what each of the others still needs
    (orientation-free, as the node learns). `directions`: unit gravity reactions of the poses."""
    width = options.segment_width_degc
    keys = segment_keys(temperatures, width)
    learned_bounds = set()
    if learned is not None and learned.kind == "segmented":
        learned_bounds = {(float(lo), float(hi)) for lo, hi in learned.segment_bounds_degc}
    done, pending = [], []
    for key in np.unique(keys):
        lo, hi = segment_bounds(float(key), width)
        inside = keys == key
        if (lo, hi) in learned_bounds:
            done.append(f"{lo:g}..{hi:g}")
            continue
        needs = segment_needs(directions[inside], False, options.min_poses_per_segment)
        pending.append(f"{lo:g}..{hi:g} degC ({int(inside.sum())} poses) needs "
                       + (describe_needs(needs) if needs else "a refit"))
    text = "segments learned: " + (", ".join(done) + " degC" if done else "none")
    return text + ("; " + "; ".join(pending) if pending else "")
