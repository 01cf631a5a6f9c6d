"""TemperatureFilter.series (replay, vectorised) against update/at one reading at a time (the node)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.core.temperature_filter import TemperatureFilter


def one_by_one(timeout_s, stamps, degc, samples, carried=None):
    """What the live session does: each reading when its stamp has come, `at` for each sample."""
    f = TemperatureFilter(timeout_s)
    if carried is not None:
        f.update(*carried)
    order = np.argsort(stamps, kind="stable")
    out, stale, k = np.full(len(samples), np.nan), 0, 0
    for i, t in enumerate(samples):
        while k < len(order) and stamps[order[k]] <= t:
            f.update(int(stamps[order[k]]), float(degc[order[k]]))
            k += 1
        value = f.at(int(t))
        if value is None:
            stale += f.value is not None
        else:
            out[i] = value
    for j in order[k:]:
        f.update(int(stamps[j]), float(degc[j]))
    return f, out, stale


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.sampled_from([0, 1, 2, 3, 17, 200, 2000]),
       timeout_s=st.sampled_from([0.5, 5.0]), shuffled=st.booleans(), carried=st.booleans())
def test_series_equals_the_readings_one_by_one(seed, n, timeout_s, shuffled, carried):
    rng = np.random.default_rng(seed)
    stamps = np.cumsum(rng.choice([1, 10**7, 10**8, 10**9, 3 * 10**9, 10**11], n)) + 10**9
    if shuffled:
        rng.shuffle(stamps)
    degc = 25 + np.cumsum(rng.normal(0, 0.5, n))
    bad = rng.random(n) < 0.1
    degc[bad] = rng.choice([np.nan, np.inf, -np.inf, 200.0, -61.0, 150.0, -60.0], int(bad.sum()))
    high = (int(stamps.max()) if n else 10) + 10**10
    samples = np.sort(rng.integers(0, high, 300))
    start = (int(rng.integers(0, 10**9)), float(rng.uniform(0, 40))) if carried else None
    batch = TemperatureFilter(timeout_s)
    if start is not None:
        batch.update(*start)
    series, stale = batch.series(stamps, degc, samples)
    reference, expected, expected_stale = one_by_one(timeout_s, stamps, degc, samples, start)
    if start is None:  # with a carried state, samples before the first reading differ by design
        np.testing.assert_array_equal(np.isnan(series), np.isnan(expected))
        np.testing.assert_allclose(series[~np.isnan(series)], expected[~np.isnan(expected)], rtol=0, atol=1e-12)
        assert stale == expected_stale
    assert batch.rejected == reference.rejected
    assert batch.stamp_ns == reference.stamp_ns
    assert (batch.value is None) == (reference.value is None)
    if batch.value is not None:
        assert abs(batch.value - reference.value) < 1e-12
