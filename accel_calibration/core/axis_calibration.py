"""What an autopilot can hold of a calibration, and what it costs: per-axis offset and scale with a
bias drift polynomial in temperature, fitted to our correction over all orientations and the
calibrated temperature range.

The form both autopilots apply (PX4 `calibration::Accelerometer::Correct`, ArduPilot
`_rotate_and_correct_accel`), per axis i, before any board rotation:

    a_i = (raw_i - drift_i(T) - offset_i) * scale_i

with drift_i(T) = constant_i + sum_k c_ki (t - origin)^k - [sum_k c_ki (t_zero - origin)^k], where t is the
temperature clamped to the thermal calibration's range and t_zero (ArduPilot's CALTEMP, also clamped) the
temperature at which the drift is zero; PX4 has no t_zero. No misalignment, no thermal scale: what our
calibration holds beyond that is the export's cost, measured here as the worst error over all orientations
of a 1 g specific force, in mg, over the calibrated temperature range.

The best axis-wise calibration is a linear least-squares problem per axis: with s = scale,
    a_i = s raw_i - s offset_i - s drift_i(T)
is linear in (s, s offset_i, s c_ki) on regressors (raw_i, 1, dT, dT^2, dT^3).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration
from .errors import CalibrationError
from .units import AXES, MG, STANDARD_GRAVITY

# Orientations the cost is evaluated on (a Fibonacci sphere: ~4.5 deg apart) and fitted on; temperatures
# across the calibrated range. The worst case between grid points differs from the grid's by < 0.1 %.
EVALUATION_DIRECTIONS = 2000
FIT_DIRECTIONS = 600
TEMPERATURE_STEPS = 21


def sphere_directions(count: int) -> np.ndarray:
    """`count` unit vectors spread evenly over the sphere (Fibonacci lattice), (count, 3)."""
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    radius = np.sqrt(1.0 - z * z)
    angle = math.pi * (3.0 - math.sqrt(5.0)) * index
    return np.column_stack([radius * np.cos(angle), radius * np.sin(angle), z])


@dataclass(frozen=True)
class AxisWiseCalibration:
    """a_i = (raw_i - drift_i(T) - offset_i) * scale_i: what PX4 and ArduPilot apply (m/s^2, degC)."""

    offset_mps2: np.ndarray  # (3,)
    scale: np.ndarray  # (3,)
    drift_constant_mps2: np.ndarray = field(default_factory=lambda: np.zeros(3))  # PX4's TC x0
    drift_coefficients: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # row k-1: m/s^2 per degC^k
    drift_origin_degc: float = 0.0  # the polynomial's variable is clamp(T) - origin
    drift_zero_degc: float | None = None  # ArduPilot's CALTEMP: drift is zero there
    clamp_degc: tuple[float, float] | None = None  # the thermal calibration's TMIN, TMAX

    def __post_init__(self) -> None:
        for name, shape in (("offset_mps2", (3,)), ("scale", (3,)), ("drift_constant_mps2", (3,))):
            array = np.array(getattr(self, name), dtype=float)
            if array.shape != shape or not np.all(np.isfinite(array)):
                raise CalibrationError(f"{name} must be {shape[0]} finite numbers")
            object.__setattr__(self, name, array)
        coefficients = np.array(self.drift_coefficients, dtype=float).reshape(-1, 3)
        if len(coefficients) > 3 or not np.all(np.isfinite(coefficients)):
            raise CalibrationError("drift_coefficients must be up to 3 rows of 3 finite numbers")
        object.__setattr__(self, "drift_coefficients", coefficients)

    @property
    def has_drift(self) -> bool:
        return bool(np.any(self.drift_coefficients != 0) or np.any(self.drift_constant_mps2 != 0))

    def _clamped(self, temperature_degc: np.ndarray) -> np.ndarray:
        if self.clamp_degc is None:
            return temperature_degc
        low, high = self.clamp_degc
        clamped: np.ndarray = np.clip(temperature_degc, low, high)
        return clamped

    def _polynomial(self, temperature_degc: np.ndarray) -> np.ndarray:
        dt = (self._clamped(temperature_degc) - self.drift_origin_degc)[:, None]
        value = np.zeros((len(dt), 3))
        for k, row in enumerate(self.drift_coefficients, start=1):
            value += row * dt**k
        return value

    def drift(self, temperature_degc: ArrayLike) -> np.ndarray:
        """drift(T), (N, 3) m/s^2 for N temperatures."""
        t = np.atleast_1d(np.asarray(temperature_degc, dtype=float))
        value: np.ndarray = self._polynomial(t) + self.drift_constant_mps2
        if self.drift_zero_degc is not None:
            value -= self._polynomial(np.array([self.drift_zero_degc]))
        return value

    def apply(self, raw: ArrayLike, temperature_degc: ArrayLike) -> np.ndarray:
        """Correct raw (N, 3) at temperatures (N,) or one temperature."""
        rows = np.atleast_2d(np.asarray(raw, dtype=float))
        t = np.broadcast_to(np.asarray(temperature_degc, dtype=float), (len(rows),))
        corrected: np.ndarray = (rows - self.drift(t) - self.offset_mps2) * self.scale
        return corrected


def raw_for_true(calibration: Calibration, true_mps2: np.ndarray, temperature_degc: np.ndarray) -> np.ndarray:
    """The raw output (N, 3) our calibration maps to `true_mps2` (N, 3) at these temperatures (N,): the
    sensor our calibration describes. Newton steps with M as the Jacobian (the quadratic, thermal scale and
    segment terms are small next to it): converged to < 1e-12 m/s^2 in a few steps."""
    inverse = np.linalg.inv(calibration.matrix)
    raw: np.ndarray = calibration.bias + true_mps2 @ inverse.T
    for _ in range(20):
        residual = true_mps2 - calibration.apply(raw, temperature_degc)
        raw = raw + residual @ inverse.T
        if float(np.max(np.abs(residual))) < 1e-12:
            break
    return raw


def temperature_grid(calibration: Calibration) -> np.ndarray:
    """Temperatures the cost is taken over: the calibrated range, or the reference temperature (else
    25 degC: a calibration without a temperature model corrects alike at every temperature)."""
    if calibration.temperature is not None:
        low, high = calibration.temperature.range_degc
        if high > low:
            return np.linspace(low, high, TEMPERATURE_STEPS)
        return np.array([low])
    reference = calibration.reference_temperature_degc
    return np.array([25.0 if reference is None else reference])


def _samples(calibration: Calibration, directions: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(true, raw, temperature) over orientations x temperatures: true specific force of 1 g."""
    unit = sphere_directions(directions)
    temps = temperature_grid(calibration)
    true = np.tile(unit * STANDARD_GRAVITY, (len(temps), 1))
    temperature = np.repeat(temps, len(unit))
    return true, raw_for_true(calibration, true, temperature), temperature


