"""accel-calib export: what each target cannot say is said, with its figure. OpenVINS holds the gyro matrix
(applied here with ov_msckf's own formula, re-implemented from its source); the autopilots hold no gyro scale
or misalignment; a rotation between sensor and vehicle is reported apart (the autopilot's level / board
rotation absorbs it); a calibration's noise block gives Kalibr its densities and rate."""
from __future__ import annotations

import re

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration.cli.export import fit_for
from accel_calibration.cli.main import main
from accel_calibration.core.axis_calibration import cost_after_best_rotation, cost_against
from accel_calibration.core.calibration import Calibration, MeasuredNoise
from accel_calibration.core.units import MG
from accel_calibration.io.autopilot_params import parse_parameter_text
from accel_calibration.io.calibration_file import save_calibration
from accel_calibration.io.estimator_yaml import NoiseFigures, kalibr_imu_yaml


def _rotation(axis, angle_rad: float) -> np.ndarray:
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle_rad) * k + (1 - np.cos(angle_rad)) * k @ k


def _noise_file(tmp_path):
    path = tmp_path / "imu.yaml"
    path.write_text(kalibr_imu_yaml(NoiseFigures(2e-3, 3e-4, 1.7e-4, 2e-5, 200.0), "/imu0"))
    return path


def _openvins_file(text: str) -> dict:
    assert text.startswith("%YAML:1.0\n")
    imu: dict = yaml.safe_load(text.split("\n", 1)[1])["imu0"]
    return imu


def _openvins_lower(matrix: np.ndarray) -> np.ndarray:
    """ov_msckf, model kalibr: D = T^-1, of which only the lower triangle is kept (vec_d takes column 0
    rows 0..2, column 1 rows 1..2 and (2, 2); State::Dm rebuilds a lower-triangular matrix from them)."""
    d = np.linalg.inv(matrix)
    return np.tril(d)


def openvins_gyro(imu: dict, wm: np.ndarray, bias_g: np.ndarray, a_hat: np.ndarray) -> np.ndarray:
    """Propagator: w_hat = R_GYROtoIMU Dw (wm - b_g - Tg a_hat), R_GYROtoIMU = R_IMUtoGYRO^T."""
    dw = _openvins_lower(np.array(imu["Tw"], dtype=float))
    r_gyro_to_imu = np.array(imu["R_IMUtoGYRO"], dtype=float).T
    tg = np.array(imu["Tg"], dtype=float)
    return (wm - bias_g - a_hat @ tg.T) @ (r_gyro_to_imu @ dw).T


def openvins_accel(imu: dict, am: np.ndarray, bias_a: np.ndarray) -> np.ndarray:
    """Propagator: a_hat = R_ACCtoIMU Da (am - b_a)."""
    da = _openvins_lower(np.array(imu["Ta"], dtype=float))
    return (am - bias_a) @ (np.array(imu["R_IMUtoACC"], dtype=float).T @ da).T


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**16))
def test_openvins_holds_any_gyro_matrix_exactly(seed, tmp_path):
    rng = np.random.default_rng(seed)
    gyro_matrix = np.eye(3) + rng.uniform(-0.03, 0.03, (3, 3))
    accel_matrix = np.eye(3) + rng.uniform(-0.01, 0.01, (3, 3))
    calibration = Calibration(bias=rng.uniform(-0.2, 0.2, 3), matrix=accel_matrix, model="reference12",
                              gyro_bias_radps=rng.uniform(-0.02, 0.02, 3), gyro_matrix=gyro_matrix)
    save_calibration(calibration, tmp_path / "cal.yaml")
    out = tmp_path / "chain.yaml"
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "openvins", "--noise", str(_noise_file(tmp_path)),
                 "-o", str(out)]) == 0
    imu = _openvins_file(out.read_text())
    wm = rng.normal(size=(40, 3)) * 2.0
    am = rng.normal(size=(40, 3)) * 9.8
    a_hat = openvins_accel(imu, am, calibration.bias)
    np.testing.assert_allclose(a_hat, calibration.apply(am), atol=1e-9)
    # Our gyro bias is OpenVINS' b_g state (estimated online); with it the rates are ours to 1e-9 rad/s.
    np.testing.assert_allclose(openvins_gyro(imu, wm, calibration.gyro_bias_radps, a_hat),
                               calibration.apply_gyro(wm), atol=1e-9)


def test_openvins_says_what_the_accelerometer_bias_costs_until_estimated(tmp_path, capsys):
    bias = np.array([0.3, -0.4, 0.45])
    matrix = np.diag([1.01, 0.99, 1.0])
    save_calibration(Calibration(bias=bias, matrix=matrix), tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "openvins", "--noise", str(_noise_file(tmp_path)),
                 "-o", str(tmp_path / "chain.yaml")]) == 0
    out = capsys.readouterr().out
    expected_mg = np.linalg.norm(matrix @ bias) / MG  # a constant error: the same at every orientation
    line = next(line for line in out.splitlines() if "bias" in line and "online" in line)
    assert f"{expected_mg:.1f} mg" in line, line


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_autopilots_say_what_the_gyro_matrix_they_cannot_hold_costs(target, tmp_path, capsys):
    rng = np.random.default_rng(11)
    gyro_matrix = np.eye(3) + rng.uniform(-0.01, 0.01, (3, 3))
    gyro_bias = np.array([0.01, -0.02, 0.005])
    calibration = Calibration(bias=[0.02, 0.01, -0.03], matrix=np.eye(3), gyro_bias_radps=gyro_bias,
                              gyro_matrix=gyro_matrix)
    save_calibration(calibration, tmp_path / "cal.yaml")
    out_path = tmp_path / "out"
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", target, "-o", str(out_path)]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if "gyro" in line and "mrad" in line)
    figure = float(re.search(r"([0-9.]+) mrad per rad/s", line).group(1))
    # The autopilots apply w = w_raw - offset: per rad/s of true rate, the error over all directions.
    values = parse_parameter_text(out_path.read_text(), "out").values
    names = ["CAL_GYRO0_XOFF", "CAL_GYRO0_YOFF", "CAL_GYRO0_ZOFF"] if target == "px4" else \
        ["INS_GYROFFS_X", "INS_GYROFFS_Y", "INS_GYROFFS_Z"]
    offset = np.array([values[n] for n in names])
    true = rng.normal(size=(4000, 3))
    true /= np.linalg.norm(true, axis=1, keepdims=True)
    raw = true @ np.linalg.inv(gyro_matrix).T + gyro_bias
    worst_mrad = np.max(np.linalg.norm((raw - offset) - true, axis=1)) * 1e3
    assert worst_mrad <= figure + 0.05 and worst_mrad > 0.97 * figure  # the figure is the worst direction's
    assert figure > 5.0


