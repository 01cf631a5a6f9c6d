"""fit() never raises on finite data of the right shape: every numerical problem -- no degree of
freedom left, overflow, singular or mirrored solutions -- comes back as a failed FitResult whose
message says what to do. Bad arguments still raise CalibrationError (see test_fuzz.py)."""
import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from accel_calibration import CalibrationError, fit
from accel_calibration.core.fit import FitResult
from accel_calibration.core.temperature_models import TemperatureOptions

G = 9.80665
FACES = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
CORNERS = [(1, 1, 1), (-1, -1, 1), (1, -1, -1), (-1, 1, -1), (1, -1, 1), (-1, 1, 1), (1, 1, -1), (-1, -1, -1)]
EDGES = [(1, 1, 0), (1, 0, 1), (0, 1, 1), (-1, 1, 0), (-1, 0, 1), (0, -1, 1),
         (1, -1, 0), (1, 0, -1), (0, 1, -1), (-1, -1, 0), (-1, 0, -1), (0, -1, -1)]
SPREAD = np.array(FACES + CORNERS + EDGES, dtype=float)
SPREAD /= np.linalg.norm(SPREAD, axis=1)[:, None]

# Polynomial temperature model small enough to reach "exactly as many poses as parameters":
# sphere9 (9) + bias drift order 1 (3) = 12 parameters.
POLYNOMIAL = TemperatureOptions(model="polynomial", bias_order=1, scale_order=0)
POLYNOMIAL_SIZE = 12


def sensor(rng):
    bias = rng.normal(0.0, 0.3, 3)
    matrix = np.eye(3) + np.tril(rng.normal(0.0, 0.01, (3, 3)))
    return bias, matrix


def synthetic(seed, n, directions=None, noise_mps2=0.002, drift_per_degc=None, temps=None):
    """raw = inv(M) a + b (+ drift dT) + noise, a = g * unit direction."""
    rng = np.random.default_rng(seed)
    bias, matrix = sensor(rng)
    if directions is None:
        directions = SPREAD[:n]
    true = G * directions
    raw = true @ np.linalg.inv(matrix).T + bias
    if drift_per_degc is not None:
        raw = raw + np.outer(temps - np.median(temps), drift_per_degc)
    return raw + rng.normal(0.0, noise_mps2, raw.shape), true


def random_directions(seed, n):
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1)[:, None]


def case(kind, n, seed=3):
    """(accel, keyword arguments) for fit() with n poses of the given kind."""
    if kind in ("six", "sphere9"):
        raw, _ = synthetic(seed, n)
        return raw, dict(model=kind)
    if kind in ("reference12", "reference15"):
        directions = random_directions(seed, n)
        raw, _ = synthetic(seed, n, directions=directions)
        return raw, dict(model=kind, reference=directions)
    assert kind == "polynomial"
    temps = np.linspace(5.0, 45.0, n)
    raw, _ = synthetic(seed, n, drift_per_degc=np.array([1.0, -1.2, 0.8]) * 1e-2, temps=temps)
    return raw, dict(model="sphere9", temperature_degc=temps, temperature_model="polynomial",
                     temperature_options=POLYNOMIAL)


PARAMETERS = {"six": 6, "sphere9": 9, "reference12": 4, "reference15": 5, "polynomial": POLYNOMIAL_SIZE}


def assert_sound(result):
    assert isinstance(result, FitResult)
    if result.success:
        cal, sigma = result.calibration, result.sigma
        assert np.all(np.isfinite(cal.bias)) and np.all(np.isfinite(cal.matrix))
        assert np.all(np.isfinite(sigma.bias)) and np.all(np.isfinite(sigma.matrix))
        assert abs(np.linalg.det(cal.matrix)) > 0
        assert math.isfinite(cal.quality.residual_rms_mg)
    else:
        assert result.message and result.calibration is None


@pytest.mark.parametrize("kind", list(PARAMETERS))
def test_exactly_as_many_poses_as_parameters_is_a_failed_result(kind):
    size = PARAMETERS[kind]
    accel, kwargs = case(kind, size)
    result = fit(accel, **kwargs)
    assert not result.success
    assert "degree of freedom" in result.message, result.message
    assert f"{size} poses" in result.message and "one more" in result.message, result.message
    assert result.calibration is None and result.poses == size


@pytest.mark.parametrize("kind", list(PARAMETERS))
def test_one_pose_more_than_parameters_succeeds(kind):
    size = PARAMETERS[kind]
    accel, kwargs = case(kind, size + 1)
    result = fit(accel, **kwargs)
    assert result.success, result.message
    assert_sound(result)


def test_sphere9_degree_of_freedom_message_reads_well():
    accel, kwargs = case("sphere9", 9)
    assert fit(accel, **kwargs).message == (
        "9 poses for the 9 parameters of model sphere9 leave no degree of freedom to judge the fit: "
        "hold at least one more orientation"
    )


@pytest.mark.parametrize("kind", list(PARAMETERS))
@pytest.mark.parametrize("value", [1e154, -1e154, 1e300])
def test_one_huge_pose_is_a_failed_result(kind, value):
    accel, kwargs = case(kind, 24)
    accel = accel.copy()
    accel[5] = [value, value, value]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no numpy RuntimeWarning may leak either
        result = fit(accel, **kwargs)
    assert not result.success and result.calibration is None
    assert result.message and result.poses == 24


