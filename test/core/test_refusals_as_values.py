"""Refusals are values: a verdict, a calibration file's check, the gyro's gates, the prior and a motion not
used each carry an enum member saying which rule refused, and the text a person reads is made from it
once, where it is shown: no gate wrapped inside another, no prefix stripped off."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from accel_calibration.core.calibration import Calibration
from accel_calibration.core.pose import Pose
from accel_calibration.core.refusal import Gate
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings

G = 9.80665
BIAS_MPS2 = np.array([0.2, -0.3, 0.1])
BIAS_DRIFT_MPS2_PER_DEGC = np.array([0.05, 0.0, 0.0])  # within the bias gate at 20 degC, beyond it near -20 and 60


def drifting_poses(rng: np.random.Generator, count: int = 64) -> list[Pose]:
    """Still poses of a sensor whose x bias drifts 50 mg/degC, at temperatures spread over -20..60 degC."""
    temperatures = np.linspace(-20.0, 60.0, count)
    directions = Rotation.random(count, random_state=rng).apply([0.0, 0.0, G])
    poses = []
    for i, (direction, temperature) in enumerate(zip(directions, temperatures)):
        bias = BIAS_MPS2 + BIAS_DRIFT_MPS2_PER_DEGC * (temperature - 20.0)
        mean = direction + bias + rng.normal(0.0, 2e-4, 3)
        start = i * 3_000_000_000
        poses.append(Pose(mean, np.eye(3) * 4e-4, 200, start, start + 2_000_000_000,
                          temperature_degc=float(temperature)))
    return poses


def test_a_bias_beyond_the_gate_over_the_temperature_range_is_refused_by_the_bias_gate_named_once():
    """The fit passes every gate at its reference temperature; over its calibrated range its bias leaves the
    bias gate. The verdict's refusal is the bias gate's (it was the plausibility gate wrapping the bias
    gate's text: "gate plausibility: temperature block: gate bias: ...")."""
    session = CalibrationSession(Settings(temperature_model="polynomial", temperature_bias_order=1,
                                          temperature_scale_order=0))
    for pose in drifting_poses(np.random.default_rng(5)):
        session.add_pose(pose)
    verdict = session.calibrate()
    assert not verdict.success and verdict.refusal is not None
    assert verdict.refusal.gate is Gate.BIAS, verdict.message
    assert verdict.message.startswith("temperature block: gate bias: |b| 2.0"), verdict.message
    assert verdict.message.count("gate") == 1, verdict.message


def test_a_prior_that_cannot_serve_is_the_prior_gates_refusal_and_the_session_fits_without_one():
    session = CalibrationSession(Settings())
    without_sigma = Calibration(bias=BIAS_MPS2, matrix=np.eye(3))
    refusal = session.use_prior(without_sigma)
    assert refusal is not None and refusal.gate is Gate.PRIOR and session.prior is None
    assert refusal.text.startswith("the prior has no uncertainty"), refusal
    assert session.use_prior(None) is None
