"""A recording fed to the session in pieces, as a streaming reader gives it (RecordingFeed): whatever the
piece sizes and however the temperature readings interleave, the poses and counters are bit for bit
those of the whole arrays; memory is bounded by a part. (That the parts agree with the live node sample
by sample: test_session's live-and-replay test, run in parts too.)"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.stream.feed import RecordingFeed

from helpers.session_doors import per_message
from helpers.session_streams import hostile, stream, temperature_readings

FAST = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                      HealthCheck.function_scoped_fixture])


def pose_keys(poses):
    return [(p.start_ns, p.end_ns, p.samples, *p.accel_mps2.tolist(), p.temperature_degc) for p in poses]


def fed_in_pieces(session, t, accel, gyro, readings, cuts, collecting=None, part_rows=RecordingFeed.PART_ROWS):
    """As a reader streaming the storage: pieces of samples, each preceded by the readings received by then."""
    feed = session.recording_feed(has_temperature=readings is not None, part_rows=part_rows)
    bounds = [0, *cuts, len(t)]
    k = 0
    for first, stop in zip(bounds[:-1], bounds[1:]):
        if readings is not None:
            upto = np.searchsorted(readings[0], t[stop - 1], side="right")
            feed.add_temperatures(readings[0][k:upto], readings[1][k:upto])
            k = upto
        feed.add_samples(t[first:stop], accel[first:stop], gyro[first:stop],
                         None if collecting is None else collecting[first:stop])
    if readings is not None:
        feed.add_temperatures(readings[0][k:], readings[1][k:])
    return feed.finish()


@FAST
@given(data=st.data())
def test_pieces_give_the_whole_recordings_poses_bit_for_bit(data):
    part_rows = data.draw(st.sampled_from([300, 1000, 4096]))
    faults = data.draw(st.booleans())
    _, samples = stream(seed=data.draw(st.integers(0, 50)), poses=8, temperature_degc=lambda t: 20.0 + 0.2 * t)
    t, accel, gyro = hostile(samples) if faults else (samples.t_ns, samples.accel_raw, samples.gyro_raw)
    readings = temperature_readings(samples) if data.draw(st.booleans()) else None
    collecting = None
    if data.draw(st.booleans()):  # armed for a while: collection paused there
        collecting = np.ones(len(t), bool)
        first = data.draw(st.integers(0, len(t) - 1))
        collecting[first:first + data.draw(st.integers(1, 1000))] = False
    cuts = sorted(set(data.draw(st.lists(st.integers(1, len(t) - 1), max_size=12))))

    whole_session, pieces_session = CalibrationSession(), CalibrationSession()
    whole = whole_session.add_recording(t, accel, gyro, *(readings or (None, None)), collecting=collecting,
                                        part_rows=part_rows)
    pieces = fed_in_pieces(pieces_session, t, accel, gyro, readings, cuts, collecting, part_rows)
    assert pose_keys(pieces) == pose_keys(whole)
    assert pieces_session.counters == whole_session.counters
    assert len(whole) >= 3  # something to compare


def test_a_late_temperature_stream_holds_samples_back_only_so_long():
    """Readings that never come (a temperature topic that died): samples wait at most MAX_LAG_PARTS parts,
    so memory stays bounded, and the poses are still found (without temperature)."""
    _, samples = stream(poses=8)
    session = CalibrationSession()
    feed = session.recording_feed(has_temperature=True, part_rows=500)
    most = 0
    for first in range(0, len(samples.t_ns), 250):
        part = slice(first, first + 250)
        feed.add_samples(samples.t_ns[part], samples.accel_raw[part], samples.gyro_raw[part])
        most = max(most, feed._buffered)
    poses = feed.finish()
    assert most <= RecordingFeed.MAX_LAG_PARTS * 500
    assert len(poses) >= 6 and all(p.temperature_degc is None for p in poses)


@pytest.mark.parametrize("where", ["pause ends at a part's end", "pause starts a part", "clock jumps at a part's end"])
def test_a_pause_or_a_clock_jump_at_a_part_boundary(where):
    """The break between two parts (a pause that ended with a part, a stamp jump among its last samples
    screened out) still drops or ends the interval then open, as in one call and live."""
    _, samples = stream(poses=8)
    t, accel, gyro = samples.t_ns.copy(), samples.accel_raw.copy(), samples.gyro_raw.copy()
    # The first part ends inside a still interval (the third), so the break has something to end.
    boundary = part = next(b for b in range(1500, len(t)) if np.ptp(accel[b - 150:b + 150], axis=0).max() < 0.2)
    collecting = np.ones(len(t), bool)
    if where == "pause ends at a part's end":
        collecting[boundary - 40:boundary] = False
    elif where == "pause starts a part":
        collecting[boundary:boundary + 40] = False
    else:
        t[boundary - 3:] += 86_400 * 10**9  # re-synchronised forward: the jump rule
        accel[boundary - 3:boundary] = 1e6  # saturated, screened out: the break lands on the next part
        t[boundary - 3:] -= 2 * 86_400 * 10**9
    live = CalibrationSession()
    live_poses = per_message(live, t, accel, gyro, collecting=collecting, store=False)
    whole = CalibrationSession()
    one_call = whole.add_recording(t, accel, gyro, collecting=collecting, part_rows=10**9)
    parts = CalibrationSession()
    in_parts = parts.add_recording(t, accel, gyro, collecting=collecting, part_rows=part)
    keys = [(p.start_ns, p.end_ns, p.samples) for p in live_poses]
    assert [(p.start_ns, p.end_ns, p.samples) for p in one_call] == keys
    assert [(p.start_ns, p.end_ns, p.samples) for p in in_parts] == keys
    assert parts.counters == whole.counters == live.counters
