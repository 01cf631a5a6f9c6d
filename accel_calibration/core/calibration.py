"""The Calibration value: what a fit produces, what the node applies and what a file holds."""
from __future__ import annotations

import datetime as _dt
import math
import time
from dataclasses import MISSING, dataclass, field, fields, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .dividing_head import DividingHeadTerms
from .errors import CalibrationError
from .models import CALIBRATION_MODELS, DIVIDING_HEAD, apply_forward_inverse
from .temperature_models import TemperatureModel
from .units import STANDARD_GRAVITY


def _frozen(values: ArrayLike, shape: tuple[int, ...], name: str) -> np.ndarray:
    """A read-only float copy of `values`, checked for shape and finiteness. Plain float arrays (what
    fit() passes) take the short way: every fit builds a Calibration, and on 3 and 9 numbers Python's
    float checks cost a fraction of numpy's."""
    if type(values) is np.ndarray and values.dtype == np.float64:
        array = values.copy()
    else:
        try:
            array = np.array(values, dtype=float)
        except (TypeError, ValueError):
            raise CalibrationError(f"{name} must be numbers, got {values!r:.60}") from None
    if array.shape != shape:
        raise CalibrationError(f"{name} must have shape {shape}, got {array.shape}")
    if not all(map(math.isfinite, array.ravel().tolist())):
        raise CalibrationError(f"{name} must be finite, got {array.tolist()}")
    array.setflags(write=False)
    return array


def _scaled_determinant(matrix: np.ndarray) -> float:
    """det of a finite 3 x 3 matrix with each row divided by its largest magnitude (0 when a row is
    zero): singularity relative to each row's size. Closed form on floats: numpy's det costs more."""
    (a, b, c), (d, e, f), (g, h, i) = matrix.tolist()
    first, second, third = max(abs(a), abs(b), abs(c)), max(abs(d), abs(e), abs(f)), max(abs(g), abs(h), abs(i))
    if not (first > 0 and second > 0 and third > 0):
        return 0.0
    a, b, c = a / first, b / first, c / first
    d, e, f = d / second, e / second, f / second
    g, h, i = g / third, h / third, i / third
    return float(a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g))


MAX_IDENTIFIER_CHARS = 256  # a frame_id or sensor_id; ROS names are far shorter


def bounded_identifier(value: object) -> str:
    """A frame_id or sensor_id as a Calibration keeps it: text of at most MAX_IDENTIFIER_CHARS printable
    characters (each other one, a control character, a NUL, an undecodable byte of a file name, becomes
    '?'), so a file saved with it stays small and loadable whatever a message or a path carried."""
    text = value if isinstance(value, str) else "" if value is None else str(value)
    if len(text) <= MAX_IDENTIFIER_CHARS and text.isprintable():
        return text
    return "".join(c if c.isprintable() else "?" for c in text[:MAX_IDENTIFIER_CHARS])


_CREATED: tuple[int, str] = (-1, "")


def _created_now() -> str:
    """UTC now in ISO format to the second, formatted once per second (fits run thousands per second)."""
    global _CREATED
    second = int(time.time())
    cached = _CREATED
    if cached[0] != second:
        cached = (second, _dt.datetime.fromtimestamp(second, _dt.UTC).isoformat(timespec="seconds"))
        _CREATED = cached
    return cached[1]


@dataclass(frozen=True)
class Quality:
    """How well the calibration explains the poses it was fitted to."""

    residual_rms_mg: float
    residual_max_mg: float
    poses: int
    condition_number: float | None = None


