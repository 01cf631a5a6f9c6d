"""A verdict never carries what the loader refuses: a calibration that passes the fit's gates but would
be refused by `apply`, `report` or the node at their plausibility check (a gyro bias of 2 rad/s)
keeps its accelerometer part and leaves the gyro part out, saying so in the verdict's one line."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.core.plausibility import plausibility_refusal
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings

from helpers.session_streams import stream


def verdict_of(t_ns, accel, gyro, settings: Settings | None = None):
    session = CalibrationSession(settings or Settings())
    for pose in session.add_recording(t_ns, accel, gyro):
        session.add_pose(pose)
    return session.calibrate()


@pytest.mark.parametrize("offset", [np.array([2.0, 0.0, 0.0]), np.array([0.0, -1.5, 3.0])])
def test_an_implausible_gyro_bias_is_left_out_and_the_accelerometer_kept(offset):
    _, samples = stream(seed=3)
    clean = verdict_of(samples.t_ns, samples.accel_raw, samples.gyro_raw)
    assert clean.success and clean.calibration is not None, clean.message
    verdict = verdict_of(samples.t_ns, samples.accel_raw, samples.gyro_raw + offset)
    assert verdict.success, verdict.message
    calibration = verdict.calibration
    assert calibration is not None
    assert plausibility_refusal(calibration) is None
    assert calibration.gyro_bias_radps is None and calibration.gyro_matrix is None
    np.testing.assert_array_equal(calibration.bias, clean.calibration.bias)
    np.testing.assert_array_equal(calibration.matrix, clean.calibration.matrix)
    assert "gyro" in verdict.message and "left out" in verdict.message, verdict.message
    assert "\n" not in verdict.message
    assert verdict.result is not None and verdict.result.calibration is calibration


def test_a_plausible_gyro_bias_is_kept():
    _, samples = stream(seed=3)
    verdict = verdict_of(samples.t_ns, samples.accel_raw, samples.gyro_raw + np.array([0.5, 0.0, 0.0]))
    assert verdict.success and verdict.calibration is not None, verdict.message
    assert verdict.calibration.gyro_bias_radps is not None
    assert "left out" not in verdict.message
