"""The live calibration's work: everything the node does besides correcting and publishing, without ROS.

`feed` takes what the stream side (live/per_message.py) put in the sample rings and hands it to the
session's live feed (the batch pipeline replay uses: live equals replay by construction), takes the poses,
refits, judges and applies; `calibrate`, `reset` and `save` are the services' jobs, each answering
(success, one line). A calibration put in force, and the noise measured, go to the stream side through its
`link` (a LiveStream, or the node's pipe to it from the worker process, live/worker_process.py).

In one process (tests, tools): `LiveCalibration(settings, path, log)` makes its own rings and LiveStream
(`.stream`), wired directly. The node runs this in a worker process over shared rings instead.
"""
from __future__ import annotations

import collections
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from ..core.answers import calibrate_answer, yaml_quoted
from ..core.calibration import Calibration, MeasuredNoise
from ..core.fit import FitResult
from ..core.fit_outliers import nearest_face
from ..core.pose import Pose
from ..core.pose_map import PoseMap, PoseStatus, holes, pose_map
from ..core.session import CalibrationSession, Progress, Verdict
from ..core.settings import Settings
from ..core.warmup_poses import poses_at_reference
from ..core.watch import CalibrationWatch
from .calibration_store import ERROR, OK, WARN, CalibrationStore, Level
from .per_message import LOG_THROTTLE_S, LiveStream, Log, imu_ring, temperature_ring
from .sample_ring import SampleRing
from .warmup_watch import WarmupWatch

__all__ = ["LOG_THROTTLE_S", "LiveCalibration", "Log", "StreamLink", "WorkSnapshot", "diagnostic_values",
           "file_status", "open_calibration_file", "starting_snapshot"]


class StreamLink(Protocol):
    """What the work tells the stream side: the calibration put in force, the noise measured."""

    def install(self, calibration: Calibration | None) -> None: ...
    def set_noise(self, accel_var: float | None, gyro_var: float | None) -> None: ...


@dataclass(frozen=True)
class WorkSnapshot:
    """The work's state as the diagnostics show it, sent whole to the node after each feed or job."""

    status: tuple[Level, str]
    progress: Progress
    pose_map: PoseMap
    values: dict[str, str]
    counts: dict[str, int]


def open_calibration_file(store: CalibrationStore, log: Log, calibrate_service: str) -> tuple[Level, str]:
    """At start: clear what an interrupted save left beside the file, load it, and say in one line what it
    held: (level, that line)."""
    removed = store.remove_stale_temp_files()
    if removed:
        log.info(f"removed {removed} stale temporary file(s) beside {store.path}")
    level, text = store.load()
    if level == WARN:
        log.info(f"{text} (call {calibrate_service} once poses are held)")
    elif level == OK:
        log.info(text)
    else:
        log.error(text)
    return level, text


def file_status(level: Level, text: str) -> tuple[Level, str]:
    """The diagnostics' level and first words after the file was opened."""
    return (level, "calibrated from file" if level == OK else
            "uncalibrated: raw passes through" if level == WARN else f"calibration file unusable: {text}")


NO_NOISE_VALUES = {"accel_noise_density": "", "gyro_noise_density": "", "noise_source": "not yet measured"}


def work_values(still: bool, calibration_path: Path, watch: str, prior_unchecked: str, pose_being_held: str,
                noise: dict[str, str], warmup: dict[str, str]) -> dict[str, str]:
    """The work's diagnostic values, one set of keys from the node's start on."""
    return {"detector_state": "still" if still else "moving", "calibration_file": str(calibration_path),
            "calibration_watch": watch, "prior_unchecked": prior_unchecked, "pose_being_held": pose_being_held,
            **noise, **warmup}


