"""A static pose: what the detector hands to the fit, the same record live, in replay and in the CLI."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pose:
    """Statistics of one interval during which the sensor was held still.

    Units are SI: accelerations in m/s^2 (raw, uncorrected sensor output), angular rates in rad/s,
    temperature in degC, times in nanoseconds of the stream's own clock (header stamps).
    """

    accel_mps2: np.ndarray  # (3,) mean raw acceleration
    accel_cov: np.ndarray  # (3, 3) sample covariance of the raw acceleration in the interval
    samples: int
    start_ns: int
    end_ns: int
    gyro_radps: np.ndarray | None = None  # (3,) mean angular rate, None when no gyro
    temperature_degc: float | None = None  # mean temperature, None when no temperature stream
    temperature_spread_degc: float | None = None  # max - min temperature inside the interval

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9

    @property
    def direction(self) -> np.ndarray:
        """Unit vector of the mean specific force (points up, away from the earth)."""
        direction: np.ndarray = self.accel_mps2 / np.linalg.norm(self.accel_mps2)
        return direction

