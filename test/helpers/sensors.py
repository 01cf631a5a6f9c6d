"""Simulated sensors with known errors, shared by the temperature tests of the core and the node."""
from __future__ import annotations

import numpy as np

from accel_calibration.core.calibration import Calibration, GyroQuality
from accel_calibration.core.temperature_models import TemperatureModel
from accel_calibration.core.units import MG
from msg_tools.synthetic_imu import SensorErrors

# ~1 mg/degC of bias drift with curvature, ~1e-4/degC of scale drift (per axis, about T_ref = 25 degC).
DRIFTING = SensorErrors(
    bias_mps2=np.array([0.31, -0.42, 0.27]),
    matrix=np.array([[1.021, 0.0, 0.0], [0.011, 0.984, 0.0], [-0.008, 0.013, 1.017]]),
    bias_drift=np.array([[1.1, -1.2, 1.0], [0.02, 0.025, -0.015]]) * MG,
    scale_drift=np.array([[1.0e-4, -1.0e-4, 0.8e-4]]),
    t_ref_degc=25.0,
)


def calibration_with_drift() -> Calibration:
    """Accelerometer and gyro terms, sigmas, a gyro quality and a temperature drift: every part of a
    correction (and of its covariances) takes part."""
    rng = np.random.default_rng(2)
    return Calibration(bias=rng.normal(0, 0.05, 3), matrix=np.eye(3) + np.tril(rng.normal(0, 0.01, (3, 3))),
                       bias_sigma=np.full(3, 2e-4), matrix_sigma=np.full((3, 3), 1e-5),
                       gyro_bias_radps=np.array([0.01, -0.02, 0.003]),
                       gyro_matrix=np.eye(3) + rng.normal(0, 0.01, (3, 3)),
                       gyro_quality=GyroQuality(matrix_sigma=np.full((3, 3), 2e-4), residual_rms_mrad=0.5,
                                                residual_max_mrad=1.0, motions=17,
                                                bias_sigma_radps=np.full(3, 1e-4)),
                       temperature=TemperatureModel("polynomial", 22.0, (15.0, 35.0),
                                                    bias_coefficients=[[0.01, -0.01, 0.005]]))
