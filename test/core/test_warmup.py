"""A warm-up is a calibration: bias curves against temperature for accelerometer and gyro from a sensor
sitting still while it warms, checked against a known, non-polynomial truth."""
from __future__ import annotations

import re

import numpy as np
import pytest

from accel_calibration.core.settings import Settings
from accel_calibration.core.units import MG
from accel_calibration.core.warmup import WarmupFit, WarmupOptions, fit_warmup, still_mask

from helpers.warmup_sessions import Heating, WarmupTruth, true_accel_curve, true_gyro_bias, two_imus, warmup_recording


def worst_errors(fit: WarmupFit, truth: WarmupTruth, low: float | None = None,
                 high: float | None = None) -> tuple[float, float]:
    """The fitted curves' worst temperature error across their range (or low..high), mg and mrad/s."""
    fit_low, fit_high = fit.range_degc
    grid = np.linspace(fit_low if low is None else low, fit_high if high is None else high, 400)
    accel = true_accel_curve(truth, grid, fit.reference_degc) - fit.accel.at(grid)
    assert fit.gyro is not None and fit.gyro_bias_radps is not None
    gyro = true_gyro_bias(truth, grid) - (fit.gyro_bias_radps + fit.gyro.at(grid))
    return float(np.abs(accel).max() / MG), float(np.abs(gyro).max() * 1e3)


def time_weighted_cubic(recording, truth: WarmupTruth, reference: float, grid: np.ndarray) -> tuple[float, float]:
    """The autopilots' approach as the baseline: a cubic per axis in temperature over every sample (so
    weighted by time), of the accelerometer's and gyro's output corrected by the calibration in force."""
    calibration = truth.calibration
    accel = calibration.apply(recording.accel_mps2)
    gyro = calibration.apply_gyro(recording.gyro_radps)
    dt = recording.temperature_degc - reference
    polyfit, polyval = np.polynomial.polynomial.polyfit, np.polynomial.polynomial.polyval
    accel_coefficients = polyfit(dt, accel, 3)
    gyro_coefficients = polyfit(dt, gyro, 3)
    accel_curve = polyval(grid - reference, accel_coefficients).T - polyval(0.0, accel_coefficients)
    gyro_curve = polyval(grid - reference, gyro_coefficients).T
    accel_error = true_accel_curve(truth, grid, reference) - accel_curve
    gyro_error = true_gyro_bias(truth, grid) - gyro_curve
    return float(np.abs(accel_error).max() / MG), float(np.abs(gyro_error).max() * 1e3)


@pytest.mark.parametrize("imu", [0, 1])
def test_a_still_warm_up_gives_both_curves_within_1_mg_and_half_a_mrad_and_beats_a_time_weighted_cubic(imu):
    truth = two_imus()[imu]
    recording = warmup_recording(truth, np.random.default_rng(10 + imu))
    # the session's detector keeps the whole 15 minutes still while the mean drifts by tens of mg
    assert still_mask(recording, Settings()).mean() > 0.99
    result = fit_warmup([recording], truth.calibration)
    assert result.refusal is None and result.fit is not None
    fit = result.fit
    low, high = fit.range_degc
    assert low < 15.5 and high > 44.4
    accel_mg, gyro_mradps = worst_errors(fit, truth)
    assert accel_mg <= 1.0 and gyro_mradps <= 0.5
    cubic_mg, cubic_mradps = time_weighted_cubic(recording, truth, fit.reference_degc, np.linspace(low, high, 400))
    assert cubic_mg > 2 * accel_mg and cubic_mradps > 2 * gyro_mradps
    # sigma per temperature: none at the reference (the curve is zero there by definition), some at the
    # range's ends, never more than the error allows
    assert np.all(fit.accel.sigma_at([fit.reference_degc]) < 1e-9)
    assert np.all(fit.accel.sigma_at([low, high]) > 0.01 * MG) and np.all(fit.accel.sigma_at([low, high]) < 0.5 * MG)
    assert not fit.lag_seen and fit.steps == () and fit.left_out == ()
    text = "\n".join(result.said)
    assert "z: along gravity, its curve is bias + scale drift x g together" in text
    assert "x: level, its curve is the bias drift alone" in text
    assert "lag: not seen" in text


