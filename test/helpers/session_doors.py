"""The node's door into a CalibrationSession, as the tests use it: the live feed (RecordingFeed, live) fed
in the batches a busy or idle worker would take from the Imu callback's buffer. One copy here, so every
test feeds the session the way the node does."""
from __future__ import annotations

import numpy as np

from accel_calibration.core.session import CalibrationSession


def per_message(session: CalibrationSession, t_ns, accel, gyro, temperatures=None, collecting=None,
                reason: str = "armed", store: bool = True, batch_seed: int | None = 0,
                max_batch: int = 300) -> list:
    """What the node does: temperature and IMU messages in arrival order (a reading goes in before the
    first sample stamped at or after it), buffered and handed to the session's live feed in batches of
    1..`max_batch` messages (random, from `batch_seed`; None: one message at a time), each batch's readings
    before its samples, then the end of the stream (finish). `collecting` (one bool per message,
    optional): collection paused where False, as the armed input or calibration/pause marks each sample.
    `store`: the poses go into the store too. `reason` is kept for callers' readability."""
    stamps, values = temperatures if temperatures is not None else (np.zeros(0, dtype=np.int64), np.zeros(0))
    stamps, values = np.asarray(stamps, dtype=np.int64), np.asarray(values, dtype=float)
    t = np.asarray(t_ns, dtype=np.int64)
    a, g = np.asarray(accel, dtype=float).reshape(-1, 3), np.asarray(gyro, dtype=float).reshape(-1, 3)
    on = np.ones(len(t), bool) if collecting is None else np.asarray(collecting, dtype=bool)
    # Where each reading arrives: before the first sample stamped at or after it.
    arrival = np.searchsorted(t, stamps, side="left") if np.all(np.diff(t) >= 0) else \
        np.array([next((i for i, ti in enumerate(t.tolist()) if ti >= s), len(t)) for s in stamps.tolist()])
    rng = None if batch_seed is None else np.random.default_rng(batch_seed)
    feed = session.live_feed()
    poses: list = []
    start = 0
    while start < len(t):
        size = 1 if rng is None else int(rng.integers(1, max_batch + 1))
        stop = min(len(t), start + size)
        readings = (arrival >= start) & (arrival < stop) if start else arrival < stop
        if readings.any():
            feed.add_temperatures(stamps[readings], values[readings])
        feed.add_samples(t[start:stop], a[start:stop], g[start:stop], on[start:stop])
        poses += feed.take_poses()
        start = stop
    late = arrival >= len(t)
    if late.any():
        feed.add_temperatures(stamps[late], values[late])
    poses += feed.finish()
    if store:
        for pose in poses:
            session.add_pose(pose)
    return poses


class LogLines:
    """A logger as rclpy's, for LiveCalibration (the node's door without ROS): every line kept as
    (level, text), throttling arguments accepted."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def __getattr__(self, level: str):
        return lambda message, **kwargs: self.lines.append((level, message))


def buffer_messages(live, samples, start: int = 0, stop: int | None = None) -> None:
    """What the node's Imu callback hands LiveCalibration, one message at a time: samples[start:stop]."""
    for i in range(start, len(samples.t_ns) if stop is None else stop):
        live.stream.buffer_imu(int(samples.t_ns[i]), *samples.accel_raw[i].tolist(), *samples.gyro_raw[i].tolist())
