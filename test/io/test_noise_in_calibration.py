"""The white noise measured at the poses travels with the calibration: the file keeps it
as Kalibr's noise densities at the rate they were measured at, a restart's covariance starts from it (it
held the driver's, or nothing, until a still pose completed, and never did in a flight armed first), and
the node says it on /diagnostics and in calibration/get. Files without it load as before; implausible
values are refused in one line."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from accel_calibration import CalibrationError, load_calibration, save_calibration
from accel_calibration.core.calibration import MeasuredNoise
from accel_calibration.core.correction import Correction
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings
from accel_calibration.io.calibration_file import calibration_to_dict
from accel_calibration.live.calibration_work import LiveCalibration

from helpers.session_doors import LogLines, buffer_messages
from helpers.session_streams import stream

RATE_HZ = 200.0


@pytest.fixture(scope="module")
def session():
    errors, samples = stream(seed=5, poses=16, rate_hz=RATE_HZ)
    return errors, samples


def calibrated_live(path, samples) -> LiveCalibration:
    live = LiveCalibration(Settings(), path, LogLines())
    live.start()
    buffer_messages(live, samples)
    live.feed()
    success, message = live.calibrate()
    assert success, message
    return live


def test_the_calibration_carries_the_noise_measured_at_its_poses(session):
    """Simulated white noise 0.02 m/s^2 and 0.002 rad/s per sample at 200 Hz: the densities (sigma /
    sqrt(rate), Kalibr's convention) within 15 % (the detector's floor is its quietest windows')."""
    errors, samples = session
    poses = CalibrationSession(Settings())
    for pose in poses.add_recording(samples.t_ns, samples.accel_raw, samples.gyro_raw):
        poses.add_pose(pose)
    noise = poses.calibrate().calibration.noise
    assert noise is not None and noise.rate_hz == RATE_HZ
    assert abs(noise.accel_density / (errors.noise_mps2 / math.sqrt(RATE_HZ)) - 1) < 0.15
    assert abs(noise.gyro_density / (errors.gyro_noise_radps / math.sqrt(RATE_HZ)) - 1) < 0.15


def test_a_restart_starts_from_the_noise_the_file_keeps(tmp_path, session):
    _, samples = session
    path = tmp_path / "cal.yaml"
    first = calibrated_live(path, samples)
    noise = first.store.calibration.noise
    assert first.diagnostic_values()["noise_source"] == f"measured at {RATE_HZ:g} Hz"

    again = LiveCalibration(Settings(), path, LogLines())
    again.start()
    calibration, correction = again.store.calibration, again.stream.in_force.correction
    assert calibration.noise == noise
    # From the first message, before any pose: the whole covariance (the noise through M plus the
    # calibration's own part), whatever the driver said, unknown (zeros) included.
    own = np.asarray(Correction.build(calibration.replace(noise=None), None).calibration_covariance)
    covariance = correction.covariance_for(np.zeros(9))
    expected = noise.accel_var * (calibration.matrix[0] ** 2).sum() + own[0]
    assert covariance[0] == pytest.approx(expected, rel=1e-9) and covariance[0] > 100 * own[0]
    angular = correction.angular_covariance_for(np.zeros(9), np.zeros(3))
    assert angular[0] >= noise.gyro_var * 0.9
    values = again.diagnostic_values()
    assert values["noise_source"] == f"calibration file at {RATE_HZ:g} Hz"
    assert values["accel_noise_density"] == f"{noise.accel_density:.3e} m/s^2/sqrt(Hz)"
    success, text = again.stream.calibration_text()
    block = yaml.safe_load(text)["accel_calibration"]["noise"]
    assert success and block == {"rate_hz": RATE_HZ, "accel_density_mps2_per_sqrt_hz": noise.accel_density,
                                 "gyro_density_radps_per_sqrt_hz": noise.gyro_density}


def test_round_trip_and_files_without_noise(tmp_path, session):
    _, samples = session
    live = calibrated_live(tmp_path / "cal.yaml", samples)
    calibration = live.store.calibration
    assert load_calibration(tmp_path / "cal.yaml") == calibration
    save_calibration(calibration.replace(noise=None), tmp_path / "plain.yaml")
    plain = load_calibration(tmp_path / "plain.yaml")
    assert plain.noise is None and "noise" not in calibration_to_dict(plain)["accel_calibration"]
    # Without it, the covariance is the driver's plus the calibration's until the noise is measured.
    driver = np.full(9, 1.6e-3)
    out = Correction.build(plain, None).covariance_for(driver)
    assert np.all(out >= driver) and out[0] < 1.01 * driver[0]


def _written(tmp_path, calibration, noise):
    body = calibration_to_dict(calibration)
    body["accel_calibration"]["noise"] = noise
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(body))
    return path


@pytest.mark.parametrize("noise, match", [
    ("quiet", "noise must be a mapping"),
    ({"rate_hz": 200.0}, "noise is missing accel_density_mps2_per_sqrt_hz"),
    ({"rate_hz": 0.1, "accel_density_mps2_per_sqrt_hz": 1e-3}, r"noise.rate_hz 0.1 outside 1..100000"),
    ({"rate_hz": 200.0, "accel_density_mps2_per_sqrt_hz": 0.0}, "noise.accel_density 0 outside"),
    ({"rate_hz": 200.0, "accel_density_mps2_per_sqrt_hz": 3.0}, "no MEMS sensor's"),
    ({"rate_hz": 200.0, "accel_density_mps2_per_sqrt_hz": "1e-3"}, "must be numbers"),
    ({"rate_hz": 200.0, "accel_density_mps2_per_sqrt_hz": 1e-3, "gyro_density_radps_per_sqrt_hz": 2.0},
     "noise.gyro_density 2 outside"),
])
def test_implausible_noise_is_refused_in_one_line(tmp_path, session, noise, match):
    _, samples = session
    calibration = calibrated_live(tmp_path / "first.yaml", samples).store.calibration
    with pytest.raises(CalibrationError, match=match) as refused:
        load_calibration(_written(tmp_path, calibration, noise))
    assert "\n" not in str(refused.value)


def test_measured_noise_is_a_value():
    noise = MeasuredNoise.from_variances(400.0, 4e-4, 1e-6)
    assert noise == MeasuredNoise(400.0, 1e-3, 5e-5)
    assert noise.accel_var == pytest.approx(4e-4) and noise.gyro_var == pytest.approx(1e-6)
    with pytest.raises(CalibrationError, match="noise.rate_hz must be a number"):
        MeasuredNoise(float("nan"), 1e-3)
