"""A long recording goes through the batch detector in parts of bounded memory (process(final=False)
then a final part): whatever the cut points, the poses are those of one call (the same start, end and
sample count; means to 1e-12: window variances are summed over other blocks, the pose sums are
elementwise over the pose's own rows, no BLAS), and the learned state (floors, quietest floors, the
thresholds) is the one call's."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.core.stream.detector_batch import DetectorConfig
from accel_calibration.core.stream.noise_floor import FloorConfig, VarianceFloor

from helpers.detector_streams import assert_same_poses, stream_with_breaks, streams

FAST = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def in_parts(detector: StaticDetector, cuts, t_ns, accel, gyro=None, temperature_degc=None, breaks=None,
             flush=True):
    """process() over the parts between `cuts` (sorted row indices), the last one final."""
    bounds = [0, *cuts, len(t_ns)]
    poses, segments, offset = [], [], 0
    for k, (first, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
        part = slice(first, stop)
        final = k == len(bounds) - 2
        got = detector.find(t_ns[part], accel[part], None if gyro is None else gyro[part],
                            None if temperature_degc is None else temperature_degc[part],
                            None if breaks is None else breaks[part], flush=flush, final=final)
        poses += [found.pose for found in got]
        # a found pose's segment counts from the segment in force when the part began
        segments += [offset + found.segment for found in got]
        if breaks is not None:
            offset += int(np.count_nonzero(breaks[part][(1 if first == 0 else 0):]))
    return poses, segments


def assert_close_or_none(got, expected):
    assert [g is None for g in got] == [e is None for e in expected]
    for g, e in zip(got, expected):
        if e is not None:
            assert g == pytest.approx(e, rel=1e-9)


def cut_points(data, n):
    return sorted(set(data.draw(st.lists(st.integers(1, n - 1), min_size=1, max_size=8))))


@pytest.mark.parametrize("name, stream, options", list(streams()), ids=lambda v: v if isinstance(v, str) else "")
@FAST
@given(data=st.data())
def test_parts_give_the_poses_of_one_call(name, stream, options, data):
    n = len(stream["t_ns"])
    cuts = cut_points(data, n)
    config = DetectorConfig(**options)
    whole_detector, parts_detector = StaticDetector(config), StaticDetector(config)
    whole = whole_detector.process(**stream)
    parts, _ = in_parts(parts_detector, cuts, **stream)
    assert len(whole) >= 2
    assert_same_poses(parts, whole)
    assert parts_detector.rejected_samples == whole_detector.rejected_samples
    # The learned state is the one call's: the floors, the quietest floors, the thresholds.
    assert_close_or_none(parts_detector.thresholds, whole_detector.thresholds)
    assert_close_or_none(parts_detector.quietest_floors, whole_detector.quietest_floors)
    np.testing.assert_array_equal(parts_detector.state.accel_floor.counts, whole_detector.state.accel_floor.counts)


@FAST
@given(data=st.data())
def test_parts_with_restarts_and_discards(data):
    s, t, breaks = stream_with_breaks(data)
    cuts = cut_points(data, len(t))
    if data.draw(st.booleans()):  # a cut exactly at a break
        cuts = sorted(set(cuts) | {int(i) for i in np.flatnonzero(breaks) if i > 0})
    flush = data.draw(st.booleans())
    whole_detector, parts_detector = StaticDetector(), StaticDetector()
    whole_found = whole_detector.find(t, s.accel_raw, s.gyro_raw, breaks=breaks, flush=flush)
    whole = [found.pose for found in whole_found]
    parts, segments = in_parts(parts_detector, cuts, t, s.accel_raw, s.gyro_raw, breaks=breaks, flush=flush)
    assert_same_poses(parts, whole)
    assert segments == [found.segment for found in whole_found]
    assert parts_detector.rejected_samples == whole_detector.rejected_samples


def test_a_floor_carried_across_its_halving():
    """More windows than the floor's half-life (200k): the histogram halves inside a part and the parts
    still give the one call's floor state exactly."""
    rng = np.random.default_rng(7)
    n = 450_000
    t = np.arange(n, dtype=np.int64) * 1_000_000  # 1 kHz, 7.5 min, still
    accel = np.array([0.0, 0.0, 9.80665]) + rng.normal(0, 0.02, (n, 3))
    accel[200_000:260_000] += rng.normal(0, 0.5, (60_000, 3))  # a minute of vibration in the middle
    whole_detector, parts_detector = StaticDetector(), StaticDetector()
    whole = whole_detector.process(t, accel)
    parts, _ = in_parts(parts_detector, [70_001, 199_999, 200_000, 333_333], t, accel)
    assert_same_poses(parts, whole)
    np.testing.assert_array_equal(parts_detector.state.accel_floor.counts, whole_detector.state.accel_floor.counts)
    assert parts_detector.state.accel_floor.total == whole_detector.state.accel_floor.total
    assert parts_detector.thresholds == whole_detector.thresholds


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 3000), cuts=st.lists(st.floats(0.0, 1.0), max_size=8),
       half_life=st.sampled_from([50, 200_000]), quantile=st.sampled_from([0.01, 0.05, 0.3]))
