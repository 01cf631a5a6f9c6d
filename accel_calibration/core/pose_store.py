"""The poses the online calibration holds: a new pose at an orientation already held is merged
into it (its mean gets better, the geometry does not change) when the two means agree within their
noise: each one's standard error of the mean (its covariance, at least the noise floor of the poses held,
over its samples) and a small allowance (`merge_tolerance_mg`). One at a new orientation, or one that
disagrees (another tilt; a bias that moved, which a band of several mg would average into the poses from
before; or not still at all: a hover that passed as still must not pull a ground pose towards it), is added
and the disagreement counted.
Bounded: at capacity a pose gives way, the oldest of those whose orientation is held more than once
(so coverage is kept), else the oldest; a node that runs for days keeps a fixed size."""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import CalibrationError
from .pose import Pose


@dataclass(frozen=True)
class StoreEvent:
    index: int  # position of the pose in the store
    merged: bool  # True when merged into a pose already held
    replaced_oldest: bool = False
    disagreed: bool = False  # a held pose at this orientation (and temperature bin) disagreed: kept apart


# Two means agree when the Mahalanobis distance of their difference is within this (chi-square, 3
# degrees of freedom, 99.9 %): a false split of one still orientation once in a thousand. The value of
# scipy.stats.chi2.ppf(0.999, 3), written out: importing scipy.stats costs every command start ~0.1-0.5 s
# (test_fit_fast_paths checks it against scipy).
AGREEMENT_CHI2 = 16.26623619623813


def merge_poses(a: Pose, b: Pose) -> Pose:
    """Sample-weighted mean and pooled covariance of two static intervals."""
    n = a.samples + b.samples
    wa, wb = a.samples / n, b.samples / n
    mean = wa * a.accel_mps2 + wb * b.accel_mps2
    da, db = a.accel_mps2 - mean, b.accel_mps2 - mean
    cov = wa * (a.accel_cov + np.outer(da, da)) + wb * (b.accel_cov + np.outer(db, db))
    gyro = None
    if a.gyro_radps is not None and b.gyro_radps is not None:
        gyro = wa * a.gyro_radps + wb * b.gyro_radps
    temperature = spread = None
    if a.temperature_degc is not None and b.temperature_degc is not None:
        temperature = wa * a.temperature_degc + wb * b.temperature_degc
        lows = [a.temperature_degc - (a.temperature_spread_degc or 0) / 2,
                b.temperature_degc - (b.temperature_spread_degc or 0) / 2]
        highs = [a.temperature_degc + (a.temperature_spread_degc or 0) / 2,
                 b.temperature_degc + (b.temperature_spread_degc or 0) / 2]
        spread = max(highs) - min(lows)
    return replace(
        b,
        accel_mps2=mean,
        accel_cov=cov,
        samples=n,
        start_ns=min(a.start_ns, b.start_ns),
        end_ns=max(a.end_ns, b.end_ns),
        gyro_radps=gyro,
        temperature_degc=temperature,
        temperature_spread_degc=spread,
    )


def means_agree(a: Pose, b: Pose, tolerance_mps2: float, noise_floor_var: float = 0.0) -> bool:
    """The two poses' mean accelerations differ by no more than their standard errors (covariance / samples,
    each axis' variance at least `noise_floor_var`, (m/s^2)^2: a pose whose samples happened to be quiet or
    quantised claims no better mean than the sensor's noise allows) plus `tolerance_mps2` per axis (what the
    standard errors do not hold: correlated noise, slow drift) allow, at 99.9 %."""
    difference = a.accel_mps2 - b.accel_mps2
    covariance = (_floored(a.accel_cov, noise_floor_var) / max(a.samples, 1)
                  + _floored(b.accel_cov, noise_floor_var) / max(b.samples, 1)
                  + np.eye(3) * tolerance_mps2 ** 2)
    try:
        distance = float(difference @ np.linalg.solve(covariance, difference))
    except np.linalg.LinAlgError:  # no noise and no tolerance: only identical means agree
        return bool(np.all(difference == 0.0))
    return distance <= AGREEMENT_CHI2 if np.isfinite(distance) else False


def _floored(covariance: np.ndarray, floor_var: float) -> np.ndarray:
    """`covariance` with each axis' variance raised to `floor_var` where below it (still positive semi-definite:
    only the diagonal grows)."""
    diagonal = np.diag(covariance)
    return np.asarray(covariance + np.diag(np.maximum(floor_var - diagonal, 0.0)), dtype=float)


