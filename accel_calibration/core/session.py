"""The calibration session: one pure object owns the chain screening -> detector -> pose store ->
fit -> gates -> calibration, and keeps the counters. The live node feeds it messages (stream side
on its executor, pose side on its worker), replay feeds it arrays, tests feed it either: a session
gives the same calibration whichever door the samples came through. No ROS here.

Threads (the node): `add_temperature`, `add_sample`, `holding` touch the screen, temperature filter
and detector; `add_pose`, `refit`, `calibrate`, `reset`, `progress` touch the store and the fit.
Each half is used from one thread; they share nothing mutable but the counters (ints).
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from .calibration import MG, Calibration
from .coverage import missing_directions
from .errors import SettingsError
from .fit import FitResult, fit
from .gates import QualityGates
from .models import parameter_count
from .pose import Pose
from .pose_store import PoseStore, StoreEvent
from .screening import Counters, SampleScreen
from .settings import BY_NAME, DYNAMIC, Settings
from .static_detector import StaticDetector
from .temperature_filter import TemperatureFilter
from .temperature_models import temperature_span_problem
from .units import units_problem

ALL_FACES = ("x pointing up", "x pointing down", "y pointing up", "y pointing down", "z pointing up", "z pointing down")


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


def advice_for(missing: Sequence[str]) -> str:
    """'turn x down' style advice for the first face not yet covered."""
    axis, _, way = missing[0].partition(" pointing ")
    return f"turn {axis} {way}"


@dataclass(frozen=True)
class Verdict:
    """What /calibrate (or replay) decides: a calibration ready to apply, or the gate that refused."""

    success: bool
    message: str  # "gate <name>: <reason>" on refusal
    result: FitResult | None = None
    calibration: Calibration | None = None  # with gyro bias, frame_id and sensor_id filled in


class CalibrationSession:
    def __init__(self, settings: Settings | None = None):
        settings = settings if settings is not None else Settings()
        self.settings = settings
        self.gates = QualityGates.from_settings(settings)
        self.counters = Counters()
        self.screen = SampleScreen(settings, self.counters)
        self.temperature = TemperatureFilter(timeout_s=settings.temperature_timeout_s)
        self.detector = StaticDetector(
            window_s=settings.static_window_s,
            min_hold_s=settings.static_min_hold_s,
            accel_var_threshold=settings.static_accel_var_threshold or None,
            gyro_var_threshold=settings.static_gyro_var_threshold or None,
            k_sigma=settings.static_k_sigma,
        )
        self.store = PoseStore(merge_angle_deg=settings.merge_angle_deg, capacity=settings.max_poses,
                               temperature_bin_degc=settings.temperature_bin_degc)
        self.last_fit: FitResult | None = None
        self.frame_id = ""  # of the samples, from the first message; goes into the calibration

    @property
    def model(self) -> str:
        return self.settings.model

    def update_settings(self, settings: Settings) -> None:
        """Take new values of the run-time settings (gates, auto_calibrate); the others shape the
        detector and store already built and are refused."""
        fixed = [p.name for p in BY_NAME.values() if p.name not in DYNAMIC
                 and getattr(settings, p.field) != getattr(self.settings, p.field)]
        if fixed:
            raise SettingsError(f"{fixed[0]} is fixed at start-up (read-only); restart to change it")
        self.gates = QualityGates.from_settings(settings)
        self.settings = settings

    # ------------------------------------------------------------------ stream side
    def add_temperature(self, stamp_ns: int, degc: float) -> bool:
        """One temperature reading; False (counted) when implausible."""
        if self.temperature.update(stamp_ns, degc):
            return True
        self.counters.temperature_bad += 1
        return False

    def add_sample(self, t_ns: int, ax: float, ay: float, az: float,
                   gx: float = 0.0, gy: float = 0.0, gz: float = 0.0) -> Pose | None:
        """One IMU sample (SI, header stamp in ns). Returns a pose when a still interval ends."""
        if not self.screen.check(t_ns, ax, ay, az, gx, gy, gz):
            return None
        temperature = self.temperature.at(t_ns)
        if temperature is None and self.temperature.value is not None:
            self.counters.temperature_stale += 1
        return self._usable(self.detector.update(t_ns, ax, ay, az, gx, gy, gz, temperature))

    def holding(self) -> Pose | None:
        """The still interval in progress as a pose (what a person holding a pose expects counted)."""
        return self._usable(self.detector.peek())

    def flush(self) -> Pose | None:
        """End of a stream: the interval in progress, if long enough."""
        return self._usable(self.detector.flush())

    def add_recording(self, t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray,
                      temperature_stamps_ns: np.ndarray | None = None,
                      temperature_degc: np.ndarray | None = None) -> list[Pose]:
        """A whole recording in arrival order: the poses `add_sample` per sample then `flush` would give
        (same screening, temperature filter and detector rules, with array operations). Fresh session only."""
        t = np.asarray(t_ns, dtype=np.int64)
        accel = np.asarray(accel_mps2, dtype=float).reshape(-1, 3)
        gyro = np.asarray(gyro_radps, dtype=float).reshape(-1, 3)
        keep = self.screen.screen_arrays(t, accel, gyro)
        temps = None
        if temperature_stamps_ns is not None and temperature_degc is not None and len(temperature_stamps_ns):
            rejected = self.temperature.rejected
            temps, stale = self.temperature.series(temperature_stamps_ns, temperature_degc, t[keep])
            self.counters.temperature_stale += stale
            self.counters.temperature_bad += self.temperature.rejected - rejected
        poses = self.detector.process(t[keep], accel[keep], gyro[keep], temps)
        return [p for p in poses if self._usable(p) is not None]

    def _usable(self, pose: Pose | None) -> Pose | None:
        if pose is not None and self.screen.overlaps_frozen(pose.start_ns, pose.end_ns):
            self.counters.frozen_poses_dropped += 1
            return None
        return pose

    # ------------------------------------------------------------------ pose side
    def add_pose(self, pose: Pose) -> StoreEvent:
        return self.store.add(pose)

    def reset(self) -> int:
        """Drop the poses held (not the learned noise floor); returns how many were dropped."""
        dropped = len(self.store)
        self.store.clear()
        self.last_fit = None
        return dropped

    def temperature_problem(self, poses: Sequence[Pose] | None = None) -> str | None:
        """Why the poses held cannot carry the temperature model yet (None when they can)."""
        if self.settings.temperature_model == "none":
            return "temperature model off"
        temps = [p.temperature_degc for p in (self.store.poses if poses is None else poses)]
        if not temps or any(t is None for t in temps):
            return "no temperature on the poses (imu/temperature silent or stale)"
        return temperature_span_problem(np.array(temps, dtype=float), self.settings.temperature)

    def refit(self, extra_poses: Iterable[Pose] = ()) -> FitResult | None:
        """Fit the poses held (plus `extra_poses`, merged into a copy of the store, not kept), warm-started
        from the last good fit; with the temperature model once the poses' temperature span allows it.
        None while there are fewer poses than parameters. Never raises on poses the detector gives."""
        extra = list(extra_poses)
        store = self.store
        if extra:
            store = store.copy()
            for pose in extra:
                store.add(pose)
        poses = store.poses
        if len(poses) < parameter_count(self.model):
            return None
        accel = [p.accel_mps2 for p in poses]
        gravity = self.settings.gravity
        if self.temperature_problem(poses) is None:
            options = self.settings.temperature
            result = fit(accel, model=self.model, gravity=gravity,
                         temperature_degc=[p.temperature_degc for p in poses if p.temperature_degc is not None],
                         temperature_model=options.model, temperature_options=options)
            if result.success:
                self.last_fit = result
                return result
            # Not yet enough poses per temperature: the temperature-blind fit, said in progress.
        initial = self.last_fit.calibration if self.last_fit is not None and self.last_fit.success else None
        if initial is not None and initial.temperature is not None:
            initial = initial.replace(temperature=None)
        result = fit(accel, model=self.model, gravity=gravity, initial=initial)
        if initial is not None and not result.success:
            # A warm start from a calibration that no longer fits (the poses changed) must not decide.
            result = fit(accel, model=self.model, gravity=gravity)
        self.last_fit = result
        return result

    def calibrate(self, holding: Pose | None = None) -> Verdict:
        """Fit the poses held (and the one being held) and judge the fit; the verdict names the gate."""
        extra = () if holding is None else (holding,)
        poses = self.store.poses + list(extra)
        need = max(self.settings.min_poses, parameter_count(self.model) + 1)
        if len(poses) < need:
            return Verdict(False, f"gate poses: have {len(poses)} poses, need min_poses={need}"
                           f" ({self._missing_text(poses)})")
        problem = units_problem([p.accel_mps2 for p in poses], self.settings.gravity)
        if problem is not None:
            return Verdict(False, "gate " + problem)
        result = self.refit(extra)
        refusal = None if result is None else self.gates.check(result)
        if result is None or result.calibration is None or refusal is not None:
            return Verdict(False, refusal or f"gate fit: no fit from {len(poses)} poses", result)
        calibration = result.calibration.replace(
            gyro_bias_radps=self.gyro_bias_radps(), frame_id=self.frame_id, sensor_id=self.settings.sensor_id)
        return Verdict(True, "passed every gate", replace(result, calibration=calibration), calibration)

    def _missing_text(self, poses: Sequence[Pose]) -> str:
        missing = missing_directions(_directions(poses)) if poses else list(ALL_FACES)
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
        missing = tuple(missing_directions(self.directions(calibration))) if n else ALL_FACES
        fit_ = self.last_fit if self.last_fit is not None and self.last_fit.success else None
        rms = sigma = None
        fitted_temperature = None
        if fit_ is not None:
            # fit() gives every successful result its calibration (with quality) and sigma.
            assert fit_.calibration is not None and fit_.calibration.quality is not None and fit_.sigma is not None
            rms = fit_.calibration.quality.residual_rms_mg
            sigma = float(np.max(fit_.sigma.bias) / MG) if np.all(np.isfinite(fit_.sigma.bias)) else None
            fitted_temperature = fit_.calibration.temperature
        need = max(self.settings.min_poses, parameter_count(self.model) + 1)
        ready = fit_ is not None and self.gates.check(fit_) is None and n >= need
        temps = [p.temperature_degc for p in self.store.poses if p.temperature_degc is not None]
        span = (float(min(temps)), float(max(temps))) if temps else None
        problem = self.temperature_problem()
        if problem is None:
            status = "temperature model fitted" if fitted_temperature is not None else \
                "temperature span sufficient; needs more poses per temperature"
        else:
            status = problem
        if missing:
            advice = advice_for(missing)
        elif n < need:
            advice = f"hold still in a new orientation ({n} of {need} poses)"
        elif not ready:
            advice = "hold still in more orientations (fit not yet within the gates)"
        else:
            advice = f"ready: call {calibrate_service}"
        return Progress(n, need, missing, rms, sigma, ready, advice, span, status)


def _directions(poses: Sequence[Pose], calibration: Calibration | None = None) -> np.ndarray:
    accel = np.array([p.accel_mps2 for p in poses], dtype=float).reshape(-1, 3)
    if calibration is not None:
        accel = calibration.apply(accel)
    norms = np.linalg.norm(accel, axis=1)
    return accel / norms[:, None] if len(accel) else accel
