"""A gyro whose axes or unit disagree with the accelerometer's (a board rotation or driver-frame mistake,
deg/s given as rad/s) is named in one line before the gyro fit iterates, and the doomed fit is not run;
a right gyro is never flagged."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from accel_calibration import fit
from accel_calibration.core.gyro_fit import Motion, fit_gyro
from msg_tools.synthetic_motion import simulate_session

from helpers.gyro_sessions import poses_and_motions

SWAP_XY = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
CASES = [
    (-np.eye(3), "gyro axes look negated against the accelerometer's: x→−x, y→−y, z→−z"),
    (np.diag([-1.0, -1.0, 1.0]), "gyro axes look negated against the accelerometer's: x→−x, y→−y"),
    (np.diag([1.0, 1.0, -1.0]), "gyro axes look negated against the accelerometer's: z→−z"),
    (SWAP_XY, "gyro axes look swapped against the accelerometer's: x↔y"),
    (np.degrees(1.0) * np.eye(3), "gyro in deg/s given as rad/s"),
    # A board turned 90 deg about z: the gyro reads (y, -x, z) of the accelerometer's rate.
    (np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
     "gyro axes look turned against the accelerometer's: x→y, y→−x, z→z"),
    (-np.degrees(1.0) * np.eye(3),
     "gyro axes look negated against the accelerometer's: x→−x, y→−y, z→−z; gyro in deg/s given as rad/s"),
]


def session(seed, poses=14, rate_hz=200.0):
    simulated = simulate_session(np.random.default_rng(seed), poses=poses, rate_hz=rate_hz)
    pose_list, motions = poses_and_motions(simulated)
    return simulated, pose_list, motions, fit(pose_list).calibration


def recorded_as(wrong, poses, motions):
    """The same session as a gyro reading raw' = wrong @ raw would record it."""
    return ([replace(p, gyro_radps=wrong @ p.gyro_radps) for p in poses],
            [Motion(m.stamps_ns, m.gyro_radps @ wrong.T) for m in motions])


@pytest.mark.parametrize("wrong, said", CASES)
def test_a_gyro_mapped_wrong_is_named_and_not_fitted(wrong, said):
    simulated, poses, motions, accel = session(5)
    poses, motions = recorded_as(wrong, poses, motions)
    result = fit_gyro(poses, motions, accel, gyro_noise_radps=simulated.gyro_noise_radps)
    assert not result.success and result.iterations == 0, result.message
    assert result.message.startswith(f"{said} ("), result.message
    assert "\n" not in result.message


@pytest.mark.parametrize("seed", range(8))
def test_a_right_gyro_is_never_flagged(seed):
    rate_hz = (200.0, 400.0, 1000.0)[seed % 3]
    simulated, poses, motions, accel = session(100 + seed, poses=12 + seed, rate_hz=rate_hz)
    result = fit_gyro(poses, motions, accel, gyro_noise_radps=simulated.gyro_noise_radps)
    assert result.success, result.message
    difference = result.matrix - simulated.gyro.matrix
    assert np.abs(difference).max() < 2e-3  # and the fit found the truth


def test_through_the_session_the_accelerometer_is_applied_and_the_gyro_refused_in_one_line():
    """The sample path (detector, motion recorder) of a session whose gyro reads -x, -y, -z: the
    accelerometer calibration stands, the gyro's refusal names the negated axes and no fit iterated."""
    from accel_calibration.core.session import CalibrationSession

    simulated = simulate_session(np.random.default_rng(9), poses=16, rate_hz=400.0)
    session = CalibrationSession()
    for pose in session.add_recording(simulated.stamps_ns, simulated.accel_mps2, -simulated.gyro_radps):
        session.add_pose(pose)
    verdict = session.calibrate()
    assert verdict.success and verdict.calibration.gyro_matrix is None, verdict.message
    assert verdict.gyro_refusal.startswith("gyro: gate fit: gyro axes look negated against the accelerometer's: "
                                           "x→−x, y→−y, z→−z ("), verdict.gyro_refusal


def test_a_gyro_in_deg_per_s_whose_noise_keeps_every_pose_out_is_named():
    """In deg/s the gyro's noise reads 57.3 times larger, above the limit of a still window, so the session
    finds no pose at all and never reaches the gyro fit; the accelerometer was quiet meanwhile, and the
    refusal names the unit before offering to raise the limit."""
    from accel_calibration.core.session import CalibrationSession

    simulated = simulate_session(np.random.default_rng(9), poses=16, rate_hz=400.0)
    session = CalibrationSession()
    for pose in session.add_recording(simulated.stamps_ns, simulated.accel_mps2, np.degrees(simulated.gyro_radps)):
        session.add_pose(pose)
    verdict = session.calibrate()
    assert not verdict.success and len(session.store) == 0
    assert "static.max_gyro_noise_mradps refused every window" in verdict.message, verdict.message
    assert "only the gyro was that noisy: is it in deg/s given as rad/s? (its quietest noise would then be 1." \
        in verdict.message, verdict.message
