"""The live calibration's stream side: what runs per message, in the process that publishes.

`buffer_imu` pushes the raw sample, marked collecting or not, into the sample ring (the one path to the
calibration work, live/sample_ring.py); `take_temperature` moves the correction's temperature and pushes the
reading. The correction in force is this side's copy of the calibration work's (`install`, `set_noise`),
so correcting a message never waits for a fit, a file or the other process. The armed input,
calibration/pause and calibration/enable are answered here, at once.
"""
from __future__ import annotations

import collections
from collections.abc import Callable
from typing import Any, Protocol

from ..core.calibration import Calibration
from ..core.settings import Settings
from ..core.stream.collection_pause import CollectionPause
from ..core.text import quoted
from ..io.calibration_file import calibration_to_yaml
from .in_force import CorrectionInForce
from .sample_ring import SampleRing

__all__ = ["LOG_THROTTLE_S", "TEMPERATURE_AHEAD_NS", "LiveStream", "Log"]

LOG_THROTTLE_S = 5.0  # a warning a stream can repeat at 1 kHz is logged at most this often
# A temperature reading stamped further than this ahead of the latest IMU stamp is another clock's: dropped
# and counted (temperature_future). Generous: an IMU stream that pauses for a while keeps its readings.
TEMPERATURE_AHEAD_NS = 60_000_000_000
IMU_VALUES = 6  # ax, ay, az (m/s^2), gx, gy, gz (rad/s); the flag: collecting


class Log(Protocol):
    """rclpy's logger, as used here (a throttled line takes `throttle_duration_sec`)."""

    def debug(self, message: str, **kwargs: Any) -> Any: ...
    def info(self, message: str, **kwargs: Any) -> Any: ...
    def warning(self, message: str, **kwargs: Any) -> Any: ...
    def error(self, message: str, **kwargs: Any) -> Any: ...


def imu_ring(context: Any = None) -> SampleRing:
    return SampleRing(IMU_VALUES, context=context)


def temperature_ring(context: Any = None) -> SampleRing:
    return SampleRing(1, capacity=1 << 14, context=context)


class LiveStream:
    def __init__(self, settings: Settings, log: Log, samples: SampleRing,
                 readings: SampleRing, *, imu_topic: str = "imu/data_raw",
                 on_frame_id: Callable[[str], None] = lambda frame_id: None):
        self.settings = settings
        self.in_force = CorrectionInForce(settings.temperature_timeout_s)  # the file is the work's
        self.enabled = True  # calibration/enable: off passes raw through
        self.frame_id: str | None = None
        self.pause = CollectionPause()
        # What this side set aside, by name (the calibration work keeps its own counters).
        self.set_aside: collections.Counter[str] = collections.Counter()
        self.samples, self.readings = samples, readings
        self._log = log
        self._imu_topic = imu_topic
        self.on_frame_id = on_frame_id  # tells the work the frame (its calibration is of that frame)
        self._latest_imu_ns = -1  # the latest IMU header stamp: temperature stamps are judged against it

    # ------------------------------------------------------------------ per message
    def buffer_imu(self, stamp_ns: int, ax: float, ay: float, az: float, gx: float, gy: float, gz: float) -> None:
        if stamp_ns > self._latest_imu_ns:
            self._latest_imu_ns = stamp_ns
        self.samples.push(stamp_ns, ax, ay, az, gx, gy, gz, self.pause.collecting)

    def flush(self) -> None:
        """Show the work the last records, if the stream stopped just when the work was reading the rings."""
        self.samples.flush()
        self.readings.flush()

    def take_temperature(self, stamp_ns: int, degc: float) -> None:
        # A reading stamped far ahead of the IMU stream (another publisher's clock) would take the
        # correction temperature with it, and leave the true readings after it none.
        if self._latest_imu_ns >= 0 and stamp_ns > self._latest_imu_ns + TEMPERATURE_AHEAD_NS:
            self.set_aside["temperature_future"] += 1
            return
        self.readings.push(stamp_ns, degc, True)
        clamped = self.in_force.clamped_rebuilds
        if self.in_force.take_temperature(stamp_ns, degc) and self.in_force.clamped_rebuilds > clamped:
            self.set_aside["temperature_clamped"] += 1

    def set_frame_id(self, frame_id: str) -> None:
        self.on_frame_id(frame_id)
        if self.frame_id is not None:
            self.set_aside["frame_id_changes"] += 1
            self._log.warning(f"{self._imu_topic} frame_id changed from {quoted(self.frame_id)} to {quoted(frame_id)}",
                              throttle_duration_sec=LOG_THROTTLE_S)
        self.frame_id = frame_id
        self.check_frame()

    def check_frame(self) -> None:
        calibration = self.in_force.calibration
        if calibration is not None and calibration.frame_id and self.frame_id is not None \
                and calibration.frame_id != self.frame_id:
            self.set_aside["frame_id_mismatch"] += 1
            self._log.warning(
                f"the calibration in force was made for frame {quoted(calibration.frame_id)} but {self._imu_topic} "
                f"is in {quoted(self.frame_id)}: is this the same sensor?", throttle_duration_sec=LOG_THROTTLE_S)

    # ------------------------------------------------------------------ from the calibration work
    def install(self, calibration: Calibration | None) -> None:
        self.in_force.install(calibration)
        self.check_frame()

    def set_noise(self, accel_var: float | None, gyro_var: float | None) -> None:
        self.in_force.set_noise(accel_var, gyro_var)

    # ------------------------------------------------------------------ immediate answers
    def set_armed(self, armed: bool) -> None:
        if armed == ("armed" in self.pause.reasons):
            return
        self.pause.set_collecting(not armed, "armed")  # marks the samples from the next one on
        # Throttled: an armed input flapping at 1 kHz must not flood the log.
        self._log.info("armed: collection paused (nothing of a flight becomes a pose)" if armed
                       else "disarmed: collection resumed" + self._still_paused(), throttle_duration_sec=LOG_THROTTLE_S)

    def set_paused(self, pause: bool) -> str:
        self.pause.set_collecting(not pause, "calibration/pause")
        return ("collection paused: the corrected stream goes on, no poses are collected" if pause
                else "collection resumed" + self._still_paused())

    def _still_paused(self) -> str:
        reasons = self.pause.reasons
        return f" (still paused: {', '.join(reasons)})" if reasons else ""

    def enable(self, on: bool) -> str:
        self.enabled = on
        return "correction on" if on else "correction off: raw passes through"

    def calibration_text(self) -> tuple[bool, str]:
        calibration = self.in_force.calibration
        if calibration is None:
            return False, "no calibration in force: raw acceleration passes through"
        return True, calibration_to_yaml(calibration)

    def hardware_id(self) -> str:
        calibration = self.in_force.calibration
        if calibration is not None and calibration.sensor_id:
            return calibration.sensor_id
        return self.settings.sensor_id or self.frame_id or ""

    def values(self) -> dict[str, str]:
        """This side's diagnostic values."""
        temperature = self.in_force.temperature_degc
        return {
            # "yes", or why not: "paused (armed)", "paused (calibration/pause)" -- the stream is corrected still
            "collecting": "yes" if self.pause.collecting else "paused (" + ", ".join(self.pause.reasons) + ")",
            "correction": "on" if self.enabled and self.in_force.calibration is not None else "off",
            "frame_id": self.frame_id or "",
            "temperature_degc": "" if temperature is None else f"{temperature:.2f}",
        }
