"""The pose map the node draws on calibration/markers: one point per pose held, at the orientation it was
held in, its status from the fit and the store, the arrow where the advice says to turn, the holes where no
pose is."""
from __future__ import annotations

import numpy as np

from accel_calibration.core.coverage import CANDIDATE_DIRECTIONS
from accel_calibration.core.pose_map import PoseStatus, holes, pose_map
from accel_calibration.core.session import CalibrationSession
from msg_tools.synthetic_imu import FACE_DIRECTIONS, SensorErrors, SyntheticImu, rotation_with_up

from helpers.session_doors import per_message


def held(directions, seed=3, repeat_first=False):
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    turns = [rotation_with_up(d) for d in directions]
    if repeat_first:
        turns.append(turns[0])
    samples = SyntheticImu(errors, turns, dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=seed).samples()
    session = CalibrationSession()
    per_message(session, samples.t_ns, samples.accel_raw, samples.gyro_raw)
    session.refit()
    return session


def angles_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0)))


def test_each_pose_held_is_a_point_at_the_orientation_it_was_held_in():
    faces = np.asarray(FACE_DIRECTIONS[:4], dtype=float)
    session = held(faces)
    progress = session.progress()
    drawn = pose_map(session, None, progress)
    assert len(drawn.directions) == len(session.store) == 4
    # Raw directions (no calibration in force): a few degrees off at most for a 1-3 % scale, 50 mg bias.
    assert np.all(angles_deg(drawn.directions, faces) < 4.0)
    assert drawn.statuses == (PoseStatus.USED,) * 4


def test_the_arrow_is_the_advice_and_the_holes_are_where_no_pose_is():
    faces = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=float)  # z never seen
    session = held(faces)
    progress = session.progress()
    drawn = pose_map(session, None, progress)
    assert progress.advice == "turn z up"
    np.testing.assert_array_equal(drawn.next_direction, [0.0, 0.0, 1.0])
    assert drawn.advice == progress.advice
    # Both z faces are holes; the four faces seen are not.
    hole_set = {tuple(np.round(h, 6)) for h in drawn.holes}
    assert (0.0, 0.0, 1.0) in hole_set and (0.0, 0.0, -1.0) in hole_set
    for face in faces:
        assert tuple(face) not in hole_set


def test_a_pose_held_again_is_drawn_once_as_merged():
    faces = np.asarray(FACE_DIRECTIONS[:3], dtype=float)
    session = held(faces, repeat_first=True)
    drawn = pose_map(session, None, session.progress())
    assert len(drawn.directions) == 3
    assert drawn.statuses[0] is PoseStatus.MERGED and drawn.statuses[1:] == (PoseStatus.USED,) * 2


def test_a_pose_the_fit_left_out_is_drawn_as_an_outlier():
    rng = np.random.default_rng(7)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    imu = SyntheticImu(errors, [rotation_with_up(d) for d in CANDIDATE_DIRECTIONS[:14]], dwell_s=2.5, move_s=1.0,
                       rate_hz=200.0, seed=7)
    samples = imu.samples()
    accel = samples.accel_raw.copy()
    start, end, _ = imu.static_intervals()[9]
    dwell = (samples.t_ns >= start) & (samples.t_ns < end)
    accel[dwell] *= 1.02  # 20 mg off the sphere: a pose no calibration puts on it with the rest
    session = CalibrationSession()
    per_message(session, samples.t_ns, accel, samples.gyro_raw)
    result = session.refit()
    assert result is not None and len(result.outliers) == 1
    drawn = pose_map(session, None, session.progress())
    assert [s for s in drawn.statuses if s is PoseStatus.OUTLIER] == [PoseStatus.OUTLIER]
    assert drawn.statuses[result.outliers[0].index] is PoseStatus.OUTLIER


def test_no_pose_leaves_every_candidate_a_hole_and_one_covers_its_own():
    assert len(holes(np.zeros((0, 3)))) == len(CANDIDATE_DIRECTIONS)
    assert len(holes(np.array([[0.0, 0.0, 1.0]]))) == len(CANDIDATE_DIRECTIONS) - 1