class PoseStore:
    def __init__(self, *, merge_angle_deg: float = 5.0, capacity: int = 100, temperature_bin_degc: float | None = None,
                 merge_tolerance_mps2: float = 0.005):
        if not (0.0 < merge_angle_deg < 90.0):
            raise CalibrationError(f"merge_angle_deg must be in (0, 90), got {merge_angle_deg}")
        if not (isinstance(merge_tolerance_mps2, (int, float)) and 0.0 <= merge_tolerance_mps2 < np.inf):
            raise CalibrationError(f"merge_tolerance_mps2 must be a finite number >= 0, got {merge_tolerance_mps2!r}")
        if not (isinstance(capacity, int) and capacity >= 6):
            raise CalibrationError(f"capacity must be an integer >= 6, got {capacity!r}")
        if temperature_bin_degc is not None and not temperature_bin_degc > 0:
            raise CalibrationError(f"temperature_bin_degc must be positive, got {temperature_bin_degc}")
        self._cos_merge = float(np.cos(np.radians(merge_angle_deg)))
        self.merge_tolerance_mps2 = float(merge_tolerance_mps2)
        self.capacity = capacity
        self.temperature_bin_degc = temperature_bin_degc
        self._poses: list[Pose] = []
        self._merges: list[int] = []  # per pose held: how many later poses were merged into it

    def __len__(self) -> int:
        return len(self._poses)

    @property
    def poses(self) -> list[Pose]:
        return list(self._poses)

    @property
    def merges(self) -> list[int]:
        """Per pose held, in the order of `poses`: how many later poses were merged into it."""
        return list(self._merges)

    def copy(self) -> PoseStore:
        other = PoseStore.__new__(PoseStore)
        other.__dict__.update(self.__dict__)
        other._poses = list(self._poses)
        other._merges = list(self._merges)
        return other

    def clear(self) -> None:
        self._poses.clear()
        self._merges.clear()

    def _same_bin(self, a: Pose, b: Pose) -> bool:
        if self.temperature_bin_degc is None or a.temperature_degc is None or b.temperature_degc is None:
            return True
        return abs(a.temperature_degc - b.temperature_degc) < self.temperature_bin_degc

    def _neighbours(self, pose: Pose) -> list[int]:
        """Held poses at the same orientation (within the merge angle) and temperature bin."""
        direction = pose.direction
        return [index for index, held in enumerate(self._poses)
                if float(direction @ held.direction) >= self._cos_merge and self._same_bin(held, pose)]

    def noise_floor_var(self) -> float:
        """The noise of the poses held, per axis, (m/s^2)^2: the median of their per-axis variances (a hover
        that passed as still does not raise it); 0 when none is held."""
        if not self._poses:
            return 0.0
        return float(np.median([np.trace(held.accel_cov) / 3.0 for held in self._poses]))

    def add(self, pose: Pose) -> StoreEvent:
        neighbours = self._neighbours(pose)
        floor = self.noise_floor_var() if neighbours else 0.0
        for index in neighbours:
            held = self._poses[index]
            if means_agree(held, pose, self.merge_tolerance_mps2, floor):
                self._poses[index] = merge_poses(held, pose)
                self._merges[index] += 1
                return StoreEvent(index, merged=True)
        disagreed = bool(neighbours)
        if len(self._poses) < self.capacity:
            self._poses.append(pose)
            self._merges.append(0)
            return StoreEvent(len(self._poses) - 1, merged=False, disagreed=disagreed)
        # The oldest pose whose orientation is held at least twice (itself excluded) gives way: dropping it
        # loses no coverage. Only when every orientation is held once does the oldest overall.
        directions = np.array([held.direction for held in self._poses])
        close = directions @ directions.T >= self._cos_merge
        if self.temperature_bin_degc is not None:
            temperatures = np.array([np.nan if held.temperature_degc is None else held.temperature_degc
                                     for held in self._poses])
            apart = np.abs(temperatures[:, None] - temperatures[None, :]) >= self.temperature_bin_degc
            close &= ~apart  # NaN (no temperature) compares False: the same bin, as _same_bin says
        redundant = np.flatnonzero(close.sum(axis=1) > 1).tolist()
        candidates = redundant or list(range(len(self._poses)))
        oldest = min(candidates, key=lambda i: self._poses[i].end_ns)
        self._poses[oldest] = pose
        self._merges[oldest] = 0
        return StoreEvent(oldest, merged=False, replaced_oldest=True, disagreed=disagreed)
