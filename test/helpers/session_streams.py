"""Simulated sessions for the calibration session's doors: the samples, the Temperature topic's readings
beside them, and the same stream with the faults seen in the field spliced in."""
from __future__ import annotations

import numpy as np

from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations


def stream(seed=1, poses=16, dwell_s=2.5, rate_hz=200.0, temperature_degc=25.0):
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    imu = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=dwell_s, move_s=1.0, rate_hz=rate_hz,
                       seed=seed, temperature_degc=temperature_degc)
    return errors, imu.samples()


def temperature_readings(samples, period_s=0.1):
    """(stamps, values) at ~10 Hz, as a Temperature topic gives."""
    step = max(1, int(round(period_s / (samples.t_ns[1] - samples.t_ns[0]) * 1e9)))
    index = np.arange(0, len(samples.t_ns), step)
    return samples.t_ns[index], samples.temperature_degc[index]


def hostile(samples):
    """The session's stream with the faults seen in the field spliced in: NaN, a 2e154 gyro, a stamp
    going backwards, a 1e300 accel, and a frozen sensor (the same sample 400 times)."""
    t, accel, gyro = samples.t_ns.copy(), samples.accel_raw.copy(), samples.gyro_raw.copy()
    accel[1000] = np.nan
    gyro[2000, 1] = 2e154
    t[3000] = t[2990]
    accel[4000, 2] = 1e300
    frozen = slice(5000, 5400)
    accel[frozen], gyro[frozen] = accel[5000], gyro[5000]
    return t, accel, gyro
