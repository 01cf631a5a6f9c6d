"""StaticDetector against hostile samples: one finite but absurd value (gyro 2e154, accel 1e300, -1e200)
in the middle of a still interval must neither crash process() nor cost the rest of the recording, whole
or in parts.

What is asserted:
  * a sample beyond the hard internal guard (or the user's accel_limit / gyro_limit) is rejected and
    counted (rejected_samples and rejected_out_of_range); the poses are then *identical* (count,
    stamps, sample counts; means within 1e-9) to those of the same stream with that sample deleted;
  * a large value below the guard is accepted: it breaks the still interval it falls in (the window is
    not still while it is inside), so that dwell may give a pose before and one after it, but every
    other pose is unchanged, no pose holds a non-finite value, and once it has left the window the
    detector finds still poses again (a window's sums hold only its own samples);
  * a glitch as the very first sample costs at most the warm-up pose;
  * process() in parts (cut at thirds and either side of each hostile row) gives the poses and counts of
    one call on all these streams, also when the hole a rejected sample leaves makes a window inside a
    still interval not full;
  * property (hypothesis): arbitrary finite floats, huge magnitudes included, never make process() or
    peek_open() raise, never put a non-finite value into the noise floor's histogram, and every pose has
    finite accel_mps2 / accel_cov (and gyro, temperature); the rejection counts in any parts agree, and
    on noisy streams with hostile values injected the poses agree too (not asserted on wholly arbitrary
    floats, where a window variance can fall exactly on a histogram bin edge and the rounding of other
    blocks may decide differently).
"""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration import CalibrationError
from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.core.stream.detector_batch import DetectorConfig
from accel_calibration.core.stream.noise_floor import FloorConfig, VarianceFloor
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

RATE_HZ = 200.0
DWELL_S = 6.0


def still_stream(seed: int = 1):
    """Four 6 s dwells joined by 1.5 s turns at 200 Hz, with noise, gyro and a slowly rising temperature."""
    rng = np.random.default_rng(seed)
    errors = SensorErrors(noise_mps2=0.02, gyro_noise_radps=0.002, gyro_bias_radps=np.array([0.01, -0.02, 0.005]))
    imu = SyntheticImu(errors, spread_orientations(4, rng), dwell_s=DWELL_S, move_s=1.5, rate_hz=RATE_HZ,
                       temperature_degc=lambda t: 25.0 + 0.05 * t, seed=seed)
    s = imu.samples()
    return s.t_ns, s.accel_raw, s.gyro_raw, s.temperature_degc


def middle_of_second_dwell(t_ns) -> int:
    """Index of the sample in the middle of the second still dwell (a pose that is not the warm-up one)."""
    start = DWELL_S + 1.5
    return int(np.searchsorted(t_ns, int((start + DWELL_S / 2) * 1e9)))


def assert_state_finite(detector):
    state = detector.state
    for floor in (state.accel_floor, state.gyro_floor):
        assert np.all(np.isfinite(floor.counts)) and math.isfinite(floor.total)
        assert floor.value is None or math.isfinite(floor.value)
    assert not math.isnan(state.accel_quietest) and not math.isnan(state.gyro_quietest)


def streamed(detector, t, accel, gyro, temps, cuts=()):
    """process() over the parts between `cuts` (the last one final), checking the learned state stays
    finite and the interval held at each cut is a finite pose."""
    bounds = [0, *sorted(c for c in set(cuts) if 0 < c < len(t)), len(t)]
    poses = []
    for first, stop in zip(bounds[:-1], bounds[1:]):
        part = slice(first, stop)
        poses += detector.process(t[part], accel[part], gyro[part], temps[part], final=stop == len(t))
        assert_state_finite(detector)
        if stop < len(t) and (held := detector.peek_open()) is not None:
            assert_finite(held)
    return poses


def assert_finite(pose):
    assert np.all(np.isfinite(pose.accel_mps2)) and np.all(np.isfinite(pose.accel_cov))
    assert pose.gyro_radps is None or np.all(np.isfinite(pose.gyro_radps))
    assert pose.temperature_degc is None or math.isfinite(pose.temperature_degc)
    assert pose.temperature_spread_degc is None or math.isfinite(pose.temperature_spread_degc)