@pytest.mark.parametrize("kind", list(PARAMETERS))
def test_all_poses_identical_is_a_failed_result(kind):
    accel, kwargs = case(kind, 24)
    accel = np.tile(accel[0], (24, 1))
    if "reference" in kwargs:
        kwargs["reference"] = np.tile(kwargs["reference"][0], (24, 1))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = fit(accel, **kwargs)
    assert not result.success and result.calibration is None and result.message


@pytest.mark.parametrize("model", ["six", "sphere9"])
def test_overflow_inside_the_fit_is_a_numerical_failure(model):
    """No value is beyond the up-front limit, but against poses of ~1e-80 the starting scale is ~1e80
    and the residual of the 3e136 pose overflows."""
    accel = np.full((20, 3), 1e-80)
    accel[0] = [3e136, 0.0, 0.0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        result = fit(accel, model=model)
    assert not result.success and result.calibration is None
    assert "numerical failure" in result.message and "pose 0" in result.message, result.message


@pytest.mark.parametrize("model", ["reference12", "reference15"])
@pytest.mark.parametrize("scale", [1e300, 1e-300])
def test_reference_directions_of_any_finite_length(model, scale):
    """Only the direction of a reference row counts, also where its squares overflow or underflow."""
    accel, kwargs = case(model, 12)
    unit = fit(accel, **kwargs)
    scaled = fit(accel, **{**kwargs, "reference": kwargs["reference"] * scale})
    assert unit.success and scaled.success, scaled.message
    np.testing.assert_allclose(scaled.calibration.matrix, unit.calibration.matrix, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(scaled.calibration.bias, unit.calibration.bias, rtol=1e-12, atol=1e-12)


def test_bad_arguments_still_raise():
    accel, _ = case("sphere9", 12)
    with pytest.raises(CalibrationError):
        fit(accel[:, :2])
    with pytest.raises(CalibrationError):
        fit(np.where(np.arange(36).reshape(12, 3) == 7, np.nan, accel))
    with pytest.raises(CalibrationError):
        fit(accel, model="bogus")
    with pytest.raises(CalibrationError):
        fit(accel, gravity=-1.0)


anything_finite = st.floats(allow_nan=False, allow_infinity=False)
plausible = st.floats(min_value=-20.0, max_value=20.0, allow_nan=False)
huge = st.sampled_from([1e154, -1e154, 1e300, -1e300, 1.7976931348623157e308, 5e-324, 0.0])
values = st.one_of(plausible, anything_finite, huge)
KINDS = ["six", "sphere9", "reference12", "reference15", "polynomial", "segmented"]


@st.composite
def fit_cases(draw):
    n = draw(st.integers(min_value=0, max_value=30))
    kind = draw(st.sampled_from(KINDS))
    accel = draw(arrays(np.float64, (n, 3), elements=values))
    if draw(st.booleans()) and n:
        # Mostly sensible poses with a few wild ones, so the fits get far enough to fail late.
        base, _ = synthetic(draw(st.integers(0, 3)), n, directions=random_directions(n, n))
        mask = draw(arrays(np.bool_, (n, 3)))
        accel = np.where(mask, accel, base)
    kwargs = {}
    if kind in ("six", "sphere9"):
        kwargs["model"] = kind
    elif kind in ("reference12", "reference15"):
        reference = draw(arrays(np.float64, (n, 3), elements=values))
        reference[~np.any(reference != 0, axis=1)] = [0.0, 0.0, 1.0]  # a zero row is a bad argument
        kwargs.update(model=kind, reference=reference)
    else:
        temps = draw(st.one_of(arrays(np.float64, (n,), elements=values),
                               st.just(np.linspace(-10.0, 50.0, n))))
        options = POLYNOMIAL if kind == "polynomial" else TemperatureOptions(model="segmented", min_poses_per_segment=9)
        kwargs.update(model=draw(st.sampled_from(["six", "sphere9"])), temperature_degc=temps,
                      temperature_model=kind, temperature_options=options)
    return accel, kwargs


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(fit_cases())
def test_finite_poses_never_raise(args):
    accel, kwargs = args
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy RuntimeWarning would be raised here, and fail the test
        result = fit(accel, **kwargs)
    assert_sound(result)


@pytest.mark.parametrize("units_per_mps2", [1e-6, 1.0, 2.6e4])
def test_reference_fit_takes_data_in_any_units(units_per_mps2):
    """No absolute determinant limit: raw data in micro-units or high-resolution counts fit alike."""
    rng = np.random.default_rng(1)
    directions = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                           [1, 1, 0], [0, 1, 1], [1, 0, 1], [-1, 1, 0], [0, -1, 1], [1, 0, -1]], float)
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    matrix, bias = np.eye(3) + rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.05, 3)
    raw = (np.linalg.inv(matrix) @ (directions * 9.80665).T).T + bias + rng.normal(0, 1e-4, (12, 3))
    result = fit(raw * units_per_mps2, model="reference12", reference=directions)
    assert result.success, result.message
    np.testing.assert_allclose(result.calibration.bias / units_per_mps2, bias, atol=1e-4)
    np.testing.assert_allclose(result.calibration.matrix * units_per_mps2, matrix, atol=1e-4)
