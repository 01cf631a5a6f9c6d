"""Recalibration with a prior, for a vehicle that cannot be turned over: poses within 30 deg of level and
the calibration in force as a Gaussian pseudo-measurement. What the poses observe moves to them, the rest
stays at the prior with the prior's sigma, and the gates judge poses and prior together."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from accel_calibration import MG, fit
from accel_calibration.core.calibration import Calibration
from accel_calibration.core.errors import CalibrationError
from accel_calibration.core.gates import QualityGates
from accel_calibration.core.prior import Prior
from accel_calibration.core.refusal import Gate
from msg_tools.synthetic_imu import SensorErrors

from helpers.prior_sessions import POSE_NOISE_MG, Z_BIAS_MOVE_MG, G, level_poses, sensor_and_old_calibration

# What 8 poses within 30 deg of level leave to the prior: the z row's cross terms (a level vehicle's
# gravity barely reaches x and y of the z row).
UNSEEN = ("M_zx", "M_zy")


@pytest.mark.parametrize("seed", range(5))
def test_a_moved_z_bias_comes_back_from_eight_level_poses_with_the_old_calibration_as_prior(seed):
    rng, moved, old = sensor_and_old_calibration(seed)
    result = fit(level_poses(moved, rng), prior=old)
    assert result.success, result.message
    assert abs(old.bias[2] - moved.bias_mps2[2]) / MG > 7.0  # the prior is 8 mg off
    assert abs(result.calibration.bias[2] - moved.bias_mps2[2]) / MG < 1.0
    sources = {s.name: s for s in result.parameter_sources}
    for name in UNSEEN:  # not seen by the poses: the prior's sigma, within 5 %
        assert 0.95 < sources[name].sigma / sources[name].prior_sigma <= 1.0, sources[name]
        assert sources[name].source == "prior"
    for name in ("b_x", "b_y", "b_z"):  # seen: far below the prior's (file sigma and 10 mg of drift)
        assert sources[name].sigma / sources[name].prior_sigma < 0.2, sources[name]
        assert sources[name].source == "poses"
    assert QualityGates(min_poses=8).check(result) is None
    text = result.summary()
    assert "M_zx" in text and "from prior" in text and "from poses" in text


def test_the_same_level_poses_without_a_prior_are_refused_as_today():
    rng, moved, _ = sensor_and_old_calibration(0)
    eight = fit(level_poses(moved, rng))
    assert not eight.success and "needs at least 9 poses, got 8" in eight.message
    assert QualityGates(min_poses=8).check(eight).gate is Gate.FIT
    twelve = fit(level_poses(moved, rng, 12))
    refusal = QualityGates().check(twelve)
    assert refusal.gate is Gate.SIGMA or str(refusal).startswith("gate fit: poses do not constrain"), refusal


def test_a_prior_with_huge_sigma_does_not_pass_the_gates():
    """A prior that says nothing cannot stand in for the orientations the poses lack: refused by the fit
    (numerically singular) or by the sigma gate, which names a parameter the poses do not see."""
    rng, moved, old = sensor_and_old_calibration(1)
    raw = level_poses(moved, rng)
    for factor in (1e3, 1e9):
        loose = old.replace(bias_sigma=old.bias_sigma * factor, matrix_sigma=old.matrix_sigma * factor)
        refusal = QualityGates(min_poses=8).check(fit(raw, prior=Prior(loose, bias_drift_mps2=0.0)))
        assert refusal is not None and refusal.gate in (Gate.SIGMA, Gate.FIT), refusal
        if refusal.gate is Gate.SIGMA:
            assert "misalignment z" in refusal.text or "scale" in refusal.text, refusal


def test_with_poses_all_round_a_loose_prior_changes_the_fit_by_a_small_fraction_of_its_sigma():
    rng = np.random.default_rng(11)
    errors = SensorErrors.mpu6050_like(rng)
    d = Rotation.random(24, random_state=rng).apply([0.0, 0.0, 1.0])
    raw = errors.raw_from_true(G * d) + rng.normal(0.0, POSE_NOISE_MG * MG, (24, 3))
    plain = fit(raw)
    prior = Calibration(bias=np.zeros(3), matrix=np.eye(3), model="sphere9", bias_sigma=np.full(3, 1.0),
                        matrix_sigma=np.tril(np.full((3, 3), 0.1)))
    with_prior = fit(raw, prior=prior)
    assert with_prior.success, with_prior.message
    shift = np.abs(with_prior.calibration.bias - plain.calibration.bias) / plain.sigma.bias
    assert shift.max() < 0.05
    assert np.allclose(with_prior.sigma.bias, plain.sigma.bias, rtol=0.3)
    assert all(s.source == "poses" for s in with_prior.parameter_sources)


def test_a_prior_that_cannot_serve_is_refused_in_one_line():
    rng, moved, old = sensor_and_old_calibration(2)
    raw = level_poses(moved, rng)
    cases = [
        (old.replace(bias_sigma=None, matrix_sigma=None), "the prior has no uncertainty"),
        (old.replace(model="six", matrix=np.diag(np.diag(old.matrix)), matrix_sigma=np.diag(np.diag(old.matrix_sigma))),
         "the prior is model six and the fit model sphere9"),
        (old.replace(matrix_sigma=old.matrix_sigma * np.eye(3)), "the prior's sigma of M_yx is 0"),
    ]
    for prior, message in cases:
        with pytest.raises(CalibrationError, match=message) as caught:
            fit(raw, prior=prior)
        assert "\n" not in str(caught.value)
    with pytest.raises(CalibrationError, match="sphere models"):
        fit(raw, model="reference12", reference=np.tile([0.0, 0.0, 1.0], (8, 1)), prior=old)


@pytest.mark.parametrize("seed", range(3))
def test_a_bias_moved_beyond_the_drift_allowed_is_refused_not_taken_for_pose_noise(seed):
    """No drift allowed: the prior holds b_z to its file sigma (a few tenths of a mg) and the 8 mg move
    would pass for 7-8 mg of pose noise. Freeing the bias explains the poses to 0.1 mg: refused, saying so."""
    rng, moved, old = sensor_and_old_calibration(seed)
    raw = level_poses(moved, rng)
    result = fit(raw, prior=Prior(old, bias_drift_mps2=0.0))
    assert not result.success
    assert result.message.startswith("the poses disagree with the prior"), result.message
    z_move = float(result.message.split("moves (")[1].split(")")[0].split(", ")[2])
    assert z_move == pytest.approx(Z_BIAS_MOVE_MG, abs=1.0)
    assert str(QualityGates(min_poses=8).check(result)).startswith("gate fit: the poses disagree with the prior")
    assert fit(raw, prior=Prior(old, bias_drift_mps2=10 * MG)).success


@pytest.mark.parametrize("seed", range(3))
def test_the_six_parameter_model_takes_a_prior_too(seed):
    """A sensor without cross-axis terms, calibrated with `six` before its z bias moved 8 mg: the level poses
    bring all three biases back within 1 mg (the old scales' errors, ~0.5 mg at 1 g, pass into them) and
    leave the scales mostly to the prior (tilts of 30 deg give x and y a little: at most 25 % of g^2)."""
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng)
    errors = dataclasses.replace(errors, matrix=np.diag(np.diag(errors.matrix)))
    d = Rotation.random(24, random_state=rng).apply([0.0, 0.0, 1.0])
    old = fit(errors.raw_from_true(G * d) + rng.normal(0.0, 0.5 * MG, (24, 3)), model="six").calibration
    moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + np.array([0.0, 0.0, Z_BIAS_MOVE_MG * MG]))
    result = fit(level_poses(moved, rng), model="six", prior=old)
    assert result.success, result.message
    assert np.abs(result.calibration.bias - moved.bias_mps2).max() / MG < 1.0
    assert [s.source for s in result.parameter_sources[:3]] == ["poses"] * 3
    assert all(s.sigma / s.prior_sigma > 0.75 for s in result.parameter_sources[3:]), result.parameter_sources


def test_with_a_prior_finite_poses_never_raise():
    """Hostile poses give a failed or a successful result, never an exception: one pose, the same pose
    repeated, zeros, values that overflow, poses at the prior's bias, random counts."""
    _, _, old = sensor_and_old_calibration(5)
    rng = np.random.default_rng(9)
    cases = [np.array([[0.0, 0.0, G]]), np.tile([0.1, 0.2, G], (8, 1)), np.zeros((8, 3)),
             np.full((8, 3), 1e200), np.tile(old.bias, (8, 1)), rng.normal(0.0, 3e4, (10, 3)),
             rng.normal(0.0, 1e-3, (10, 3))]
    for raw in cases:
        result = fit(raw, prior=old)
        assert result.success in (True, False)
        if not result.success:
            assert result.message and "\n" not in result.message
    assert not fit(cases[0], prior=old).success  # one pose: too few


def sphere_error_mg(calibration, errors):
    """The calibrated sensor's | |a| - g | over 2000 orientations: (rms, largest), mg."""
    d = Rotation.random(2000, random_state=1).apply([0.0, 0.0, 1.0])
    off = np.abs(np.linalg.norm(calibration.apply(errors.raw_from_true(G * d)), axis=1) - G) / MG
    return float(np.sqrt(np.mean(off**2))), float(off.max())


@pytest.mark.parametrize("seed", range(6))
def test_another_sensors_calibration_as_prior_is_refused_naming_what_disagrees_and_by_how_much(seed):
    """14 poses within 30 deg of level and the calibration of another sensor of the same kind (its bias
    10-130 mg away, its gains and cross-axis terms 1-3 % off): kept, it would leave the sphere 25-100 mg off.
    Refused, naming the parameters and the distance; the sensor's own calibration still serves."""
    rng, moved, old = sensor_and_old_calibration(seed)
    raw = level_poses(moved, rng, 14)
    _, _, other = sensor_and_old_calibration(seed + 50)
    for prior in (other, old.replace(matrix=other.matrix)):  # all of it, and its matrix with the right bias
        result = fit(raw, prior=prior)
        assert not result.success, sphere_error_mg(result.calibration, moved)
        # Named with the distance: by the chi^2 of what the poses observe, or by the bias freed (its F test).
        assert result.message.startswith("the poses disagree with the prior"), result.message
        assert " mg" in result.message and "\n" not in result.message, result.message
        assert any(name in result.message for name in ("bias", "scale", "misalignment")), result.message
    own = fit(raw, prior=old)
    assert own.success, own.message
    assert sphere_error_mg(own.calibration, moved)[0] < 1.0


def _gain_moved(errors, axis, factor):
    matrix = errors.matrix.copy()
    matrix[axis] *= factor  # the correction's row: the raw output's gain on that axis changed by 1/factor
    return dataclasses.replace(errors, matrix=matrix)


@pytest.mark.parametrize("seed", range(3))
def test_a_one_percent_x_gain_change_from_level_poses_is_refused_or_said_never_written_silently(seed):
    rng, moved, old = sensor_and_old_calibration(seed)
    moved = _gain_moved(moved, 0, 1.01)
    result = fit(level_poses(moved, rng, 14), prior=old)
    if not result.success:
        assert "scale x" in result.message, result.message
        return
    by_name = {s.name: s for s in result.parameter_sources}
    fitted = abs(result.calibration.matrix[0, 0] - moved.matrix[0, 0]) < 0.002 * moved.matrix[0, 0]
    assert fitted or "kept from the prior, not checked" in by_name["M_xx"].note, by_name["M_xx"]


@pytest.mark.parametrize("seed", range(3))
def test_a_z_gain_change_from_level_poses_is_not_silently_taken_up_as_a_z_bias(seed):
    rng, moved, old = sensor_and_old_calibration(seed)
    moved = _gain_moved(moved, 2, 1.01)
    result = fit(level_poses(moved, rng, 14), prior=old)
    if not result.success:
        assert "scale z" in result.message, result.message
        return
    by_name = {s.name: s for s in result.parameter_sources}
    assert "M_zz" in by_name["b_z"].note and "not separable" in by_name["b_z"].note, by_name["b_z"]
    assert "kept from the prior, not checked" in by_name["M_zz"].note, by_name["M_zz"]
    assert "not separable" in result.summary() and "kept from the prior, not checked" in result.summary()
