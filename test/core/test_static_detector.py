"""Static detector on real recordings (against the references in ../shared/data/real/README.md) and
on synthetic streams at 50 Hz and 2 kHz."""
import csv
import gzip

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration import MG, CalibrationError, fit
from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.core.stream.detector_batch import DetectorConfig

from helpers.detector_streams import assert_same_poses, synthetic_stream

G = 9.80665


def load_imu_tk(shared):
    """Xsens MTi at 100 Hz: raw unsigned counts (~4060 counts/g, centred near 32768)."""
    accel = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_acc.txt.gz")))
    gyro = np.loadtxt(gzip.open(shared("real/imu_tk/xsens_gyro.txt.gz")))
    return (accel[:, 0] * 1e9).astype(np.int64), accel[:, 1:], gyro[:, 1:]


def load_mpu6050(shared):
    """MPU-6050 at 100 Hz: int16 counts (~16.4k counts/g); five header lines then a column row."""
    with open(shared("real/mpu6050_tomisuarez2/example_data_calibration.csv")) as f:
        rows = list(csv.reader(f))[6:]
    data = np.array(rows, dtype=float)
    return (np.arange(len(data)) * 10_000_000).astype(np.int64), data[:, :3], data[:, 3:]


def detect_imu_tk_poses(shared):
    t, accel, gyro = load_imu_tk(shared)
    return StaticDetector().process(t, accel, gyro)


def detect_mpu6050_poses(shared):
    t, accel, gyro = load_mpu6050(shared)
    return StaticDetector().process(t, accel, gyro)


def distinct_orientations(directions, angle_deg=10.0):
    centres = []
    for d in directions:
        if not any(d @ c > np.cos(np.radians(angle_deg)) for c in centres):
            centres.append(d)
    return len(centres)


def raw_residual_mg(accel_counts, offset, counts_per_g):
    """| |a| - 1 g | of the raw data read with the datasheet's nominal offset and sensitivity."""
    return np.abs(np.linalg.norm(accel_counts - offset, axis=1) / counts_per_g - 1.0) * 1000.0


def test_imu_tk_xsens_intervals_and_fit(shared):
    poses = detect_imu_tk_poses(shared)
    # imu_tk's own detector finds 38 static intervals; ours may split or merge one or two where a hand
    # paused briefly (window lengths differ), so +-4.
    assert 34 <= len(poses) <= 42, len(poses)
    directions = np.array([p.accel_mps2 - 32768 for p in poses])
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    assert 14 <= distinct_orientations(directions) <= 16
    first = poses[0]
    assert first.start_ns < 3e9 and first.end_ns > 48e9  # the first ~50 s are still
    assert first.gyro_radps is not None

    result = fit(poses, gravity=9.81744)  # the authors' local g
    assert result.success, result.message
    fitted = result.calibration.quality.residual_rms_mg
    raw = np.sqrt(np.mean(raw_residual_mg(np.array([p.accel_mps2 for p in poses]), 32768, 4060) ** 2))
    assert fitted < 0.5, fitted  # Xsens-grade part: pose means fit the sphere to a fraction of a mg
    assert fitted < raw / 20, (fitted, raw)


def test_mpu6050_matches_reference_intervals(shared):
    reference = np.loadtxt(shared("real/mpu6050_tomisuarez2/static_intervals_reference.csv"), delimiter=",").astype(int)
    poses = detect_mpu6050_poses(shared)
    intervals = [(p.start_ns // 10_000_000, p.end_ns // 10_000_000) for p in poses]
    assert len(intervals) == reference.shape[1] == 10
    for start, end in reference.T:
        overlap = max(max(0, min(end, e) - max(start, s)) for s, e in intervals)
        # The reference's intervals are short cores of each still phase (one is 2 samples long); every
        # one lies inside one of ours, apart from the first sample or two of the 36.5 s initial period.
        assert overlap >= 0.9 * max(1, end - start) - 2, (start, end, intervals)

    result = fit(poses)
    assert result.success, result.message
    raw = np.sqrt(np.mean(raw_residual_mg(np.array([p.accel_mps2 for p in poses]), 0.0, 16384) ** 2))
    fitted = result.calibration.quality.residual_rms_mg
    # 10 poses, 9 parameters: one degree of freedom, so the residual is tiny by construction; what
    # matters is that the raw sensor is tens of mg off and the fit is not.
    assert raw > 10.0 and fitted < raw / 10, (fitted, raw)


@pytest.mark.parametrize("rate_hz", [50.0, 2000.0])
def test_same_settings_work_from_50_hz_to_2_khz(rate_hz):
    rng = np.random.default_rng(int(rate_hz))
    t, accel, directions = synthetic_stream(rate_hz, rng)
    poses = StaticDetector().process(t, accel)
    assert len(poses) == len(directions)
    for pose, direction in zip(poses, directions):
        standard_error = 0.02 / np.sqrt(pose.samples)
        assert np.all(np.abs(pose.accel_mps2 - G * direction) < 5 * standard_error + 1e-9)
        assert 1.5 < pose.duration_s <= 3.0




def test_bad_samples_are_skipped_and_counted():
    """NaN rows and stamps not after the last are skipped and counted; the poses are those of the stream
    without them."""
    rng = np.random.default_rng(4)
    t, accel, _ = synthetic_stream(100.0, rng)
    clean = StaticDetector().process(t, accel)
    bad_t, bad_accel, inserted = [], [], 0
    for i in range(len(t)):
        if i % 97 == 0 and i:
            bad_t += [int(t[i]) - 5, int(t[i - 1])]  # NaN; then a stamp not after the last
            bad_accel += [[np.nan, 0.0, 9.8], [0.0, 0.0, 9.8]]
            inserted += 2
        bad_t.append(int(t[i]))
        bad_accel.append(accel[i])
    detector = StaticDetector()
    poses = detector.process(np.array(bad_t, dtype=np.int64), np.array(bad_accel))
    assert detector.rejected_samples == inserted and detector.rejected_out_of_range == 0
    assert len(clean) == 8
    assert_same_poses(poses, clean)


def test_gap_longer_than_a_window_ends_the_interval():
    rng = np.random.default_rng(5)
    t = np.concatenate([np.arange(0, 3e9, 1e7), np.arange(8e9, 11e9, 1e7)]).astype(np.int64)
    accel = np.tile([0.0, 0.0, G], (len(t), 1)) + rng.normal(0, 0.02, (len(t), 3))
    poses = StaticDetector(DetectorConfig(warmup_s=0.5)).process(t, accel)
    assert all(p.end_ns < 3e9 or p.start_ns >= 8e9 for p in poses)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(window_s=0), "window_s"),
        (dict(min_hold_s=-1), "min_hold_s"),
        (dict(k_sigma=float("nan")), "k_sigma"),
        (dict(accel_var_threshold="low"), "accel_var_threshold"),
        (dict(trim_s=5.0), "trim_s"),
        (dict(noise_quantile=0.9), "noise_quantile"),
    ],
)
def test_bad_settings_name_the_argument(kwargs, name):
    with pytest.raises(CalibrationError, match=name):
        StaticDetector(DetectorConfig(**kwargs))


