"""The IMU files visual-inertial estimators read: Kalibr's `imu.yaml` and OpenVINS' `kalibr_imu_chain.yaml`.

Kalibr's imu.yaml holds the four noise figures (continuous-time densities, what `accel-calib noise`
measures), the IMU topic and its rate; Kalibr estimates the intrinsics itself. OpenVINS' file holds the
same plus the intrinsics in its own model (ov_msckf VioManagerOptions / Propagator):
    a_I = R_ACCtoI D_a (a_m - b_a),  D_a = Ta^-1,  R_ACCtoI = R_IMUtoACC^T
    w_I = R_GYROtoI D_w (w_m - T_g a_I - b_g),  D_w = Tw^-1
with model "kalibr": D_a and D_w lower-triangular. Our a_true = M (a_raw - b) is that with M = R_ACCtoI D_a
(a QL decomposition, exact); the biases are OpenVINS states it estimates online, not file entries.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.errors import CalibrationError
from .calibration_file import read_regular_file, safe_yaml_load

NOISE_FIELDS = ("accelerometer_noise_density", "accelerometer_random_walk",
                "gyroscope_noise_density", "gyroscope_random_walk")
NOISE_UNITS = {"accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)",
               "gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)"}


class EstimatorFileError(CalibrationError):
    """io: an estimator IMU file that cannot be read or written as asked."""


@dataclass(frozen=True)
class NoiseFigures:
    """Kalibr's four figures (continuous time) and the rate they were measured at."""

    accelerometer_noise_density: float
    accelerometer_random_walk: float
    gyroscope_noise_density: float
    gyroscope_random_walk: float
    update_rate_hz: float

    def __post_init__(self) -> None:
        for name in (*NOISE_FIELDS, "update_rate_hz"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise EstimatorFileError(f"{name} must be a finite number >= 0, got {value!r:.40}")
        if not self.update_rate_hz > 0:
            raise EstimatorFileError(f"update_rate must be positive, got {self.update_rate_hz}")


def _number(value: float) -> str:
    return f"{value:.6e}"


def kalibr_imu_yaml(noise: NoiseFigures, rostopic: str, comment: str = "") -> str:
    lines = [f"# {line}" for line in comment.splitlines()]
    for name in NOISE_FIELDS:
        lines.append(f"{name}: {_number(getattr(noise, name))}  # [{NOISE_UNITS[name]}]")
    lines.append(f"rostopic: {rostopic}")
    lines.append(f"update_rate: {noise.update_rate_hz:.6g}  # Hz")
    return "\n".join(lines) + "\n"


def _matrix(name: str, matrix: np.ndarray) -> list[str]:
    rows = [f"    - [ {', '.join(f'{v:.12g}' for v in row)} ]" for row in np.asarray(matrix)]
    return [f"  {name}:", *rows]


def openvins_imu_chain_yaml(noise: NoiseFigures, rostopic: str, accel_rotation: np.ndarray,
                            accel_lower: np.ndarray, comment: str = "") -> str:
    """OpenVINS' kalibr_imu_chain.yaml (%YAML:1.0, OpenCV's reader), model kalibr: Ta = D_a^-1 with
    D_a = accel_lower, R_IMUtoACC = accel_rotation^T; gyro intrinsics identity (not calibrated here)."""
    ta = np.linalg.inv(accel_lower)
    lines = ["%YAML:1.0", *[f"# {line}" for line in comment.splitlines()], "", "imu0:", "  T_i_b:"]
    lines += [f"    - [{', '.join(f'{v:.1f}' for v in row)}]" for row in np.eye(4)]
    for name in NOISE_FIELDS:
        lines.append(f"  {name}: {_number(getattr(noise, name))}  # [{NOISE_UNITS[name]}]")
    lines += [f"  rostopic: {rostopic}", "  time_offset: 0.0", f"  update_rate: {noise.update_rate_hz:.6g}",
              '  model: "kalibr"']
    lines += _matrix("Tw", np.eye(3))
    lines += _matrix("R_IMUtoGYRO", np.eye(3))
    lines += _matrix("Ta", ta)
    lines += _matrix("R_IMUtoACC", np.asarray(accel_rotation).T)
    lines += _matrix("Tg", np.zeros((3, 3)))
    return "\n".join(lines) + "\n"


def read_noise_figures(path: str, update_rate_hz: float | None = None) -> NoiseFigures:
    """The four figures from a Kalibr imu.yaml or an OpenVINS kalibr_imu_chain.yaml (its imu0 block)."""
    raw = read_regular_file(path, 1 << 20, "noise file (Kalibr imu.yaml)", error=EstimatorFileError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise EstimatorFileError(f"{path}: not a text file") from None
    if text.startswith("%YAML:1.0"):  # OpenCV's header, which PyYAML does not read
        text = text.split("\n", 1)[1] if "\n" in text else ""
    document = safe_yaml_load(text, str(path), error=EstimatorFileError)
    if isinstance(document, dict) and isinstance(document.get("imu0"), dict):
        document = document["imu0"]
    if not isinstance(document, dict):
        raise EstimatorFileError(f"{path}: not a Kalibr imu.yaml (a mapping with {', '.join(NOISE_FIELDS)})")
    missing = [name for name in NOISE_FIELDS if name not in document]
    if missing:
        raise EstimatorFileError(f"{path}: missing {', '.join(missing)} (write it with "
                                 "'accel-calib noise RECORDING --kalibr imu.yaml')")
    rate = update_rate_hz if update_rate_hz is not None else document.get("update_rate")
    if rate is None:
        raise EstimatorFileError(f"{path}: no update_rate: give --update-rate HZ")
    try:
        return NoiseFigures(**{name: document[name] for name in NOISE_FIELDS}, update_rate_hz=rate)
    except EstimatorFileError as error:
        raise EstimatorFileError(f"{path}: {error}") from None
