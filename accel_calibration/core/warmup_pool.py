"""Warm-ups of one IMU from many logs (a vehicle's cold mornings and warm afternoons) pooled into one curve,
each log with its own turn-on bias (core/warmup.fit_warmup ties them where their temperatures overlap), and
a log whose warm-up disagrees with the others' beyond noise (another vehicle's sensor under the same device
ID, a drift the log's own fit could not tell from a step) left out and named, never averaged in.

A log is judged by its own curve (fitted alone, on top of its own calibration in force) against the pooled
curve, both taken back to the sensor's raw units, over the temperatures they share, each log's constant
removed (its turn-on bias). When the pool disagrees, the log whose leaving out makes the rest agree best is
the one left out; two logs that disagree cannot say which of them is the stranger: refused."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .calibration import Calibration
from .units import MG
from .warmup import WarmupFit, WarmupRecording, WarmupResult
from .warmup_curve import BiasCurve

# Beyond noise: this many sigma of the two curves together, and never less than a physical floor (what
# two fits of one sensor's warm-ups differ by at their ends: a few tenths of a mg, a tenth of a mrad/s).
DISAGREE_SIGMAS = 5.0
DISAGREE_MG = 2.0
DISAGREE_MRADPS = 0.4
MIN_COMMON_DEGC = 2.0  # less common temperature than this cannot show a difference of shape
GRID_POINTS = 41


@dataclass(frozen=True)
class PoolMember:
    """One log's warm-up of the IMU: its samples, its own fit (on top of `base`), and `base`, its calibration
    in force (None: the raw output)."""

    name: str
    recording: WarmupRecording
    alone: WarmupFit
    base: Calibration | None


@dataclass(frozen=True)
class Disagreement:
    """A log's curve against another's over their common temperatures, its constant removed: the worst
    difference (mg, mrad/s), where, and its ratio to what noise allows (above 1: beyond noise)."""

    accel_mg: float
    gyro_mradps: float
    at_degc: float
    ratio: float

    def text(self) -> str:
        gyro = f", gyro {self.gyro_mradps:.2f} mrad/s" if self.gyro_mradps == self.gyro_mradps else ""
        return (f"accelerometer {self.accel_mg:.1f} mg{gyro} at {self.at_degc:.1f} degC "
                f"({self.ratio:.1f} x what noise allows)")


@dataclass(frozen=True)
class PooledWarmup:
    """The pooled fit (or its refusal), the members it used and those left out with why (index, reason)."""

    result: WarmupResult
    used: tuple[int, ...]
    left_out: tuple[tuple[int, str], ...]


def _raw(curve: BiasCurve, base: Calibration | None, degc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The curve and its sigma at `degc` in the sensor's raw units (undoing the matrix it was fitted under)."""
    values, sigma = curve.at(degc), curve.sigma_at(degc)
    if base is None:
        return values, sigma
    inverse = np.linalg.inv(base.matrix)
    return values @ inverse.T, sigma @ np.abs(inverse).T


def _raw_gyro(curve: BiasCurve, base: Calibration | None, degc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    values, sigma = curve.at(degc), curve.sigma_at(degc)
    if base is None or base.gyro_matrix is None:
        return values, sigma
    inverse = np.linalg.inv(base.gyro_matrix)
    return values @ inverse.T, sigma @ np.abs(inverse).T


def _worst(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], floor: float
           ) -> tuple[float, int, float]:
    """(worst |difference| with the constant removed, at which grid point, its ratio to the allowed)."""
    difference = a[0] - b[0]
    difference = difference - difference.mean(axis=0)
    allowed = np.maximum(floor, DISAGREE_SIGMAS * np.hypot(a[1], b[1]))
    ratio = np.abs(difference) / allowed
    row = int(np.argmax(ratio.max(axis=1)))
    return float(np.abs(difference).max()), row, float(ratio.max())


def disagreement(member: PoolMember, fit: WarmupFit, base: Calibration | None) -> Disagreement | None:
    """The member's own curve against `fit` (on top of `base`) over their common temperatures; None when they
    share too little temperature to show a difference of shape."""
    low = max(member.alone.range_degc[0], fit.range_degc[0])
    high = min(member.alone.range_degc[1], fit.range_degc[1])
    if high - low < MIN_COMMON_DEGC:
        return None
    degc = np.linspace(low, high, GRID_POINTS)
    accel, row, ratio = _worst(_raw(member.alone.accel, member.base, degc), _raw(fit.accel, base, degc),
                               DISAGREE_MG * MG)
    gyro_mradps = float("nan")
    if member.alone.gyro is not None and fit.gyro is not None:
        gyro, gyro_row, gyro_ratio = _worst(_raw_gyro(member.alone.gyro, member.base, degc),
                                            _raw_gyro(fit.gyro, base, degc), DISAGREE_MRADPS * 1e-3)
        gyro_mradps = gyro * 1e3
        if gyro_ratio > ratio:
            row, ratio = gyro_row, gyro_ratio
    return Disagreement(accel / MG, gyro_mradps, float(degc[row]), ratio)


def _ratio(found: Disagreement | None) -> float:
    return 0.0 if found is None else found.ratio


FitPool = Callable[[list[WarmupRecording]], WarmupResult]  # recordings -> their pooled fit on top of `base`


def pool_warmups(members: list[PoolMember], base: Calibration | None, fit_pool: FitPool) -> PooledWarmup:
    """Every member's warm-up pooled into one curve on top of `base` (`fit_pool`: core/warmup.fit_warmup with
    `base` and the caller's options and settings); a member that disagrees beyond noise left out (the one
    whose leaving out makes the rest agree best, again while they disagree). Never raises on data: a
    refusal says why."""
    used = list(range(len(members)))
    left_out: list[tuple[int, str]] = []
    result = fit_pool([members[i].recording for i in used])
    while result.fit is not None:
        fit = result.fit
        checks = {i: disagreement(members[i], fit, base) for i in used}
        worst = max(used, key=lambda i: _ratio(checks[i]))
        if _ratio(checks[worst]) <= 1.0:
            break
        if len(used) == 2:
            found = checks[worst]
            assert found is not None
            names = " and ".join(members[i].name for i in used)
            return PooledWarmup(WarmupResult(None, f"warm-up: the warm-ups of {names} disagree beyond noise "
                                                   f"({found.text()}) and two cannot say which is the stranger "
                                                   "(another sensor under this device ID, a step): give a third "
                                                   "warm-up of this IMU, or leave the wrong one out"),
                                tuple(used), tuple(left_out))
        trials = []
        for i in used:
            rest = [j for j in used if j != i]
            trial = fit_pool([members[j].recording for j in rest])
            if trial.fit is not None:
                trial_fit = trial.fit
                trials.append((max(_ratio(disagreement(members[j], trial_fit, base)) for j in rest), i, trial))
        if not trials:
            break
        _, stranger, result = min(trials, key=lambda trial: trial[0])
        used.remove(stranger)
        assert result.fit is not None
        against = disagreement(members[stranger], result.fit, base)
        said = "beyond noise" if against is None else against.text()
        left_out.append((stranger, f"its warm-up disagrees with the other logs' ({said}): another sensor, or a "
                                   "step; left out, not averaged in"))
    return PooledWarmup(result, tuple(used), tuple(left_out))
