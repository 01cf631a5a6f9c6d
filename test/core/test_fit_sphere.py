"""Sphere fit: honest uncertainties, the same optimum as scipy, refusals that name what is missing."""
import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from accel_calibration import Calibration, CalibrationError, fit
from accel_calibration.core.models import SphereModel, seed_sphere

G = 9.80665
FACES = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)


def simulated_sensor(rng):
    """A badly calibrated MEMS part: bias ~0.3 m/s^2 (30 mg), scale ~1 %, non-orthogonality ~0.5 deg."""
    bias = rng.normal(0.0, 0.3, 3)
    matrix = np.eye(3) + np.tril(rng.normal(0.0, 0.01, (3, 3)))
    return bias, matrix


def simulated_poses(rng, bias, matrix, n=24, noise_mps2=0.002, directions=None):
    if directions is None:
        directions = Rotation.random(n, random_state=rng).apply([0.0, 0.0, 1.0])
        directions[:6] = FACES
    raw = (G * directions) @ np.linalg.inv(matrix).T + bias
    return raw + rng.normal(0.0, noise_mps2, raw.shape)


def test_monte_carlo_sigma_is_honest():
    """In >= 95 % of trials each parameter lies within 3 sigma of the truth (3 sigma covers 99.7 % for a
    Gaussian; 95 % leaves room for the t-distribution with 15 degrees of freedom and 300 trials)."""
    rng = np.random.default_rng(20261122)
    entries = SphereModel("sphere9").entries
    inside = []
    for _ in range(300):
        bias, matrix = simulated_sensor(rng)
        result = fit(simulated_poses(rng, bias, matrix))
        assert result.success, result.message
        cal, sigma = result.calibration, result.sigma
        z_bias = (cal.bias - bias) / sigma.bias
        z_matrix = [(cal.matrix[i, j] - matrix[i, j]) / sigma.matrix[i, j] for i, j in entries]
        inside.append(np.abs(np.concatenate([z_bias, z_matrix])) <= 3.0)
    fraction = np.mean(inside, axis=0)
    assert np.all(fraction >= 0.95), fraction
    # And the sigmas are not inflated either: the truth is not always inside 1 sigma.
    assert np.all(fraction <= 1.0)


def test_recovers_truth_and_corrects_fresh_orientations_within_1_mg():
    rng = np.random.default_rng(7)
    bias, matrix = simulated_sensor(rng)
    result = fit(simulated_poses(rng, bias, matrix, n=30, noise_mps2=0.001))
    assert result.success
    fresh = Rotation.random(200, random_state=rng).apply([0.0, 0.0, G])
    raw = fresh @ np.linalg.inv(matrix).T + bias
    error_mg = np.linalg.norm(result.calibration.apply(raw) - fresh, axis=1) / (G * 1e-3)
    # sphere9 fixes the frame to the sensor's x axis and x-y plane; the truth here is lower-triangular
    # too, so the full vector is recovered, not only its length.
    assert error_mg.max() < 1.0
    uncorrected_mg = np.linalg.norm(raw - fresh, axis=1) / (G * 1e-3)
    assert uncorrected_mg.mean() > 10.0  # the sensor was worth calibrating


def test_same_optimum_as_scipy_least_squares():
    rng = np.random.default_rng(3)
    bias, matrix = simulated_sensor(rng)
    accel = simulated_poses(rng, bias, matrix)
    model = SphereModel("sphere9")
    ours = fit(accel)
    x0 = model.project(*seed_sphere(accel, G))
    fun = lambda p: model.residual_and_jacobian(p, accel, G)  # noqa: E731
    reference = least_squares(lambda p: fun(p)[0], x0, jac=lambda p: fun(p)[1], ftol=1e-15, xtol=1e-15, gtol=1e-15)
    assert_allclose(model.pack(ours.calibration.bias, ours.calibration.matrix), reference.x, rtol=0, atol=1e-9)
    assert ours.cost == pytest.approx(reference.cost, rel=1e-9)
    assert ours.iterations <= 10


