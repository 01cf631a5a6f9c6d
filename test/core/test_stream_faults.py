"""Stream faults that blinded or misled the calibrator, in-process through the session, per
message (the node's door) and per recording (replay's door) alike. Each fault is counted under a
plain name, never becomes a pose, never feeds the noise floor, and the calibrator recovers by itself.

Before the fix, per message at 200 Hz on a 15-pose session (15 poses clean):
  3 s of zero accelerations (gyro live)      -> 9 poses, one of them |a| = 0, /calibrate refused
  gyro exactly 0 for 30 s while accel varies -> 1 pose (the floor learned a zero gyro variance)
  one message stamped a day ahead            -> 5 poses (8799 samples "stamp backwards")
  publisher restarting an hour earlier       -> 8 poses (6600 samples "stamp backwards")
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration import MG, Pose
from accel_calibration.core.pose_store import AGREEMENT_CHI2, PoseStore, means_agree
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings
from accel_calibration.core.stream.collection_pause import CollectionPause
from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.core.stream.detector_batch import DetectorConfig
from accel_calibration.core.stream.screening import Counters
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers import session_doors as doors
from helpers.detector_streams import stream_with_breaks

G = 9.80665
DAY_NS = 86_400 * 10**9
POSES = 15
FAST = settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def session_stream(seed=1, rate_hz=200.0, poses=POSES):
    """A person holding the sensor still in `poses` orientations, 3 s each, 1.5 s turns between."""
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    s = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=3.0, move_s=1.5, rate_hz=rate_hz,
                     seed=seed).samples()
    return errors, s.t_ns.copy(), s.accel_raw.copy(), s.gyro_raw.copy()


def per_message(t, accel, gyro, settings_=None, paused=None):
    """The node's door: one add_sample per message; `paused` (bool per message) toggles set_collecting."""
    session = CalibrationSession(settings_)
    poses = doors.per_message(session, t, accel, gyro, collecting=None if paused is None else ~np.asarray(paused))
    return session, poses


def per_recording(t, accel, gyro, settings_=None, paused=None):
    """Replay's door: the whole recording at once."""
    session = CalibrationSession(settings_)
    extra = {} if paused is None else {"collecting": ~np.asarray(paused)}
    poses = session.add_recording(np.asarray(t, dtype=np.int64), accel, gyro, **extra)
    for pose in poses:
        session.add_pose(pose)
    return session, poses


def assert_both_doors_agree(t, accel, gyro, settings_=None, paused=None):
    live, live_poses = per_message(t, accel, gyro, settings_, paused)
    replay, replay_poses = per_recording(t, accel, gyro, settings_, paused)
    assert [(p.start_ns, p.end_ns, p.samples) for p in live_poses] == \
        [(p.start_ns, p.end_ns, p.samples) for p in replay_poses]
    for a, b in zip(live_poses, replay_poses):
        np.testing.assert_allclose(a.accel_mps2, b.accel_mps2, rtol=0, atol=1e-9)
    assert live.counters == replay.counters
    return live, live_poses


def insert(t, accel, gyro, at, accel_block, gyro_block, period_ns):
    """Messages spliced in before index `at` (stamps continuing the stream), later stamps shifted on."""
    count = len(accel_block)
    stamps = t[at - 1] + period_ns * np.arange(1, count + 1)
    return (np.concatenate([t[:at], stamps, t[at:] + count * period_ns]),
            np.concatenate([accel[:at], accel_block, accel[at:]]), np.concatenate([gyro[:at], gyro_block, gyro[at:]]))


def calibrates(session):
    verdict = session.calibrate()
    assert verdict.success, verdict.message
    return verdict.calibration


# ---------------------------------------------------------------- all-zero messages
@FAST
@given(seconds=st.floats(2.0, 3.0), dwell=st.integers(1, POSES - 2), gyro_live=st.booleans(),
       rate_hz=st.sampled_from([50.0, 200.0]))
