"""Every setting of a calibration session, its default, range and meaning, written once.

The node declares its ROS parameters from `PARAMETERS` (types and ranges go into the descriptors,
so `ros2 param describe` shows them); `accel-calib replay --params-file` reads the same YAML; the
CLI's flags override by the same names. `Settings.from_parameters` validates once, and every
message names the parameter as the user typed it (`static.window_s`, not an internal field).
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

from .errors import SettingsError
from .fit import OutlierOptions
from .gates import QualityGates
from .gravity import HEIGHT_RANGE_M, LATITUDE_RANGE_DEG, given_gravity_source, normal_gravity, normal_gravity_source
from .gyro_fit import GyroFitOptions
from .gyro_gates import GyroGates
from .stream.detector_batch import DetectorConfig
from .temperature_models import TEMPERATURE_MODELS, TemperatureOptions
from .units import STANDARD_GRAVITY

ONLINE_MODELS = ("six", "sphere9")
_TEMPERATURE = TemperatureOptions()  # the temperature fit's defaults, written once (temperature_models.py)
RELIABILITIES = ("reliable", "best_effort")
_GYRO_GATES, _GYRO_FIT = GyroGates(), GyroFitOptions()  # the gyro fit's defaults, written once
_DETECTOR = DetectorConfig()  # the detector's defaults, written once (core/stream/detector_batch.py)
_GATES = QualityGates()  # the quality gates' defaults, written once (core/gates.py, core/plausibility.py)


@dataclass(frozen=True)
class Parameter:
    """One user-facing setting: its name as typed (`-p name:=value`, params file, CLI flag)."""

    name: str
    default: Any  # its Python type is the parameter's type (bool, int, float, str)
    description: str
    low: float | None = None  # inclusive bounds (shown in the ROS descriptor)
    high: float | None = None
    choices: tuple[str, ...] = ()
    dynamic: bool = False  # changeable while the node runs (the gates and auto_calibrate)
    zero_means_auto: bool = False  # 0 is allowed and means "learned" (detector thresholds)
    nan_means_unset: bool = False  # NaN (the default) means "not given" (the latitude: 0 is the equator)

    @property
    def field(self) -> str:
        return self.name.replace(".", "_")


PARAMETERS: tuple[Parameter, ...] = (
    Parameter("model", "sphere9", "online error model: sphere9 (bias + lower-triangular M) or six (bias + diagonal)",
              choices=ONLINE_MODELS),
    Parameter("gravity", STANDARD_GRAVITY, "local gravity magnitude, m/s^2", 9.7, 9.9),
    Parameter("latitude_deg", math.nan, "geodetic latitude, deg: gravity is then the WGS84 normal gravity there "
              "(instead of the gravity parameter); NaN = not given", *LATITUDE_RANGE_DEG, nan_means_unset=True),
    Parameter("height_m", 0.0, "with latitude_deg: height above the WGS84 ellipsoid, m (free-air correction)",
              *HEIGHT_RANGE_M),
    Parameter("sensor_id", "", "identity of the sensor, written into the calibration file"),
    Parameter("auto_calibrate", False, "apply (and save) a new fit by itself once it passes the quality gates",
              dynamic=True),
    Parameter("min_poses", _GATES.min_poses, "quality gate: poses needed before a fit may be applied", 6, 1000,
              dynamic=True),
    Parameter("max_residual_rms_mg", _GATES.max_residual_rms_mg,
              "quality gate: largest residual rms of a fit that may be applied, mg", 0.01, 1000.0, dynamic=True),
    Parameter("max_bias_sigma_mg", _GATES.max_bias_sigma_mg,
              "quality gate: largest bias uncertainty (1 sigma) that may be applied, mg", 0.001, 1000.0, dynamic=True),
    Parameter("max_scale_sigma_ppm", _GATES.max_scale_sigma_ppm,
              "quality gate: largest scale-factor uncertainty (1 sigma, of the axis' gain) that may be applied, ppm "
              "(5000 ppm is 5 mg at 1 g)", 0.1, 1e6, dynamic=True),
    Parameter("max_misalignment_sigma_mrad", _GATES.max_misalignment_sigma_mrad,
              "quality gate: largest misalignment uncertainty (1 sigma) that may be applied, mrad (5 mrad is ~5 mg "
              "at 1 g)", 0.001, 1000.0, dynamic=True),
    Parameter("outlier_threshold_mg", OutlierOptions.threshold_mg,
              "robust fit: a pose this far off the sphere the other poses fit (and outlier_k_sigma times their "
              "spread) is left out and named as an outlier, mg; 0 = never leave a pose out", 0.0, 10_000.0,
              dynamic=True),
    Parameter("outlier_k_sigma", OutlierOptions.k_sigma,
              "robust fit: a pose is left out only when its residual is beyond this many sigmas of what the other "
              "poses' scatter predicts for it (as improbable as k Gaussian sigmas, allowing for their degrees of "
              "freedom)", 2.0, 1000.0, dynamic=True),
    Parameter("max_bias_mps2", _GATES.max_bias_mps2, "plausibility gate: largest |bias| per axis, m/s^2", 0.001,
              100.0, dynamic=True),
    Parameter("scale_min", _GATES.scale_band[0], "plausibility gate: smallest correction gain per axis (row norm of M)",
              0.01, 0.999, dynamic=True),
    Parameter("scale_max", _GATES.scale_band[1], "plausibility gate: largest correction gain per axis (row norm of M)",
              1.001, 100.0, dynamic=True),
    Parameter("merge_angle_deg", 5.0, "a new pose within this angle of a held one (same temperature bin) refines it",
              0.1, 45.0),
    Parameter("merge_tolerance_mg", 0.5,
              "a new pose is merged into a held one at its orientation only when their means agree within their "
              "standard errors plus this, mg (what white noise does not explain: slow drift); otherwise it is kept "
              "apart and counted (merge_disagreements)",
              0.0, 1000.0),
    Parameter("max_poses", 100, "pose store capacity; the oldest pose gives way beyond it", 6, 100_000),
    Parameter("accel_range_mps2", 16 * STANDARD_GRAVITY,
              "accelerometer full scale; samples at or beyond it are counted as saturated and kept out of the fit",
              1.0, 10_000.0),
    Parameter("gyro_range_radps", 34.9,
              "gyro full scale (2000 deg/s); samples beyond it are counted out of range and kept out of the fit",
              0.1, 1000.0),
    Parameter("frozen_samples", 50,
              "this many bit-identical samples in a row mean a frozen sensor: counted and kept out of the fit",
              3, 1_000_000),
    Parameter("temperature_timeout_s", 5.0, "a temperature older than this (header time) is stale and not used, s",
              0.01, 3600.0),
    Parameter("temperature.model", _TEMPERATURE.model,
              "temperature model learned once the poses span min_span_degc: polynomial, segmented or none",
              choices=TEMPERATURE_MODELS),
    Parameter("temperature.bias_order", _TEMPERATURE.bias_order, "polynomial model: order of the bias drift", 0, 3),
    Parameter("temperature.scale_order", _TEMPERATURE.scale_order, "polynomial model: order of the scale drift", 0, 2),
    Parameter("temperature.segment_width_degc", _TEMPERATURE.segment_width_degc,
              "segmented model: segment width, degC", 1.0, 100.0),
    Parameter("temperature.segment_blend", _TEMPERATURE.segment_blend,
              "segmented model: interpolate the drift between the temperatures neighbouring segments were "
              "learned at (no step at a segment edge); false: the seed paper's pick of the segment holding "
              "the temperature"),
    Parameter("temperature.min_span_degc", _TEMPERATURE.min_span_degc,
              "smallest span of pose temperatures to fit a temperature model, degC", 0.0, 200.0),
    Parameter("temperature.bin_degc", 5.0, "poses at one orientation but temperatures this far apart are kept apart, "
              "degC", 0.1, 100.0),
    Parameter("static.window_s", _DETECTOR.window_s, "static detector: sliding window, s of header time", 0.02, 10.0),
    Parameter("static.min_hold_s", _DETECTOR.min_hold_s, "static detector: shortest still interval kept as a pose, s",
              0.05, 600.0),
    Parameter("static.accel_var_threshold", 0.0,
              "static detector: accel window variance threshold, (m/s^2)^2; 0 = k_sigma x learned noise floor",
              0.0, 1e6, zero_means_auto=True),
    Parameter("static.gyro_var_threshold", 0.0,
              "static detector: gyro window variance threshold, (rad/s)^2; 0 = learned noise floor",
              0.0, 1e6, zero_means_auto=True),
    Parameter("static.k_sigma", _DETECTOR.k_sigma, "static detector: threshold as a multiple of the noise-floor "
              "variance", 1.0, 1000.0),
    Parameter("static.max_noise_mg", 15.0,
              "static detector: largest accel noise of a still window, mg rms per axis; the learned threshold never "
              "exceeds it (MEMS parts at rest: 0.5-10 mg; motor vibration in flight: 20 mg and more)", 0.1, 1000.0),
    Parameter("static.max_gyro_noise_mradps", 50.0,
              "static detector: largest gyro noise of a still window, mrad/s rms per axis (50 mrad/s = 2.9 deg/s); "
              "the learned gyro threshold never exceeds it", 0.1, 10_000.0),
    Parameter("static.max_floor_rise", _DETECTOR.max_floor_rise,
              "static detector: the learned noise floors may rise at most this factor (rms) above the quietest "
              "floor seen since start, so flight vibration is never learned as noise", 1.0, 1000.0),
    Parameter("use_calibration_in_force_as_prior", False,
              "at /calibrate fit with the calibration in force at start-up (or at calibration/reset) as the prior: "
              "what the poses observe is fitted, the rest kept at the prior (poses near level suffice); the pose "
              "count is then no gate, the fit's own checks and the other gates decide"),
    Parameter("gyro.calibrate", True,
              "fit the gyro's scale and misalignment from the motions between poses at /calibrate (and in replay) "
              "when they pass the gyro.* gates; false: the gyro gets its bias only", dynamic=True),
    Parameter("gyro.max_motion_s", _GYRO_FIT.max_motion_s,
              "a motion between two poses longer than this is not used for the gyro fit (nor kept), s", 1.0, 600.0),
    Parameter("gyro.min_motions", _GYRO_GATES.min_motions, "gyro gate: usable motions needed", 5, 10_000,
              dynamic=True),
    Parameter("gyro.max_residual_rms_mrad", _GYRO_GATES.max_residual_rms_mrad,
              "gyro gate: largest rms by which the fitted motions miss the next pose, mrad", 0.01, 1000.0,
              dynamic=True),
    Parameter("gyro.max_scale_sigma_ppm", _GYRO_GATES.max_scale_sigma_ppm,
              "gyro gate: largest scale uncertainty (1 sigma) that may be applied, ppm", 0.1, 1e6, dynamic=True),
    Parameter("gyro.max_misalignment_sigma_mrad", _GYRO_GATES.max_misalignment_sigma_mrad,
              "gyro gate: largest misalignment uncertainty (1 sigma) that may be applied, mrad", 0.001, 1000.0,
              dynamic=True),
    Parameter("gyro.scale_min", _GYRO_GATES.scale_band[0], "gyro gate: smallest gain per axis (row norm of M_g)",
              0.01, 0.999, dynamic=True),
    Parameter("gyro.scale_max", _GYRO_GATES.scale_band[1], "gyro gate: largest gain per axis (row norm of M_g)",
              1.001, 100.0, dynamic=True),
)
BY_NAME = {p.name: p for p in PARAMETERS}


def _default(name: str) -> Any:
    return BY_NAME[name].default
DYNAMIC = tuple(p.name for p in PARAMETERS if p.dynamic)


def check_value(parameter: Parameter, value: Any) -> Any:
    """The value as its parameter's type, or SettingsError naming the parameter as the user typed it."""
    name, kind = parameter.name, type(parameter.default)
    if kind is float:
        # ROS parameters are typed: 10 is an integer, and a double parameter does not take it.
        if isinstance(value, bool) or not isinstance(value, float):
            raise SettingsError(f"{name} must be a floating-point number (write {_as_float_text(value)}), "
                                f"got {value!r}")
        if math.isnan(value) and parameter.nan_means_unset:
            return value
        if not math.isfinite(value):
            raise SettingsError(f"{name} must be a finite number, got {value!r}")
    elif kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SettingsError(f"{name} must be an integer, got {value!r}")
    elif kind is bool:
        if not isinstance(value, bool):
            raise SettingsError(f"{name} must be true or false, got {value!r}")
    elif not isinstance(value, str):
        raise SettingsError(f"{name} must be a string, got {value!r}")
    if parameter.choices and value not in parameter.choices:
        raise SettingsError(f"{name} must be one of {', '.join(parameter.choices)}, got {value!r}")
    if parameter.low is not None and isinstance(value, (int, float)) and not isinstance(value, bool):
        if parameter.zero_means_auto and value == 0:
            return value
        if not parameter.low <= value <= parameter.high:  # type: ignore[operator]
            raise SettingsError(f"{name} must be within {parameter.low:g}..{parameter.high:g}, got {value!r}")
    return value


