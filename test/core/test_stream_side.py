"""The stream side takes a recording part by part itself (StreamSide.take): screened, paused, its
temperature filtered and its still intervals found, each pose with the clock it was measured on. Driven
part by part by hand, it gives the poses and counters of the session's own feed over the same parts."""
from __future__ import annotations

import numpy as np

from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings
from accel_calibration.core.stream.stream_side import StreamPart, StreamSide

from helpers.session_streams import hostile, stream, temperature_readings

PART_ROWS = 1000


def pose_keys(poses):
    return [(p.start_ns, p.end_ns, p.samples, *p.accel_mps2.tolist(), p.temperature_degc) for p in poses]


def test_a_stream_side_taking_parts_by_hand_finds_the_poses_and_counts_of_the_feed():
    _, samples = stream(seed=5, poses=8, temperature_degc=lambda t: 20.0 + 0.2 * t)
    t, accel, gyro = hostile(samples)
    assert len(t) % PART_ROWS  # the last part is a short one
    stamps, values = temperature_readings(samples)
    collecting = np.ones(len(t), bool)
    collecting[2500:3300] = False  # armed for a while
    session = CalibrationSession()
    expected = session.add_recording(t, accel, gyro, stamps, values, collecting=collecting, part_rows=PART_ROWS)
    assert len(expected) >= 4

    side = StreamSide(Settings())
    found, taken = [], 0
    for first in range(0, len(t), PART_ROWS):
        stop = min(len(t), first + PART_ROWS)
        final = stop == len(t)
        upto = len(stamps) if final else int(np.searchsorted(stamps, t[first:stop].max(), side="right"))
        part = StreamPart(t[first:stop], accel[first:stop], gyro[first:stop], collecting[first:stop],
                          (stamps[taken:upto], values[taken:upto]), final=final)
        taken = upto
        found += side.take(part)
    poses = [pose for pose, clock in found if side.usable_pose(pose, clock) is not None]
    assert pose_keys(poses) == pose_keys(expected)
    assert side.counters.as_dict() == session.counters.as_dict()
    assert side.counters.samples_paused > 0 and side.counters.frozen > 0