@dataclass(frozen=True)
class Cost:
    """How far another correction is from ours: worst and rms error of a 1 g specific force over all
    orientations and the temperature range, in mg, and where the worst one is."""

    worst_mg: float
    rms_mg: float
    worst_direction: tuple[float, float, float]
    worst_temperature_degc: float
    temperature_range_degc: tuple[float, float]

    def describe(self) -> str:
        low, high = self.temperature_range_degc
        where = f"{low:.1f}..{high:.1f} degC" if high > low else f"{low:.1f} degC"
        x, y, z = self.worst_direction
        return (f"worst {self.worst_mg:.3f} mg (rms {self.rms_mg:.3f} mg) over all orientations at 1 g, {where}; "
                f"worst with gravity along ({x:+.2f}, {y:+.2f}, {z:+.2f}) at {self.worst_temperature_degc:.1f} degC")


Correction = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (raw (N, 3), degC (N,)) -> corrected (N, 3)


def cost_against(calibration: Calibration, other: AxisWiseCalibration | Correction,
                 directions: int = EVALUATION_DIRECTIONS) -> Cost:
    """Worst error (mg at 1 g) of `other`'s correction of the sensor our calibration describes."""
    true, raw, temperature = _samples(calibration, directions)
    correct = other.apply if isinstance(other, AxisWiseCalibration) else other
    try:
        with np.errstate(over="raise", invalid="raise"):
            error = np.linalg.norm(correct(raw, temperature) - true, axis=1) / MG
    except FloatingPointError:
        raise CalibrationError("the other correction overflows: its parameters are beyond any sensor's") from None
    worst = int(np.argmax(error))
    direction = true[worst] / STANDARD_GRAVITY
    temps = temperature_grid(calibration)
    return Cost(worst_mg=float(error[worst]), rms_mg=float(np.sqrt(np.mean(error**2))),
                worst_direction=(float(direction[0]), float(direction[1]), float(direction[2])),
                worst_temperature_degc=float(temperature[worst]),
                temperature_range_degc=(float(temps[0]), float(temps[-1])))


