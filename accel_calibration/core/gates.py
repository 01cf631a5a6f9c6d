"""Quality gates: what a fit must meet before it is applied (by /calibrate, auto_calibrate or
replay), and what a calibration file must meet before the node puts it in force. Each refusal
names its gate, so a person knows what to change."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .calibration import MG, Calibration
from .errors import CalibrationError
from .fit import FitResult
from .settings import Settings


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

    def __post_init__(self) -> None:
        if not (isinstance(self.min_poses, int) and self.min_poses >= 6):
            raise CalibrationError(f"min_poses must be an integer >= 6, got {self.min_poses!r}")
        for name in ("max_residual_rms_mg", "max_bias_sigma_mg", "max_bias_mps2"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise CalibrationError(f"{name} must be a positive number, got {value!r}")
        lo, hi = self.scale_band
        if not (0 < lo < 1 < hi):
            raise CalibrationError(f"scale_min < 1 < scale_max must hold, got {lo!r}, {hi!r}")

    @classmethod
    def from_settings(cls, settings: Settings) -> QualityGates:
        return cls(min_poses=settings.min_poses, max_residual_rms_mg=settings.max_residual_rms_mg,
                   max_bias_sigma_mg=settings.max_bias_sigma_mg, max_bias_mps2=settings.max_bias_mps2,
                   scale_band=(settings.scale_min, settings.scale_max))

    def check(self, result: FitResult) -> str | None:
        """None when the result passes, else the first gate it fails, said plainly."""
        if result.poses < self.min_poses:
            return f"gate poses: have {result.poses} poses, need min_poses={self.min_poses}"
        if not result.success:
            return f"gate fit: {result.message}"
        calibration = result.calibration
        # fit() gives every successful result its calibration, with quality.
        assert calibration is not None and calibration.quality is not None
        rms = calibration.quality.residual_rms_mg
        if rms > self.max_residual_rms_mg:
            return f"gate residual: rms {rms:.1f} mg above {self.max_residual_rms_mg:g} mg (motion in the poses?)"
        sigma_mg = float(np.max(result.sigma.bias)) / MG if result.sigma is not None else float("nan")
        if not sigma_mg <= self.max_bias_sigma_mg:
            return f"gate sigma: bias uncertainty {sigma_mg:.2f} mg above {self.max_bias_sigma_mg:g} mg (add poses)"
        if self.require_all_faces and result.missing_directions:
            return "gate coverage: no pose with " + ", no pose with ".join(result.missing_directions)
        return self.plausibility(calibration)

    def plausibility(self, calibration: Calibration) -> str | None:
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