@dataclass(frozen=True, eq=False)
class GyroQuality:
    """How well the gyro calibration explains the motions between the poses it was fitted to."""

    matrix_sigma: np.ndarray  # (3, 3) 1 sigma of the gyro matrix's entries
    residual_rms_mrad: float  # |R^T u_i - u_{i+1}| over the motions used
    residual_max_mrad: float
    motions: int  # motions used
    bias_sigma_radps: np.ndarray | None = None  # (3,) when a bias change was fitted with the matrix

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "matrix_sigma", _frozen(self.matrix_sigma, (3, 3), "gyro_quality.matrix_sigma"))
        if np.any(self.matrix_sigma < 0):
            raise CalibrationError("gyro_quality.matrix_sigma must be >= 0")
        if self.bias_sigma_radps is not None:
            set_(self, "bias_sigma_radps", _frozen(self.bias_sigma_radps, (3,), "gyro_quality.bias_sigma_radps"))
            if np.any(self.bias_sigma_radps < 0):
                raise CalibrationError("gyro_quality.bias_sigma_radps must be >= 0")
        for name in ("residual_rms_mrad", "residual_max_mrad"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise CalibrationError(f"gyro_quality.{name} must be a number >= 0, got {value!r:.40}")
            set_(self, name, float(value))
        if isinstance(self.motions, bool) or not isinstance(self.motions, int) or self.motions < 0:
            raise CalibrationError(f"gyro_quality.motions must be an integer >= 0, got {self.motions!r:.40}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, GyroQuality):
            return NotImplemented
        return (np.array_equal(self.matrix_sigma, other.matrix_sigma)
                and _same_optional(self.bias_sigma_radps, other.bias_sigma_radps)
                and (self.residual_rms_mrad, self.residual_max_mrad, self.motions)
                == (other.residual_rms_mrad, other.residual_max_mrad, other.motions))

    __hash__ = None  # type: ignore[assignment]


# What a noise block may say: a MEMS accelerometer's white noise is ~50-1000 ug/sqrt(Hz), a gyro's
# ~0.003-0.1 deg/s/sqrt(Hz); beyond these bounds it is no sensor's (or another unit's).
NOISE_RATE_HZ = (1.0, 100_000.0)
MAX_ACCEL_DENSITY = 1.0  # m/s^2/sqrt(Hz)
MAX_GYRO_DENSITY = 0.1  # rad/s/sqrt(Hz)


@dataclass(frozen=True)
class MeasuredNoise:
    """The sensor's white noise as measured at the still poses, in Kalibr's terms: the noise density per
    axis (sigma of one sample = density * sqrt(rate), the discrete-time convention Kalibr and OpenVINS use)
    and the sample rate it was measured at. Kept in the calibration so that a restart's covariance starts
    from it instead of from nothing."""

    rate_hz: float
    accel_density: float  # m/s^2/sqrt(Hz)
    gyro_density: float | None = None  # rad/s/sqrt(Hz); None without a gyro

    def __post_init__(self) -> None:
        bounds = {"rate_hz": NOISE_RATE_HZ, "accel_density": (0.0, MAX_ACCEL_DENSITY),
                  "gyro_density": (0.0, MAX_GYRO_DENSITY)}
        for name, (low, high) in bounds.items():
            value = getattr(self, name)
            if value is None and name == "gyro_density":
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise CalibrationError(f"noise.{name} must be a number, got {value!r:.40}")
            # A rate of 1 Hz is a (slow) rate; a density of 0 is no sensor's.
            inside = low <= value <= high if name == "rate_hz" else low < value <= high
            if not inside:
                raise CalibrationError(f"noise.{name} {value:.4g} outside {low:g}..{high:g}: no MEMS sensor's")
            object.__setattr__(self, name, float(value))

    @classmethod
    def from_variances(cls, rate_hz: float, accel_var: float, gyro_var: float | None) -> MeasuredNoise:
        """From the per-sample variances per axis ((m/s^2)^2, (rad/s)^2) at `rate_hz`."""
        return cls(rate_hz, math.sqrt(accel_var / rate_hz),
                   None if gyro_var is None else math.sqrt(gyro_var / rate_hz))

    def describe(self) -> str:
        """One line, as replay says it."""
        gyro = "" if self.gyro_density is None else f", gyro {self.gyro_density:.3e} rad/s/sqrt(Hz)"
        return (f"white noise at the poses: accel {self.accel_density:.3e} m/s^2/sqrt(Hz){gyro} at {self.rate_hz:g} Hz "
                "(random walk and bias instability: accel-calib noise)")

    @property
    def accel_var(self) -> float:
        """Variance of one sample per axis, (m/s^2)^2."""
        return self.accel_density * self.accel_density * self.rate_hz

    @property
    def gyro_var(self) -> float | None:
        """Variance of one sample per axis, (rad/s)^2."""
        return None if self.gyro_density is None else self.gyro_density * self.gyro_density * self.rate_hz


def _same_optional(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return np.array_equal(a, b)


@dataclass(frozen=True)
class Calibration:
    """a_true = M (a_raw - b) (+ the inverse of the quadratic term for ``reference15``).

    Immutable: a new fit makes a new Calibration.
    """

    bias: np.ndarray  # b, (3,), units of the raw data (m/s^2 at every ROS interface)
    matrix: np.ndarray  # M, (3, 3)
    model: str = "sphere9"
    gravity: float = STANDARD_GRAVITY
    quadratic: np.ndarray | None = None  # q, (3,), forward a_raw = b + M^-1 a + q a^2, s^2/m
    bias_sigma: np.ndarray | None = None  # 1-sigma of b
    matrix_sigma: np.ndarray | None = None  # 1-sigma of M's entries (0 where the model fixes them)
    quality: Quality | None = None
    created: str = field(default_factory=_created_now)
    frame_id: str = ""
    sensor_id: str = ""
    reference_temperature_degc: float | None = None
    gyro_bias_radps: np.ndarray | None = None  # (3,) mean gyro output at rest, from the static poses
    temperature: TemperatureModel | None = None  # bias/scale drift with temperature
    # Model dividing-head: the fitted terms in the paper's words (scale, mounting, tilt errors, ...).
    dividing_head: DividingHeadTerms | None = None
    # w_true = gyro_matrix (w_raw - gyro_bias_radps), in the accelerometer's calibrated frame (fit_gyro)
    gyro_matrix: np.ndarray | None = None
    gyro_quality: GyroQuality | None = None
    noise: MeasuredNoise | None = None  # white noise measured at the poses (the covariance's start)
    # Where `gravity` came from: "standard", "given", "WGS84 normal gravity, latitude .. deg, height .. m";
    # "" when not recorded (files written before it was).
    gravity_source: str = ""
    # What the fit saw, where a recording says: "raw: ..." (the sensor's own output, or a log's stream with
    # the log's correction undone) or a stream as logged, corrected by a calibration this one goes on top of.
    fitted_to: str = ""
    # The device IDs (PX4 / ArduPilot: bus type, bus, address, device type) of the accelerometer and of the
    # gyro the calibration was fitted to, where the recording says them; a gyro of its own die has its own ID.
    accel_device_id: int | None = None
    gyro_device_id: int | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if self.noise is not None and not isinstance(self.noise, MeasuredNoise):
            raise CalibrationError("noise must be a MeasuredNoise or None")
        set_(self, "bias", _frozen(self.bias, (3,), "bias"))
        set_(self, "matrix", _frozen(self.matrix, (3, 3), "matrix"))
        self._check_model_gravity_matrix()
        if self.quadratic is not None:
            set_(self, "quadratic", _frozen(self.quadratic, (3,), "quadratic"))
        if self.temperature is not None and not isinstance(self.temperature, TemperatureModel):
            raise CalibrationError("temperature must be a TemperatureModel or None")
        if self.temperature is not None and self.temperature.kind != "segmented" and self.quadratic is not None:
            # The segmented drift is added after the whole room-temperature correction, the polynomial
            # and spline ones are folded into M and b, which the quadratic's inversion does not allow.
            raise CalibrationError(f"a {self.temperature.kind} temperature model cannot be combined with the "
                                   "quadratic (reference15) term")
        if self.dividing_head is not None:
            if not isinstance(self.dividing_head, DividingHeadTerms):
                raise CalibrationError("dividing_head must be a DividingHeadTerms or None")
            if self.model != DIVIDING_HEAD:
                raise CalibrationError(f"a dividing_head block belongs to model {DIVIDING_HEAD}, not {self.model}")
        if self.gyro_bias_radps is not None:
            set_(self, "gyro_bias_radps", _frozen(self.gyro_bias_radps, (3,), "gyro_bias_radps"))
        if self.gyro_matrix is not None:
            set_(self, "gyro_matrix", _frozen(self.gyro_matrix, (3, 3), "gyro_matrix"))
            if self.gyro_bias_radps is None:
                raise CalibrationError("gyro_matrix needs gyro_bias_radps "
                                       "(w_true = gyro_matrix (w_raw - gyro_bias_radps))")
            if abs(_scaled_determinant(self.gyro_matrix)) < 1e-12:
                raise CalibrationError("gyro_matrix is singular: it would collapse the angular rate")
        if self.gyro_quality is not None:
            if not isinstance(self.gyro_quality, GyroQuality):
                raise CalibrationError("gyro_quality must be a GyroQuality or None")
            if self.gyro_matrix is None:
                raise CalibrationError("gyro_quality belongs to a gyro_matrix, and there is none")
        if self.bias_sigma is not None:
            set_(self, "bias_sigma", _frozen(self.bias_sigma, (3,), "bias_sigma"))
        if self.matrix_sigma is not None:
            set_(self, "matrix_sigma", _frozen(self.matrix_sigma, (3, 3), "matrix_sigma"))

    @classmethod
    def from_fit(cls, bias: np.ndarray, matrix: np.ndarray, bias_sigma: np.ndarray, matrix_sigma: np.ndarray,
                 **others: Any) -> Calibration:
        """What fit() builds on every fit: float64 arrays of the right shapes that it has just computed
        and found finite. They are validated once, there: here only what fit() does not check (M
        singular relative to its rows, the model, gravity) is, and read-only copies are taken as
        always. Anything else given (quadratic, temperature, ...) takes the full constructor."""
        if others.keys() - _FIT_FIELDS:
            return cls(bias=bias, matrix=matrix, bias_sigma=bias_sigma, matrix_sigma=matrix_sigma, **others)
        values = {"bias": _read_only(bias), "matrix": _read_only(matrix), "bias_sigma": _read_only(bias_sigma),
                  "matrix_sigma": _read_only(matrix_sigma), **others}
        self = object.__new__(cls)
        for f in _FIELDS:
            if f.name in values:
                value = values[f.name]
            elif f.default_factory is not MISSING:
                value = f.default_factory()
            else:  # a field without a default is one of the required ones, given above
                value = f.default
            object.__setattr__(self, f.name, value)
        self._check_model_gravity_matrix()
        return self

    def _check_model_gravity_matrix(self) -> None:
        """The checks both constructors make (gravity becomes a float): a known model, a positive finite
        gravity, M not singular, and the identifiers bounded (bounded_identifier)."""
        for name in ("frame_id", "sensor_id", "gravity_source"):
            object.__setattr__(self, name, bounded_identifier(getattr(self, name)))
        for name in ("accel_device_id", "gyro_device_id"):
            device = getattr(self, name)
            if device is not None and (isinstance(device, bool) or not isinstance(device, int)
                                       or not 0 < device < 2**32):
                raise CalibrationError(f"{name} must be a 32-bit device ID above 0, got {device!r:.40}")
        if self.model not in CALIBRATION_MODELS:
            raise CalibrationError(f"unknown model {self.model!r}; expected one of {', '.join(CALIBRATION_MODELS)}")
        if not (isinstance(self.gravity, (int, float)) and np.isfinite(self.gravity) and self.gravity > 0):
            raise CalibrationError(f"gravity must be a positive number of m/s^2, got {self.gravity!r}")
        object.__setattr__(self, "gravity", float(self.gravity))
        # Relative to each row's size, never absolute: raw counts at 256 000 LSB/g give M ~ 4e-5.
        if abs(_scaled_determinant(self.matrix)) < 1e-12:
            raise CalibrationError("matrix is singular: it would collapse the measurement")

    @classmethod
    def identity(cls, **kwargs: Any) -> Calibration:
        """The do-nothing calibration (raw passes through)."""
        return cls(bias=np.zeros(3), matrix=np.eye(3), **kwargs)

    def apply(self, raw: ArrayLike, temperature: ArrayLike | None = None) -> np.ndarray:
        """Correct raw accelerations, (3,) or (N, 3), vectorised.

        `temperature` (degC, scalar or (N,)) is used when the calibration has a temperature model;
        without it such a calibration corrects as at its reference temperature. Temperatures outside
        the calibrated range are clamped to its edge (see `temperature_clamped`)."""
        array = np.asarray(raw, dtype=float)
        if array.shape[-1:] != (3,) or array.ndim > 2:
            raise CalibrationError(f"raw accelerations must have shape (3,) or (N, 3), got {array.shape}")
        if self.temperature is None:
            return apply_forward_inverse(array, self.bias, self.matrix, self.quadratic)
        if temperature is None:
            temperature = self.temperature.reference_degc
        rows = np.atleast_2d(array)
        temps = np.broadcast_to(np.asarray(temperature, dtype=float), (len(rows),))
        if not np.all(np.isfinite(temps)):
            raise CalibrationError("temperature must be finite")
        if self.temperature.kind == "segmented":
            # The paper's eq. 5: the room-temperature correction plus the segment's drift of the raw output.
            room = apply_forward_inverse(rows, self.bias, self.matrix, self.quadratic)
            segmented: np.ndarray = room + self.temperature.segment_drift(rows, temps)
            return segmented.reshape(array.shape)
        drift, scale = self.temperature.bias_and_scale(temps)
        corrected: np.ndarray = ((rows - self.bias - drift) / scale) @ self.matrix.T
        return corrected.reshape(array.shape)

    def apply_gyro(self, raw_radps: ArrayLike, temperature: ArrayLike | None = None) -> np.ndarray:
        """Correct raw angular rates, (3,) or (N, 3): w = gyro_matrix (w_raw - gyro_bias_radps), each term
        left out when the calibration has none (the bias alone before a gyro fit). With a gyro temperature
        model its drift at `temperature` (degC, scalar or (N,); None: the reference) is taken off too."""
        array = np.asarray(raw_radps, dtype=float)
        if array.shape[-1:] != (3,) or array.ndim > 2:
            raise CalibrationError(f"raw angular rates must have shape (3,) or (N, 3), got {array.shape}")
        if self.gyro_bias_radps is not None:
            array = array - self.gyro_bias_radps
        if self.temperature is not None and self.temperature.has_gyro:
            rows = np.atleast_2d(array)
            at = self.temperature.reference_degc if temperature is None else temperature
            temps = np.broadcast_to(np.asarray(at, dtype=float), (len(rows),))
            if not np.all(np.isfinite(temps)):
                raise CalibrationError("temperature must be finite")
            array = (rows - self.temperature.gyro_drift(temps)).reshape(array.shape)
        if self.gyro_matrix is None:
            return array.copy() if self.gyro_bias_radps is None else array
        corrected: np.ndarray = array @ self.gyro_matrix.T
        return corrected

    def gyro_bias_at(self, temperature_degc: float | None) -> np.ndarray | None:
        """The gyro bias taken off at this temperature (the reference when None): gyro_bias_radps plus the
        temperature model's gyro drift there; None when the calibration has neither."""
        if self.temperature is None or not self.temperature.has_gyro:
            return self.gyro_bias_radps
        at = self.temperature.reference_degc if temperature_degc is None else float(temperature_degc)
        drift: np.ndarray = self.temperature.gyro_drift(np.array([at]))[0]
        return drift if self.gyro_bias_radps is None else self.gyro_bias_radps + drift

    def gyro_rate_covariance(self, raw_radps: ArrayLike, noise_radps: ArrayLike) -> np.ndarray:
        """(3, 3) covariance of one corrected angular rate (REP-145 angular_velocity_covariance): the raw
        white noise (per axis, rad/s, 1 sigma) through the gyro matrix, plus the gyro calibration's own
        uncertainty at this rate (its matrix sigma times the bias-free raw rate, and its bias sigma, entries
        taken as independent)."""
        raw = np.asarray(raw_radps, dtype=float).reshape(3)
        noise = np.broadcast_to(np.asarray(noise_radps, dtype=float), (3,))
        matrix = np.eye(3) if self.gyro_matrix is None else self.gyro_matrix
        unbiased = raw if self.gyro_bias_radps is None else raw - self.gyro_bias_radps
        covariance: np.ndarray = (matrix * noise**2) @ matrix.T
        quality = self.gyro_quality
        if quality is not None:
            covariance = covariance + np.diag((quality.matrix_sigma**2) @ unbiased**2)
            if quality.bias_sigma_radps is not None:
                covariance = covariance + (matrix * quality.bias_sigma_radps**2) @ matrix.T
        return covariance

    def temperature_clamped(self, temperature: ArrayLike | None) -> np.ndarray:
        """Which temperatures lie outside the calibrated range (and are clamped by `apply`)."""
        if self.temperature is None or temperature is None:
            return np.zeros(() if temperature is None else np.shape(temperature), dtype=bool)
        return self.temperature.clamp(temperature)[1]

    def terms_at(self, temperature_degc: float | None) -> tuple[float, ...]:
        """M_eff row-major and b_eff as 12 plain floats with a_true = M_eff (a_raw - b_eff) at this
        temperature: what per-message code applies, recomputed only when the temperature moves.
        Segmented: the room-temperature M and b (its drift is `drift_terms_at`)."""
        if self.temperature is None or temperature_degc is None or self.temperature.kind == "segmented":
            m, b = self.correction_terms()
            return m + b
        drift, scale = self.temperature.bias_and_scale(np.array([float(temperature_degc)]))
        matrix = self.matrix / scale[0]  # M diag(1/scale)
        bias = self.bias + drift[0]
        return tuple(float(v) for v in matrix.ravel()) + tuple(float(v) for v in bias)

    def drift_terms_at(self, temperature_degc: float | None) -> tuple[float, ...] | None:
        """Segmented model: its (l, m, n) rows per axis at this temperature (the reference temperature when
        None) as 9 plain floats, sigma_i = l_i a_raw_i^2 + m_i a_raw_i + n_i added after M (a_raw - b).
        None for the other models."""
        if self.temperature is None or self.temperature.kind != "segmented":
            return None
        at = self.temperature.reference_degc if temperature_degc is None else float(temperature_degc)
        return tuple(float(v) for v in self.temperature.segment_terms(np.array([at]))[0].ravel())

    def correction_terms(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """M row-major and b as plain floats, for per-message code where numpy costs more than it saves."""
        return tuple(float(v) for v in self.matrix.ravel()), tuple(float(v) for v in self.bias)

    def replace(self, **changes: Any) -> Calibration:
        return replace(self, **changes)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Calibration):
            return NotImplemented

        def same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
            if a is None or b is None:
                return a is None and b is None
            return np.array_equal(a, b)

        return (
            same(self.bias, other.bias)
            and same(self.matrix, other.matrix)
            and same(self.quadratic, other.quadratic)
            and same(self.bias_sigma, other.bias_sigma)
            and same(self.matrix_sigma, other.matrix_sigma)
            and same(self.gyro_bias_radps, other.gyro_bias_radps)
            and same(self.gyro_matrix, other.gyro_matrix)
            and self.gyro_quality == other.gyro_quality
            and (self.model, self.gravity, self.quality, self.created, self.frame_id, self.sensor_id)
            == (other.model, other.gravity, other.quality, other.created, other.frame_id, other.sensor_id)
            and self.reference_temperature_degc == other.reference_temperature_degc
            and _same_temperature(self.temperature, other.temperature)
            and self.dividing_head == other.dividing_head
            and self.noise == other.noise
            and self.gravity_source == other.gravity_source
            and self.fitted_to == other.fitted_to
            and (self.accel_device_id, self.gyro_device_id) == (other.accel_device_id, other.gyro_device_id)
        )

    # typeshed types object.__hash__ as a method; None is Python's documented way to mark a class unhashable.
    __hash__ = None  # type: ignore[assignment]


_FIELDS = fields(Calibration)
# What from_fit() takes besides the arrays: the checks it keeps cover these; others go the full way.
_FIT_FIELDS = frozenset({"model", "gravity", "quality", "frame_id", "reference_temperature_degc"})


def _read_only(array: np.ndarray) -> np.ndarray:
    copy = array.copy()
    copy.setflags(write=False)
    return copy


def _same_temperature(a: TemperatureModel | None, b: TemperatureModel | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return (
        a.kind == b.kind
        and a.reference_degc == b.reference_degc
        and a.range_degc == b.range_degc
        and a.segment_poses == b.segment_poses
        and a.segment_blend == b.segment_blend
        and all(
            np.array_equal(getattr(a, name), getattr(b, name))
            for name in ("bias_coefficients", "scale_coefficients", "segment_bounds_degc",
                         "segment_temperatures_degc", "segment_coefficients", "spline_knots_degc", "spline_bias",
                         "spline_gyro_knots_degc", "spline_gyro_bias")
        )
    )
