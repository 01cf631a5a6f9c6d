"""Simulated sensors with known errors, shared by the temperature tests of the core and the node."""
from __future__ import annotations

import numpy as np

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
