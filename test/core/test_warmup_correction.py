"""A warm-up's curves in the calibration: the one correction (node, apply, copies) takes the accelerometer's
and the gyro's bias drift off at each sample's temperature, flat outside the range, and the file keeps them."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.core.calibration import Calibration
from accel_calibration.core.correction import Correction, correct_rows, correct_samples
from accel_calibration.core.errors import CalibrationError
from accel_calibration.core.temperature_models import TemperatureModel
from accel_calibration.core.units import MG
from accel_calibration.core.warmup import fit_warmup, warmup_calibration
from accel_calibration.io.calibration_file import (
    FORMAT_VERSION,
    CalibrationFileError,
    calibration_from_yaml,
    calibration_to_yaml,
    load_calibration,
    save_calibration,
)

from helpers.warmup_sessions import Heating, two_imus, warmup_recording


def warm_calibration(imu: int = 0, seed: int = 20) -> Calibration:
    truth = two_imus()[imu]
    fit = fit_warmup([warmup_recording(truth, np.random.default_rng(seed))], truth.calibration).fit
    assert fit is not None
    return warmup_calibration(fit, truth.calibration)


@pytest.mark.parametrize("imu", [0, 1])
def test_the_one_correction_leaves_under_1_mg_and_half_a_mrad_across_a_fresh_warm_up(imu):
    truth = two_imus()[imu]
    calibration = warm_calibration(imu)
    # A fresh warm-up of the same IMU, noise-free, through the node's correction at each sample's temperature.
    fresh = warmup_recording(truth, np.random.default_rng(99), Heating(minutes=15.0))
    still = np.linalg.solve(truth.calibration.matrix, [0.0, 0.0, 9.80665]) + truth.calibration.bias
    accel_raw = still + truth.accel_drift(fresh.temperature_degc)
    gyro_raw = truth.calibration.gyro_bias_radps + truth.gyro_drift(fresh.temperature_degc)
    corrected = correct_samples(calibration, fresh.t_ns, accel_raw, gyro_raw,
                                temperatures=(fresh.t_ns, fresh.temperature_degc))
    # The accelerometer's temperature error: its output's change from the value at the reference (one
    # orientation does not see the constant); the gyro's: its whole output (it reads zero at rest).
    at_reference = Correction.build(calibration, calibration.temperature.reference_degc)
    reference_accel = np.array(at_reference.apply(*(still + truth.accel_drift(
        np.array([calibration.temperature.reference_degc]))[0])))
    accel_error = np.abs(corrected.accel_mps2 - reference_accel).max() / MG
    gyro_error = np.abs(corrected.gyro_radps).max() * 1e3
    assert accel_error <= 1.0 and gyro_error <= 0.5
    # without the warm-up's model: tens of mg and mrad/s
    uncorrected = correct_samples(truth.calibration, fresh.t_ns, accel_raw, gyro_raw)
    assert np.abs(np.ptp(uncorrected.accel_mps2, axis=0)).max() / MG > 10 * accel_error
    assert np.abs(uncorrected.gyro_radps).max() * 1e3 > 1.0
    # Calibration.apply / apply_gyro agree with the per-message correction at one temperature
    temps = np.round(fresh.temperature_degc[::5000], 3)
    np.testing.assert_allclose(calibration.apply(accel_raw[::5000], temps),
                               correct_rows(calibration, accel_raw[::5000], temps), atol=1e-9)
    per_message = [Correction.build(calibration, float(t)).apply_gyro(*g) for t, g in zip(temps, gyro_raw[::5000])]
    np.testing.assert_allclose(calibration.apply_gyro(gyro_raw[::5000], temps), per_message, atol=1e-12)


def test_the_correction_is_held_flat_outside_the_range():
    calibration = warm_calibration()
    model = calibration.temperature
    low, high = model.range_degc
    raw = np.array([0.1, -0.2, 9.7])
    assert np.array_equal(calibration.apply(raw, low - 20.0), calibration.apply(raw, low))
    assert np.array_equal(calibration.apply_gyro(raw * 1e-3, high + 30.0), calibration.apply_gyro(raw * 1e-3, high))
    assert Correction.build(calibration, high + 30.0).temperature_clamped
    hot, edge = Correction.build(calibration, high + 30.0), Correction.build(calibration, high)
    assert hot is not None and edge is not None and hot.gyro_bias_radps == edge.gyro_bias_radps


def test_the_warm_up_calibration_round_trips_through_its_file(tmp_path):
    calibration = warm_calibration(1)
    save_calibration(calibration, tmp_path / "warm.yaml")
    loaded = load_calibration(tmp_path / "warm.yaml")
    assert loaded == calibration
    text = (tmp_path / "warm.yaml").read_text()
    assert "format_version: 2" in text and "model: spline" in text and "gyro_bias_radps:" in text
    assert FORMAT_VERSION == 2
    # a file without a warm-up stays format 1 (readable by the readers before it)
    assert "format_version: 1" in calibration_to_yaml(two_imus()[0].calibration)


def test_a_spline_block_in_a_format_1_file_is_refused_and_a_newer_format_too():
    text = calibration_to_yaml(warm_calibration())
    with pytest.raises(CalibrationFileError, match="temperature model spline needs format_version 2"):
        calibration_from_yaml(text.replace("format_version: 2", "format_version: 1"))
    with pytest.raises(CalibrationFileError, match="newer accel_calibration"):
        calibration_from_yaml(text.replace("format_version: 2", "format_version: 3"))


def test_a_spline_model_checks_its_knots_and_rows():
    with pytest.raises(CalibrationError, match="knots must be at least 2, increasing"):
        TemperatureModel("spline", 20.0, (10.0, 30.0), spline_knots_degc=[10.0, 10.0, 30.0],
                         spline_bias=np.zeros((3, 3)))
    with pytest.raises(CalibrationError, match="its range is its first and last knot"):
        TemperatureModel("spline", 20.0, (10.0, 40.0), spline_knots_degc=[10.0, 30.0], spline_bias=np.zeros((2, 3)))
    with pytest.raises(CalibrationError, match="belong to the spline model"):
        TemperatureModel("polynomial", 20.0, (10.0, 30.0), spline_knots_degc=[10.0, 30.0])


@settings(max_examples=40, deadline=None)
@given(low=st.floats(-40.0, 40.0), width=st.floats(2.0, 60.0), knots=st.integers(2, 12),
       seed=st.integers(0, 2**32 - 1), gyro=st.booleans())
def test_any_spline_model_round_trips_and_holds_flat_outside_its_knots(low, width, knots, seed, gyro):
    rng = np.random.default_rng(seed)
    where = np.linspace(low, low + width, knots)
    gyro_knots = np.linspace(low, low + width, max(2, knots - 1)) if gyro else np.zeros(0)
    model = TemperatureModel("spline", float(where[knots // 2]), (float(where[0]), float(where[-1])),
                             spline_knots_degc=where, spline_bias=rng.normal(0, 0.05, (knots, 3)),
                             spline_gyro_knots_degc=gyro_knots,
                             spline_gyro_bias=rng.normal(0, 2e-3, (len(gyro_knots), 3)))
    calibration = Calibration(bias=rng.normal(0, 0.1, 3), matrix=np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3))),
                              gyro_bias_radps=rng.normal(0, 0.01, 3), temperature=model)
    assert calibration_from_yaml(calibration_to_yaml(calibration)) == calibration
    raw = np.array([0.2, -0.1, 9.9])
    lo, hi = model.range_degc
    assert np.array_equal(calibration.apply(raw, lo - 50.0), calibration.apply(raw, lo))
    assert np.array_equal(calibration.apply_gyro(raw * 1e-3, hi + 50.0), calibration.apply_gyro(raw * 1e-3, hi))
