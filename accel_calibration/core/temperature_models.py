"""Temperature compensation: how bias and scale drift with temperature, fitted from the static poses.

Two models, both carried by a Calibration and applied with the current temperature:

- ``polynomial`` (default): b(T) = b + sum_k c_k dT^k (k = 1..bias_order <= 3) and a per-axis scale
  drift 1 + sum_k d_k dT^k (k = 1..scale_order <= 2), dT = T - T_ref, fitted jointly with M and b by
  the same Gauss-Newton on the sphere constraint, using each pose's mean temperature:
      a_true = M ((a_raw - b(T)) / (1 + s(T)))          (per-axis division)
  The autopilots (ArduPilot, PX4) fit bias only; MEMS scale factors drift too (~1e-4/degC), which at
  1 g is ~1 mg per 10 degC: scale_order=0 gives their model, for comparison.
- ``segmented``: the seed paper's scheme. Per temperature segment (default 10 degC) a per-axis
  quadratic of the drift of the measured acceleration, least squares against the room-temperature
  calibration; neighbouring segments are blended linearly between their centres so the output has
  no step at a boundary:
      a_true = M (a_raw - b - drift(T))

Both store T_ref and the calibrated range; outside it the temperature is clamped to the edge and
the clamp is reported. A temperature fit is refused, with the reason, when the poses' temperature
span is under `min_span_degc` (10 by default) or a segment has too few or too alike poses.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .errors import CalibrationError

if TYPE_CHECKING:
    from .models import SphereModel

TEMPERATURE_MODELS = ("none", "polynomial", "segmented")
SEGMENT_BLEND = 0.1  # half-width of the cross-fade around a segment edge, as a fraction of the segment


@dataclass(frozen=True)
class TemperatureOptions:
    """Settings of a temperature fit (validated here, so the CLI, node and API share the checks)."""

    model: str = "polynomial"
    bias_order: int = 2
    scale_order: int = 1
    segment_width_degc: float = 10.0
    min_span_degc: float = 10.0
    reference_degc: float | None = None  # T_ref; None = the poses' median temperature
    min_poses_per_segment: int = 12  # 9 unknowns per segment (3 axes x quadratic) plus margin

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


@dataclass(frozen=True)
class TemperatureModel:
    """The temperature block of a calibration."""

    kind: str  # "polynomial" or "segmented"
    reference_degc: float
    range_degc: tuple[float, float]  # calibrated range; outside it the temperature is clamped
    bias_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # polynomial: c_k rows
    scale_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # polynomial: d_k rows
    segment_edges_degc: np.ndarray = field(default_factory=lambda: np.zeros(0))  # segmented: K+1 edges
    segment_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))  # K x (q0,q1,q2) x axis

    def __post_init__(self) -> None:
        if self.kind not in ("polynomial", "segmented"):
            raise CalibrationError(f"temperature model kind must be polynomial or segmented, got {self.kind!r}")
        set_ = object.__setattr__
        for name in ("bias_coefficients", "scale_coefficients"):
            array: np.ndarray = np.array(getattr(self, name), dtype=float).reshape((-1, 3))
            if not np.all(np.isfinite(array)) or len(array) > 3:
                raise CalibrationError(f"temperature {name} must be up to 3 rows of 3 finite numbers")
            array.flags.writeable = False
            set_(self, name, array)
        edges = np.array(self.segment_edges_degc, dtype=float).reshape(-1)
        coefficients = np.array(self.segment_coefficients, dtype=float).reshape((-1, 3, 3))
        if self.kind == "segmented" and (len(edges) != len(coefficients) + 1 or len(coefficients) == 0
                                         or np.any(np.diff(edges) <= 0)):
            raise CalibrationError("segmented temperature model needs K+1 increasing edges for K segments")
        for array in (edges, coefficients):
            if not np.all(np.isfinite(array)):
                raise CalibrationError("temperature segment values must be finite")
            array.flags.writeable = False
        set_(self, "segment_edges_degc", edges)
        set_(self, "segment_coefficients", coefficients)
        lo, hi = (float(v) for v in self.range_degc)
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi and np.isfinite(self.reference_degc)):
            raise CalibrationError(f"temperature range must be finite with low <= high, got {self.range_degc!r}")
        set_(self, "range_degc", (lo, hi))
        set_(self, "reference_degc", float(self.reference_degc))

    def clamp(self, temperature_degc: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(temperature clamped to the calibrated range, mask of the values that were clamped)."""
        t = np.asarray(temperature_degc, dtype=float)
        lo, hi = self.range_degc
        return np.clip(t, lo, hi), (t < lo) | (t > hi)

    def bias_and_scale(self, temperature_degc: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Per-sample additive drift of the raw output (N, 3) and scale divisor (N, 3)."""
        t, _ = self.clamp(np.atleast_1d(temperature_degc))
        if self.kind == "polynomial":
            dt = (t - self.reference_degc)[:, None]
            drift = np.zeros((len(t), 3))
            for k, row in enumerate(self.bias_coefficients, start=1):
                drift += row * dt**k
            scale = np.ones((len(t), 3))
            for k, row in enumerate(self.scale_coefficients, start=1):
                scale += row * dt**k
            return drift, scale
        return self._segmented_drift(t), np.ones((len(t), 3))

    def _segmented_drift(self, t: np.ndarray) -> np.ndarray:
        edges, coefficients = self.segment_edges_degc, self.segment_coefficients
        centres = (edges[:-1] + edges[1:]) / 2
        count = len(centres)
        k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, count - 1)

        def quadratic(index: np.ndarray, temps: np.ndarray) -> np.ndarray:
            d = (temps - centres[index])[:, None]
            q = coefficients[index]
            value: np.ndarray = q[:, 0] + q[:, 1] * d + q[:, 2] * d * d
            return value

        drift = quadratic(k, t)
        # Within BLEND of an inner edge, cross-fade to the neighbour so the output has no step there;
        # elsewhere each segment's own quadratic (no extrapolation beyond a segment by more than BLEND).
        half = SEGMENT_BLEND * (edges[1] - edges[0])
        for i in range(1, count):
            near = np.abs(t - edges[i]) < half
            if near.any():
                w = ((t[near] - (edges[i] - half)) / (2 * half))[:, None]  # 0 below the zone, 1 above
                drift[near] = ((1 - w) * quadratic(np.full(near.sum(), i - 1), t[near])
                               + w * quadratic(np.full(near.sum(), i), t[near]))
        return drift


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


def fit_segmented_drift(accel: np.ndarray, temperature: np.ndarray, bias: np.ndarray, matrix: np.ndarray,
                        gravity: float, options: TemperatureOptions) -> tuple[np.ndarray, np.ndarray]:
    """Per segment, the drift of the raw output as a per-axis quadratic of temperature, least squares on
    the sphere constraint |M (a - b - drift(T))| = g with M, b held at the room-temperature calibration.
    (Estimating each pose's drift from its direction alone would see only the drift along gravity.)
    Returns (edges, coefficients); raises CalibrationError naming a segment that cannot be fitted."""
    from .coverage import scaled_condition_number
    from .gauss_newton import gauss_newton

    width = options.segment_width_degc
    first = np.floor(temperature.min() / width) * width
    last = np.ceil((temperature.max() + 1e-9) / width) * width
    edges = np.arange(first, last + width / 2, width)
    needed = max(options.min_poses_per_segment, 9)  # 3 coefficients x 3 axes
    coefficients = []
    for k in range(len(edges) - 1):
        lo, hi = edges[k], edges[k + 1]
        inside = (temperature >= lo) & ((temperature < hi) if k < len(edges) - 2 else (temperature <= hi))
        temps, points = temperature[inside], accel[inside]
        distinct = len(np.unique(np.round(temps, 1)))
        if len(temps) < needed or distinct < 3 or np.ptp(temps) < 0.1 * width:
            raise CalibrationError(
                f"segment {lo:g}..{hi:g} degC has {len(temps)} poses at {distinct} distinct temperatures "
                f"(spread {np.ptp(temps) if len(temps) else 0:.1f} degC): its quadratic needs at least {needed} poses "
                f"in several orientations at 3 or more temperatures spread over {0.1 * width:g} degC"
            )
        d = (temps - (lo + hi) / 2)[:, None]

        def residual_and_jacobian(q: np.ndarray, d: np.ndarray = d,
                                  points: np.ndarray = points) -> tuple[np.ndarray, np.ndarray]:
            q = q.reshape(3, 3)
            centred = points - bias - (q[0] + q[1] * d + q[2] * d * d)
            y = centred @ matrix.T
            norm = np.sqrt((y * y).sum(axis=1))
            em = (y / norm[:, None]) @ matrix
            return norm - gravity, np.hstack([-em, -em * d, -em * d * d])

        solution = gauss_newton(residual_and_jacobian, np.zeros(9))
        condition = scaled_condition_number(solution.jacobian)
        if not solution.success or condition > 1e6:
            raise CalibrationError(
                f"segment {lo:g}..{hi:g} degC: its {len(temps)} poses are too alike to separate the drift "
                f"(condition number {condition:.3g}): hold more orientations at these temperatures"
            )
        coefficients.append(solution.x.reshape(3, 3))
    return edges, np.array(coefficients)
