"""The calibration session: one pure object owns the chain screening -> detector -> pose store ->
fit -> gates -> calibration, and keeps the counters. There is one sample path: arrays in parts through a
RecordingFeed. Replay hands it a recording (`add_recording`, or `recording_feed` for a streamed one); the
node's worker process hands it what the Imu callback put in the sample ring, every fifth of a second
(`live_feed`), the armed/pause state as a per-sample collecting mask (core/stream/collection_pause.py). So
live equals replay by construction. No ROS here, and one thread: the worker's.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration, MeasuredNoise
from .coverage import Face, missing_directions, missing_faces
from .errors import CalibrationError
from .fit import FitResult, fit, pose_mean_sigma
from .gyro_fit import GyroFitResult, fit_gyro
from .models import parameter_count
from .plausibility import implausible_text
from .pose import Pose
from .pose_store import PoseStore, StoreEvent
from .prior import Prior, prior_terms
from .refusal import OPENED_BY_POSES, Gate, Refusal
from .settings import BY_NAME, Settings, check_run_time_change
from .stream.detector import StaticDetector
from .stream.feed import RecordingFeed
from .stream.motion_recorder import MotionRecorder
from .stream.screening import Counters
from .stream.stream_side import StreamSide
from .temperature_models import segment_status, temperature_span_problem
from .units import MG, units_text
from .watch import CalibrationWatch


@dataclass(frozen=True)
class Progress:
    poses: int
    min_poses: int
    missing: tuple[str, ...]
    residual_rms_mg: float | None
    max_bias_sigma_mg: float | None
    ready: bool
    advice: str
    temperature_span_degc: tuple[float, float] | None = None  # lowest and highest pose temperature
    temperature_status: str = "no temperature"
    # The unit specific force of the orientation the advice turns to; None when the advice is no turn.
    advised_direction: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Verdict:
    """What /calibrate (or replay) decides: a calibration ready to apply, or the gate that refused."""

    success: bool
    message: str  # "gate <name>: <reason>" on refusal, with the poses left out as outliers
    result: FitResult | None = None
    calibration: Calibration | None = None  # with gyro bias, frame_id and sensor_id filled in
    gyro: GyroFitResult | None = None  # the gyro fit tried with it (applied when its gates passed)
    gyro_refusal: str | None = None  # why it was not applied ("gyro: gate ...: ..."), None when it was or none ran
    refusal: Refusal | None = None  # the gate that refused, None on success

    @classmethod
    def refused(cls, refusal: Refusal, said: str = "", result: FitResult | None = None) -> Verdict:
        """A refusal: `said` (the outliers left out, what else helps) follows the gate's own text."""
        return cls(False, str(refusal) + said, result, refusal=refusal)


