"""The poses the online calibration holds: a new pose at an orientation already held is merged
into it (its mean gets better, the geometry does not change), one at a new orientation is added.
Bounded: at capacity the oldest pose gives way, so a node that runs for days keeps a fixed size."""
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


class PoseStore:
    def __init__(self, *, merge_angle_deg: float = 5.0, capacity: int = 100, temperature_bin_degc: float | None = None):
        if not (0.0 < merge_angle_deg < 90.0):
            raise CalibrationError(f"merge_angle_deg must be in (0, 90), got {merge_angle_deg}")
        if not (isinstance(capacity, int) and capacity >= 6):
            raise CalibrationError(f"capacity must be an integer >= 6, got {capacity!r}")
        if temperature_bin_degc is not None and not temperature_bin_degc > 0:
            raise CalibrationError(f"temperature_bin_degc must be positive, got {temperature_bin_degc}")
        self._cos_merge = float(np.cos(np.radians(merge_angle_deg)))
        self.capacity = capacity
        self.temperature_bin_degc = temperature_bin_degc
        self._poses: list[Pose] = []

    def __len__(self) -> int:
        return len(self._poses)

    @property
    def poses(self) -> list[Pose]:
        return list(self._poses)

    def copy(self) -> PoseStore:
        other = PoseStore.__new__(PoseStore)
        other.__dict__.update(self.__dict__)
        other._poses = list(self._poses)
        return other

    def clear(self) -> None:
        self._poses.clear()

    def _same_bin(self, a: Pose, b: Pose) -> bool:
        if self.temperature_bin_degc is None or a.temperature_degc is None or b.temperature_degc is None:
            return True
        return abs(a.temperature_degc - b.temperature_degc) < self.temperature_bin_degc

    def add(self, pose: Pose) -> StoreEvent:
        direction = pose.direction
        for index, held in enumerate(self._poses):
            if float(direction @ held.direction) >= self._cos_merge and self._same_bin(held, pose):
                self._poses[index] = merge_poses(held, pose)
                return StoreEvent(index, merged=True)
        if len(self._poses) < self.capacity:
            self._poses.append(pose)
            return StoreEvent(len(self._poses) - 1, merged=False)
        oldest = min(range(len(self._poses)), key=lambda i: self._poses[i].end_ns)
        self._poses[oldest] = pose
        return StoreEvent(oldest, merged=False, replaced_oldest=True)
