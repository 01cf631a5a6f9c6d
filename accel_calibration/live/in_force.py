"""The correction in force, without ROS: what the node's stream is corrected with, in its own process.

A copy of the work's calibration in force (`install`, from the worker; live/calibration_store.py keeps the
file), the Correction rebuilt from it as the temperature and the measured noise move.

Threads: the stream reads `correction` (one attribute, swapped whole). The worker's pipe installs
calibrations and sets the noise; the temperature callback moves the temperature. Both rebuild under one
lock, so a correction is never built from one calibration and written back over a newer one.
"""
from __future__ import annotations

import threading

import numpy as np

from ..core.calibration import Calibration
from ..core.correction import Correction, correction_temperatures
from ..core.stream.temperature_filter import TemperatureFilter

__all__ = ["CorrectionInForce"]


class CorrectionInForce:
    def __init__(self, temperature_timeout_s: float):
        self.calibration: Calibration | None = None
        self.correction: Correction | None = None
        self.temperature_degc: float | None = None  # where the correction's temperature terms were evaluated
        self.clamped_rebuilds = 0  # corrections built outside the calibrated temperature range
        self._noise_var: float | None = None
        self._gyro_noise_var: float | None = None
        self._filter = TemperatureFilter(timeout_s=temperature_timeout_s)
        self._lock = threading.Lock()

    def install(self, calibration: Calibration | None) -> None:
        """Put a calibration in force: the correction is rebuilt and swapped whole."""
        with self._lock:
            self.calibration = calibration
            self._rebuild()

    def set_noise(self, noise_var_per_axis: float | None, gyro_noise_var_per_axis: float | None = None) -> None:
        """The sensor's white-noise variance per axis, as measured at still poses: (m/s^2)^2 and (rad/s)^2."""
        if noise_var_per_axis == self._noise_var and gyro_noise_var_per_axis == self._gyro_noise_var:
            return
        with self._lock:
            self._noise_var = noise_var_per_axis
            self._gyro_noise_var = gyro_noise_var_per_axis
            self._rebuild()

    def take_temperature(self, stamp_ns: int, degc: float) -> bool:
        """One temperature reading, as it comes: filtered (the session's filter, on this reading), and the
        correction rebuilt when the correction temperature moved (core.correction's rule). True when the
        correction was rebuilt."""
        _, filtered = self._filter.take(np.array([stamp_ns], dtype=np.int64), np.array([degc], dtype=float))
        if not len(filtered):
            return False
        with self._lock:
            moved = float(correction_temperatures(filtered[-1:], self.temperature_degc)[0])
            if moved == self.temperature_degc:
                return False
            self.temperature_degc = moved
            if self.calibration is None or self.calibration.temperature is None:
                return False
            self._rebuild()
            return True

    def _rebuild(self) -> None:
        """Caller holds the lock: calibration, temperature and noise are read together."""
        correction = Correction.build(self.calibration, self.temperature_degc, self._noise_var, self._gyro_noise_var)
        if correction is not None and correction.temperature_clamped:
            self.clamped_rebuilds += 1
        self.correction = correction