class CalibrationSession:
    def __init__(self, settings: Settings | None = None):
        settings = settings if settings is not None else Settings()
        self.settings = settings
        self.gates = settings.quality_gates
        self._stream = StreamSide(settings)
        self.store = PoseStore(merge_angle_deg=settings.merge_angle_deg, capacity=settings.max_poses,
                               temperature_bin_degc=settings.temperature_bin_degc,
                               merge_tolerance_mps2=settings.merge_tolerance_mg * MG)
        self.last_fit: FitResult | None = None
        # The last cold fit and the poses it fitted (held, not compared by value: a merge makes a new pose).
        self._cold_fit: tuple[tuple[Pose, ...], FitResult] | None = None
        # The last gyro verdict and what it was a function of, held the same way (_same_inputs).
        self._gyro_fit: tuple[tuple[object, ...], tuple[GyroFitResult | None, str | None]] | None = None
        self.frame_id = ""  # of the samples, from the first message; goes into the calibration
        # Recalibration with a prior (core/prior.py): calibrate() fits what the poses observe and keeps the
        # rest at the prior; set it with `use_prior`.
        self.prior: Prior | None = None
        # The calibration in force against the poses found since (the node drives it; replay has none in
        # force): once it saw a move, calibrate() refuses to fit poses from before it with those after.
        self.watch = CalibrationWatch()

    @property
    def model(self) -> str:
        return self.settings.model

    def update_settings(self, settings: Settings) -> None:
        """Take new values of the run-time settings (gates, auto_calibrate); the others shape the
        detector and store already built and are refused."""
        check_run_time_change(self.settings, settings)
        self.gates = settings.quality_gates
        self.settings = settings
        self._cold_fit = None
        self._gyro_fit = None

    # ------------------------------------------------------------------ stream side
    @property
    def stream(self) -> StreamSide:
        """The stream side: samples in parts -> poses and motions (core/stream/), the feeds' one target."""
        return self._stream

    # The stream side's parts the pose side and the node read: its counters, the detector's floors, the
    # motions between poses (anything else through `stream`).
    @property
    def counters(self) -> Counters:
        return self._stream.counters

    @property
    def detector(self) -> StaticDetector:
        return self._stream.detector

    @property
    def motions(self) -> MotionRecorder:
        return self._stream.motions

    def add_recording(self, t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray,
                      temperature_stamps_ns: np.ndarray | None = None,
                      temperature_degc: np.ndarray | None = None,
                      collecting: np.ndarray | None = None,
                      part_rows: int = RecordingFeed.PART_ROWS) -> list[Pose]:
        """A whole recording in arrival order: its poses (screening, temperature filter and detector rules,
        with array operations). `collecting` (one bool per sample, optional): False where collection was
        paused (armed, flying). Fresh session only. The same as feeding it in parts through
        `recording_feed` (it is done so, in parts of `part_rows`) or `live_feed`."""
        has_temperature = temperature_stamps_ns is not None and temperature_degc is not None
        feed = self.recording_feed(has_temperature=has_temperature, part_rows=part_rows)
        if has_temperature:
            feed.add_temperatures(temperature_stamps_ns, temperature_degc)  # type: ignore[arg-type]
        feed.add_samples(t_ns, accel_mps2, gyro_radps, collecting)
        return feed.finish()

    def recording_feed(self, has_temperature: bool, part_rows: int = RecordingFeed.PART_ROWS) -> RecordingFeed:
        """A recording read in pieces (a bag streamed chunk by chunk): add samples and temperature readings
        as they come, then `finish()` for the poses. Memory stays bounded by a part, whatever the length.
        `has_temperature`: temperature readings will come (samples then wait for the readings of their
        time); `part_rows`: samples per detector call (the poses do not depend on how the reader chunks).
        Fresh session only."""
        return RecordingFeed(self._stream, has_temperature, part_rows=part_rows)

    def live_feed(self) -> RecordingFeed:
        """The node's door: samples and temperature readings in whatever batches the stream gave, each part
        processed as soon as the readings of its time have come (at most LIVE_TEMPERATURE_WAIT_NS late), poses
        taken with `take_poses` as they end, the interval in progress seen with `holding`. Fresh session only."""
        return RecordingFeed(self._stream, has_temperature=True, live=True)

    # ------------------------------------------------------------------ pose side
    def add_pose(self, pose: Pose) -> StoreEvent:
        event = self.store.add(pose)
        if event.disagreed:
            self.counters.merge_disagreements += 1
        return event

    def reset(self) -> int:
        """Drop the poses held (not the learned noise floor); returns how many were dropped."""
        dropped = len(self.store)
        self.store.clear()
        self.motions.clear()
        self.last_fit = None
        self._cold_fit = None
        self._gyro_fit = None
        return dropped

    def temperature_problem(self, poses: Sequence[Pose] | None = None) -> str | None:
        """Why the poses held cannot carry the temperature model yet (None when they can)."""
        if self.settings.temperature_model == "none":
            return "temperature model off"
        temps = [p.temperature_degc for p in (self.store.poses if poses is None else poses)]
        if not temps or any(t is None for t in temps):
            return "no temperature on the poses (imu/temperature silent or stale)"
        return temperature_span_problem(np.array(temps, dtype=float), self.settings.temperature)

    def refit(self, extra_poses: Iterable[Pose] = (), warm: bool = True) -> FitResult | None:
        """Fit the poses held (plus `extra_poses`, merged into a copy of the store, not kept), warm-started
        from the last good fit unless `warm` is False; with the temperature model once the poses'
        temperature span allows it. None while there are fewer poses than parameters. Never raises on
        poses the detector gives."""
        extra = list(extra_poses)
        store = self.store
        if extra:
            store = store.copy()
            for pose in extra:
                store.add(pose)
        poses = store.poses
        if len(poses) < parameter_count(self.model):
            return None
        initial = self.last_fit.calibration if warm and self.last_fit is not None and self.last_fit.success else None
        if initial is None and self._cold_fit is not None and _same_poses(self._cold_fit[0], poses):
            # A cold fit is a function of the poses alone: these were fitted already (an auto-calibration's
            # verdict, then /calibrate's).
            self.last_fit = self._cold_fit[1]
            return self.last_fit
        result = self._fit(poses, initial)
        if initial is None:
            self._cold_fit = (tuple(poses), result)
        self.last_fit = result
        return result

    def _fit(self, poses: Sequence[Pose], initial: Calibration | None) -> FitResult:
        """The fit of `poses`: with the temperature model when their span allows it and it succeeds, else
        blind to temperature, started from `initial` (None: cold)."""
        accel = [p.accel_mps2 for p in poses]
        gravity = self.settings.gravity
        # A pose off the sphere with the rest is left out (and named) by the fit itself.
        outliers, noise = self.settings.outliers, pose_mean_sigma(poses)
        if self.temperature_problem(poses) is None:
            options = self.settings.temperature
            result = fit(accel, model=self.model, gravity=gravity,
                         temperature_degc=[p.temperature_degc for p in poses if p.temperature_degc is not None],
                         temperature_model=options.model, temperature_options=options,
                         outlier_options=outliers, pose_sigma_mps2=noise)
            if result.success:
                return result
            # Not yet enough poses per temperature: the temperature-blind fit, said in progress.
        if initial is not None and initial.temperature is not None:
            initial = initial.replace(temperature=None)
        result = fit(accel, model=self.model, gravity=gravity, initial=initial, outlier_options=outliers,
                     pose_sigma_mps2=noise)
        if initial is not None and not result.success:
            # A warm start from a calibration that no longer fits (the poses changed) must not decide.
            result = fit(accel, model=self.model, gravity=gravity, outlier_options=outliers, pose_sigma_mps2=noise)
        return result

    def _too_noisy_text(self) -> str:
        """Why few poses were found when the sensor was hardly ever still (its quietest noise near or above
        the most a still pose may have): what to do about it, which limit refused its windows and how to
        allow it; "" otherwise. Mostly frozen samples (kept out before the detector) are said instead: the
        floor then knew only the motions, so the noise it reports is theirs."""
        counters = self.counters
        if counters.frozen and 4 * counters.frozen >= counters.samples:
            # A noise-free stream: no floor to learn from its still windows, so a threshold of 1 mg rms per axis.
            threshold = 3.0 * MG**2
            return (f"; {counters.frozen} of {counters.samples} samples repeat the one before bit for bit, in runs "
                    f"of frozen_samples {self.settings.frozen_samples} or more, and were kept out (a frozen driver "
                    "or bus: a live MEMS part always shows noise); for a noise-free sensor (a simulation): "
                    f"-p frozen_samples:=1000000 -p static.accel_var_threshold:={threshold:.6f}")
        accel, gyro = self.detector.noise_near_ceilings
        noisy = ([] if accel is None else [f"accel {accel / MG:.1f} mg rms per axis (static.max_noise_mg "
                                           f"{self.settings.static_max_noise_mg:g})"]) \
            + ([] if gyro is None else [f"gyro {gyro * 1e3:.0f} mrad/s rms per axis (static.max_gyro_noise_mradps "
                                        f"{self.settings.static_max_gyro_noise_mradps:g})"])
        if not noisy:
            return ""
        return (f"; the sensor was hardly ever still: its quietest noise, {' and '.join(noisy)}, is near or above "
                "the most a still pose may have (hand-held, driving or vibrating): set it down on something firm "
                f"for each pose{self._refusing_limits_text()}")

    def _refusing_limits_text(self) -> str:
        """The noise limits that decided instead of the learned noise floor, and the `-p` values that let the
        floor decide (the node takes the same parameters); "" when none did."""
        quietest_accel, quietest_gyro = self.detector.noise_near_ceilings
        learned_accel, learned_gyro = self.detector.learned_beyond_ceilings
        said, allow = [], []
        for name, limit, quietest, learned, unit, scale in (
                ("static.max_noise_mg", self.settings.static_max_noise_mg, quietest_accel, learned_accel, "mg",
                 1.0 / MG),
                ("static.max_gyro_noise_mradps", self.settings.static_max_gyro_noise_mradps, quietest_gyro,
                 learned_gyro, "mrad/s", 1e3)):
            if learned is None:
                continue
            if quietest is not None and quietest * scale >= limit:
                said.append(f"{name} refused every window (its quietest {quietest * scale:.1f} {unit})")
            else:
                said.append(f"{name} refused windows as still as the sensor's own noise floor allows (up to "
                            f"{learned * scale:.0f} {unit})")
            allow.append(f"-p {name}:={_rounded_up(learned * scale, BY_NAME[name].high):.1f}")
        if not said:
            return ""
        in_degrees = ""
        if learned_gyro is not None and quietest_accel is None and quietest_gyro is not None \
                and math.radians(quietest_gyro) * 1e3 < self.settings.static_max_gyro_noise_mradps / 4:
            # A still accelerometer beside a gyro that in rad/s would be quiet: deg/s given as rad/s.
            in_degrees = (f"; only the gyro was that noisy: is it in deg/s given as rad/s? (its quietest "
                    f"noise would then be {math.radians(quietest_gyro) * 1e3:.1f} mrad/s)")
        return f"; {' and '.join(said)}{in_degrees}; to take this sensor as it is: {' '.join(allow)}"

    def use_prior(self, prior: Prior | Calibration | None) -> Refusal | None:
        """Fit /calibrate's verdicts with this prior (None: without one). Returns why it cannot serve as
        this session's prior (the prior gate; then none is used), None when it can."""
        if prior is None:
            self.prior = None
            return None
        given = prior if isinstance(prior, Prior) else Prior(prior)
        try:
            prior_terms(given, self.model, self.settings.gravity)
        except CalibrationError as error:
            self.prior = None
            return Refusal(Gate.PRIOR, str(error))
        self.prior = given
        return None

    def verdict_for(self, poses: Iterable[Pose], holding: Pose | None = None) -> tuple[list[StoreEvent], Verdict]:
        """/calibrate's verdict once `poses` (those found since the last) are in the store: where each went
        (the store's events, in order) and the verdict, with the pose being held."""
        events = [self.add_pose(pose) for pose in poses]
        return events, self.calibrate(holding)

    def calibrate(self, holding: Pose | None = None) -> Verdict:
        """Fit the poses held (and the one being held) and judge the fit; the verdict names the gate."""
        extra = () if holding is None else (holding,)
        mixed = self.moved_text()
        if mixed is not None:
            return Verdict.refused(Refusal(Gate.MOVED, mixed))
        if self.prior is not None:
            return self._calibrate_with_prior(self.store.poses + list(extra), self.prior)
        poses = self.store.poses + list(extra)
        need = self.poses_needed()
        if len(poses) < need:
            # Still intervals that were no gravity: a stream in g or in counts says so, not "0 poses".
            dropped = self._stream.implausible_means
            problem = units_text(dropped, self.settings.gravity) if len(dropped) > len(poses) else None
            if problem is not None:
                return Verdict.refused(Refusal(Gate.UNITS, problem))
            return Verdict.refused(Refusal(Gate.POSES, f"have {len(poses)} poses, need min_poses={need}"
                                           f" ({self._missing_text(poses)}){self._too_noisy_text()}"))
        problem = units_text([p.accel_mps2 for p in poses], self.settings.gravity)
        if problem is not None:
            return Verdict.refused(Refusal(Gate.UNITS, problem))
        # Cold: the verdict depends on the poses alone, not on how many warm refits the node's worker
        # happened to run while they arrived (live and replay then agree exactly, whatever the load).
        result = self.refit(extra, warm=False)
        refusal = None if result is None else self.gates.check(result)
        # Poses left out as outliers are said either way, counted from 1 as the node's log counts them.
        left_out = "" if result is None else "".join(f"; {o.describe(o.index + 1)}" for o in result.outliers)
        if result is None or result.calibration is None or refusal is not None:
            return Verdict.refused(refusal or Refusal(Gate.FIT, f"no fit from {len(poses)} poses"), left_out, result)
        return self._passed(result, left_out)

    def verdict_of(self, poses: Sequence[Pose]) -> Verdict:
        """The verdict on `poses` as given, neither stored nor cached: e.g. the poses with a warm-up's drift
        taken off, so that those held while the sensor warmed count at the temperature the others were. Put
        through a store of their own first: those that now agree at one orientation merge into one pose."""
        store = self.store.copy()
        store.clear()
        for pose in poses:
            store.add(pose)
        poses = store.poses
        if len(poses) < parameter_count(self.model):
            return Verdict.refused(Refusal(Gate.POSES, f"have {len(poses)} poses, need {parameter_count(self.model)}"))
        result = self._fit(poses, None)
        refusal = self.gates.check(result)
        left_out = "".join(f"; {o.describe(o.index + 1)}" for o in result.outliers)
        if result.calibration is None or refusal is not None:
            return Verdict.refused(refusal or Refusal(Gate.FIT, f"no fit from {len(poses)} poses"), left_out, result)
        return self._passed(result, left_out)

    def moved_text(self) -> str | None:
        """Why the poses held cannot be fitted together: the watch saw the calibration in force move and some
        were found before it (a fit would average the sensor before and after the move, with a sigma that
        knows nothing of it); None when none was."""
        since = self.watch.moved_since_ns
        before = 0 if since is None else sum(1 for pose in self.store.poses if pose.start_ns < since)
        if not before:
            return None
        moved = self.watch.state.text.split(": recalibrate")[0]
        return (f"the calibration in force moved ({moved}); {before} of the {len(self.store)} poses held are from "
                "before the move: fitted with those after, they would mix the sensor before and after it; call "
                "calibration/reset, hold each orientation again, then calibrate")

    def poses_needed(self) -> int:
        """The poses a fit without a prior needs: min_poses, and at least one more than the model has
        parameters (so the residual can say whether the poses agree)."""
        return max(self.settings.min_poses, parameter_count(self.model) + 1)

    def _calibrate_with_prior(self, poses: list[Pose], prior: Prior) -> Verdict:
        """With a prior the pose count is no gate: what poses and prior support together decides (the fit's
        own checks, then every gate but the count). No temperature model: a prior fits b and M alone."""
        if not poses:
            return Verdict.refused(Refusal(Gate.POSES, "no pose held (a fit with a prior still needs poses)"))
        problem = units_text([p.accel_mps2 for p in poses], self.settings.gravity)
        if problem is not None:
            return Verdict.refused(Refusal(Gate.UNITS, problem))
        result = fit([p.accel_mps2 for p in poses], model=self.model, gravity=self.settings.gravity,
                     outlier_options=self.settings.outliers, pose_sigma_mps2=pose_mean_sigma(poses), prior=prior)
        refusal = self.gates.check_fit(result)
        left_out = "".join(f"; {o.describe(o.index + 1)}" for o in result.outliers)
        if result.calibration is None or refusal is not None:
            return Verdict.refused(refusal or Refusal(Gate.FIT, f"no fit from {len(poses)} poses"), left_out, result)
        return self._passed(result, left_out)

    def _passed(self, result: FitResult, left_out: str) -> Verdict:
        """A fit that passed the gates: the calibration with what the session adds, and the gyro's fit."""
        assert result.calibration is not None
        calibration = result.calibration.replace(
            gyro_bias_radps=self.gyro_bias_radps(), frame_id=self.frame_id, sensor_id=self.settings.sensor_id,
            noise=self.measured_noise(), gravity_source=self.settings.gravity_source)
        gyro, gyro_text = self._gyro_verdict_of(result, calibration)
        if gyro is not None and gyro_text is None:
            calibration = gyro.apply_to(calibration)
        said = "" if gyro_text is None and gyro is None else (
            f"; gyro: {gyro.motions_used} motions, residual {gyro.residual_rms_mrad:.2f} mrad rms"
            if gyro_text is None and gyro is not None else f"; {gyro_text} (the gyro keeps its bias only)")
        # Never hand on what the file's readers would refuse: every writer (node, replay, fleet) saves this.
        loadable, refusal = self.gates.loadable(calibration)
        if loadable is None:
            assert refusal is not None
            return Verdict.refused(refusal, left_out, result)
        if refusal is not None:  # the gyro part left out
            gyro_text = f"gyro left out: {implausible_text(refusal)}"
            said = f"; {gyro_text}; the accelerometer calibration is kept"
        return Verdict(True, "passed every gate" + left_out + said, replace(result, calibration=loadable),
                       loadable, gyro, gyro_text)

    def measured_noise(self) -> MeasuredNoise | None:
        """The white noise measured at the still poses, as a density at the poses' sample rate (None
        before the noise floor is learned or a pose is held)."""
        accel_var = self.accel_noise_var()
        poses = [p for p in self.store.poses if p.samples > 1 and p.end_ns > p.start_ns]
        if accel_var is None or accel_var <= 0 or not poses:
            return None
        rate_hz = round(float(np.median([(p.samples - 1) / p.duration_s for p in poses])), 2)
        try:
            gyro_var = self.gyro_noise_var()
            return MeasuredNoise.from_variances(rate_hz, accel_var, gyro_var if gyro_var else None)
        except CalibrationError:  # a stream in counts or another unit: no density to keep
            return None

    def accel_noise_var(self) -> float | None:
        """The accelerometer's white-noise variance per axis, (m/s^2)^2: the pooled variance of the samples
        within the still poses held (each pose's spread about its own mean, weighted by its degrees of
        freedom). Not the detector's floor: a low quantile of window variances reads low (0.83x the real
        variance at 0.03 m/s^2 per sample). None before a pose of two samples is held."""
        poses = [p for p in self.store.poses if p.samples > 1]
        if not poses:
            return None
        dof = np.array([p.samples - 1 for p in poses], dtype=float)
        per_axis = np.array([float(np.trace(p.accel_cov)) / 3.0 for p in poses])
        return float(dof @ per_axis / dof.sum())

    def gyro_noise_var(self) -> float | None:
        """The gyro's white-noise variance per axis, (rad/s)^2: the quietest still windows' (None before)."""
        _, floor = self.detector.quietest_floors  # window total over the three axes
        return None if floor is None else floor / 3.0

    def gyro_verdict(self, accel: Calibration) -> tuple[GyroFitResult | None, str | None]:
        """The gyro fit from the motions between the poses found, in the frame of this accelerometer
        calibration, and why it may not be applied (None: it may). (None, None) when gyro.calibrate is off
        or no two consecutive poses were seen."""
        poses, motions = self.motions.poses_and_motions()
        if not self.settings.gyro_calibrate or len(poses) < 2 or all(p.gyro_radps is None for p in poses):
            return None, None
        if any(p.gyro_radps is None for p in poses):
            return None, "gyro: the poses hold no angular rate"
        variance = self.gyro_noise_var()
        noise = None if variance is None else float(np.sqrt(variance))
        try:
            result = fit_gyro(poses, motions, accel, options=self.settings.gyro_fit, gyro_noise_radps=noise)
        except CalibrationError as error:  # the accelerometer's calibration stands whatever the gyro's inputs
            return None, f"gyro: not fitted ({error})"
        refusal = self.settings.gyro_gates.check(result)
        return result, None if refusal is None else str(refusal)

    def _gyro_verdict_of(self, result: FitResult, accel: Calibration) -> tuple[GyroFitResult | None, str | None]:
        """gyro_verdict for the calibration of `result`, taken from the last when nothing it is a function of
        changed: the fit (held, not compared by value), the poses and motions the recorder holds and the gyro's
        noise. An auto-calibration's verdict, then /calibrate's on the same poses, fit the gyro once."""
        poses, motions = self.motions.poses_and_motions()
        inputs = (result, *poses, None, *motions, self.gyro_noise_var())
        if self._gyro_fit is not None and _same_inputs(self._gyro_fit[0], inputs):
            return self._gyro_fit[1]
        verdict = self.gyro_verdict(accel)
        self._gyro_fit = (inputs, verdict)
        return verdict

    def auto_verdict(self, result: FitResult | None) -> Verdict | None:
        """With auto_calibrate on: the verdict to apply once the latest refit passes every gate (None when
        nothing is to be applied)."""
        if not self.settings.auto_calibrate or result is None or self.gates.check(result) is not None:
            return None
        verdict = self.calibrate()
        return verdict if verdict.success else None

    def _missing_text(self, poses: Sequence[Pose]) -> str:
        missing = missing_directions(_directions(poses)) if poses else [str(face) for face in Face]
        return "still missing: " + ", ".join(missing) if missing else "every face seen; hold more orientations"

    def gyro_bias_radps(self) -> np.ndarray | None:
        """Mean angular rate over the static poses (earth rate, 7e-5 rad/s, is below MEMS noise)."""
        gyros = [(p.gyro_radps, p.samples) for p in self.store.poses if p.gyro_radps is not None]
        if not gyros:
            return None
        weights = np.array([n for _, n in gyros], dtype=float)
        return np.average(np.array([g for g, _ in gyros]), axis=0, weights=weights)

    def directions(self, calibration: Calibration | None = None) -> np.ndarray:
        return _directions(self.store.poses, calibration)

    def progress(self, calibration: Calibration | None = None, calibrate_service: str = "/calibrate") -> Progress:
        """Poses held, faces missing, the last fit and what to do next; `calibration` (the one in force)
        turns the poses into directions, `calibrate_service` is the service name as the node resolves it."""
        n = len(self.store)
        faces = missing_faces(self.directions(calibration)) if n else list(Face)
        fit_ = self.last_fit if self.last_fit is not None and self.last_fit.success else None
        rms = sigma = None
        fitted_temperature = None
        if fit_ is not None:
            # fit() gives every successful result its calibration (with quality) and sigma.
            assert fit_.calibration is not None and fit_.calibration.quality is not None and fit_.sigma is not None
            rms = fit_.calibration.quality.residual_rms_mg
            sigma = float(np.max(fit_.sigma.bias) / MG) if np.all(np.isfinite(fit_.sigma.bias)) else None
            fitted_temperature = fit_.calibration.temperature
        need = self.poses_needed()
        refusal = None if self.last_fit is None else self.gates.check(self.last_fit)
        moved = self.moved_text() is not None
        ready = fit_ is not None and refusal is None and n >= need and not moved
        # Once there is a fit (one that failed for want of observability too), the orientation that would
        # pin the loosest parameter down most; before, the first face not yet seen.
        turn = None
        if self.last_fit is not None and refusal is not None and refusal.gate in OPENED_BY_POSES:
            turn = self.gates.next_orientation(self.last_fit)
        temps = [p.temperature_degc for p in self.store.poses if p.temperature_degc is not None]
        span = (float(min(temps)), float(max(temps))) if temps else None
        problem = self.temperature_problem()
        if problem is None and self.settings.temperature_model == "segmented":
            # Which segments are learned, and which orientations each of the others still needs.
            status = segment_status(np.array(temps, dtype=float), self.directions(calibration),
                                    self.settings.temperature, fitted_temperature)
        elif problem is None:
            status = "temperature model fitted" if fitted_temperature is not None else \
                "temperature span sufficient; needs more poses per temperature"
        else:
            status = problem
        direction: ArrayLike | None = None
        if ready:
            advice = f"ready: call {calibrate_service}"
        elif moved:
            advice = "the calibration moved after poses held were found: call calibration/reset, then hold again"
        elif turn is not None:
            advice, direction = turn.text, turn.direction
        elif faces:
            advice, direction = faces[0].turn, faces[0].direction
        elif n < need:
            advice = f"hold still in a new orientation ({n} of {need} poses)"
        else:
            advice = "hold still in more orientations (fit not yet within the gates)"
        missing = tuple(str(face) for face in faces)
        return Progress(n, need, missing, rms, sigma, ready, advice, span, status,
                        None if direction is None else _unit_tuple(direction))