def diagnostic_values(stream: dict[str, str], work: dict[str, str]) -> dict[str, str]:
    """The stream side's values and the work's, in the diagnostics' order."""
    merged = {**stream, **work}
    order = ("detector_state", "collecting", "correction", "calibration_file", "frame_id", "temperature_degc",
             "calibration_watch")
    return {**{key: merged[key] for key in order if key in merged}, **merged}


class LiveCalibration:
    def __init__(self, settings: Settings, calibration_path: Path, log: Log, *, calibrate_service: str = "/calibrate",
                 imu_topic: str = "imu/data_raw", rings: tuple[SampleRing, SampleRing] | None = None,
                 link: StreamLink | None = None):
        self.session = CalibrationSession(settings)
        self.store = CalibrationStore(calibration_path, self.session.settings)  # the file, and what it holds
        # In one process: rings and a stream side of its own; in the worker process: the node's shared rings.
        self.stream: LiveStream | None = None
        if rings is None:
            rings = imu_ring(), temperature_ring()
            self.stream = LiveStream(settings, log, *rings, imu_topic=imu_topic,
                                     on_frame_id=self.set_frame_id)
        self._samples, self._readings = rings
        self._link: StreamLink | None = link or self.stream
        self.still = False  # the detector's state at the last feed
        self._poses_taken = 0  # poses handed to the store since start
        self._applied_at: int | None = None  # _poses_taken when a fit of the poses held was put in force
        self._applied_with_held = False  # that fit counted the pose being held then (it is handed on later)
        self._held: Pose | None = None  # the still interval in progress, as the pose /calibrate would count
        self._dropped_hold_ns: int | None = None  # start of the hold in progress at calibration/reset: dropped too
        self.stream_flowing = False  # the last feed took samples
        # What the work itself set aside, by name (the session's screening keeps its own counters).
        self.set_aside: collections.Counter[str] = collections.Counter()
        self.status: tuple[Level, str] = (OK, "")  # the level and first words of the diagnostics
        self._changed_underneath: tuple[Level, str] | None = None  # the status a save refused for it set
        self.noise: MeasuredNoise | None = None  # measured at this session's poses
        self.prior_unchecked = ""  # what the calibration this session applied took from its prior unchecked
        self._log = log
        self._calibrate_service = calibrate_service
        self._feed = self.session.live_feed()
        self.progress = self.session.progress(None, calibrate_service)
        self.pose_map = pose_map(self.session, None, self.progress)  # the latest, replaced whole
        self.watch: CalibrationWatch = self.session.watch  # the calibration in force against the poses found since
        self.warmup = WarmupWatch(settings.temperature_timeout_s)  # a still warm-up's bias curves

    def start(self, open_file: bool = True) -> None:
        """Put the file's calibration in force. `open_file`: first clear what an interrupted save left and
        log what the file holds (open_calibration_file); the node's process has done both already, at once."""
        if open_file:
            level, text = open_calibration_file(self.store, self._log, self._calibrate_service)
        else:
            level, text = self.store.load()
        self.status = file_status(level, text)
        self._put_in_force(self.store.calibration)
        self.watch.restart(self.store.calibration)
        self._take_prior()
        self.refresh_progress()

    def _put_in_force(self, calibration: Calibration | None) -> None:
        """The stream side corrects with what this side holds in force."""
        if self._link is not None:
            self._link.install(calibration)

    def _take_prior(self) -> None:
        """With use_calibration_in_force_as_prior: /calibrate fits against the calibration in force now (at
        start, at calibration/reset), not one fitted from the poses since (that would count them twice)."""
        if not self.session.settings.use_calibration_in_force_as_prior:
            return
        calibration = self.store.calibration
        refusal = self.session.use_prior(calibration)
        if calibration is None:
            self._log.info("use_calibration_in_force_as_prior: no calibration in force; /calibrate fits without one")
        elif refusal is not None:
            self._log.warning(f"use_calibration_in_force_as_prior: the calibration in force cannot serve as the "
                              f"prior ({refusal.text}); /calibrate fits without one")

    def set_frame_id(self, frame_id: str) -> None:
        self.session.frame_id = frame_id  # a calibration is of the frame the samples were in

    # ------------------------------------------------------------------ what the diagnostics show
    def reported_status(self) -> tuple[Level, str]:
        """The diagnostics' level and first words: the node's status, warned when the watch says the
        calibration in force moved (nothing is applied for it)."""
        level, message = self.status
        watch = self.watch.state
        if watch.moved and level == OK:
            return WARN, f"{message}; calibration moved: {watch.text}"
        return level, message

    def all_counts(self) -> dict[str, int]:
        """Everything set aside or gone wrong, by name: the session's screening counters, what the work set
        aside itself and, in one process, what the stream side set aside."""
        counts = self.session.counters.as_dict()
        for set_aside in (self.set_aside, {} if self.stream is None else self.stream.set_aside):
            for name, count in set_aside.items():
                counts[name] = counts.get(name, 0) + count
        return counts

    def values(self) -> dict[str, str]:
        """The work's diagnostic values (the stream side has its own: diagnostic_values merges them)."""
        held = "" if self._held is None else (
            f"counted: {nearest_face(self._held.accel_mps2)}, {self._held.duration_s:.1f} s still (/calibrate fits "
            "it; a pose of its own once the sensor moves)")
        return work_values(self.still, self.store.path, self.watch.state.text, self.prior_unchecked, held,
                           self._noise_values(), self.warmup.values(self.still))

    def diagnostic_values(self) -> dict[str, str]:
        """In one process: both sides' values."""
        return diagnostic_values({} if self.stream is None else self.stream.values(), self.values())

    def snapshot(self) -> WorkSnapshot:
        progress, shown = self.progress, self.pose_map
        if self._held is not None:  # counted and drawn as /calibrate would fit it
            store = self.session.store.copy()
            if not store.add(self._held).merged:
                accel = self._held.accel_mps2 if self.store.calibration is None else \
                    self.store.calibration.apply(self._held.accel_mps2)
                directions = np.vstack([shown.directions.reshape(-1, 3), accel / np.linalg.norm(accel)])
                shown = dataclasses.replace(shown, directions=directions, statuses=(*shown.statuses, PoseStatus.USED),
                                            holes=holes(directions))
            progress = dataclasses.replace(progress, poses=len(store))
        return WorkSnapshot(self.reported_status(), progress, shown, self.values(), self.all_counts())

    def _noise_values(self) -> dict[str, str]:
        """The white noise measured at this session's poses, else the one the calibration in force was
        made with (Kalibr's *_noise_density, for the estimator's IMU file)."""
        noise, source = self.noise, "measured"
        if noise is None and self.store.calibration is not None:
            noise, source = self.store.calibration.noise, "calibration file"
        if noise is None:
            return dict(NO_NOISE_VALUES)
        gyro = noise.gyro_density
        return {"accel_noise_density": f"{noise.accel_density:.3e} m/s^2/sqrt(Hz)",
                "gyro_noise_density": "" if gyro is None else f"{gyro:.3e} rad/s/sqrt(Hz)",
                "noise_source": f"{source} at {noise.rate_hz:g} Hz"}

    # ------------------------------------------------------------------ worker side
    def update_settings(self, settings: Settings) -> None:
        self.session.update_settings(settings)

    def refresh_progress(self) -> Progress:
        progress = self.session.progress(self.store.calibration, self._calibrate_service)
        since = None if self._applied_at is None else self._poses_taken - self._applied_at
        if progress.ready and since in ((0, 1) if self._applied_with_held else (0,)):
            # What "ready" offered is done: the calibration in force is the fit of these very poses.
            progress = dataclasses.replace(progress, advised_direction=None, advice=(
                "calibrated: the fit of the poses held is applied (more orientations would refine it)"))
        self.progress = progress
        self.pose_map = pose_map(self.session, self.store.calibration, self.progress)
        return self.progress

    def _say_moved(self) -> None:
        """The watch says the calibration in force moved: a warning in the log as well as on /diagnostics
        (throttled: the poses that show it keep coming)."""
        state = self.watch.state
        if state.moved:
            self._log.warning(f"calibration moved: {state.text}", throttle_duration_sec=LOG_THROTTLE_S)

    def feed(self) -> list[Pose]:
        """What the stream put in the rings into the live feed; new poses into the store, a refit."""
        readings, samples = self._readings.take(), self._samples.take()
        self.stream_flowing = len(samples.stamps_ns) > 0
        for name, lost in (("temperature_dropped_backlog", readings.lost), ("samples_dropped_backlog", samples.lost)):
            if lost:
                self.set_aside[name] += lost
        if len(readings.stamps_ns):
            self._feed.add_temperatures(readings.stamps_ns, readings.values[:, 0])
            self.warmup.add_readings(readings.stamps_ns, readings.values[:, 0])
        if len(samples.stamps_ns):
            self._feed.add_samples(samples.stamps_ns, samples.values[:, :3], samples.values[:, 3:], samples.flags)
            self.warmup.add_samples(samples.stamps_ns, samples.values[:, :3], samples.values[:, 3:])
        else:  # the stream is idle: no later reading will come for what waits on one
            self._feed.drain()
        self.still = self.session.detector.holding_still
        poses = [pose for pose in self._feed.take_poses() if pose.start_ns != self._dropped_hold_ns]
        self.warmup.add_still(poses)
        if poses:
            self._absorb(poses)
        # A stream that stops during a hold leaves it open (only later samples could end it): it is shown
        # with the poses, as /calibrate counts it.
        self._held = self._holding() if self.still else None
        return poses

    def _holding(self) -> Pose | None:
        """The hold in progress as the pose it would end as now; not one a calibration/reset dropped."""
        held = self._feed.holding()
        return None if held is None or held.start_ns == self._dropped_hold_ns else held

    def _absorb(self, poses: list[Pose]) -> None:
        log = self._log
        for pose in poses:
            event = self.session.add_pose(pose)
            verb = "refined" if event.merged else "accepted"
            log.info(f"pose {event.index + 1} {verb} ({nearest_face(pose.accel_mps2)}, {pose.duration_s:.1f} s still)")
            log.debug(f"pose {event.index + 1}: mean {np.round(pose.accel_mps2, 5).tolist()} m/s^2 over "
                      f"{pose.samples} samples, {'merged' if event.merged else 'new'}"
                      + (" (disagreed with the pose it would merge into: kept apart)" if event.disagreed else ""))
        self._poses_taken += len(poses)
        # The covariances follow the noise measured at the still poses.
        if self._link is not None:
            self._link.set_noise(self.session.accel_noise_var(), self.session.gyro_noise_var())
        self.noise = self.session.measured_noise()  # read by the diagnostics' thread: set whole
        self.watch.add(poses)
        result = self.session.refit()
        progress = self.refresh_progress()
        self._log_refit(result, progress)
        verdict = self.session.auto_verdict(result)
        if verdict is not None and verdict.calibration is not None:
            applied, message = self._apply(self._keeping_gyro(verdict)[0], verdict.result, asked=False)
            (log.info if applied else log.warning)(("auto-calibrated: " if applied
                                                    else "auto-calibration not applied: ") + message)
        self._say_moved()

    def _log_refit(self, result: FitResult | None, progress: Progress) -> None:
        calibration = None if result is None or not result.success else result.calibration
        if result is None or calibration is None or calibration.quality is None:
            self._log.info(f"{progress.poses} poses held: {progress.advice}")
            return
        self._log.info(f"{progress.poses} poses, fit residual {calibration.quality.residual_rms_mg:.2f} mg rms: "
                       f"{progress.advice}")
        self._log.debug(f"refit: bias {np.round(calibration.bias, 6).tolist()} m/s^2, "
                        f"M {np.round(calibration.matrix, 7).tolist()}, {result.iterations} iterations")

    def _keeping_gyro(self, verdict: Verdict) -> tuple[Calibration, bool]:
        """The calibration a passed verdict puts in force, and whether it keeps the gyro part in force: a
        verdict without a gyro matrix (its gyro fit refused, or none ran) never drops the matrix in force, nor
        the bias it was fitted with (w = M_g (w_raw - b_g): one without the other is neither calibration).
        A gyro part left out whole (implausible) keeps the bias in force too."""
        new, old = verdict.calibration, self.store.calibration
        assert new is not None
        if old is None or new.gyro_matrix is not None or old.gyro_bias_radps is None \
                or (old.gyro_matrix is None and new.gyro_bias_radps is not None):
            return new, False
        kept = new.replace(gyro_bias_radps=old.gyro_bias_radps, gyro_matrix=old.gyro_matrix,
                           gyro_quality=old.gyro_quality)
        loadable, left_aside = self.session.gates.loadable(kept)
        if loadable is None or left_aside is not None:  # never hand on what the file's readers refuse
            return new, False
        return kept, True

    def _apply(self, calibration: Calibration, result: FitResult | None = None, asked: bool = True
               ) -> tuple[bool, str]:
        sources = () if result is None else result.parameter_sources
        prior = f"the calibration in force before ({self.store.path})" if sources else None
        applied, message = self.store.save_then_apply(calibration, asked, sources, prior)
        if applied:
            self.prior_unchecked = "" if result is None else result.unchecked_line()
            self._put_in_force(calibration)
            self.watch.restart(calibration)
            self.status = (OK, "calibrated")
            self._applied_at, self._applied_with_held = self._poses_taken, False
            self.refresh_progress()
        else:
            self._say_unsaved(message)
        return applied, message

    def _say_unsaved(self, message: str) -> None:
        """A save refused because the file changed underneath is a WARN (nothing is broken: two writers
        share the file); any other failed save an ERROR (a file we could not read keeps its own)."""
        if self.store.changed_underneath is not None:
            self.status = self._changed_underneath = (WARN, message)
            self._log.warning(message)
        elif not self.store.file_unreadable:
            self.status = (ERROR, f"save failed: {message}")

    def _warmup_alone(self, not_calibrated: str) -> tuple[bool, str]:
        """/calibrate when the poses give no calibration: a warm-up's curves alone, on top of the calibration
        in force (or the raw output); else the refusal as before, and why no temperature model was added."""
        added, line = self.warmup.added(self.store.calibration, self.session.gates)
        applied, saved = (False, "") if added is None else self._apply(added)
        if not applied:
            message = f"{not_calibrated}; {line}" if added is None else saved
            self._log.warning(f"{self._calibrate_service}: {message}")
            return False, message
        self._log.info(f"{self._calibrate_service}: the warm-up's temperature curves applied, {saved}")
        return True, f"poses: {yaml_quoted(not_calibrated)}\n{line}\nsaved: {saved}"

    def _warmed_refit(self, verdict: Verdict, poses: list[Pose]) -> tuple[Verdict, tuple[Calibration, str]] | None:
        """With a warm-up collected: the poses refitted as at the curves' reference temperature (the drift
        of those held while it warmed taken off) and the curves on top, when that passes; None otherwise. The
        curves come from the poses' own fit, or from the raw output when the poses as they are failed (a
        warm-up's drift fitted as a scale can fail the gates)."""
        if not self.warmup.collected():
            return None
        base = self._keeping_gyro(verdict)[0] if verdict.success and verdict.calibration is not None else None
        warmed, _ = self.warmup.added(base, self.session.gates, poses)
        at_reference = None if warmed is None else poses_at_reference(warmed, poses)
        if at_reference is None:
            return None
        again = self.session.verdict_of(at_reference)
        if not again.success or again.result is None or again.calibration is None:
            return None
        rewarmed, line = self.warmup.added(self._keeping_gyro(again)[0], self.session.gates, at_reference)
        if rewarmed is None:
            return None
        return again, (rewarmed, line[:-1] + ", poses_refitted_at_reference: true}" if line.endswith("}") else line)

    def calibrate(self) -> tuple[bool, str]:
        """/calibrate's job: every sample up to the call counts, and the pose being held right now."""
        self.feed()
        self._feed.drain()
        last = [pose for pose in self._feed.take_poses() if pose.start_ns != self._dropped_hold_ns]
        self._held = self._holding()
        self.warmup.add_still([*last, *([] if self._held is None else [self._held])])
        _, verdict = self.session.verdict_for(last, self._held)
        self._poses_taken += len(last)
        self.watch.add(last)
        self.refresh_progress()
        self._say_moved()
        poses = [*self.session.store.poses, *([] if self._held is None else [self._held])]
        warmed_fit = self._warmed_refit(verdict, poses)
        warmed: Calibration | None = None
        if warmed_fit is not None:
            verdict, (warmed, warmup_line) = warmed_fit
        if not verdict.success or verdict.result is None or verdict.calibration is None:
            message = f"not calibrated ({verdict.message}); {self.store.kept()}"
            if self.warmup.collected():
                return self._warmup_alone(message)
            self._log.warning(f"{self._calibrate_service}: {message}")
            return False, message
        calibration, gyro_kept = self._keeping_gyro(verdict)
        if warmed_fit is None:
            warmed, warmup_line = self.warmup.added(calibration, self.session.gates, poses)
        calibration = warmed or calibration
        applied, saved = self._apply(calibration, verdict.result)
        if not applied:
            self._log.warning(f"{self._calibrate_service}: {saved}")
            return False, saved
        self._applied_with_held = self._held is not None
        self.refresh_progress()
        self._log.info(f"{self._calibrate_service}: calibrated, {saved}")
        if verdict.result.unchecked_line():  # with a prior: what the poses could not check, said
            self._log.warning(f"{self._calibrate_service}: {verdict.result.unchecked_line()}")
        return True, calibrate_answer(verdict.result, saved, verdict.gyro_refusal, gyro_kept) + (
            f"\n{warmup_line}" if warmup_line else "")

    def reset(self) -> tuple[bool, str]:
        self.feed()
        held = self._holding()
        dropped = self.session.reset() + (held is not None)
        # The hold in progress goes too: held before the reset, it is never counted after it.
        self._dropped_hold_ns = None if held is None else held.start_ns
        self._applied_at, self._held = None, None
        self.warmup.reset()
        self._take_prior()
        self.refresh_progress()
        message = f"dropped {dropped} poses; the calibration in force is unchanged"
        self._log.info("calibration/reset: " + message)
        return True, message

    def save(self) -> tuple[bool, str]:
        saved, message = self.store.save()
        if saved and self._changed_underneath is not None and self.status == self._changed_underneath:
            self.status = (OK, "calibrated")  # the change underneath is overwritten on purpose
        elif not saved and self.store.changed_underneath is not None:
            self._say_unsaved(message)
        return saved, message


def starting_snapshot(settings: Settings, calibration_path: Path, calibrate_service: str,
                      status: tuple[Level, str]) -> WorkSnapshot:
    """What the diagnostics show until the work has sent its own (the worker process is starting): `status`
    from the node's own opening of the file."""
    session = CalibrationSession(settings)
    progress = session.progress(None, calibrate_service)
    values = work_values(False, calibration_path, "", "", "", dict(NO_NOISE_VALUES),
                         WarmupWatch(settings.temperature_timeout_s).values(False))
    return WorkSnapshot(status, progress, pose_map(session, None, progress), values, session.counters.as_dict())