def best_rotation(corrected: np.ndarray, true: np.ndarray) -> np.ndarray:
    """The rotation R minimising sum |R corrected_i - true_i|^2 (Kabsch: the SVD of sum corrected_i true_i^T,
    with the sign fixed so that det R = +1)."""
    u, _, vt = np.linalg.svd(corrected.T @ true)
    sign = 1.0 if np.linalg.det(vt.T @ u.T) > 0 else -1.0
    rotation: np.ndarray = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return rotation


def cost_after_best_rotation(calibration: Calibration, other: AxisWiseCalibration | Correction,
                             directions: int = EVALUATION_DIRECTIONS) -> tuple[Cost, np.ndarray]:
    """(cost, R): `other`'s cost once its output is rotated by the best rotation R (least squares over the
    evaluation grid). Our calibrated frame's orientation is the fit's convention (sphere9 ties it to the
    sensor's x axis and xy plane); the rotation from it to the vehicle is what the autopilot's level and
    board-rotation calibration measure on the vehicle, so only the rest is a loss of the sensor calibration."""
    true, raw, temperature = _samples(calibration, directions)
    correct = other.apply if isinstance(other, AxisWiseCalibration) else other
    rotation = best_rotation(correct(raw, temperature), true)

    def rotated(raw_mps2: np.ndarray, temperature_degc: np.ndarray) -> np.ndarray:
        corrected: np.ndarray = correct(raw_mps2, temperature_degc) @ rotation.T
        return corrected

    return cost_against(calibration, rotated, directions), rotation


def rotation_angle_mrad(rotation: np.ndarray) -> float:
    """The angle of a rotation matrix, mrad."""
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0))) * 1e3


def gyro_matrix_loss_mrad_per_radps(gyro_matrix: np.ndarray) -> float:
    """What dropping the gyro matrix costs (a target that applies w = w_raw - b_g only): the worst error per
    rad/s of true rate over all directions, mrad/s per rad/s = the largest singular value of M_g^-1 - I."""
    return float(np.linalg.norm(np.linalg.inv(gyro_matrix) - np.eye(3), 2)) * 1e3