def assert_same_poses(a_list, b_list, atol=1e-9):
    assert len(a_list) == len(b_list), ([(p.start_ns, p.end_ns) for p in a_list],
                                        [(p.start_ns, p.end_ns) for p in b_list])
    for a, b in zip(a_list, b_list):
        assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
        np.testing.assert_allclose(a.accel_mps2, b.accel_mps2, rtol=0, atol=atol)
        np.testing.assert_allclose(a.accel_cov, b.accel_cov, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(a.gyro_radps, b.gyro_radps, rtol=0, atol=atol)
        assert a.temperature_degc == pytest.approx(b.temperature_degc, abs=atol)


def assert_parts_equal_whole(t, accel, gyro, temps, **settings):
    """Whole, and in parts cut at thirds and either side of every hostile row: the same poses and counts."""
    config = DetectorConfig(**settings)
    whole_detector, parts_detector = StaticDetector(config), StaticDetector(config)
    whole = whole_detector.process(t, accel, gyro, temps)
    odd = np.flatnonzero((np.abs(accel) > 100).any(axis=1) | (np.abs(gyro) > 100).any(axis=1))
    cuts = [len(t) // 3, 2 * len(t) // 3, *odd.tolist(), *(odd + 1).tolist()]
    parts = streamed(parts_detector, t, accel, gyro, temps, cuts)
    for pose in whole:
        assert_finite(pose)
    assert_same_poses(parts, whole, atol=1e-12)
    assert parts_detector.rejected_samples == whole_detector.rejected_samples
    assert parts_detector.rejected_out_of_range == whole_detector.rejected_out_of_range
    return whole


HOSTILE = [
    ("gyro 2e154", "gyro", (2e154, 0.0, 0.0)),
    ("accel 1e300", "accel", (0.0, 1e300, 0.0)),
    ("accel -1e200", "accel", (-1e200, 0.0, 0.0)),
    ("all axes 1.7e308", "accel", (1.7e308, -1.7e308, 1.7e308)),
]


@pytest.mark.parametrize("name, sensor, value", HOSTILE, ids=[h[0] for h in HOSTILE])
def test_one_absurd_sample_is_rejected_and_changes_nothing(name, sensor, value):
    t, accel, gyro, temps = still_stream()
    i = middle_of_second_dwell(t)
    accel_h, gyro_h = accel.copy(), gyro.copy()
    (gyro_h if sensor == "gyro" else accel_h)[i] = value

    detector = StaticDetector()
    poses = streamed(detector, t, accel_h, gyro_h, temps)  # must not raise
    clean = streamed(StaticDetector(), *(np.delete(x, i, axis=0) for x in (t, accel, gyro, temps)))

    assert len(clean) == 4  # one pose per dwell: the stream is a fair test
    for pose in poses:
        assert_finite(pose)
    assert_same_poses(poses, clean)  # identical to the stream without that sample
    assert detector.rejected_samples == 1 and detector.rejected_out_of_range == 1
    assert_parts_equal_whole(t, accel_h, gyro_h, temps)


def test_several_absurd_samples_and_the_stream_still_recovers():
    t, accel, gyro, temps = still_stream(2)
    accel_h, gyro_h = accel.copy(), gyro.copy()
    i = middle_of_second_dwell(t)
    hits = [i, i + 1, i + 50, i + 400]
    gyro_h[hits[0]] = 2e154
    accel_h[hits[1], 1] = 1e300
    accel_h[hits[2], 0] = -1e200
    gyro_h[hits[3], 2] = -3e250
    detector = StaticDetector()
    poses = streamed(detector, t, accel_h, gyro_h, temps)
    clean = streamed(StaticDetector(), *(np.delete(x, hits, axis=0) for x in (t, accel, gyro, temps)))
    assert_same_poses(poses, clean)
    assert detector.rejected_samples == detector.rejected_out_of_range == len(hits)
    assert_parts_equal_whole(t, accel_h, gyro_h, temps)


@pytest.mark.parametrize("sensor, value, limits", [
    ("accel", (0.0, 0.0, 500.0), dict(accel_limit=160.0)),  # ~16 g part: 500 m/s^2 is a glitch
    ("gyro", (0.0, -40.0, 0.0), dict(gyro_limit=35.0)),  # ~2000 deg/s part
])
def test_user_limits_reject_what_the_sensor_cannot_read(sensor, value, limits):
    t, accel, gyro, temps = still_stream(3)
    i = middle_of_second_dwell(t)
    accel_h, gyro_h = accel.copy(), gyro.copy()
    (gyro_h if sensor == "gyro" else accel_h)[i] = value
    detector = StaticDetector(DetectorConfig(**limits))
    poses = streamed(detector, t, accel_h, gyro_h, temps)
    clean = streamed(StaticDetector(DetectorConfig(**limits)),
                     *(np.delete(x, i, axis=0) for x in (t, accel, gyro, temps)))
    assert_same_poses(poses, clean)
    assert detector.rejected_out_of_range == 1
    assert_parts_equal_whole(t, accel_h, gyro_h, temps, **limits)


@pytest.mark.parametrize("sensor, axis, value", [("gyro", 0, 1e9), ("accel", 2, -3e11), ("gyro", 1, 7e5)])
def test_a_large_accepted_sample_only_breaks_its_own_dwell(sensor, axis, value):
    """Below the guard and with no user limit the sample is data: the window holding it is not still,
    so the second dwell is cut around it. Asserted: the other dwells' poses are unchanged; the second
    dwell gives a pose ending before the spike and one starting after it left the window (the sums
    recovered: without that the rest of the recording is lost); nothing non-finite; parts == whole."""
    t, accel, gyro, temps = still_stream(4)
    i = middle_of_second_dwell(t)
    accel_h, gyro_h = accel.copy(), gyro.copy()
    (gyro_h if sensor == "gyro" else accel_h)[i, axis] = value

    poses = streamed(StaticDetector(), t, accel_h, gyro_h, temps)
    clean = streamed(StaticDetector(), t, accel, gyro, temps)
    assert len(clean) == 4
    for pose in poses:
        assert_finite(pose)
    assert len(poses) == 5
    assert_same_poses([poses[0], *poses[3:]], [clean[0], *clean[2:]])
    before, after = poses[1], poses[2]
    spike = int(t[i])
    assert clean[1].start_ns == before.start_ns and before.end_ns < spike
    assert after.start_ns > spike and after.end_ns == clean[1].end_ns
    for part in (before, after):
        assert part.duration_s > 1.0
        # Same dwell: means agree with the clean pose's within the noise (0.02 m/s^2 per sample).
        assert np.all(np.abs(part.accel_mps2 - clean[1].accel_mps2) < 0.01)
    assert_parts_equal_whole(t, accel_h, gyro_h, temps)


def test_a_rejected_sample_that_leaves_the_window_short_loses_no_other_sample():
    """With a 10-sample window the hole a rejected sample leaves makes one window not full (no verdict)
    inside the still interval: that sample still belongs to the pose."""
    t, accel, gyro, temps = still_stream(6)
    i = middle_of_second_dwell(t)
    accel_h = accel.copy()
    accel_h[i, 0] = 1e300
    settings_ = dict(window_s=0.05, min_hold_s=0.5)
    poses = assert_parts_equal_whole(t, accel_h, gyro, temps, **settings_)
    clean = streamed(StaticDetector(DetectorConfig(**settings_)),
                     *(np.delete(x, i, axis=0) for x in (t, accel, gyro, temps)))
    assert_same_poses(poses, clean)
    second = poses[1]
    assert second.start_ns < t[i] < second.end_ns
    assert second.samples == np.count_nonzero((t >= second.start_ns) & (t <= second.end_ns)) - 1


def test_a_glitch_as_the_very_first_sample_does_not_spoil_the_stream():
    """Accepted (below the guard), it is data: it spoils the warm-up (the loudest window held it), so the
    first pose starts later; every other pose is unchanged."""
    t, accel, gyro, temps = still_stream(7)
    gyro_h = gyro.copy()
    gyro_h[0, 1] = 1e9
    poses = streamed(StaticDetector(), t, accel, gyro_h, temps)
    clean = streamed(StaticDetector(), t, accel, gyro, temps)
    assert len(poses) == len(clean) == 4
    assert_same_poses(poses[1:], clean[1:])
    assert poses[0].start_ns > clean[0].start_ns and poses[0].end_ns == clean[0].end_ns
    assert_parts_equal_whole(t, accel, gyro_h, temps)


def test_bad_temperatures_are_treated_as_missing():
    t, accel, gyro, temps = still_stream(5)
    temps_h = temps.copy()
    i = middle_of_second_dwell(t)
    temps_h[i], temps_h[i + 1], temps_h[i + 2] = 1.7e308, np.inf, np.nan
    poses = streamed(StaticDetector(), t, accel, gyro, temps_h)
    for pose in poses:
        assert_finite(pose)
    assert len(poses) == 4
    assert_parts_equal_whole(t, accel, gyro, temps_h)


def test_variance_floor_ignores_non_finite_and_survives_extremes():
    floor = VarianceFloor(FloorConfig(0.05))
    values = floor.add(np.array([1e-3, np.nan, np.inf, -np.inf, 1.7e308, -5.0, 0.0, 5e-324]))
    assert floor.total == 5.0 and np.all(np.isfinite(floor.counts))
    assert floor.value is not None and math.isfinite(floor.value)
    assert np.all(np.isfinite(values))  # after the first add, the value in force is carried over the skipped


@pytest.mark.parametrize("name", ["accel_limit", "gyro_limit"])
@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), "big", True])
def test_bad_limits_name_the_argument(name, bad):
    with pytest.raises(CalibrationError, match=name):
        StaticDetector(DetectorConfig(**{name: bad}))


