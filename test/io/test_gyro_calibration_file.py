"""The gyro calibration in the calibration file: gyro_matrix beside gyro_bias_radps and a
gyro_quality block; round trips, files without them as before, implausible values refused in one line."""
import numpy as np
import pytest
import yaml

from accel_calibration import Calibration, CalibrationError, fit, load_calibration, save_calibration
from accel_calibration.core.calibration import GyroQuality
from accel_calibration.core.gyro_fit import fit_gyro
from accel_calibration.core.plausibility import plausibility_refusal
from msg_tools.synthetic_motion import simulate_session

from helpers.gyro_sessions import poses_and_motions


@pytest.fixture(scope="module")
def calibrated():
    simulated = simulate_session(np.random.default_rng(7), poses=14)
    poses, motions = poses_and_motions(simulated)
    accel = fit(poses).calibration
    result = fit_gyro(poses, motions, accel, gyro_noise_radps=simulated.gyro_noise_radps)
    assert result.success, result.message
    return result.apply_to(accel), result


def test_round_trip_with_the_gyro_is_exact(tmp_path, calibrated):
    calibration, result = calibrated
    save_calibration(calibration, tmp_path / "cal.yaml")
    again = load_calibration(tmp_path / "cal.yaml")
    assert again == calibration
    np.testing.assert_array_equal(again.gyro_matrix, result.matrix)
    assert again.gyro_quality.motions == 13 and again.gyro_quality.residual_rms_mrad == result.residual_rms_mrad
    body = yaml.safe_load((tmp_path / "cal.yaml").read_text())["accel_calibration"]
    assert list(body).index("gyro_matrix") == list(body).index("gyro_bias_radps") + 1
    assert set(body["gyro_quality"]) == {"matrix_sigma", "residual_rms_mrad", "residual_max_mrad", "motions"}
    assert plausibility_refusal(again) is None


def test_files_without_the_gyro_load_as_before(tmp_path, calibrated):
    calibration, _ = calibrated
    plain = calibration.replace(gyro_matrix=None, gyro_quality=None)
    save_calibration(plain, tmp_path / "cal.yaml")
    body = yaml.safe_load((tmp_path / "cal.yaml").read_text())["accel_calibration"]
    assert "gyro_matrix" not in body and "gyro_quality" not in body and "gyro_bias_radps" in body
    assert load_calibration(tmp_path / "cal.yaml") == plain
    assert plain != calibration


def _write(tmp_path, calibration, **changes):
    document = yaml.safe_load(yaml.safe_dump({"accel_calibration": _body(calibration)}))
    document["accel_calibration"].update(changes)
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def _body(calibration):
    from accel_calibration.io.calibration_file import calibration_to_dict

    return calibration_to_dict(calibration)["accel_calibration"]


def _quality(sigma=0.0, rms=1.0, motions=12):
    return {"matrix_sigma": [[sigma] * 3 for _ in range(3)], "residual_rms_mrad": rms, "residual_max_mrad": 2.0,
            "motions": motions}


@pytest.mark.parametrize("change, match", [
    (dict(gyro_matrix=[[1, 0], [0, 1]]), r"gyro_matrix must have shape \(3, 3\)"),
    (dict(gyro_matrix=[[0, 0, 0], [0, 1, 0], [0, 0, 1]]), "gyro_matrix is singular"),
    (dict(gyro_matrix=[[1, 0, 0], [0, 1, 0], [0, 0, ".nan"]]), "gyro_matrix must be numbers"),
    (dict(gyro_bias_radps=None), "gyro_matrix needs gyro_bias_radps"),
    (dict(gyro_quality="good"), "gyro_quality must be a mapping"),
    (dict(gyro_quality={"residual_rms_mrad": 1.0}), "gyro_quality is missing matrix_sigma"),
    (dict(gyro_quality=_quality(sigma=-1.0)), "matrix_sigma must be >= 0"),
    (dict(gyro_quality=_quality(rms=-1.0)), "residual_rms_mrad must be a number >= 0"),
    (dict(gyro_quality=_quality(motions=1.5)), "motions must be an integer"),
])
def test_bad_gyro_entries_are_refused_with_a_reason(tmp_path, calibrated, change, match):
    with pytest.raises(CalibrationError, match=match):
        load_calibration(_write(tmp_path, calibrated[0], **change))


def test_a_quality_without_a_matrix_is_refused(calibrated):
    calibration, _ = calibrated
    with pytest.raises(CalibrationError, match="gyro_quality belongs to a gyro_matrix"):
        calibration.replace(gyro_matrix=None)


@pytest.mark.parametrize("matrix, match", [
    (np.diag([1.0, 1.0, -1.0]), "gyro matrix is mirrored"),
    (np.eye(3) * 57.3,
     r"gyro matrix: correction gain .* outside 0.9..1.1 \(gyro.scale_min..gyro.scale_max; .*other units than rad/s"),
])
def test_implausible_gyro_matrices_are_not_put_in_force(calibrated, matrix, match):
    calibration, _ = calibrated
    refusal = plausibility_refusal(calibration.replace(gyro_matrix=matrix))
    assert refusal is not None and __import__("re").search(match, refusal.text), refusal


def test_gyro_quality_is_a_value():
    quality = GyroQuality(matrix_sigma=np.full((3, 3), 1e-4), residual_rms_mrad=1.0, residual_max_mrad=2, motions=12)
    assert quality == GyroQuality(matrix_sigma=np.full((3, 3), 1e-4), residual_rms_mrad=1, residual_max_mrad=2.0,
                                  motions=12)
    assert quality.residual_max_mrad == 2.0 and isinstance(quality.residual_max_mrad, float)
    with pytest.raises(ValueError):
        quality.matrix_sigma[0, 0] = 1.0
    with pytest.raises(CalibrationError, match="gyro_quality.matrix_sigma must have shape"):
        GyroQuality(matrix_sigma=np.zeros(3), residual_rms_mrad=1.0, residual_max_mrad=2.0, motions=1)
    assert Calibration.identity() == Calibration.identity().replace(gyro_matrix=None)


def test_apply_gyro_and_its_covariance(calibrated):
    calibration, result = calibrated
    raw = np.array([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]) + result.bias_radps
    np.testing.assert_allclose(calibration.apply_gyro(raw), (raw - result.bias_radps) @ result.matrix.T, rtol=1e-15)
    bias_only = calibration.replace(gyro_matrix=None, gyro_quality=None)
    np.testing.assert_allclose(bias_only.apply_gyro(raw), raw - result.bias_radps, rtol=1e-15)
    np.testing.assert_array_equal(Calibration.identity().apply_gyro(raw[0]), raw[0])
    with pytest.raises(CalibrationError, match="raw angular rates"):
        calibration.apply_gyro([1.0, 2.0])
    # At 2 rad/s about x: the noise through M_g plus the x column's sigma times 2 rad/s on the diagonal.
    covariance = calibration.gyro_rate_covariance(raw[0], 0.002)
    expected = 0.002**2 * result.matrix @ result.matrix.T + np.diag(4.0 * result.matrix_sigma[:, 0] ** 2)
    np.testing.assert_allclose(covariance, expected, rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(covariance) > 0)
