"""The Calibration value: what a fit produces, what the node applies and what a file holds."""
from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import CalibrationError
from .models import MODELS, apply_forward_inverse

STANDARD_GRAVITY = 9.80665
MG = STANDARD_GRAVITY * 1e-3  # 1 mg in m/s^2


def _frozen(values, shape, name) -> np.ndarray:
    try:
        array = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise CalibrationError(f"{name} must be numbers, got {values!r:.60}") from None
    if array.shape != shape:
        raise CalibrationError(f"{name} must have shape {shape}, got {array.shape}")
    if not np.all(np.isfinite(array)):
        raise CalibrationError(f"{name} must be finite, got {array.tolist()}")
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class Quality:
    """How well the calibration explains the poses it was fitted to."""

    residual_rms_mg: float
    residual_max_mg: float
    poses: int
    condition_number: float | None = None


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
    created: str = field(default_factory=lambda: _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"))
    frame_id: str = ""
    sensor_id: str = ""
    reference_temperature_degc: float | None = None
    gyro_bias_radps: np.ndarray | None = None  # (3,) mean gyro output at rest, from the static poses

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "bias", _frozen(self.bias, (3,), "bias"))
        set_(self, "matrix", _frozen(self.matrix, (3, 3), "matrix"))
        if self.model not in MODELS:
            raise CalibrationError(f"unknown model {self.model!r}; expected one of {', '.join(MODELS)}")
        if not (isinstance(self.gravity, (int, float)) and np.isfinite(self.gravity) and self.gravity > 0):
            raise CalibrationError(f"gravity must be a positive number of m/s^2, got {self.gravity!r}")
        set_(self, "gravity", float(self.gravity))
        if abs(np.linalg.det(self.matrix)) < 1e-12 * max(1.0, float(np.abs(self.matrix).max()) ** 3):
            raise CalibrationError("matrix is singular: it would collapse the measurement")
        if self.quadratic is not None:
            set_(self, "quadratic", _frozen(self.quadratic, (3,), "quadratic"))
        if self.gyro_bias_radps is not None:
            set_(self, "gyro_bias_radps", _frozen(self.gyro_bias_radps, (3,), "gyro_bias_radps"))
        if self.bias_sigma is not None:
            set_(self, "bias_sigma", _frozen(self.bias_sigma, (3,), "bias_sigma"))
        if self.matrix_sigma is not None:
            set_(self, "matrix_sigma", _frozen(self.matrix_sigma, (3, 3), "matrix_sigma"))

    @classmethod
    def identity(cls, **kwargs) -> "Calibration":
        """The do-nothing calibration (raw passes through)."""
        return cls(bias=np.zeros(3), matrix=np.eye(3), **kwargs)

    def apply(self, raw, temperature=None) -> np.ndarray:
        """Correct raw accelerations, (3,) or (N, 3), vectorised. `temperature` (degC, scalar or (N,))
        is accepted for calibrations with a temperature model; it is unused by this one."""
        array = np.asarray(raw, dtype=float)
        if array.shape[-1:] != (3,) or array.ndim > 2:
            raise CalibrationError(f"raw accelerations must have shape (3,) or (N, 3), got {array.shape}")
        return apply_forward_inverse(array, self.bias, self.matrix, self.quadratic)

    def correction_terms(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """M row-major and b as plain floats, for per-message code where numpy costs more than it saves."""
        return tuple(float(v) for v in self.matrix.ravel()), tuple(float(v) for v in self.bias)

    def replace(self, **changes) -> "Calibration":
        return replace(self, **changes)

    def save(self, path) -> None:
        from .calibration_file import save_calibration

        save_calibration(self, path)

    @staticmethod
    def load(path) -> "Calibration":
        from .calibration_file import load_calibration

        return load_calibration(path)

    def __eq__(self, other):
        if not isinstance(other, Calibration):
            return NotImplemented

        def same(a, b):
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
            and (self.model, self.gravity, self.quality, self.created, self.frame_id, self.sensor_id)
            == (other.model, other.gravity, other.quality, other.created, other.frame_id, other.sensor_id)
            and self.reference_temperature_degc == other.reference_temperature_degc
        )

    __hash__ = None
