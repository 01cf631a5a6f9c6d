"""Still poses as the detector hands them over, drawn directly (fast, for Monte Carlo over seeds), and a
calibration fitted from them: the checks of a calibration against new poses (`accel-calib check`, the
node's watch) use these."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from accel_calibration.core.pose import Pose
from accel_calibration.core.session import CalibrationSession
from msg_tools.synthetic_imu import SensorErrors, spread_orientations

SAMPLES = 200  # 2 s at 100 Hz per pose
NOISE_MPS2 = 0.02  # per sample and axis, ~2 mg


def poses_of(errors: SensorErrors, rotations: list[Rotation], rng: np.random.Generator,
             first_ns: int = 0) -> list[Pose]:
    """The poses the detector hands over for these orientations: the mean of SAMPLES white-noise samples
    (drawn as their mean and sample covariance) of the sensor's raw output, 3 s apart from `first_ns`."""
    out = []
    for i, rotation in enumerate(rotations):
        true = rotation.inv().apply([0.0, 0.0, 9.80665])
        mean = errors.raw_from_true(true[None])[0] + rng.normal(0.0, errors.noise_mps2 / np.sqrt(SAMPLES), 3)
        cov = np.diag(rng.chisquare(SAMPLES - 1, 3) / (SAMPLES - 1)) * errors.noise_mps2**2
        start = first_ns + i * 3_000_000_000
        out.append(Pose(mean, cov, SAMPLES, start, start + 2_000_000_000))
    return out


def fitted(errors: SensorErrors, rng: np.random.Generator, count: int = 14):
    session = CalibrationSession()
    for pose in poses_of(errors, spread_orientations(count, rng), rng):
        session.add_pose(pose)
    verdict = session.calibrate()
    assert verdict.success, verdict.message
    return verdict.calibration


def sensor(seed: int) -> tuple[SensorErrors, np.random.Generator]:
    rng = np.random.default_rng(seed)
    return SensorErrors.mpu6050_like(rng, noise_mps2=NOISE_MPS2), rng