def fit_axis_wise(calibration: Calibration, *, drift_order: int, drift_origin_degc: float,
                  drift_zero_degc: float | None = None, worst_case: bool = False) -> AxisWiseCalibration:
    """The axis-wise calibration closest to ours (least squares over orientations x temperatures), with a
    bias drift polynomial of `drift_order` (0..3) in T - drift_origin_degc, zero at drift_zero_degc when given
    (ArduPilot's form), or with its constant folded into the offset (PX4's form). No drift is fitted when
    the calibration has no temperature model or a single temperature. `worst_case`: closest at the worst
    orientation and temperature instead (minimax_fit), for a drift a cubic cannot follow exactly (a
    warm-up's spline), where least squares leaves the range's ends worse than they need be."""
    if not (isinstance(drift_order, int) and 0 <= drift_order <= 3):
        raise CalibrationError(f"drift_order must be 0..3, got {drift_order!r}")
    true, raw, temperature = _samples(calibration, FIT_DIRECTIONS)
    temps = temperature_grid(calibration)
    order = drift_order if len(temps) > 1 else 0
    # Regressor columns scaled to ~1 so that the cubic's column does not dominate the conditioning.
    span = max(float(np.max(np.abs(temps - drift_origin_degc))), 1.0)
    clamp = (float(temps[0]), float(temps[-1]))
    if worst_case and order:
        clamp = worst_case_clamp(calibration, drift_origin_degc)
    dt = (np.clip(temperature, *clamp) - drift_origin_degc) / span
    offset = np.zeros(3)
    scale = np.ones(3)
    coefficients = np.zeros((order, 3))
    for axis in range(3):
        columns = [raw[:, axis], np.ones(len(raw))] + [dt**k for k in range(1, order + 1)]
        design = np.column_stack(columns)
        if worst_case and order:
            solution = minimax_fit(design, true[:, axis])
        else:
            solution, *_ = np.linalg.lstsq(design, true[:, axis], rcond=None)
        s = float(solution[0])
        if not s > 0:
            raise CalibrationError(f"axis {AXES[axis]}: the best scale is {s:g}, not positive")
        scale[axis] = s
        coefficients[:, axis] = [-solution[1 + k] / s / span**k for k in range(1, order + 1)]
        offset[axis] = -solution[1] / s
    fitted = AxisWiseCalibration(offset_mps2=offset, scale=scale, drift_coefficients=coefficients,
                                 drift_origin_degc=drift_origin_degc,
                                 clamp_degc=clamp if order else None)
    if drift_zero_degc is not None and order:
        # raw - o - P(T) = raw - (o + P(T_zero)) - (P(T) - P(T_zero)): the offset takes P(T_zero).
        offset = offset + fitted.drift(np.array([drift_zero_degc]))[0]
        fitted = AxisWiseCalibration(offset_mps2=offset, scale=scale, drift_coefficients=coefficients,
                                     drift_origin_degc=drift_origin_degc, drift_zero_degc=drift_zero_degc,
                                     clamp_degc=fitted.clamp_degc)
    return fitted