def test_the_correction_is_held_flat_outside_the_range_never_extrapolated():
    truth = two_imus()[0]
    fit = fit_warmup([warmup_recording(truth, np.random.default_rng(3))], truth.calibration).fit
    assert fit is not None and fit.gyro is not None
    low, high = fit.range_degc
    np.testing.assert_array_equal(fit.accel.at([-30.0, low - 5.0]), np.repeat(fit.accel.at([low]), 2, axis=0))
    np.testing.assert_array_equal(fit.gyro.at([high + 0.1, 90.0]), np.repeat(fit.gyro.at([high]), 2, axis=0))
    assert f"{low:.1f}..{high:.1f} degC" in fit.describe()[0] and "held flat outside" in fit.describe()[0]


def test_the_slow_end_does_not_dominate_bins_weighted_alike():
    """A warm-up that sits at its top for 40 minutes more: the time-weighted cubic degrades, ours does not."""
    truth = two_imus()[1]
    short = warmup_recording(truth, np.random.default_rng(4), Heating(minutes=10.0))
    long = warmup_recording(truth, np.random.default_rng(4), Heating(minutes=50.0))
    errors = []
    for recording in (short, long):
        fit = fit_warmup([recording], truth.calibration).fit
        assert fit is not None
        errors.append(worst_errors(fit, truth, 16.0, 44.0))
    grid = np.linspace(16.0, 44.0, 400)
    cubic_short = time_weighted_cubic(short, truth, 30.0, grid)[0]
    cubic_long = time_weighted_cubic(long, truth, 30.0, grid)[0]
    assert errors[1][0] <= 1.0 and errors[1][1] <= 0.5
    assert cubic_long > cubic_short > errors[1][0]


def test_warm_ups_of_a_cold_morning_and_a_warm_afternoon_are_pooled_each_with_its_turn_on_bias():
    truth = two_imus()[0]
    rng = np.random.default_rng(5)
    morning = warmup_recording(truth, rng, Heating(start_degc=2.0, end_degc=28.0),
                               accel_turn_on=np.array([4.0, -3.0, 2.0]) * MG,
                               gyro_turn_on=np.array([1.0, -0.8, 0.5]) * 1e-3)
    afternoon = warmup_recording(truth, rng, Heating(start_degc=22.0, end_degc=48.0),
                                 accel_turn_on=np.array([-2.0, 5.0, -1.0]) * MG,
                                 gyro_turn_on=np.array([-0.6, 0.9, -1.2]) * 1e-3)
    result = fit_warmup([morning, afternoon], truth.calibration)
    fit = result.fit
    assert fit is not None and fit.gyro_offsets is not None
    low, high = fit.range_degc
    assert low < 3.0 and high > 46.0 and len(fit.runs) == 2
    # each run's own offset: the gyro's turn-on difference recovered within 0.1 mrad/s
    np.testing.assert_allclose(fit.gyro_offsets[1] - fit.gyro_offsets[0], np.array([-1.6, 1.7, -1.7]) * 1e-3,
                               atol=0.1e-3)
    accel_mg, _ = worst_errors(fit, truth)
    assert accel_mg <= 1.0
    # the gyro's absolute bias is each run's own: against the mean of the two turn-ons
    grid = np.linspace(low, high, 400)
    mean_turn_on = np.array([0.2, 0.05, -0.35]) * 1e-3
    gyro_error = true_gyro_bias(truth, grid) + mean_turn_on - (fit.gyro_bias_radps + fit.gyro.at(grid))
    assert np.abs(gyro_error).max() <= 0.5e-3


def test_a_warm_up_whose_temperatures_meet_no_other_is_left_out_and_said():
    truth = two_imus()[0]
    rng = np.random.default_rng(6)
    first = warmup_recording(truth, rng, Heating(start_degc=15.0, end_degc=35.0))
    apart = warmup_recording(truth, rng, Heating(start_degc=40.0, end_degc=50.0, minutes=5.0))
    result = fit_warmup([first, apart], truth.calibration)
    assert result.fit is not None and len(result.fit.runs) == 1
    assert result.fit.range_degc[1] < 35.5
    assert any("recording 2" in line and "overlap none of the others'" in line for line in result.said)