def test_px4_export_writes_the_accel_and_gyro_ids(tmp_path):
    calibration = Calibration(bias=[0.1, 0.2, 0.3], matrix=np.eye(3), gyro_bias_radps=[0.01, 0.02, 0.03],
                              sensor_id="px4 device 1310988", accel_device_id=1310988)
    save_calibration(calibration, tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "px4", "--instance", "2",
                 "-o", str(tmp_path / "p.params")]) == 0
    values = parse_parameter_text((tmp_path / "p.params").read_text(), "p").values
    assert values["CAL_ACC2_ID"] == 1310988 and values["CAL_GYRO2_ID"] == 1310988
    assert values["CAL_GYRO2_YOFF"] == pytest.approx(0.02)


def test_kalibr_takes_the_noise_blocks_densities_and_says_it_lacks_the_random_walks(tmp_path, capsys):
    noise = MeasuredNoise(rate_hz=400.0, accel_density=1.9e-3, gyro_density=1.6e-4)
    save_calibration(Calibration.identity(noise=noise), tmp_path / "cal.yaml")
    out = tmp_path / "imu.yaml"
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "kalibr", "-o", str(out)]) == 1
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "random walk" in error and "1.900e-03" in error
    assert "--noise" in error and not out.exists()
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", "kalibr", "--random-walks", "3e-4", "2e-5",
                 "-o", str(out)]) == 0
    document = yaml.safe_load(out.read_text())
    assert document["accelerometer_noise_density"] == pytest.approx(1.9e-3)
    assert document["gyroscope_noise_density"] == pytest.approx(1.6e-4)
    assert document["accelerometer_random_walk"] == pytest.approx(3e-4)
    assert document["gyroscope_random_walk"] == pytest.approx(2e-5)
    assert document["update_rate"] == 400


def test_a_noise_block_without_gyro_and_zero_figures_are_refused(tmp_path, capsys):
    noise = MeasuredNoise(rate_hz=400.0, accel_density=1.9e-3)
    save_calibration(Calibration.identity(noise=noise), tmp_path / "cal.yaml")
    out = tmp_path / "imu.yaml"
    args = ["export", str(tmp_path / "cal.yaml"), "--to", "openvins", "-o", str(out)]
    assert main(args + ["--random-walks", "3e-4", "2e-5"]) == 1
    assert "gyroscope_noise_density" in capsys.readouterr().err and not out.exists()
    save_calibration(Calibration.identity(noise=MeasuredNoise(400.0, 1.9e-3, 1.6e-4)), tmp_path / "cal.yaml")
    assert main(args + ["--random-walks", "0", "2e-5"]) == 1  # Kalibr refuses a figure <= 0
    assert "accelerometer_random_walk" in capsys.readouterr().err and not out.exists()


def _cost_figures(out: str) -> tuple[float, float]:
    line = next(line for line in out.splitlines() if "holds offset and scale" in line)
    as_is = float(re.search(r"worst ([0-9.]+) mg", line).group(1))
    rotated = float(re.search(r"after the best rotation [^:]*: worst ([0-9.]+) mg", line).group(1))
    return as_is, rotated


@pytest.mark.parametrize("target", ["px4", "ardupilot"])
def test_a_rotation_the_autopilots_level_calibration_absorbs_is_reported_apart(target, tmp_path, capsys):
    angle = 0.005  # 5 mrad between the calibrated frame and the sensor's axes
    matrix = _rotation([1, 2, 0.5], angle) @ np.diag([1.01, 0.99, 1.0])
    save_calibration(Calibration(bias=[0.05, -0.02, 0.1], matrix=matrix, model="reference12"), tmp_path / "cal.yaml")
    assert main(["export", str(tmp_path / "cal.yaml"), "--to", target, "-o", str(tmp_path / "out")]) == 0
    as_is, rotated = _cost_figures(capsys.readouterr().out)
    assert as_is == pytest.approx(angle * 1000, rel=0.03)  # 1 mrad ~ 1 mg at 1 g
    assert rotated < 0.05  # the default 2 mg refusal applies to what the autopilot cannot absorb


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_the_rotation_absorbed_figure_never_exceeds_the_as_is_one(seed):
    rng = np.random.default_rng(seed)
    matrix = np.eye(3) + rng.uniform(-0.004, 0.004, (3, 3))
    calibration = Calibration(bias=rng.uniform(-0.3, 0.3, 3), matrix=matrix, model="reference12")
    fitted = fit_for("px4", calibration)
    as_is = cost_against(calibration, fitted)
    rotated, rotation = cost_after_best_rotation(calibration, fitted)
    assert rotated.worst_mg <= as_is.worst_mg + 1e-9
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) > 0
