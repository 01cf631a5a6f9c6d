"""Synthetic streams for the static detector, and how two detectors' poses are compared: the batch path
against sample-by-sample updates, whole against in parts."""
from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from accel_calibration.core.stream.detector import DISCARD, RESTART
from accel_calibration.core.units import STANDARD_GRAVITY as G
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

DAY_NS = 86_400 * 10**9


def synthetic_stream(rate_hz, rng, noise_mps2=0.02):
    """Dwells of 3 s at the six faces and two tilts, joined by 1 s rotations (smooth step). The first
    dwell also teaches the detector its noise floor (warmup_s = 2 s) and must still become a pose."""
    directions = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 0, -1], [-1, 0, 0], [0, -1, 0], [0.6, 0.0, 0.8],
                           [0.0, -0.6, 0.8]], float)
    t, accel = [], []
    dt = 1.0 / rate_hz
    now = 0.0
    for i, d in enumerate(directions):
        for _ in range(int(3.0 * rate_hz)):
            t.append(now)
            accel.append(G * d)
            now += dt
        if i + 1 < len(directions):
            nxt = directions[i + 1]
            for k in range(int(1.0 * rate_hz)):
                s = (k + 1) / (1.0 * rate_hz)
                s = s * s * (3 - 2 * s)
                v = (1 - s) * d + s * nxt
                t.append(now)
                accel.append(G * v / np.linalg.norm(v))
                now += dt
    accel = np.array(accel) + rng.normal(0, noise_mps2, (len(accel), 3))
    return (np.array(t) * 1e9).astype(np.int64), accel, directions


def assert_same_poses(batch, streamed):
    assert len(batch) == len(streamed)
    for a, b in zip(batch, streamed):
        assert (a.start_ns, a.end_ns, a.samples) == (b.start_ns, b.end_ns, b.samples)
        np.testing.assert_allclose(a.accel_mps2, b.accel_mps2, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a.accel_cov, b.accel_cov, rtol=1e-8, atol=1e-15)
        for name in ("gyro_radps", "temperature_degc", "temperature_spread_degc"):
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None) == (y is None)
            if x is not None:
                np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-12)


def streams():
    """Streams that exercise every rule: warm-up adoption, a stream starting in motion, gaps, a
    long still period cut by max_pose_s, gyro and temperature, NaN rows and stamps going backwards."""
    rng = np.random.default_rng(3)
    t, accel, _ = synthetic_stream(200.0, rng)
    temperature = 25.0 + 0.001 * np.arange(len(t))
    gyro = rng.normal(0, 0.002, accel.shape)
    yield "plain", dict(t_ns=t, accel=accel, temperature_degc=temperature), {}
    yield "gyro", dict(t_ns=t, accel=accel, gyro=gyro, temperature_degc=temperature), {}
    moving = int(3.2 * 200)
    yield "starts moving", dict(t_ns=t[moving:], accel=accel[moving:]), {}
    holes = t.copy()
    holes[len(t) // 3:] += 2 * 10**9
    holes[2 * len(t) // 3:] += 3 * 10**9
    yield "gaps", dict(t_ns=holes, accel=accel, gyro=gyro), {}
    yield "max pose", dict(t_ns=t, accel=accel), dict(max_pose_s=1.3, min_hold_s=0.6)
    dirty = accel.copy()
    dirty[::101] = np.nan
    backwards = t.copy()
    backwards[::89] -= 10**9
    yield "dirty", dict(t_ns=backwards, accel=dirty, gyro=gyro), {}
    yield "explicit threshold", dict(t_ns=t, accel=accel), dict(accel_var_threshold=0.01)


def stream_with_breaks(data):
    """Six poses at 100 Hz with 1-5 restarts (the clock starting over anywhere) and discards drawn by
    hypothesis: (samples, stamps, breaks)."""
    rng = np.random.default_rng(data.draw(st.integers(0, 1000)))
    errors = SensorErrors(noise_mps2=0.02, gyro_noise_radps=0.002)
    s = SyntheticImu(errors, spread_orientations(6, rng), dwell_s=3.0, move_s=1.0, rate_hz=100.0,
                     seed=data.draw(st.integers(0, 1000))).samples()
    t = s.t_ns.copy()
    breaks = np.zeros(len(t), dtype=np.int64)
    for _ in range(data.draw(st.integers(1, 5))):
        i = data.draw(st.integers(0, len(t) - 1))
        kind = data.draw(st.sampled_from([RESTART, DISCARD]))
        breaks[i] = kind
        if kind == RESTART:  # a clock that starts over, anywhere
            t[i:] += data.draw(st.integers(-2 * DAY_NS, 2 * DAY_NS))
    return s, t, breaks
