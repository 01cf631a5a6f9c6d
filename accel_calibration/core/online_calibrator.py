"""Online calibration: poses in, a warm-started refit after each new pose, progress and advice out.

The live node and bag replay both drive this one class with the same Pose records, so a session
gives the same calibration whichever way it arrives. No ROS here.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .calibration import MG, STANDARD_GRAVITY, Calibration
from .coverage import missing_directions
from .errors import CalibrationError
from .fit import FitResult, fit
from .models import MODELS, parameter_count
from .pose import Pose
from .pose_store import PoseStore, StoreEvent
from .temperature_models import TemperatureOptions, temperature_span_problem
from .units import units_problem


@dataclass(frozen=True)
class QualityGates:
    """What a fit must meet before it is applied (by /calibrate, automatically, or by replay). Each
    refusal names the gate: `poses`, `fit`, `residual`, `sigma`, `coverage`, `bias`, `scale`."""

    min_poses: int = 12
    max_residual_rms_mg: float = 15.0  # a MEMS part's pose means fit the sphere to a few mg
    max_bias_sigma_mg: float = 5.0  # the bias must be known this well
    require_all_faces: bool = True  # every axis seen pointing up and down (within ~45 deg)
    max_bias_mps2: float = 2.0  # plausibility: MEMS zero-g offsets are below ~150 mg
    scale_band: tuple[float, float] = (0.9, 1.1)  # plausibility: gain of each axis (row norm of M)

    def __post_init__(self):
        if not (isinstance(self.min_poses, int) and self.min_poses >= 6):
            raise CalibrationError(f"min_poses must be an integer >= 6, got {self.min_poses!r}")
        for name in ("max_residual_rms_mg", "max_bias_sigma_mg", "max_bias_mps2"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise CalibrationError(f"{name} must be a positive number, got {value!r}")
        lo, hi = self.scale_band
        if not (0 < lo < 1 < hi):
            raise CalibrationError(f"scale_band must be (low < 1 < high), got {self.scale_band!r}")

    def check(self, result: FitResult) -> str | None:
        """None when the result passes, else the first gate it fails, said plainly."""
        if result.poses < self.min_poses:
            return f"gate poses: have {result.poses} poses, need min_poses={self.min_poses}"
        if not result.success:
            return f"gate fit: {result.message}"
        calibration = result.calibration
        rms = calibration.quality.residual_rms_mg
        if rms > self.max_residual_rms_mg:
            return f"gate residual: rms {rms:.1f} mg above {self.max_residual_rms_mg:g} mg (motion in the poses?)"
        sigma_mg = float(np.max(result.sigma.bias)) / MG if result.sigma is not None else float("nan")
        if not sigma_mg <= self.max_bias_sigma_mg:
            return f"gate sigma: bias uncertainty {sigma_mg:.2f} mg above {self.max_bias_sigma_mg:g} mg (add poses)"
        if self.require_all_faces and result.missing_directions:
            return "gate coverage: no pose with " + ", no pose with ".join(result.missing_directions)
        return self.plausibility(calibration)

    def plausibility(self, calibration) -> str | None:
        """The bias-range and scale-band gates alone: also what a calibration file must meet before the
        node puts it in force (a well-formed file can still hold absurd numbers)."""
        bias = float(np.max(np.abs(calibration.bias)))
        if bias > self.max_bias_mps2:
            return f"gate bias: |b| {bias:.3f} m/s^2 above the plausible {self.max_bias_mps2:g} m/s^2"
        lo, hi = self.scale_band
        gains = np.linalg.norm(calibration.matrix, axis=1)  # correction gain of each axis (row of M)
        outside = [f"{'xyz'[i]} {g:.4f}" for i, g in enumerate(gains) if not lo <= g <= hi]
        if outside:
            return f"gate scale: correction gain {', '.join(outside)} outside {lo:g}..{hi:g}"
        return None


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


def advice_for(missing) -> str:
    """'turn x down' style advice for the first face not yet covered."""
    axis, _, way = missing[0].partition(" pointing ")
    return f"turn {axis} {way}"


class OnlineCalibrator:
    def __init__(
        self,
        *,
        model: str = "sphere9",
        gravity: float = STANDARD_GRAVITY,
        gates: QualityGates | None = None,
        store: PoseStore | None = None,
        temperature: TemperatureOptions | None = None,
    ):
        if model not in MODELS or model.startswith("reference"):
            raise CalibrationError(f"online model must be six or sphere9 (orientations are unknown), got {model!r}")
        self.model = model
        self.gravity = float(gravity)
        self.gates = gates or QualityGates()
        self.store = store or PoseStore()
        self.temperature = temperature  # None or model "none": temperature-blind
        self.last_fit: FitResult | None = None

    def add_pose(self, pose: Pose) -> StoreEvent:
        return self.store.add(pose)

    def temperature_problem(self, poses=None) -> str | None:
        """Why the poses held cannot carry the temperature model yet (None when they can)."""
        if self.temperature is None or self.temperature.model == "none":
            return "temperature model off"
        temps = [p.temperature_degc for p in (self.store.poses if poses is None else poses)]
        if not temps or any(t is None for t in temps):
            return "no temperature on the poses (imu/temperature silent or stale)"
        return temperature_span_problem(np.array(temps), self.temperature)

    def refit(self, extra_poses=()) -> FitResult | None:
        """Fit the poses held (plus `extra_poses`, merged into a copy of the store, not kept), warm-started
        from the last good fit; with the temperature model once the poses' temperature span allows it.
        None while there are too few poses."""
        store = self.store
        if extra_poses:
            store = store.copy()
            for pose in extra_poses:
                store.add(pose)
        poses = store.poses
        if len(poses) < parameter_count(self.model):
            return None
        accel = [p.accel_mps2 for p in poses]
        if self.temperature_problem(poses) is None:
            result = fit(accel, model=self.model, gravity=self.gravity,
                         temperature_degc=[p.temperature_degc for p in poses],
                         temperature_model=self.temperature.model, temperature_options=self.temperature)
            if result.success:
                self.last_fit = result
                return result
            # Not yet enough poses per temperature: fall back to the temperature-blind fit, said in progress.
        initial = self.last_fit.calibration if self.last_fit is not None and self.last_fit.success else None
        if initial is not None and initial.temperature is not None:
            initial = initial.replace(temperature=None)
        result = fit(accel, model=self.model, gravity=self.gravity, initial=initial)
        if initial is not None and not result.success:
            # A warm start from a calibration that no longer fits (the poses changed) must not decide.
            result = fit(accel, model=self.model, gravity=self.gravity)
        self.last_fit = result
        return result

    def calibrate(self, extra_poses=()) -> tuple[FitResult | None, str | None]:
        """Fit now and judge it: (result, None) when it passes the gates, else (result, reason)."""
        poses = self.store.poses + list(extra_poses)
        problem = units_problem([p.accel_mps2 for p in poses], self.gravity)
        if problem is not None:
            return None, problem
        result = self.refit(extra_poses)
        if result is None:
            return None, f"have {len(self.store) + len(extra_poses)} poses, need at least {max(parameter_count(self.model), self.gates.min_poses)}"
        return result, self.gates.check(result)

    def gyro_bias_radps(self) -> np.ndarray | None:
        """Mean angular rate over the static poses (earth rate, 7e-5 rad/s, is below MEMS noise)."""
        gyros = [(p.gyro_radps, p.samples) for p in self.store.poses if p.gyro_radps is not None]
        if not gyros:
            return None
        weights = np.array([n for _, n in gyros], dtype=float)
        return np.average(np.array([g for g, _ in gyros]), axis=0, weights=weights)

    def directions(self, calibration: Calibration | None = None) -> np.ndarray:
        accel = np.array([p.accel_mps2 for p in self.store.poses]).reshape(-1, 3)
        if calibration is not None:
            accel = calibration.apply(accel)
        norms = np.linalg.norm(accel, axis=1)
        return accel / norms[:, None] if len(accel) else accel

    def progress(self, calibration: Calibration | None = None) -> Progress:
        n = len(self.store)
        missing = tuple(missing_directions(self.directions(calibration))) if n else (
            "x pointing up", "x pointing down", "y pointing up", "y pointing down", "z pointing up", "z pointing down")
        fit_ = self.last_fit if self.last_fit is not None and self.last_fit.success else None
        rms = fit_.calibration.quality.residual_rms_mg if fit_ else None
        sigma = float(np.max(fit_.sigma.bias) / MG) if fit_ and np.all(np.isfinite(fit_.sigma.bias)) else None
        need = max(self.gates.min_poses, parameter_count(self.model))
        ready = fit_ is not None and self.gates.check(fit_) is None and n >= need
        temps = [p.temperature_degc for p in self.store.poses if p.temperature_degc is not None]
        span = (float(min(temps)), float(max(temps))) if temps else None
        problem = self.temperature_problem()
        if problem is None:
            status = "temperature model fitted" if fit_ and fit_.calibration.temperature is not None else \
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
            advice = "ready: call /calibrate"
        return Progress(n, need, missing, rms, sigma, ready, advice, span, status)