def test_zero_accelerations_are_never_a_pose(seconds, dwell, gyro_live, rate_hz):
    errors, t, accel, gyro = session_stream(rate_hz=rate_hz)
    at = int((dwell * 4.5 + 1.0) * rate_hz)  # in the middle of a still dwell
    count = int(seconds * rate_hz)
    zeros = np.zeros((count, 3))
    t, accel, gyro = insert(t, accel, gyro, at, zeros, gyro[at:at + count] if gyro_live else zeros,
                            int(1e9 / rate_hz))
    session, poses = assert_both_doors_agree(t, accel, gyro)
    assert all(np.linalg.norm(p.accel_mps2) > 0.5 * G for p in poses)
    assert session.counters.zero_accel == count
    assert len(session.store) >= POSES  # the dwell it fell in may give a pose before and after it
    np.testing.assert_allclose(calibrates(session).bias, errors.bias_mps2, atol=3 * MG)


def test_a_dead_sensor_reading_near_zero_is_counted_implausible_and_a_stream_in_g_is_named():
    errors, t, accel, gyro = session_stream()
    rng = np.random.default_rng(2)
    dead = rng.normal(0.0, 1e-4, (1200, 3))  # 6 s of a sensor whose output is noise about 0
    t, accel, gyro = insert(t, accel, gyro, int(3 * 4.5 * 200), dead, gyro[:1200], 5_000_000)
    session, poses = assert_both_doors_agree(t, accel, gyro)
    assert session.counters.implausible_poses >= 1
    assert all(np.linalg.norm(p.accel_mps2) > 0.5 * G for p in poses)
    calibrates(session)
    # A stream in g: every still interval is implausible (|a| ~ 1), and /calibrate says what it looks like.
    in_g, _ = per_message(t, accel / G, gyro)
    verdict = in_g.calibrate()
    assert not verdict.success and "looks like g, not m/s^2" in verdict.message


# ---------------------------------------------------------------- frozen stretches
@FAST
@given(kind=st.sampled_from(["whole sample", "gyro at zero", "accel stuck"]), seconds=st.floats(5.0, 40.0),
       where=st.sampled_from(["first", "between poses"]), rate_hz=st.sampled_from([50.0, 200.0]))
def test_a_frozen_stretch_does_not_poison_the_noise_floor(kind, seconds, where, rate_hz):
    errors, t, accel, gyro = session_stream(rate_hz=rate_hz)
    period = int(1e9 / rate_hz)
    count = int(seconds * rate_hz)
    at = 1 if where == "first" else int((6 * 4.5 + 3.2) * rate_hz)  # start of the 7th turn
    rng = np.random.default_rng(count)
    level = errors.raw_from_true(np.tile([0.0, 0.0, G], (count, 1))) + rng.normal(0.0, 0.02, (count, 3))
    live_gyro = rng.normal(0.0, 0.002, (count, 3)) + errors.gyro_bias_radps
    block = {"whole sample": (np.tile(level[0], (count, 1)), np.tile(live_gyro[0], (count, 1))),
             "gyro at zero": (level, np.zeros((count, 3))),  # held still on a table, gyro warming up
             "accel stuck": (np.tile(level[0], (count, 1)), live_gyro)}[kind]
    t, accel, gyro = insert(t, accel, gyro, at, *block, period)
    session, poses = assert_both_doors_agree(t, accel, gyro)
    c = session.counters
    frozen_samples = Settings().frozen_samples
    if kind == "gyro at zero":
        assert c.gyro_frozen == count - frozen_samples + 1 and c.frozen == 0
    else:
        assert c.frozen == count - frozen_samples + 1
    # Every dwell of the session is a pose (the first dwell, level as the block, may begin in a live block).
    session_poses = [p for p in poses if p.end_ns > t[at + count - 1] or p.end_ns < t[at]]
    assert len(session_poses) >= POSES
    np.testing.assert_allclose(calibrates(session).bias, errors.bias_mps2, atol=3 * MG)


