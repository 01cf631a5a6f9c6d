"""TemperatureFilter: the first-order filter it states (tau 0.5 s, readings outside -60..150 degC or not
finite rejected, a value held until `timeout_s` old), over readings and samples in any batches, as the
feed hands them over (each part with the readings stamped up to its last sample)."""
from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.core.stream.temperature_filter import PLAUSIBLE_DEGC, TAU_S, TemperatureFilter


def definition(timeout_s, stamps, degc, samples):
    """The filter as its docstring states it, one reading at a time in stamp order: (value held at each
    sample, NaN when none or stale; stale samples; rejected readings; the last value)."""
    value, held_stamp, rejected, held = None, -1, 0, []
    for k in np.argsort(stamps, kind="stable"):
        x, stamp = float(degc[k]), int(stamps[k])
        if not (math.isfinite(x) and PLAUSIBLE_DEGC[0] < x < PLAUSIBLE_DEGC[1]):
            rejected += 1
            continue
        if value is None or held_stamp < 0:
            value = x
        else:
            dt = max(0.0, (stamp - held_stamp) * 1e-9)
            value += dt / (TAU_S + dt) * (x - value)
        held_stamp = stamp
        held.append((stamp, value))
    out, stale = np.full(len(samples), np.nan), 0
    held_stamps = np.array([h[0] for h in held], dtype=np.int64)
    for i, t in enumerate(samples.tolist()):
        k = int(np.searchsorted(held_stamps, t, side="right")) - 1
        if k < 0:
            continue
        if t - held[k][0] <= int(timeout_s * 1e9):
            out[i] = held[k][1]
        else:
            stale += 1
    return out, stale, rejected, value


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.sampled_from([0, 1, 2, 3, 17, 200, 2000]),
       timeout_s=st.sampled_from([0.5, 5.0]), shuffled=st.booleans(),
       cuts=st.lists(st.integers(1, 299), max_size=8))
def test_the_filter_in_any_batches_is_its_definition(seed, n, timeout_s, shuffled, cuts):
    rng = np.random.default_rng(seed)
    stamps = np.cumsum(rng.choice([1, 10**7, 10**8, 10**9, 3 * 10**9, 10**11], n)) + 10**9
    if shuffled:
        rng.shuffle(stamps)
    degc = 25 + np.cumsum(rng.normal(0, 0.5, n))
    bad = rng.random(n) < 0.1
    degc[bad] = rng.choice([np.nan, np.inf, -np.inf, 200.0, -61.0, 150.0, -60.0], int(bad.sum()))
    high = (int(stamps.max()) if n else 10) + 10**10
    samples = np.sort(rng.integers(0, high, 300))
    expected, expected_stale, expected_rejected, expected_value = definition(timeout_s, stamps, degc, samples)

    batched = TemperatureFilter(timeout_s)
    order = np.argsort(stamps, kind="stable")
    stamps, degc = stamps[order], degc[order]
    got, stale, taken = [], 0, 0
    for first, stop in zip([0, *sorted(set(cuts))], [*sorted(set(cuts)), len(samples)]):
        upto = int(np.searchsorted(stamps, samples[stop - 1], side="right"))  # readings by the part's end
        values, part_stale = batched.series(stamps[taken:upto], degc[taken:upto], samples[first:stop])
        got.append(values)
        stale += part_stale
        taken = upto
    batched.series(stamps[taken:], degc[taken:], np.zeros(0, np.int64))
    got = np.concatenate(got)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(expected))
    np.testing.assert_allclose(got[~np.isnan(got)], expected[~np.isnan(expected)], rtol=0, atol=1e-12)
    assert stale == expected_stale and batched.rejected == expected_rejected
    assert (batched.value is None) == (expected_value is None)
    if expected_value is not None:
        assert abs(batched.value - expected_value) < 1e-12


def test_a_warm_up_ramp_lags_by_rate_times_tau():
    """0.1 degC/s (a fast warm-up) read at 10 Hz: the filtered value lags by at most 0.1 x 0.5 = 0.05 degC
    and settles there (steady state of the step: lag = rate x tau)."""
    stamps = np.arange(0, 30 * 10**9, 10**8, dtype=np.int64)
    degc = 20.0 + 0.1 * stamps * 1e-9
    held, stale = TemperatureFilter().series(stamps, degc, stamps)
    lag = degc - held
    assert stale == 0 and np.all(lag <= 0.05 + 1e-12) and np.all(lag >= 0.0)
    assert abs(lag[-1] - 0.05) < 1e-6