def _directions(poses: Sequence[Pose], calibration: Calibration | None = None) -> np.ndarray:
    accel = np.array([p.accel_mps2 for p in poses], dtype=float).reshape(-1, 3)
    if calibration is not None:
        accel = calibration.apply(accel)
    norms = np.linalg.norm(accel, axis=1)
    return accel / norms[:, None] if len(accel) else accel


def _same_poses(fitted: Sequence[Pose], poses: Sequence[Pose]) -> bool:
    return len(fitted) == len(poses) and all(a is b for a, b in zip(fitted, poses, strict=True))


def _same_inputs(held: Sequence[object], inputs: Sequence[object]) -> bool:
    """The same objects (numbers: equal) in the same order."""
    return len(held) == len(inputs) and all(
        a == b if isinstance(a, float) or a is None else a is b for a, b in zip(held, inputs, strict=True))


def _unit_tuple(direction: ArrayLike) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in np.asarray(direction, dtype=float).reshape(3))
    return (x, y, z)


def _rounded_up(value: float, highest: float | None) -> float:
    """`value` rounded up to two significant digits (a limit to type), at most `highest`."""
    step = 10.0 ** (math.floor(math.log10(value)) - 1)
    rounded = math.ceil(value / step) * step
    return rounded if highest is None else min(rounded, highest)
