"""Quality gates of a gyro fit (`gyro.*`), apart from the accelerometer's: a refused gyro fit keeps
the accelerometer calibration and says why. Each refusal is a GyroRefusal naming its gate (said
"gyro: gate <name>: ...") and says what to do; pure functions of a GyroFitResult."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import CalibrationError
from .gyro_fit import GyroFitResult, refused_text, turn_advice, unobserved_axes
from .plausibility import GYRO_SCALE_BAND, gains_outside
from .refusal import GyroGate, GyroRefusal
from .units import AXES


@dataclass(frozen=True)
class GyroGates:
    min_motions: int = 8
    # A hand-turned MEMS session misses the next pose by a few mrad (bias drift, white noise over a few s);
    # a wrong scale of 1 % misses a 90 deg turn by 16 mrad.
    max_residual_rms_mrad: float = 10.0
    # 1 sigma of 0.1 % on a turn at 3 rad/s is 3 mrad/s. The imu_tk Xsens session (38 motions, ~3.5 times the
    # white-noise scatter) gives 540-830 ppm and up to 1.0 mrad; simulated MPU-6050 sessions of 18 poses
    # ~100 ppm and ~0.15 mrad.
    max_scale_sigma_ppm: float = 1000.0
    max_misalignment_sigma_mrad: float = 1.5
    scale_band: tuple[float, float] = GYRO_SCALE_BAND  # gain of each axis (row norm of M_g), SI raw rates

    def __post_init__(self) -> None:
        if isinstance(self.min_motions, bool) or not isinstance(self.min_motions, int) or self.min_motions < 5:
            raise CalibrationError(f"gyro min_motions must be an integer >= 5, got {self.min_motions!r}")
        for name in ("max_residual_rms_mrad", "max_scale_sigma_ppm", "max_misalignment_sigma_mrad"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value <= 0:
                raise CalibrationError(f"gyro {name} must be a positive number, got {value!r}")
        lo, hi = self.scale_band
        if not (0 < lo < 1 < hi):
            raise CalibrationError(f"gyro scale_min < 1 < scale_max must hold, got {lo!r}, {hi!r}")

    def check(self, result: GyroFitResult) -> GyroRefusal | None:
        """None when the gyro fit may be applied, else the first gate it fails, one line."""
        return (motions_gate(result, self.min_motions)
                or fit_gate(result)
                or residual_gate(result, self.max_residual_rms_mrad)
                or sigma_gate(result, self.max_scale_sigma_ppm, self.max_misalignment_sigma_mrad)
                or scale_gate(result, self.scale_band))


def motions_gate(result: GyroFitResult, min_motions: int) -> GyroRefusal | None:
    if result.motions_used >= min_motions:
        return None
    counts = refused_text(result.refused)
    not_used = f"; not used: {counts}" if counts else ""
    return GyroRefusal(GyroGate.MOTIONS, f"{result.motions_used} usable motions between poses, need {min_motions}"
                       f"{not_used}; turn the sensor from pose to pose without stopping halfway")


def fit_gate(result: GyroFitResult) -> GyroRefusal | None:
    if result.success:
        return None
    return GyroRefusal(GyroGate.FIT, result.message)


def residual_gate(result: GyroFitResult, max_rms_mrad: float) -> GyroRefusal | None:
    rms = result.residual_rms_mrad
    if rms <= max_rms_mrad:
        return None
    return GyroRefusal(GyroGate.RESIDUAL, f"motions miss the next pose by {rms:.1f} mrad rms, above {max_rms_mrad:g} "
                       "mrad (poses not still, a knock, or the gyro's bias drifting: hold each pose still and turn "
                       "smoothly)")


def sigma_gate(result: GyroFitResult, max_scale_ppm: float, max_misalignment_mrad: float) -> GyroRefusal | None:
    """The loosest parameter against its bound, and the axes to turn about."""
    loose = unobserved_axes(result, max_scale_ppm, max_misalignment_mrad)
    if not loose:
        return None
    scale, misalignment = result.scale_sigma_ppm(), result.misalignment_sigma_mrad()
    ratios = [(scale[q] / max_scale_ppm, f"scale {AXES[q]} sigma {scale[q]:.3g} ppm above {max_scale_ppm:g} ppm")
              for q in range(3)]
    ratios += [(misalignment[p, q] / max_misalignment_mrad,
                f"misalignment {AXES[p]}{AXES[q]} sigma {misalignment[p, q]:.3g} mrad above "
                f"{max_misalignment_mrad:g} mrad") for p in range(3) for q in range(3) if p != q]
    worst = max(ratios, key=lambda item: item[0] if np.isfinite(item[0]) else np.inf)[1]
    return GyroRefusal(GyroGate.SIGMA, f"{worst}; {turn_advice(loose)}")


def scale_gate(result: GyroFitResult, scale_band: tuple[float, float]) -> GyroRefusal | None:
    if result.matrix is None:
        return GyroRefusal(GyroGate.SCALE, "no gyro matrix")
    outside = gains_outside(result.matrix, scale_band)
    if outside:
        return GyroRefusal(GyroGate.SCALE, f"{outside} (gyro.scale_min..gyro.scale_max; is the gyro in rad/s?)")
    return None
