"""A vehicle that cannot be turned over: its sensor, the calibration it had (a full session over the sphere)
and, after its z bias moved 8 mg, poses within 30 deg of level. Shared by the fit's and the CLI's tests of
the fit with a prior."""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from accel_calibration import MG, fit
from msg_tools.synthetic_imu import SensorErrors

G = 9.80665
OLD_POSE_NOISE_MG = 0.5  # a full calibration's session on a MEMS part: a few tenths of a mg per pose mean
POSE_NOISE_MG = 0.065  # an MPU-6050 at 0.02 m/s^2 per sample, 1000 samples a pose
Z_BIAS_MOVE_MG = 8.0


def near_level(count, degrees, rng):
    """`count` gravity directions within `degrees` of z up (specific force at rest, REP-103)."""
    d = Rotation.random(20000, random_state=rng).apply([0.0, 0.0, 1.0])
    return d[d[:, 2] > np.cos(np.radians(degrees))][:count]


def sensor_and_old_calibration(seed):
    """(rng, the sensor after its z bias moved 8 mg, its calibration from 24 poses over the sphere before)."""
    rng = np.random.default_rng(seed)
    errors = SensorErrors.mpu6050_like(rng)
    d = Rotation.random(24, random_state=rng).apply([0.0, 0.0, 1.0])
    old = fit(errors.raw_from_true(G * d) + rng.normal(0.0, OLD_POSE_NOISE_MG * MG, (24, 3)))
    assert old.success, old.message
    moved = dataclasses.replace(errors, bias_mps2=errors.bias_mps2 + np.array([0.0, 0.0, Z_BIAS_MOVE_MG * MG]))
    return rng, moved, old.calibration


def level_poses(errors, rng, count=8):
    """Pose means (m/s^2) of `errors` at `count` orientations within 30 deg of level."""
    d = near_level(count, 30.0, rng)
    return errors.raw_from_true(G * d) + rng.normal(0.0, POSE_NOISE_MG * MG, (count, 3))


def level_stream(errors, rng, count=8, seed=0):
    """The samples of a session of `count` still poses within 30 deg of level (3 s each, 100 Hz), as a
    recording or the node's Imu topic carries them."""
    from msg_tools.synthetic_imu import SyntheticImu, rotation_with_up

    rotations = [rotation_with_up(d) for d in near_level(count, 30.0, rng)]
    return SyntheticImu(errors, rotations, dwell_s=3.0, move_s=1.0, rate_hz=100.0, seed=seed).samples()