# ---------------------------------------------------------------- stamps
@FAST
@given(position=st.floats(0.05, 0.95), ahead_ns=st.integers(3 * 10**9, DAY_NS))
def test_one_message_stamped_far_ahead_costs_at_most_one_pose(position, ahead_ns):
    errors, t, accel, gyro = session_stream(rate_hz=100.0)
    t[int(position * len(t))] += ahead_ns
    session, poses = assert_both_doors_agree(t, accel, gyro)
    assert session.counters.stamp_jumps == 1 and session.counters.stamp_backwards == 0
    assert len(session.store) >= POSES - 1
    calibrates(session)


@FAST
@given(position=st.floats(0.05, 0.95), back_ns=st.integers(3 * 10**9, DAY_NS), repeats=st.integers(1, 3))
def test_a_publisher_restarting_with_earlier_stamps_resumes(position, back_ns, repeats):
    errors, t, accel, gyro = session_stream(rate_hz=100.0)
    for k in range(repeats):  # it may restart several times
        t[int((position + k * 0.02) % 1.0 * len(t)):] -= back_ns
    session, poses = assert_both_doors_agree(t, accel, gyro)
    assert session.counters.stamp_jumps == repeats and session.counters.stamp_backwards == 0
    assert len(session.store) >= POSES - repeats
    calibrates(session)


def test_a_small_step_back_is_still_dropped_not_a_jump():
    _, t, accel, gyro = session_stream()
    t[5000] = t[5000 - 300]  # 1.5 s back: under STAMP_JUMP_WINDOWS windows
    session, _ = assert_both_doors_agree(t, accel, gyro)
    assert (session.counters.stamp_backwards, session.counters.stamp_jumps) == (1, 0)


# ---------------------------------------------------------------- all together, and paused stretches
@FAST
@given(data=st.data())
def test_both_doors_agree_with_faults_and_pauses_anywhere(data):
    _, t, accel, gyro = session_stream(seed=data.draw(st.integers(1, 5)), rate_hz=100.0)
    n = len(t)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**16)))
    for _ in range(data.draw(st.integers(0, 4))):
        i = int(rng.integers(1, n - 400))
        fault = data.draw(st.sampled_from(["zero", "frozen", "gyro0", "ahead", "restart", "nan", "back"]))
        if fault == "zero":
            accel[i:i + 150] = 0.0
        elif fault == "frozen":
            accel[i:i + 300], gyro[i:i + 300] = accel[i], gyro[i]
        elif fault == "gyro0":
            gyro[i:i + 300] = 0.0
        elif fault == "ahead":
            t[i] += DAY_NS
        elif fault == "restart":
            t[i:] -= int(rng.integers(3, 10_000)) * 10**9
        elif fault == "nan":
            accel[i, 1] = np.nan
        else:
            t[i] = t[i - 20]
    paused = np.zeros(n, dtype=bool)
    for _ in range(data.draw(st.integers(0, 3))):
        i = int(rng.integers(0, n))
        paused[i:i + int(rng.integers(1, 1500))] = True
    assert_both_doors_agree(t, accel, gyro, paused=paused)


def test_while_paused_nothing_is_collected_and_the_interval_in_progress_is_dropped():
    _, t, accel, gyro = session_stream(rate_hz=100.0)
    paused = np.zeros(len(t), dtype=bool)
    middle_of_fourth_dwell = int((3 * 4.5 + 1.5) * 100)
    paused[middle_of_fourth_dwell:middle_of_fourth_dwell + 2000] = True  # 20 s from mid-dwell
    session, poses = assert_both_doors_agree(t, accel, gyro, paused=paused)
    lo, hi = t[middle_of_fourth_dwell - 25], t[middle_of_fourth_dwell + 2000]  # the trim before the pause
    assert all(p.end_ns < lo or p.start_ns > hi for p in poses)
    assert session.counters.samples_paused == 2000 and session.counters.problems() == 0


def test_collection_resumes_when_no_reason_to_pause_is_left():
    pause = CollectionPause()
    pause.set_collecting(False, "armed")
    pause.set_collecting(False, "calibration/pause")
    pause.set_collecting(True, "armed")
    assert not pause.collecting and pause.reasons == ("calibration/pause",)
    pause.set_collecting(True, "calibration/pause")
    assert pause.collecting