def test_six_model_and_raw_counts_with_large_offset():
    """imu_tk's Xsens data are unsigned counts centred on 32768: the seed must cope with that."""
    rng = np.random.default_rng(11)
    counts_per_mps2 = 4060 / G
    directions = Rotation.random(18, random_state=rng).apply([0.0, 0.0, 1.0])
    directions[:6] = FACES
    raw = 32768 + counts_per_mps2 * np.array([1.01, 0.99, 1.02]) * (G * directions) + rng.normal(0, 0.5, (18, 3))
    for model in ("six", "sphere9"):
        result = fit(raw, model=model)
        assert result.success, result.message
        assert_allclose(result.calibration.bias, 32768, atol=2.0)
        assert result.calibration.quality.residual_rms_mg < 1.0


def test_warm_start_converges_quickly_to_the_cold_optimum():
    """A warm start from the fit before the last pose: a few iterations (the cold start's cross-axis seed
    is itself within noise of the optimum and takes two) and the same optimum."""
    rng = np.random.default_rng(5)
    bias, matrix = simulated_sensor(rng)
    accel = simulated_poses(rng, bias, matrix, n=20)
    cold = fit(accel[:19])
    warm = fit(accel, initial=cold.calibration)
    assert warm.success and warm.iterations <= 3
    assert_allclose(warm.calibration.bias, fit(accel).calibration.bias, atol=1e-9)


def test_refuses_too_few_poses_with_the_count():
    rng = np.random.default_rng(1)
    result = fit(simulated_poses(rng, np.zeros(3), np.eye(3), n=6, directions=FACES.copy()))
    assert not result.success
    assert "needs at least 9 poses, got 6" in result.message
    assert result.calibration is None


def test_refuses_all_poses_alike():
    rng = np.random.default_rng(1)
    directions = np.tile([0.0, 0.0, 1.0], (12, 1)) + rng.normal(0, 0.01, (12, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    result = fit(simulated_poses(rng, np.zeros(3), np.eye(3), directions=directions))
    assert not result.success
    assert "same way" in result.message and "x pointing down" in result.message


def test_refuses_unobservable_hemisphere_naming_the_missing_face():
    """Poses only with z up (a vehicle that never turns over): bias z and scale z are not separable."""
    rng = np.random.default_rng(2)
    directions = Rotation.random(400, random_state=rng).apply([0.0, 0.0, 1.0])
    directions = directions[directions[:, 2] > 0.6][:20]
    result = fit(simulated_poses(rng, np.zeros(3), np.eye(3), directions=directions))
    assert not result.success
    assert "z pointing down" in result.message
    assert "condition number" in result.message


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(accel_mps2=np.zeros((10, 2))), "N x 3"),
        (dict(accel_mps2=np.full((10, 3), np.nan)), "non-finite"),
        (dict(accel_mps2=np.ones((10, 3)), model="ellipse"), "model must be one of"),
        (dict(accel_mps2=np.ones((10, 3)), gravity=-9.8), "gravity"),
        (dict(accel_mps2=np.ones((10, 3)), model="reference12"), "needs reference"),
        (dict(accel_mps2=np.ones((10, 3)), temperature_degc=[20.0]), "temperature_degc"),
        (dict(accel_mps2=np.ones((10, 3)), initial="cal.yaml"), "initial"),
        (dict(accel_mps2="junk"), "N x 3"),
    ],
)
def test_bad_arguments_raise_clearly(kwargs, match):
    with pytest.raises(CalibrationError, match=match):
        fit(**kwargs)


def test_apply_is_vectorised_and_follows_the_convention():
    cal = Calibration(bias=[0.1, -0.2, 0.3], matrix=[[1.01, 0, 0], [0.002, 0.99, 0], [0.001, -0.003, 1.02]])
    raw = np.random.default_rng(0).normal(0, 9.8, (1000, 3))
    expected = (raw - cal.bias) @ cal.matrix.T
    assert_allclose(cal.apply(raw), expected, rtol=1e-15)
    assert_allclose(cal.apply(raw[0]), expected[0], rtol=1e-15)


def test_refuses_poses_that_leave_cross_axis_terms_unobservable():
    """All six faces, but the only other poses lie along one diagonal: M_yx, M_zx, M_zy are then
    inseparable (their Jacobian columns are proportional)."""
    diagonal = np.ones((6, 3)) / np.sqrt(3.0)
    diagonal[3:] *= -1
    rng = np.random.default_rng(9)
    result = fit(simulated_poses(rng, np.zeros(3), np.eye(3), directions=np.vstack([FACES, diagonal])))
    assert not result.success
    assert "between the axes" in result.message
