"""Quality gates: what a fit must meet before it is applied (by /calibrate, auto_calibrate or
replay), and what a calibration file must meet before the node puts it in force. Each refusal
names its gate, so a person knows what to change."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .calibration import Calibration
from .coverage import NextOrientation, ParameterSigma, SigmaBounds, next_orientation, parameter_sigmas, worst
from .errors import CalibrationError
from .fit import FitResult
from .plausibility import GYRO_SCALE_BAND, MAX_BIAS_MPS2, SCALE_BAND, bias_scale_refusal, loadable_part
from .refusal import Gate, Refusal


@dataclass(frozen=True)
class QualityGates:
    """What a fit must meet before it is applied (by /calibrate, automatically, or by replay). Each
    refusal names the gate: `poses`, `fit`, `residual`, `sigma`, `bias`, `scale`. Which faces were
    seen does not matter, only how well the poses pin every parameter down (`sigma`): the refusal
    names the loosest parameter and the orientation that would pin it down most.

    The defaults of the node's gate parameters (core/settings.py reads them from here): `Settings.quality_gates`
    gives the gates of a session's settings."""

    min_poses: int = 12
    max_residual_rms_mg: float = 15.0  # a MEMS part's pose means fit the sphere to a few mg
    max_bias_sigma_mg: float = SigmaBounds.bias_mg  # the bias must be known this well
    max_scale_sigma_ppm: float = SigmaBounds.scale_ppm  # ~5 mg at 1 g, like the bias bound
    max_misalignment_sigma_mrad: float = SigmaBounds.misalignment_mrad  # ~5 mg at 1 g
    max_bias_mps2: float = MAX_BIAS_MPS2  # plausibility (core/plausibility.py)
    scale_band: tuple[float, float] = SCALE_BAND  # plausibility: gain of each axis (row norm of M)
    gyro_scale_band: tuple[float, float] = GYRO_SCALE_BAND  # the gyro's (gyro.scale_min, gyro.scale_max)

    def __post_init__(self) -> None:
        if not (isinstance(self.min_poses, int) and self.min_poses >= 6):
            raise CalibrationError(f"min_poses must be an integer >= 6, got {self.min_poses!r}")
        for name in ("max_residual_rms_mg", "max_bias_sigma_mg", "max_scale_sigma_ppm",
                     "max_misalignment_sigma_mrad", "max_bias_mps2"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value > 0):
                raise CalibrationError(f"{name} must be a positive number, got {value!r}")
        lo, hi = self.scale_band
        if not (0 < lo < 1 < hi):
            raise CalibrationError(f"scale_min < 1 < scale_max must hold, got {lo!r}, {hi!r}")

    @property
    def sigma_bounds(self) -> SigmaBounds:
        return SigmaBounds(self.max_bias_sigma_mg, self.max_scale_sigma_ppm, self.max_misalignment_sigma_mrad)

    def check(self, result: FitResult) -> Refusal | None:
        """None when the result passes, else the first gate it fails, said plainly."""
        if result.poses < self.min_poses:
            left_out = f" ({len(result.outliers)} more left out as outliers)" if result.outliers else ""
            return Refusal(Gate.POSES, f"have {result.poses} poses{left_out}, need min_poses={self.min_poses}")
        return self.check_fit(result)

    def check_fit(self, result: FitResult) -> Refusal | None:
        """Every gate but the pose count: what a fit with a prior must meet, whose few poses are its point."""
        if not result.success:
            return Refusal(Gate.FIT, result.message)
        calibration = result.calibration
        # fit() gives every successful result its calibration, with quality.
        assert calibration is not None and calibration.quality is not None
        rms = calibration.quality.residual_rms_mg
        if rms > self.max_residual_rms_mg:
            return Refusal(Gate.RESIDUAL,
                           f"rms {rms:.1f} mg above {self.max_residual_rms_mg:g} mg (motion in the poses?)")
        return self.sigma_refusal(result) or self.plausibility(calibration)

    def sigma_refusal(self, result: FitResult) -> Refusal | None:
        """The sigma gate alone (None when every parameter is known within its bound). With a prior the
        sigma are of poses and prior together, so a prior too loose to hold what the poses do not see
        is refused here, naming that parameter."""
        loosest = self.worst_sigma(result)
        if loosest is None or not loosest.ratio <= 1.0:
            advice = self.next_orientation(result)
            what = "no uncertainty from the fit" if loosest is None else str(loosest)
            return Refusal(Gate.SIGMA, f"{what}; " + (f"{advice.text} would lower it most" if advice else "add poses"))
        return None

    def worst_sigma(self, result: FitResult) -> ParameterSigma | None:
        """The parameter whose sigma is largest against its bound: from the fit's sigma, or for a fit
        that failed for want of observability, from its normal matrix. None when there is neither."""
        if result.sigma is not None and result.calibration is not None:
            bias_sigma, matrix_sigma = result.sigma.bias, result.sigma.matrix
            matrix = result.calibration.matrix
        elif result.uncertainty is not None:
            bias_sigma, matrix_sigma = result.uncertainty.sigma()
            matrix = result.uncertainty.matrix
        else:
            return None
        return worst(parameter_sigmas(result.model, bias_sigma, matrix_sigma, matrix, self.sigma_bounds))

    def next_orientation(self, result: FitResult) -> NextOrientation | None:
        """The orientation whose pose would lower the largest sigma (against these bounds) most; None
        for the fits that carry no normal matrix (reference models)."""
        if result.uncertainty is None:
            return None
        return next_orientation(result.uncertainty, self.sigma_bounds)

    def plausibility(self, calibration: Calibration) -> Refusal | None:
        """The bias-range and scale-band gates alone: also what a calibration file must meet before the
        node puts it in force (a well-formed file can still hold absurd numbers)."""
        return bias_scale_refusal(calibration.bias, calibration.matrix, self.max_bias_mps2, self.scale_band)

    def loadable(self, calibration: Calibration) -> tuple[Calibration | None, Refusal | None]:
        """What of a calibration that passed the gates may be saved: core/plausibility.loadable_part at
        these bounds, the check the file's readers (the node, `apply`, `report`) make before using it."""
        return loadable_part(calibration, max_bias_mps2=self.max_bias_mps2, scale_band=self.scale_band,
                             gyro_scale_band=self.gyro_scale_band)