def test_a_stream_that_starts_moving_gives_no_pose_from_the_warmup():
    rng = np.random.default_rng(8)
    t, accel, directions = synthetic_stream(100.0, rng)
    moving = (t >= 3e9) & (t < 4e9)  # the first turn, 1 s long
    poses = StaticDetector().process(t[moving.argmax():] - t[moving.argmax()], accel[moving.argmax():])
    assert len(poses) == len(directions) - 1
    assert all(np.abs(p.accel_mps2 - G * d).max() < 0.01 for p, d in zip(poses, directions[1:]))


def test_peek_gives_the_held_pose_without_ending_it():
    rng = np.random.default_rng(12)
    t, accel, _ = synthetic_stream(100.0, rng)  # the stream ends inside the last still dwell
    detector = StaticDetector()
    assert detector.process(t, accel, final=False) and detector.holding_still
    held = detector.peek_open()
    again = detector.peek_open()
    assert held is not None and again is not None and again.samples == held.samples  # no state changed
    (flushed,) = detector.process(np.zeros(0, np.int64), np.zeros((0, 3)))
    np.testing.assert_array_equal(held.accel_mps2, flushed.accel_mps2)
    assert (held.start_ns, held.end_ns, held.samples) == (flushed.start_ns, flushed.end_ns, flushed.samples)
    assert np.abs(held.accel_mps2 - G * np.array([0.0, -0.6, 0.8])).max() < 0.01
    assert not detector.continuing


@st.composite
def dwells_and_turns(draw):
    """Still dwells (2..6 s, the first 3..6 s) at random orientations joined by turns (0.6..2 s, smooth
    steps), at a rate of 50 Hz..1 kHz, 0.2 mg of noise: (stamps, accel, [(first, stop) rows of each
    dwell], true means)."""
    rate_hz = draw(st.sampled_from([50.0, 100.0, 400.0, 1000.0]))
    count = draw(st.integers(2, 6))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    directions = rng.normal(size=(count, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    pieces, dwells, rows = [], [], 0
    for k in range(count):
        # The first dwell also warms the floor up (2 s of full windows): it must outlast that.
        hold = int(draw(st.floats(3.0 if k == 0 else 2.0, 6.0)) * rate_hz)
        pieces.append(np.tile(G * directions[k], (hold, 1)))
        dwells.append((rows, rows + hold))
        rows += hold
        if k + 1 < count:
            turn = int(draw(st.floats(0.6, 2.0)) * rate_hz)
            s = (np.arange(1, turn + 1) / turn)[:, None]
            s = s * s * (3 - 2 * s)
            path = (1 - s) * directions[k] + s * directions[k + 1]
            pieces.append(G * path / np.linalg.norm(path, axis=1)[:, None])
            rows += turn
    truth = np.vstack(pieces)
    t = (np.arange(len(truth)) * (1e9 / rate_hz)).astype(np.int64)
    return t, truth + rng.normal(0, 0.002, truth.shape), dwells, G * directions


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=dwells_and_turns(), parts=st.lists(st.floats(0.0, 1.0), max_size=6))
def test_each_dwell_is_one_pose_with_its_mean_to_a_tenth_of_a_mg(data, parts):
    """Known still/turn sequences: one pose per dwell, inside it, its mean within 0.1 mg of the true
    gravity vector (0.2 mg noise over >= 75 samples: 6 standard errors), in any parts."""
    t, accel, dwells, truth = data
    cuts = sorted({int(f * (len(t) - 2)) + 1 for f in parts})
    detector, poses = StaticDetector(), []
    for first, stop in zip([0, *cuts], [*cuts, len(t)]):
        poses += detector.process(t[first:stop], accel[first:stop], final=stop == len(t))
    assert len(poses) == len(dwells)
    for pose, (first, stop), mean in zip(poses, dwells, truth):
        assert t[first] <= pose.start_ns and pose.end_ns <= t[stop - 1]
        assert pose.duration_s >= 1.0
        assert np.abs(pose.accel_mps2 - mean).max() < 0.1 * MG