# ---------------------------------------------------------------- the detector itself
def still_then_shaking(rate_hz=50.0, still_s=30.0, shaking_s=900.0, vibration=0.25, seed=0):
    rng = np.random.default_rng(seed)
    n_still, n_shake = int(still_s * rate_hz), int(shaking_s * rate_hz)
    t = (np.arange(n_still + n_shake) * 1e9 / rate_hz).astype(np.int64)
    accel = np.tile([0.0, 0.0, G], (len(t), 1)) + rng.normal(0.0, 0.02, (len(t), 3))
    accel[n_still:] += rng.normal(0.0, vibration, (n_shake, 3))
    gyro = rng.normal(0.0, 0.002, (len(t), 3))
    gyro[n_still:] += rng.normal(0.0, 0.05, (n_shake, 3))
    return t, accel, gyro


@pytest.mark.parametrize("rise", [1.0, 1.5, 3.0])
def test_the_learned_floor_stays_within_its_bound_of_the_quietest_floor(rise):
    """15 min of vibration after 30 s at rest: the thresholds never exceed k_sigma * rise^2 * the quietest
    floor (nor the ceilings), so no window of it is still; without the bound (rise 1000) it is learned."""
    t, accel, gyro = still_then_shaking()
    detector = StaticDetector(DetectorConfig(max_floor_rise=rise, accel_noise_ceiling=15 * MG, gyro_noise_ceiling=0.05))
    first_shake = int(30 * 50)
    poses = []
    for first in range(0, len(t), 500):  # the node's worker: parts of the stream, each checked after
        part = slice(first, first + 500)
        poses += detector.process(t[part], accel[part], gyro[part], final=first + 500 >= len(t))
        if first >= first_shake + 100 and first + 500 < len(t):
            quiet_accel, quiet_gyro = detector.quietest_floors
            accel_limit, gyro_limit = detector.thresholds
            assert accel_limit <= detector.config.k_sigma * quiet_accel * rise**2 * (1 + 1e-12)
            assert gyro_limit <= detector.config.gyro_k_sigma * quiet_gyro * rise**2 * (1 + 1e-12)
            assert accel_limit <= 3 * (15 * MG) ** 2 * (1 + 1e-12)
            assert not detector.holding_still
    assert all(p.end_ns < t[first_shake] for p in poses)
    unbounded = StaticDetector(DetectorConfig(max_floor_rise=1000.0)).process(t, accel, gyro)
    assert any(p.start_ns > t[first_shake] for p in unbounded)  # the failure the bound prevents


def test_repeated_samples_never_feed_the_floor():
    """A window mostly of repeated samples is no evidence: a stream that starts frozen learns nothing from
    it, and its floor is the live noise's, not zero."""
    rng = np.random.default_rng(1)
    frozen = np.tile([0.1, 0.2, G], (400, 1))
    live = np.tile([0.1, 0.2, G], (2000, 1)) + rng.normal(0.0, 0.02, (2000, 3))
    accel = np.vstack([frozen, live])
    t = (np.arange(len(accel)) * 5_000_000).astype(np.int64)
    detector = StaticDetector()
    detector.process(t[:400], accel[:400], final=False)
    assert detector.noise_floor_accel_var is None and detector.thresholds == (None, None)
    detector.process(t[400:], accel[400:])
    # The 5 % quantile of windows of 100 samples: close to (and not far below) the noise's variance.
    assert 0.5 * 0.02**2 < detector.noise_floor_accel_var < 1.2 * 0.02**2
    assert detector.quietest_floors[0] > 0.5 * 3 * 0.02**2