def test_the_noise_floor_gives_the_same_values_and_state_in_any_batches(seed, n, cuts, half_life, quantile):
    """The floor's histogram counts are sums of halved integers (exact in floats): the values after each
    variance and the state left are the same, bit for bit, however the variances are batched; non-finite
    ones are skipped."""
    rng = np.random.default_rng(seed)
    variances = 10.0 ** rng.uniform(-16, 16, n)
    variances[rng.random(n) < 0.05] = rng.choice([np.nan, np.inf, -np.inf, 0.0, -1.0])
    config = FloorConfig(quantile, half_life)
    whole = VarianceFloor(config)
    expected = whole.add(variances)
    batched = VarianceFloor(config)
    bounds = sorted({0, n, *(int(f * n) for f in cuts)})
    got = np.concatenate([batched.add(variances[a:b]) for a, b in zip(bounds[:-1], bounds[1:])])
    np.testing.assert_array_equal(got, expected)
    np.testing.assert_array_equal(batched.counts, whole.counts)
    assert (batched.total, batched.since_decay, batched.since_query, batched.value) == (
        whole.total, whole.since_decay, whole.since_query, whole.value)
    assert np.all(np.isfinite(whole.counts)) and whole.total == pytest.approx(whole.counts.sum())
    finite = variances[np.isfinite(variances)]
    if len(finite) and half_life > n:
        # No halving: the value read at the last query (after 1 + 64 k variances) is the centre of the
        # log bin (1/10 decade) holding that many variances' `quantile` order statistic.
        seen = np.sort(finite[:1 + 64 * ((len(finite) - 1) // 64)])
        rank = max(int(np.ceil(quantile * len(seen))) - 1, 0)
        statistic = np.clip(seen[rank], 10.0**-14, 10.0**14 * 0.999) if seen[rank] > 0 else 10.0**-14
        assert abs(np.log10(whole.value) - np.log10(statistic)) <= 0.05 + 1e-9


def test_a_long_still_interval_is_not_copied_again_with_every_part():
    """The node feeds the detector 20 parts a second; a still interval stays open (carried) up to
    max_pose_s. Its rows are appended in place into a growing store, not copied with every part (at
    4 kHz that copy took a minute's stillness from 1.5 to 7 ms per part): over 60 s of parts the store
    is reallocated a handful of times, and the poses are those of one call."""
    rng = np.random.default_rng(4)
    rate, part, seconds = 4000, 200, 60
    n = rate * seconds
    t = np.arange(n, dtype=np.int64) * (10**9 // rate)
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.02, (n, 3))
    gyro = rng.normal(0, 0.002, (n, 3))
    detector = StaticDetector()
    poses, stores, previous = [], 0, None
    for start in range(0, n, part):
        rows = slice(start, start + part)
        poses += detector.process(t[rows], accel[rows], gyro[rows], final=False)
        carry = detector.state.carry
        buffer = None if carry is None or carry.store is None else carry.store.t
        assert buffer is not None and np.shares_memory(carry.t, buffer)  # the carried rows live in the store
        stores += buffer is not previous
        previous = buffer
    poses += detector.process(t[:0], accel[:0], gyro[:0], final=True)
    assert stores <= 12, stores
    whole = StaticDetector().process(t, accel, gyro)
    assert_same_poses(poses, whole)
