"""The IMU files visual-inertial estimators read: Kalibr's `imu.yaml` and OpenVINS' `kalibr_imu_chain.yaml`.

Kalibr's imu.yaml holds the four noise figures (continuous-time densities, what `accel-calib noise`
measures), the IMU topic and its rate; Kalibr estimates the intrinsics itself. OpenVINS' file holds the
same plus the intrinsics in its own model (ov_msckf VioManagerOptions / Propagator):
    a_I = R_ACCtoI D_a (a_m - b_a),  D_a = Ta^-1,  R_ACCtoI = R_IMUtoACC^T
    w_I = R_GYROtoI D_w (w_m - T_g a_I - b_g),  D_w = Tw^-1
with model "kalibr": D_a and D_w lower-triangular. Our a_true = M (a_raw - b) is that with M = R_ACCtoI D_a
(a QL decomposition, exact), and our w_true = M_g (w_raw - b_g) with M_g = R_GYROtoI D_w likewise; T_g = 0
(no g-sensitivity fitted); the biases are OpenVINS states it estimates online, not file entries.

Values are emitted safely: the topic must be a ROS topic name, strings are double-quoted (YAML and OpenCV's
FileStorage both read them), comments carry printable characters only.
"""
from __future__ import annotations

import json
import math
import re
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


# rcl's topic name rules (rcl_validate_topic_name), without substitutions: '/'-separated tokens of
# [A-Za-z0-9_], none empty and none starting with a digit; absolute ('/'), relative, or private ('~/').
_TOPIC_TOKEN = r"[A-Za-z_][A-Za-z0-9_]*"
_TOPIC_NAME = re.compile(rf"(?:/|~/)?{_TOPIC_TOKEN}(?:/{_TOPIC_TOKEN})*")
MAX_TOPIC_CHARS = 255


def checked_topic(rostopic: str) -> str:
    """The topic name when it is a valid ROS topic name, else EstimatorFileError in one line."""
    if not (isinstance(rostopic, str) and len(rostopic) <= MAX_TOPIC_CHARS
            and _TOPIC_NAME.fullmatch(rostopic)):
        raise EstimatorFileError(f"--rostopic {json.dumps(str(rostopic)[:60])} is not a valid ROS topic name "
                                 "('/'-separated tokens of letters, digits and '_', none starting with a digit)")
    return rostopic


def _quoted(text: str) -> str:
    """A double-quoted scalar: JSON's escapes are YAML's, and ASCII only keeps OpenCV's reader content."""
    return json.dumps(text, ensure_ascii=True)


def _comment_lines(comment: str) -> list[str]:
    """'# ' lines; characters YAML would take as a line break or refuse become '?'."""
    return ["# " + "".join(c if c.isprintable() and c.isascii() else "?" for c in line)
            for line in comment.splitlines()]


def _number(value: float) -> str:
    return f"{value:.6e}"


def _checked_for_kalibr(noise: NoiseFigures) -> None:
    """Kalibr's ImuParameters refuses a noise figure <= 0 (checkAccelerometerStatistics and the gyro's)."""
    for name in NOISE_FIELDS:
        if not getattr(noise, name) > 0:
            raise EstimatorFileError(f"{name} is {getattr(noise, name):g}: Kalibr refuses a figure <= 0")


def kalibr_imu_yaml(noise: NoiseFigures, rostopic: str, comment: str = "") -> str:
    """Kalibr's imu.yaml: the four figures, the topic, the rate."""
    topic = checked_topic(rostopic)
    _checked_for_kalibr(noise)
    lines = _comment_lines(comment)
    for name in NOISE_FIELDS:
        lines.append(f"{name}: {_number(getattr(noise, name))}  # [{NOISE_UNITS[name]}]")
    lines.append(f"rostopic: {_quoted(topic)}")
    lines.append(f"update_rate: {noise.update_rate_hz:.6g}  # Hz")
    return "\n".join(lines) + "\n"


def _matrix(name: str, matrix: np.ndarray) -> list[str]:
    rows = [f"    - [ {', '.join(f'{v:.12g}' for v in row)} ]" for row in np.asarray(matrix)]
    return [f"  {name}:", *rows]


def openvins_imu_chain_yaml(noise: NoiseFigures, rostopic: str, accel_rotation: np.ndarray,
                            accel_lower: np.ndarray, comment: str = "", gyro_rotation: np.ndarray | None = None,
                            gyro_lower: np.ndarray | None = None) -> str:
    """OpenVINS' kalibr_imu_chain.yaml (%YAML:1.0, OpenCV's reader), model kalibr: Ta = D_a^-1 with
    D_a = accel_lower, R_IMUtoACC = accel_rotation^T; Tw = D_w^-1, R_IMUtoGYRO = gyro_rotation^T (identity
    when the calibration has no gyro matrix)."""
    topic = checked_topic(rostopic)
    _checked_for_kalibr(noise)
    ta = np.linalg.inv(accel_lower)
    tw = np.eye(3) if gyro_lower is None else np.linalg.inv(gyro_lower)
    r_imu_to_gyro = np.eye(3) if gyro_rotation is None else np.asarray(gyro_rotation).T
    lines = ["%YAML:1.0", *_comment_lines(comment), "", "imu0:", "  T_i_b:"]
    lines += [f"    - [{', '.join(f'{v:.1f}' for v in row)}]" for row in np.eye(4)]
    for name in NOISE_FIELDS:
        lines.append(f"  {name}: {_number(getattr(noise, name))}  # [{NOISE_UNITS[name]}]")
    lines += [f"  rostopic: {_quoted(topic)}", "  time_offset: 0.0", f"  update_rate: {noise.update_rate_hz:.6g}",
              '  model: "kalibr"']
    lines += _matrix("Tw", tw)
    lines += _matrix("R_IMUtoGYRO", r_imu_to_gyro)
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


NOISE_STATEMENTS = ("noise densities ", "random walk of ")  # what `accel-calib noise --kalibr` says of its figures


def noise_statements(path: str) -> list[str]:
    """The comment lines of a noise file saying which figures it carries (static or in operation; a random
    walk that is an upper bound), for an export to carry on; [] for a file without them."""
    raw = read_regular_file(path, 1 << 20, "noise file (Kalibr imu.yaml)", error=EstimatorFileError)
    lines = raw.decode("utf-8", errors="replace").splitlines()
    comments = [line.lstrip("# ").strip() for line in lines if line.startswith("#")]
    return [line for line in comments if line.startswith(NOISE_STATEMENTS)]