@FAST
@given(data=st.data())
def test_no_pose_spans_a_restart_or_a_discard(data):
    """Each pose lies within one segment between breaks (a clock restart or a pause), on that segment's
    own clock, and is the mean of exactly its rows there; at most two poses per break are lost."""
    s, t, breaks = stream_with_breaks(data)
    detector = StaticDetector()
    found = detector.find(t, s.accel_raw, s.gyro_raw, breaks=breaks)
    breaks[0] = 0  # a break before the first sample changes nothing
    firsts = np.concatenate([[0], np.flatnonzero(breaks)])
    stops = np.concatenate([firsts[1:], [len(t)]])
    assert len(found) >= 6 - 2 * len(firsts[1:])
    for pose, segment in ((each.pose, each.segment) for each in found):
        rows = np.arange(firsts[segment], stops[segment])
        inside = rows[(t[rows] >= pose.start_ns) & (t[rows] <= pose.end_ns)]
        assert len(inside) == pose.samples and t[inside[0]] == pose.start_ns and t[inside[-1]] == pose.end_ns
        np.testing.assert_allclose(pose.accel_mps2, s.accel_raw[inside].mean(axis=0), rtol=0, atol=1e-12)
        assert pose.duration_s >= detector.config.min_hold_s


# ---------------------------------------------------------------- the pose store
def pose(mean, sigma=0.02, samples=600, end_ns=10**9, temperature=None):
    mean = np.asarray(mean, dtype=float)
    return Pose(accel_mps2=mean, accel_cov=np.eye(3) * sigma**2, samples=samples, start_ns=end_ns - 10**9,
                end_ns=end_ns, temperature_degc=temperature)


@settings(max_examples=60, deadline=None)
@given(sigma=st.floats(1e-4, 0.3), samples=st.integers(10, 100_000), tolerance_mg=st.floats(0.0, 10.0),
       direction=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
           lambda d: np.linalg.norm(d) > 0.1))
def test_means_agree_exactly_within_their_standard_errors_plus_the_tolerance(sigma, samples, tolerance_mg, direction):
    """Mahalanobis test at 99.9 %: two poses' means agree up to sqrt(chi2) of (2 se^2 + tolerance^2) apart."""
    unit = np.asarray(direction) / np.linalg.norm(direction)
    tolerance = tolerance_mg * MG
    spread = np.sqrt(2 * sigma**2 / samples + tolerance**2)
    held = pose([0.0, 0.0, G], sigma, samples)
    for factor, agree in ((0.99, True), (1.01, False)):
        other = pose(held.accel_mps2 + unit * factor * np.sqrt(AGREEMENT_CHI2) * spread, sigma, samples)
        assert means_agree(held, other, tolerance) is agree


def test_a_disagreeing_pose_is_kept_apart_counted_and_the_held_mean_untouched():
    session = CalibrationSession()
    ground = pose([0.0, 0.0, G], sigma=0.02, samples=600)
    session.add_pose(ground)
    same = pose([1e-4, 0.0, G - 1e-4], sigma=0.02, samples=600, end_ns=2 * 10**9)
    assert session.add_pose(same).merged
    # A hover that passed as still: 60 s of vibration whose mean is 30 mg off the ground pose.
    hover = pose([0.0, 0.0, G + 30 * MG], sigma=0.25, samples=12_000, end_ns=3 * 10**9)
    event = session.add_pose(hover)
    assert not event.merged and event.disagreed
    assert session.counters.merge_disagreements == 1
    assert len(session.store) == 2
    assert abs(session.store.poses[0].accel_mps2[2] - G) < 1e-3
    assert "merge_disagreements" in Counters.INFORMATIONAL  # a re-held face is normal: no warning


def test_at_capacity_a_repeated_orientation_gives_way_before_a_lone_one():
    store = PoseStore(capacity=8)
    faces = [np.array(v, float) * G for v in ([1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1])]
    for i, face in enumerate(faces):
        store.add(pose(face, end_ns=(i + 1) * 10**9))
    for k in range(30):  # a vehicle parked level for half an hour, each minute a little different
        store.add(pose([0.0, 0.0, G + (k + 1) * 10 * MG], end_ns=(100 + k) * 10**9))
    assert len(store) == 8
    held = np.array([p.direction for p in store.poses])
    for face in faces:
        assert np.max(held @ (face / G)) > 0.99, face  # every face is still held
