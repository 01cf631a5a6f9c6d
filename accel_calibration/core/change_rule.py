"""When a calibration has moved: the rule `accel-calib history` applies between two calibrations and
`accel-calib check` between a calibration and a recording. A change is flagged when it exceeds what its
sigma explains, |delta| > k_sigma * sigma, or a plausibility bound whatever the sigma."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from .errors import AccelCalibrationError, SettingsError


@dataclass(frozen=True)
class ChangeJudgement:
    sigmas: float  # |change| / sigma; inf when the sigma is zero or unknown and the change is not 0
    by_sigma: bool
    by_bound: bool

    @property
    def flagged(self) -> bool:
        return self.by_sigma or self.by_bound


@dataclass(frozen=True)
class ChangeRule:
    """The thresholds, written once: history's and check's defaults and flags come from here."""

    k_sigma: float = 5.0
    max_bias_change_mg: float = 50.0  # a healthy MEMS part's bias does not jump this much between flights
    max_scale_change: float = 0.01  # nor its gain by 1 %
    error: ClassVar[type[AccelCalibrationError]] = SettingsError

    def __post_init__(self) -> None:
        for name in ("k_sigma", "max_bias_change_mg", "max_scale_change"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise self.error(f"{name} must be a positive number, got {value!r}")

    def judge(self, change: float, sigma: float, bound: float) -> ChangeJudgement:
        """One change with its (combined) 1-sigma against the rule; `bound` in the change's units."""
        known = math.isfinite(sigma) and sigma > 0
        sigmas = abs(change) / sigma if known else (math.inf if change != 0 else 0.0)
        return ChangeJudgement(sigmas, known and abs(change) > self.k_sigma * sigma, abs(change) > bound)