def lower_triangular_with_rotation(matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, L) with matrix = R L, R a rotation and L lower-triangular with a positive diagonal: OpenVINS'
    `kalibr` model (a_I = R_ACCtoI D_a (a_m - b_a), D_a lower-triangular). Exact for any M of positive
    determinant (a QL decomposition)."""
    m = np.asarray(matrix, dtype=float)
    if not np.linalg.det(m) > 0:
        raise CalibrationError("the calibration matrix has a non-positive determinant: it mirrors the axes, "
                               "which no rotation and triangular scale can hold")
    # QL from QR of the column- and row-reversed matrix: M J = Q R -> M = (Q J)(J R J) with J the reversal.
    reverse = np.eye(3)[::-1]
    q, r = np.linalg.qr(m @ reverse)
    rotation = q @ reverse
    lower = reverse @ r @ reverse
    signs = np.sign(np.diag(lower))
    rotation = rotation * signs  # flip columns of R and rows of L together: R L unchanged
    lower = signs[:, None] * lower
    return rotation, lower


CLAMP_SHARE = 0.3  # TMIN / TMAX are looked for this far into the range from each end
CLAMP_STEPS = 7


def _cubic_worst(temps: np.ndarray, drift: np.ndarray, clamp: tuple[float, float], origin: float) -> float:
    """The worst error of the minimax cubic (constant free) in clamp(T) - origin through `drift` (N, 3)."""
    scaled = (np.clip(temps, *clamp) - origin) / max(float(np.max(np.abs(temps - origin))), 1.0)
    design = np.column_stack([scaled**k for k in range(4)])
    return max(float(np.max(np.abs(design @ minimax_fit(design, drift[:, axis], 60) - drift[:, axis])))
               for axis in range(3))


def worst_case_clamp(calibration: Calibration, drift_origin_degc: float) -> tuple[float, float]:
    """TMIN, TMAX for the autopilots' cubic of a drift it cannot follow exactly: both autopilots hold the
    correction flat beyond them (they clamp T), which follows a drift that levels off at the range's ends
    (a warm-up's tanh-like curve) better than the cubic does; chosen within CLAMP_SHARE of each end so that
    the accelerometer's and the gyro's worst errors fall most (each against its own with the whole range)."""
    model = calibration.temperature
    assert model is not None
    low, high = model.range_degc
    temps = np.linspace(low, high, MINIMAX_STEPS // 2 + 1)
    drifts = [model.bias_and_scale(temps)[0]] + ([model.gyro_drift(temps)] if model.has_gyro else [])
    whole = [max(_cubic_worst(temps, drift, (low, high), drift_origin_degc), 1e-12) for drift in drifts]
    best = (1.0, (low, high))
    reach = CLAMP_SHARE * (high - low)
    for tmin in np.linspace(low, low + reach, CLAMP_STEPS):
        for tmax in np.linspace(high - reach, high, CLAMP_STEPS):
            clamp = (float(tmin), float(tmax))
            ratio = max(_cubic_worst(temps, drift, clamp, drift_origin_degc) / full
                        for drift, full in zip(drifts, whole))
            if ratio < best[0]:
                best = (ratio, clamp)
    return best[1]


def fit_gyro_drift(calibration: Calibration, *, drift_origin_degc: float, drift_zero_degc: float,
                   clamp_degc: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The gyro bias drift as ArduPilot's cubic holds it: rows k = 1..3 (rad/s per degC^k) of P(d), d = T -
    drift_origin_degc, and the change of the gyro offset that goes with it (rad/s; ArduPilot takes
    P(T - origin) - P(zero - origin) off before the offset), so that together they are closest to our gyro
    bias at its worst temperature over the calibrated range (Lawson's reweighted least squares, the constant
    free: the vehicle sees the worst temperature, not the average), and that worst loss (rad/s). None when
    the calibration has no gyro temperature model."""
    model = calibration.temperature
    if model is None or not model.has_gyro:
        return None
    low, high = model.range_degc
    temps = np.linspace(low, high, MINIMAX_STEPS) if high > low else np.array([low])
    clamp = (low, high) if clamp_degc is None else clamp_degc  # the TMIN, TMAX the accelerometer's fit chose
    span = max(float(np.max(np.abs(temps - drift_origin_degc))), 1.0)
    zero = (float(np.clip(drift_zero_degc, *clamp)) - drift_origin_degc) / span
    scaled = (np.clip(temps, *clamp) - drift_origin_degc) / span
    design = np.column_stack([np.ones(len(temps))] + [scaled**k - zero**k for k in range(1, 4)])
    target = model.gyro_drift(temps)
    solution = np.zeros((4, 3))
    for axis in range(3):
        solution[:, axis] = minimax_fit(design, target[:, axis])
    loss = float(np.max(np.abs(design @ solution - target)))
    rows: np.ndarray = solution[1:] / (span ** np.arange(1, 4))[:, None]
    return rows, solution[0].copy(), loss


MINIMAX_STEPS = 201
LAWSON_ITERATIONS = 200


def minimax_fit(design: np.ndarray, target: np.ndarray, iterations: int = LAWSON_ITERATIONS) -> np.ndarray:
    """x minimising max |design x - target| (Lawson's algorithm: least squares reweighted by each point's
    error, which converges to the minimax fit; stopped where the worst error stops falling)."""
    weights = np.full(len(target), 1.0 / len(target))
    best: np.ndarray | None = None
    best_worst = np.inf
    for _ in range(iterations):
        root = np.sqrt(weights)
        solution, *_ = np.linalg.lstsq(design * root[:, None], target * root, rcond=None)
        error = np.abs(design @ solution - target)
        worst = float(error.max())
        if worst < best_worst:
            best, best_worst = solution, worst
        weights = weights * error
        total = float(weights.sum())
        if not total > 0:
            break
        weights = weights / total
    assert best is not None
    return best