def test_a_lasting_step_in_the_bias_is_found_with_its_time_and_the_part_it_cuts_off_left_out():
    truth = two_imus()[1]
    recording = warmup_recording(truth, np.random.default_rng(7),
                                 step=(400.0, np.array([0.0, 5.0, 0.0]) * MG, np.array([0.0, 0.0, 1.0e-3])))
    result = fit_warmup([recording], truth.calibration)
    fit = result.fit
    assert fit is not None and len(fit.steps) == 1
    assert abs(fit.steps[0][1].time_ns * 1e-9 - 400.0) <= 2.0
    assert "step in the bias in recording 1 at 40" in "\n".join(result.said)
    assert any("overlap none of the others'" in line for line in fit.left_out)
    accel_mg, _ = worst_errors(fit, truth)
    assert accel_mg <= 1.0  # over the part kept (before the step: the wider span)


def test_a_bump_that_comes_back_is_left_out_and_the_curve_keeps_its_whole_range():
    truth = two_imus()[0]
    recording = warmup_recording(truth, np.random.default_rng(8), bump=(300.0, 30.0, np.array([8.0, 0.0, 6.0]) * MG))
    result = fit_warmup([recording], truth.calibration)
    fit = result.fit
    assert fit is not None
    assert any("a bump in the bias that came back" in line and "300.2..330.2 s" in line for line in fit.left_out)
    low, high = fit.range_degc
    assert low < 15.5 and high > 44.4
    accel_mg, gyro_mradps = worst_errors(fit, truth)
    assert accel_mg <= 1.0 and gyro_mradps <= 0.5


def test_the_temperature_sensors_lag_is_estimated_where_warming_and_cooling_pass_one_temperature():
    truth = two_imus()[0]
    heating = Heating(tau_s=150.0, minutes=12.0, cool_minutes=12.0, lag_s=30.0)
    recording = warmup_recording(truth, np.random.default_rng(9), heating)
    fit = fit_warmup([recording], truth.calibration).fit
    assert fit is not None and fit.lag_seen
    assert abs(fit.lag_s - 30.0) <= 6.0
    accel_mg, gyro_mradps = worst_errors(fit, truth)
    assert accel_mg <= 1.0 and gyro_mradps <= 0.5
    ignored = fit_warmup([recording], truth.calibration, WarmupOptions(lag_s=0.0)).fit
    assert ignored is not None
    assert worst_errors(ignored, truth)[0] > 2 * accel_mg


def test_one_warm_up_with_a_lagging_register_shows_no_lag_and_says_so():
    """One heating history: the lag only relabels its temperatures, nothing in the data shows it."""
    truth = two_imus()[0]
    recording = warmup_recording(truth, np.random.default_rng(11), Heating(lag_s=20.0))
    result = fit_warmup([recording], truth.calibration)
    assert result.fit is not None and not result.fit.lag_seen and result.fit.lag_s == 0.0
    said = "\n".join(result.said)
    assert "lag: not seen (it shows only where one temperature is passed at two heating rates)" in said


def test_a_span_too_small_is_refused_with_the_reason():
    truth = two_imus()[0]
    recording = warmup_recording(truth, np.random.default_rng(12), Heating(start_degc=30.0, end_degc=33.0, minutes=4.0))
    result = fit_warmup([recording], truth.calibration)
    assert result.fit is None and result.refusal is not None
    assert "span 2.1 degC (30.0..32.1)" in result.refusal
    assert "needs 5 degC" in result.refusal


def test_a_tilted_still_orientation_says_its_axes_mix_bias_and_scale():
    truth = two_imus()[0]
    recording = warmup_recording(truth, np.random.default_rng(13), Heating(minutes=6.0),
                                 gravity_direction=(0.0, 1.0, 1.0))
    result = fit_warmup([recording], truth.calibration)
    assert result.fit is not None
    said = "\n".join(result.said)
    assert re.search(r"y: tilted \(4[4-6] deg from gravity\), its curve mixes bias and scale drift", said)
    assert re.search(r"z: tilted \(4[4-6] deg from gravity\)", said) and "x: level" in said
