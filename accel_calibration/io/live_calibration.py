"""The live calibration: everything the node does, without ROS.

The stream side (any thread, per message): `buffer_imu` appends the raw sample, marked collecting or
not, to a bounded buffer; `take_temperature` moves the correction's temperature and buffers the reading.
The worker side (one thread): `feed` hands the buffers to the session's live feed (the batch pipeline
replay uses: live equals replay by construction), takes the poses, refits, judges and applies;
`calibrate`, `reset` and `save` are the services' jobs, each answering (success, one line). The node
wires these to topics, services and timers; tests drive them in-process with any logger.
"""
from __future__ import annotations

import collections
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..core.answers import calibrate_answer
from ..core.calibration import Calibration, MeasuredNoise
from ..core.fit import FitResult
from ..core.fit_outliers import nearest_face
from ..core.pose import Pose
from ..core.pose_map import pose_map
from ..core.session import CalibrationSession, Progress
from ..core.settings import Settings
from ..core.watch import CalibrationWatch
from .calibration_file import calibration_to_yaml
from .in_force import ERROR, OK, WARN, CalibrationInForce, Level

__all__ = ["LOG_THROTTLE_S", "MAX_BUFFERED", "TEMPERATURE_AHEAD_NS", "LiveCalibration", "Log"]

LOG_THROTTLE_S = 5.0  # a warning a stream can repeat at 1 kHz is logged at most this often
MAX_BUFFERED = 1 << 18  # raw samples waiting for the worker (~65 s at 4 kHz); beyond, the oldest are dropped
# A temperature reading stamped further than this ahead of the latest IMU stamp is another clock's: dropped
# and counted (temperature_future). Generous: an IMU stream that pauses for a while keeps its readings.
TEMPERATURE_AHEAD_NS = 60_000_000_000


class Log(Protocol):
    """rclpy's logger, as used here (a throttled line takes `throttle_duration_sec`)."""

    def debug(self, message: str, **kwargs: Any) -> Any: ...
    def info(self, message: str, **kwargs: Any) -> Any: ...
    def warning(self, message: str, **kwargs: Any) -> Any: ...
    def error(self, message: str, **kwargs: Any) -> Any: ...