def changed(before: Any, after: Any) -> bool:
    """A setting's value changed (NaN, an unset latitude, is equal to itself here)."""
    unset = isinstance(before, float) and isinstance(after, float) and math.isnan(before) and math.isnan(after)
    return not unset and bool(before != after)


def fixed_at_start_up(name: str) -> str:
    """The refusal of a change, while the node runs, to a setting that is not `dynamic` (it shaped what was
    built at start: the detector, the store)."""
    return f"{name} is fixed at start-up (read-only); restart to change it"


def check_run_time_change(before: Settings, after: Settings) -> None:
    """SettingsError (fixed_at_start_up) naming the first setting fixed at start-up that `after` changes."""
    for parameter in PARAMETERS:
        if not parameter.dynamic and changed(getattr(before, parameter.field), getattr(after, parameter.field)):
            raise SettingsError(fixed_at_start_up(parameter.name))


def _as_float_text(value: Any) -> str:
    try:
        return repr(float(value))
    except (TypeError, ValueError):
        return "a number like 1.0"


@dataclass(frozen=True)
class Settings:
    """A validated set of all settings; fields are the parameter names with '.' -> '_'."""

    model: str = _default("model")
    gravity: float = _default("gravity")
    latitude_deg: float = _default("latitude_deg")
    height_m: float = _default("height_m")
    sensor_id: str = _default("sensor_id")
    auto_calibrate: bool = _default("auto_calibrate")
    min_poses: int = _default("min_poses")
    max_residual_rms_mg: float = _default("max_residual_rms_mg")
    max_bias_sigma_mg: float = _default("max_bias_sigma_mg")
    max_scale_sigma_ppm: float = _default("max_scale_sigma_ppm")
    max_misalignment_sigma_mrad: float = _default("max_misalignment_sigma_mrad")
    outlier_threshold_mg: float = _default("outlier_threshold_mg")
    outlier_k_sigma: float = _default("outlier_k_sigma")
    max_bias_mps2: float = _default("max_bias_mps2")
    scale_min: float = _default("scale_min")
    scale_max: float = _default("scale_max")
    merge_angle_deg: float = _default("merge_angle_deg")
    max_poses: int = _default("max_poses")
    accel_range_mps2: float = _default("accel_range_mps2")
    gyro_range_radps: float = _default("gyro_range_radps")
    frozen_samples: int = _default("frozen_samples")
    temperature_timeout_s: float = _default("temperature_timeout_s")
    temperature_model: str = _default("temperature.model")
    temperature_bias_order: int = _default("temperature.bias_order")
    temperature_scale_order: int = _default("temperature.scale_order")
    temperature_segment_width_degc: float = _default("temperature.segment_width_degc")
    temperature_segment_blend: bool = _default("temperature.segment_blend")
    temperature_min_span_degc: float = _default("temperature.min_span_degc")
    temperature_bin_degc: float = _default("temperature.bin_degc")
    static_window_s: float = _default("static.window_s")
    static_min_hold_s: float = _default("static.min_hold_s")
    static_accel_var_threshold: float = _default("static.accel_var_threshold")
    static_gyro_var_threshold: float = _default("static.gyro_var_threshold")
    static_k_sigma: float = _default("static.k_sigma")
    static_max_noise_mg: float = _default("static.max_noise_mg")
    static_max_gyro_noise_mradps: float = _default("static.max_gyro_noise_mradps")
    static_max_floor_rise: float = _default("static.max_floor_rise")
    merge_tolerance_mg: float = _default("merge_tolerance_mg")
    use_calibration_in_force_as_prior: bool = _default("use_calibration_in_force_as_prior")
    gyro_calibrate: bool = _default("gyro.calibrate")
    gyro_max_motion_s: float = _default("gyro.max_motion_s")
    gyro_min_motions: int = _default("gyro.min_motions")
    gyro_max_residual_rms_mrad: float = _default("gyro.max_residual_rms_mrad")
    gyro_max_scale_sigma_ppm: float = _default("gyro.max_scale_sigma_ppm")
    gyro_max_misalignment_sigma_mrad: float = _default("gyro.max_misalignment_sigma_mrad")
    gyro_scale_min: float = _default("gyro.scale_min")
    gyro_scale_max: float = _default("gyro.scale_max")

    def __post_init__(self) -> None:
        for parameter in PARAMETERS:
            value = getattr(self, parameter.field)
            if type(parameter.default) is float and isinstance(value, int) and not isinstance(value, bool):
                # Python callers (and CLI flags parsed as float) may pass 10 for 10.0; ROS parameters may not.
                object.__setattr__(self, parameter.field, float(value))
                value = float(value)
            check_value(parameter, value)
        self._local_gravity()
        from .models import parameter_count

        needed = parameter_count(self.model)
        if self.min_poses < needed + 1:
            raise SettingsError(f"min_poses must be at least {needed + 1} for model {self.model} "
                                f"({needed} parameters and one degree of freedom to judge the fit), "
                                f"got {self.min_poses}")
        if self.max_poses < self.min_poses:
            raise SettingsError(f"max_poses ({self.max_poses}) must be at least min_poses ({self.min_poses})")
        if self.static_min_hold_s <= self.static_window_s / 2:
            raise SettingsError(f"static.min_hold_s ({self.static_min_hold_s:g}) must exceed half of static.window_s "
                                f"({self.static_window_s:g})")

    def _local_gravity(self) -> None:
        """gravity from latitude_deg and height_m when a latitude is given; the two ways exclude each other."""
        if math.isnan(self.latitude_deg):
            if self.height_m != 0.0:
                raise SettingsError("height_m needs latitude_deg (the normal gravity's height above the ellipsoid)")
            return
        local = normal_gravity(self.latitude_deg, self.height_m)
        if self.gravity not in (STANDARD_GRAVITY, local):
            raise SettingsError(f"gravity ({self.gravity:g}) and latitude_deg exclude each other: give one")
        object.__setattr__(self, "gravity", local)

    @property
    def gravity_source(self) -> str:
        """Where gravity came from, as the calibration file records it."""
        if math.isnan(self.latitude_deg):
            return given_gravity_source(self.gravity)
        return normal_gravity_source(self.latitude_deg, self.height_m)

    @classmethod
    def from_parameters(cls, values: Mapping[str, Any], base: Settings | None = None) -> Settings:
        """Settings from user-named values (`static.window_s`), over `base` (default: the defaults).
        Unknown names are refused with the list of known ones."""
        unknown = sorted(set(values) - set(BY_NAME))
        if unknown:
            raise SettingsError(f"unknown parameter {unknown[0]!r}; known: {', '.join(BY_NAME)}")
        changes = {}
        for name, value in values.items():
            parameter = BY_NAME[name]
            changes[parameter.field] = check_value(parameter, value)
        return replace(base or cls(), **changes)

    @property
    def quality_gates(self) -> QualityGates:
        return QualityGates(min_poses=self.min_poses, max_residual_rms_mg=self.max_residual_rms_mg,
                            max_bias_sigma_mg=self.max_bias_sigma_mg, max_scale_sigma_ppm=self.max_scale_sigma_ppm,
                            max_misalignment_sigma_mrad=self.max_misalignment_sigma_mrad,
                            max_bias_mps2=self.max_bias_mps2, scale_band=(self.scale_min, self.scale_max),
                            gyro_scale_band=(self.gyro_scale_min, self.gyro_scale_max))

    @property
    def outliers(self) -> OutlierOptions:
        return OutlierOptions(threshold_mg=self.outlier_threshold_mg, k_sigma=self.outlier_k_sigma)

    @property
    def gyro_gates(self) -> GyroGates:
        return GyroGates(min_motions=self.gyro_min_motions, max_residual_rms_mrad=self.gyro_max_residual_rms_mrad,
                         max_scale_sigma_ppm=self.gyro_max_scale_sigma_ppm,
                         max_misalignment_sigma_mrad=self.gyro_max_misalignment_sigma_mrad,
                         scale_band=(self.gyro_scale_min, self.gyro_scale_max))

    @property
    def gyro_fit(self) -> GyroFitOptions:
        return GyroFitOptions(max_motion_s=self.gyro_max_motion_s, gyro_range_radps=self.gyro_range_radps)

    @property
    def temperature(self) -> TemperatureOptions:
        return TemperatureOptions(
            model=self.temperature_model,
            bias_order=self.temperature_bias_order,
            scale_order=self.temperature_scale_order,
            segment_width_degc=self.temperature_segment_width_degc,
            min_span_degc=self.temperature_min_span_degc,
            segment_blend=self.temperature_segment_blend,
            # A session learns segments as poses at new temperatures come in; the rest are reported.
            every_segment=False,
        )
