"""The calibration in force, without ROS: what the node corrects its stream with.

Loaded at start (and checked for plausibility: a file that is not ours, or is implausible, is left
untouched and never overwritten); a new calibration is saved first and put in force only once saved, so
what runs is always what the file says; the Correction follows the temperature and the measured noise.

Threads: the stream reads `correction` (one attribute, swapped whole). The worker installs calibrations
and sets the noise; the temperature callback moves the temperature. Both rebuild under one lock, so a
correction is never built from one calibration and written back over a newer one.
"""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from ..core.calibration import Calibration
from ..core.correction import Correction, correction_temperatures
from ..core.errors import CalibrationError
from ..core.fit_result import ParameterSource
from ..core.plausibility import plausibility_problem
from ..core.settings import Settings
from ..core.stream.temperature_filter import TemperatureFilter
from .calibration_file import load_calibration, remove_stale_temp_files, save_calibration

OK, WARN, ERROR = "ok", "warn", "error"


class CalibrationInForce:
    def __init__(self, path: Path, settings: Settings):
        self.path = path
        self.settings = settings
        self.calibration: Calibration | None = None
        self.correction: Correction | None = None
        self.file_unreadable = False  # a file we could not read is never overwritten
        self.temperature_degc: float | None = None  # where the correction's temperature terms were evaluated
        self.clamped_rebuilds = 0  # corrections built outside the calibrated temperature range
        self._noise_var: float | None = None
        self._gyro_noise_var: float | None = None
        self._filter = TemperatureFilter(timeout_s=settings.temperature_timeout_s)
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ the file
    def remove_stale_temp_files(self) -> int:
        return remove_stale_temp_files(self.path)

    def load(self) -> tuple[str, str]:
        """Load the file at start: (level, what happened, one line)."""
        if not self.path.exists():
            return WARN, f"no calibration file at {self.path}: raw acceleration passes through until calibrated"
        try:
            calibration = load_calibration(self.path)
            implausible = plausibility_problem(calibration, max_bias_mps2=self.settings.max_bias_mps2,
                                               scale_band=(self.settings.scale_min, self.settings.scale_max))
            if implausible is not None:
                raise CalibrationError(f"{self.path}: implausible for an accelerometer in m/s^2 ({implausible})")
        except CalibrationError as error:
            self.file_unreadable = True
            return ERROR, f"calibration file unusable, left untouched, raw passes through: {error}"
        self.install(calibration)
        quality = calibration.quality
        text = f"residual {quality.residual_rms_mg:.2f} mg rms over {quality.poses} poses" if quality else \
            "no quality recorded"
        return OK, f"loaded calibration from {self.path} ({calibration.model}, {text})"

    def save_then_apply(self, calibration: Calibration, parameter_sources: tuple[ParameterSource, ...] = (),
                        prior: str | None = None) -> tuple[bool, str]:
        """Save first, then put in force: a calibration that could not be saved is not applied. A fit with a
        prior: the file says which parameters came from the poses and which from `prior`."""
        refusal = self._unwritable()
        if refusal is not None:
            return False, refusal
        try:
            self._save(calibration, parameter_sources, prior)
        except CalibrationError as error:
            return False, f"not applied: {error}; {self.kept()}"
        self.install(calibration)
        return True, f"saved to {self.path}"

    def save(self) -> tuple[bool, str]:
        """calibration/save: the calibration in force to the file again."""
        calibration = self.calibration
        if calibration is None:
            return False, "no calibration in force to save"
        refusal = self._unwritable()
        if refusal is not None:
            return False, refusal
        try:
            self._save(calibration)
        except CalibrationError as error:
            return False, str(error)
        return True, f"saved to {self.path}"

    def kept(self) -> str:
        return "previous calibration kept in force" if self.calibration is not None else \
            "no calibration in force: raw passes through"

    def _unwritable(self) -> str | None:
        if self.file_unreadable:
            return (f"{self.path} holds a file this node could not read (foreign or corrupt); it is left "
                    "untouched: move it away or set calibration_file")
        return None

    def _save(self, calibration: Calibration, parameter_sources: tuple[ParameterSource, ...] = (),
              prior: str | None = None) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise CalibrationError(f"cannot create {self.path.parent}: {error.strerror}") from None
        save_calibration(calibration, self.path, parameter_sources, prior)

    # ------------------------------------------------------------------ the correction
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