# ------------------------------------------------------------------ property
finite = st.floats(allow_nan=False, allow_infinity=False)
hostile_value = st.one_of(finite, st.sampled_from([1e12, -1e12, 1.0000001e12, 1e154, -1e200, 1e300,
                                                   1.7976931348623157e308, 5e-324]))


@st.composite
def hostile_streams(draw):
    """Still dwells at a few orientations (so that windows, the floor and poses happen), some values
    replaced by arbitrary finite floats; or wholly arbitrary finite floats. Settings in samples."""
    n = draw(st.integers(20, 300))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    dwells = draw(st.integers(1, 4))
    accel = np.repeat(rng.normal(0.0, 9.8, (dwells, 3)), -(-n // dwells), axis=0)[:n] + rng.normal(0.0, 0.02, (n, 3))
    gyro = rng.normal(0.0, 0.002, (n, 3))
    temps = 25.0 + rng.normal(0.0, 0.1, n)
    noisy = draw(st.integers(0, 3)) > 0
    if not noisy:
        accel = np.array(draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n)))
        gyro = np.array(draw(st.lists(st.tuples(finite, finite, finite), min_size=n, max_size=n)))
    for _ in range(draw(st.integers(0, 12))):
        row, column = draw(st.integers(0, n - 1)), draw(st.integers(0, 6))
        value = draw(hostile_value)
        if column < 3:
            accel[row, column] = value
        elif column < 6:
            gyro[row, column - 3] = value
        else:
            temps[row] = value
    step = draw(st.sampled_from([10_000_000, 1_000_000, 1]))  # 100 Hz, 1 kHz, 1 GHz stamps
    t = np.arange(n, dtype=np.int64) * step
    dt = step * 1e-9  # windows of ~10 samples, poses of 20..50
    settings_ = dict(window_s=10.5 * dt, min_hold_s=20 * dt, warmup_s=20 * dt, max_pose_s=50 * dt)
    if draw(st.booleans()):
        settings_["accel_var_threshold"] = 1e-2
    return t, accel, gyro, temps, settings_, noisy


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=hostile_streams(), cuts=st.lists(st.integers(1, 299), max_size=6))
def test_arbitrary_finite_floats_never_break_the_detector(data, cuts):
    t, accel, gyro, temps, settings_, noisy = data
    detector = StaticDetector(DetectorConfig(**settings_))
    poses = streamed(detector, t, accel, gyro, temps, cuts)
    for pose in poses:
        assert_finite(pose)
    whole_detector = StaticDetector(DetectorConfig(**settings_))
    whole = whole_detector.process(t, accel, gyro, temps)
    for pose in whole:
        assert_finite(pose)
    assert (whole_detector.rejected_samples, whole_detector.rejected_out_of_range) == (
        detector.rejected_samples, detector.rejected_out_of_range)
    if noisy:
        # Sensor noise under the hostile values: no window variance sits on a threshold or a histogram
        # bin edge, where other blocks' rounding could decide differently. So: the same poses.
        assert len(whole) == len(poses)
        for a, b in zip(whole, poses):
            assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
            np.testing.assert_allclose(a.accel_mps2, b.accel_mps2, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(a.accel_cov, b.accel_cov, rtol=1e-7, atol=1e-12)
            np.testing.assert_allclose(a.gyro_radps, b.gyro_radps, rtol=1e-9, atol=1e-9)