class LiveCalibration:
    def __init__(self, settings: Settings, calibration_path: Path, log: Log, *, calibrate_service: str = "/calibrate",
                 imu_topic: str = "imu/data_raw", on_applied: Callable[[Calibration], None] | None = None):
        self.session = CalibrationSession(settings)
        self.in_force = CalibrationInForce(calibration_path, self.session.settings)
        self.enabled = True  # calibration/enable: off passes raw through
        self.frame_id: str | None = None
        self.still = False  # the detector's state at the last feed
        # What the node itself set aside, by name (the session's screening keeps its own counters).
        self.set_aside: collections.Counter[str] = collections.Counter()
        self.status: tuple[Level, str] = (OK, "")  # the level and first words of the diagnostics
        self._changed_underneath: tuple[Level, str] | None = None  # the status a save refused for it set
        self.noise: MeasuredNoise | None = None  # measured at this session's poses (the worker's latest)
        self._log = log
        self._calibrate_service = calibrate_service
        self._imu_topic = imu_topic
        self._on_applied = on_applied or (lambda calibration: None)
        self._feed = self.session.live_feed()
        # The stream's thread appends, the worker pops: deque's append and popleft are atomic.
        self._samples: collections.deque[tuple[Any, ...]] = collections.deque()
        self._readings: collections.deque[tuple[int, float]] = collections.deque()
        self._latest_imu_ns = -1  # the latest IMU header stamp: temperature stamps are judged against it
        self.progress = self.session.progress(None, calibrate_service)
        self.pose_map = pose_map(self.session, None, self.progress)  # the worker's latest, replaced whole
        self.watch = CalibrationWatch()  # the calibration in force against the poses found since

    def start(self) -> None:
        """Clear what an interrupted save left, and put the file's calibration in force."""
        removed = self.in_force.remove_stale_temp_files()
        if removed:
            self._log.info(f"removed {removed} stale temporary file(s) beside {self.in_force.path}")
        level, text = self.in_force.load()
        if level == WARN:
            self._log.info(f"{text} (call {self._calibrate_service} once poses are held)")
        else:
            (self._log.info if level == OK else self._log.error)(text)
        self.status = (level, "calibrated from file" if level == OK else
                       "uncalibrated: raw passes through" if level == WARN else f"calibration file unusable: {text}")
        if self.in_force.calibration is not None:
            self._on_applied(self.in_force.calibration)
        self.watch.restart(self.in_force.calibration)
        self._take_prior()
        self.refresh_progress()

    def _take_prior(self) -> None:
        """With use_calibration_in_force_as_prior: /calibrate fits against the calibration in force now (at
        start, at calibration/reset), not one fitted from the poses since (that would count them twice)."""
        if not self.session.settings.use_calibration_in_force_as_prior:
            return
        calibration = self.in_force.calibration
        refusal = self.session.use_prior(calibration)
        if calibration is None:
            self._log.info("use_calibration_in_force_as_prior: no calibration in force; /calibrate fits without one")
        elif refusal is not None:
            self._log.warning(f"use_calibration_in_force_as_prior: the calibration in force cannot serve as the "
                              f"prior ({refusal}); /calibrate fits without one")

    # ------------------------------------------------------------------ stream side (per message)
    def buffer_imu(self, stamp_ns: int, ax: float, ay: float, az: float, gx: float, gy: float, gz: float) -> None:
        if len(self._samples) >= MAX_BUFFERED:
            self._samples.popleft()
            self.set_aside["samples_dropped_backlog"] += 1
        if stamp_ns > self._latest_imu_ns:
            self._latest_imu_ns = stamp_ns
        self._samples.append((stamp_ns, ax, ay, az, gx, gy, gz, self.session.collecting))

    def take_temperature(self, stamp_ns: int, degc: float) -> None:
        # A reading stamped far ahead of the IMU stream (another publisher's clock) would take the
        # correction temperature with it, and leave the true readings after it none.
        if self._latest_imu_ns >= 0 and stamp_ns > self._latest_imu_ns + TEMPERATURE_AHEAD_NS:
            self.set_aside["temperature_future"] += 1
            return
        self._readings.append((stamp_ns, degc))
        clamped = self.in_force.clamped_rebuilds
        if self.in_force.take_temperature(stamp_ns, degc) and self.in_force.clamped_rebuilds > clamped:
            self.set_aside["temperature_clamped"] += 1

    def set_frame_id(self, frame_id: str) -> None:
        self.session.frame_id = frame_id  # a calibration is of the frame the samples were in
        if self.frame_id is not None:
            self.set_aside["frame_id_changes"] += 1
            self._log.warning(f"{self._imu_topic} frame_id changed from {self.frame_id!r} to {frame_id!r}",
                              throttle_duration_sec=LOG_THROTTLE_S)
        self.frame_id = frame_id
        self.check_frame()

    def check_frame(self) -> None:
        calibration = self.in_force.calibration
        if calibration is not None and calibration.frame_id and self.frame_id is not None \
                and calibration.frame_id != self.frame_id:
            self.set_aside["frame_id_mismatch"] += 1
            self._log.warning(
                f"the calibration in force was made for frame {calibration.frame_id!r} but {self._imu_topic} is "
                f"in {self.frame_id!r}: is this the same sensor?", throttle_duration_sec=LOG_THROTTLE_S)

    def set_armed(self, armed: bool) -> None:
        if armed == ("armed" in self.session.pause_reasons):
            return
        self.session.set_collecting(not armed, "armed")  # marks the samples from the next one on
        # Throttled: an armed input flapping at 1 kHz must not flood the log.
        self._log.info("armed: collection paused (nothing of a flight becomes a pose)" if armed
                       else "disarmed: collection resumed" + self._still_paused(), throttle_duration_sec=LOG_THROTTLE_S)

    # ------------------------------------------------------------------ immediate answers
    def pause(self, pause: bool) -> str:
        self.session.set_collecting(not pause, "calibration/pause")
        return ("collection paused: the corrected stream goes on, no poses are collected" if pause
                else "collection resumed" + self._still_paused())

    def _still_paused(self) -> str:
        reasons = self.session.pause_reasons
        return f" (still paused: {', '.join(reasons)})" if reasons else ""

    def enable(self, on: bool) -> str:
        self.enabled = on
        return "correction on" if on else "correction off: raw passes through"

    def reported_status(self) -> tuple[Level, str]:
        """The diagnostics' level and first words: the node's status, warned when the watch says the
        calibration in force moved (nothing is applied for it)."""
        level, message = self.status
        watch = self.watch.state
        if watch.moved and level == OK:
            return WARN, f"{message}; calibration moved: {watch.text}"
        return level, message

    def calibration_text(self) -> tuple[bool, str]:
        calibration = self.in_force.calibration
        if calibration is None:
            return False, "no calibration in force: raw acceleration passes through"
        return True, calibration_to_yaml(calibration)

    def all_counts(self) -> dict[str, int]:
        """Everything set aside or gone wrong, by name: the session's screening counters and what the node
        set aside itself."""
        counts = self.session.counters.as_dict()
        counts.update(self.set_aside)
        return counts

    def diagnostic_values(self) -> dict[str, str]:
        temperature = self.in_force.temperature_degc
        return {
            "detector_state": "still" if self.still else "moving",
            # "yes", or why not: "paused (armed)", "paused (calibration/pause)" -- the stream is corrected still
            "collecting": ("yes" if self.session.collecting
                           else "paused (" + ", ".join(self.session.pause_reasons) + ")"),
            "correction": "on" if self.enabled and self.in_force.calibration is not None else "off",
            "calibration_file": str(self.in_force.path),
            "frame_id": self.frame_id or "",
            "temperature_degc": "" if temperature is None else f"{temperature:.2f}",
            "calibration_watch": self.watch.state.text,
            **self._noise_values(),
        }

    def _noise_values(self) -> dict[str, str]:
        """The white noise measured at this session's poses, else the one the calibration in force was
        made with (Kalibr's *_noise_density, for the estimator's IMU file)."""
        noise, source = self.noise, "measured"
        if noise is None and self.in_force.calibration is not None:
            noise, source = self.in_force.calibration.noise, "calibration file"
        if noise is None:
            return {"accel_noise_density": "", "gyro_noise_density": "", "noise_source": "not yet measured"}
        gyro = noise.gyro_density
        return {"accel_noise_density": f"{noise.accel_density:.3e} m/s^2/sqrt(Hz)",
                "gyro_noise_density": "" if gyro is None else f"{gyro:.3e} rad/s/sqrt(Hz)",
                "noise_source": f"{source} at {noise.rate_hz:g} Hz"}

    def hardware_id(self) -> str:
        calibration = self.in_force.calibration
        if calibration is not None and calibration.sensor_id:
            return calibration.sensor_id
        return self.session.settings.sensor_id or self.frame_id or ""

    # ------------------------------------------------------------------ worker side
    def update_settings(self, settings: Settings) -> None:
        self.session.update_settings(settings)

    def refresh_progress(self) -> Progress:
        self.progress = self.session.progress(self.in_force.calibration, self._calibrate_service)
        self.pose_map = pose_map(self.session, self.in_force.calibration, self.progress)
        return self.progress

    def feed(self) -> list[Pose]:
        """What the stream buffered into the live feed; new poses into the store, a refit."""
        readings = [self._readings.popleft() for _ in range(len(self._readings))]
        rows = [self._samples.popleft() for _ in range(len(self._samples))]
        if readings:
            self._feed.add_temperatures(np.fromiter((r[0] for r in readings), np.int64, len(readings)),
                                        np.fromiter((r[1] for r in readings), float, len(readings)))
        if rows:
            values = np.array([r[1:7] for r in rows], dtype=float)
            self._feed.add_samples(np.fromiter((r[0] for r in rows), np.int64, len(rows)), values[:, :3],
                                   values[:, 3:], np.fromiter((r[7] for r in rows), bool, len(rows)))
        else:  # the stream is idle: no later reading will come for what waits on one
            self._feed.drain()
        self.still = self.session.detector.holding_still
        poses = self._feed.take_poses()
        if poses:
            self._absorb(poses)
        return poses

    def _absorb(self, poses: list[Pose]) -> None:
        log = self._log
        for pose in poses:
            event = self.session.add_pose(pose)
            verb = "refined" if event.merged else "accepted"
            log.info(f"pose {event.index + 1} {verb} ({nearest_face(pose.accel_mps2)}, {pose.duration_s:.1f} s still)")
            log.debug(f"pose {event.index + 1}: mean {np.round(pose.accel_mps2, 5).tolist()} m/s^2 over "
                      f"{pose.samples} samples, {'merged' if event.merged else 'new'}"
                      + (" (disagreed with the pose it would merge into: kept apart)" if event.disagreed else ""))
        # The covariances follow the noise measured at the still poses.
        self.in_force.set_noise(self.session.accel_noise_var(), self.session.gyro_noise_var())
        self.noise = self.session.measured_noise()  # read by the diagnostics' thread: set whole
        self.watch.add(poses)
        result = self.session.refit()
        progress = self.refresh_progress()
        self._log_refit(result, progress)
        verdict = self.session.auto_verdict(result)
        if verdict is not None and verdict.calibration is not None:
            applied, message = self._apply(verdict.calibration, verdict.result, asked=False)
            (log.info if applied else log.warning)(("auto-calibrated: " if applied
                                                    else "auto-calibration not applied: ") + message)

    def _log_refit(self, result: FitResult | None, progress: Progress) -> None:
        calibration = None if result is None or not result.success else result.calibration
        if result is None or calibration is None or calibration.quality is None:
            self._log.info(f"{progress.poses} poses held: {progress.advice}")
            return
        self._log.info(f"{progress.poses} poses, fit residual {calibration.quality.residual_rms_mg:.2f} mg rms: "
                       f"{progress.advice}")
        self._log.debug(f"refit: bias {np.round(calibration.bias, 6).tolist()} m/s^2, "
                        f"M {np.round(calibration.matrix, 7).tolist()}, {result.iterations} iterations")

    def _apply(self, calibration: Calibration, result: FitResult | None = None, asked: bool = True
               ) -> tuple[bool, str]:
        sources = () if result is None else result.parameter_sources
        prior = f"the calibration in force before ({self.in_force.path})" if sources else None
        applied, message = self.in_force.save_then_apply(calibration, asked, sources, prior)
        if applied:
            self._on_applied(calibration)
            self.watch.restart(calibration)
            self.check_frame()
            self.status = (OK, "calibrated")
        else:
            self._say_unsaved(message)
        return applied, message

    def _say_unsaved(self, message: str) -> None:
        """A save refused because the file changed underneath is a WARN (nothing is broken: two writers
        share the file); any other failed save an ERROR (a file we could not read keeps its own)."""
        if self.in_force.changed_underneath is not None:
            self.status = self._changed_underneath = (WARN, message)
            self._log.warning(message)
        elif not self.in_force.file_unreadable:
            self.status = (ERROR, f"save failed: {message}")

    def calibrate(self) -> tuple[bool, str]:
        """/calibrate's job: every sample up to the call counts, and the pose being held right now."""
        self.feed()
        self._feed.drain()
        last = self._feed.take_poses()
        _, verdict = self.session.verdict_for(last, self._feed.holding())
        self.watch.add(last)
        self.refresh_progress()
        if not verdict.success or verdict.result is None or verdict.calibration is None:
            message = f"not calibrated ({verdict.message}); {self.in_force.kept()}"
            self._log.warning(f"{self._calibrate_service}: {message}")
            return False, message
        applied, saved = self._apply(verdict.calibration, verdict.result)
        if not applied:
            self._log.warning(f"{self._calibrate_service}: {saved}")
            return False, saved
        self._log.info(f"{self._calibrate_service}: calibrated, {saved}")
        return True, calibrate_answer(verdict.result, saved, verdict.gyro_refusal)

    def reset(self) -> tuple[bool, str]:
        self.feed()
        dropped = self.session.reset()
        self._take_prior()
        self.refresh_progress()
        message = f"dropped {dropped} poses; the calibration in force is unchanged"
        self._log.info("calibration/reset: " + message)
        return True, message

    def save(self) -> tuple[bool, str]:
        saved, message = self.in_force.save()
        if saved and self._changed_underneath is not None and self.status == self._changed_underneath:
            self.status = (OK, "calibrated")  # the change underneath is overwritten on purpose
        elif not saved and self.in_force.changed_underneath is not None:
            self._say_unsaved(message)
        return saved, message
