"""Do the IMUs of one vehicle agree in flight? Each IMU's specific force (its calibration in force applied)
and gyro rate, averaged over each second of the flight, against every sibling's over the same seconds after
the rotation between them (bag/imu_alignment.relative_rotation, fitted on those seconds' force directions,
as --all-imus fits it on still poses). An IMU's disagreement is its mean difference from the sibling it
agrees with best: one IMU that drifts differs from all its siblings, while they still agree with each other,
so with three or more IMUs the one that moved is named; with two, either may have.

What a rotation explains is not a disagreement: the fit takes in the part of a bias difference across the
force that looks like a tilt (in level flight most of x and y); along the force (z) it sees all of it. A
change common to every IMU (the vehicle's temperature, a calibration redone on all) is never seen here."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

BLOCK_NS = 10**9  # one second: the IMUs' samples need not share stamps, their means over a second do
MIN_BLOCKS = 10  # common seconds in flight needed


@dataclass(frozen=True)
class FlightMeans:
    """One IMU's means over each second in flight: `blocks` the second's index, accel m/s^2, gyro rad/s."""

    name: str  # "IMU 1 (device 1310988)"
    blocks: np.ndarray
    accel_mps2: np.ndarray  # (K, 3)
    gyro_radps: np.ndarray | None  # (K, 3)


@dataclass(frozen=True)
class Agreement:
    against: str  # the sibling agreed with best, as FlightMeans.name
    siblings: int
    seconds: int
    accel_mps2: tuple[float, float, float]  # this IMU minus its sibling rotated into its axes
    accel_sigma_mps2: tuple[float, float, float]
    gyro_radps: tuple[float, float, float] | None = None
    gyro_sigma_radps: tuple[float, float, float] | None = None

    def as_json(self) -> dict[str, Any]:
        return {"against": self.against, "siblings": self.siblings, "seconds": self.seconds,
                "accel": self.accel_mps2, "accel_sigma": self.accel_sigma_mps2, "gyro": self.gyro_radps,
                "gyro_sigma": self.gyro_sigma_radps}


class SecondSums:
    """Per-second sums of values (a triple, or any columns) over the samples in flight, added a piece at a
    time (a log read a block at a time): a few numbers per second kept, never the samples."""

    def __init__(self) -> None:
        self._parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (blocks, counts, sums (K, 3))

    def add(self, t_ns: np.ndarray, values: np.ndarray, flying: np.ndarray) -> None:
        t = np.asarray(t_ns, dtype=np.int64)[flying]
        if not len(t):
            return
        chosen = np.asarray(values, dtype=float).reshape(len(flying), -1)[flying]
        blocks, where = np.unique(t // BLOCK_NS, return_inverse=True)
        self._parts.append(_summed(blocks, where, np.ones(len(t)), chosen))

    def means(self) -> tuple[np.ndarray, np.ndarray]:
        """(the seconds' indices, their means (K, 3)), the pieces' sums of one second added together."""
        if not self._parts:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 3))  # no second in flight
        blocks, where = np.unique(np.concatenate([p[0] for p in self._parts]), return_inverse=True)
        _, counts, sums = _summed(blocks, where, np.concatenate([p[1] for p in self._parts]),
                                  np.concatenate([p[2] for p in self._parts]))
        means: np.ndarray = sums / counts[:, None]
        return blocks, means

    @property
    def empty(self) -> bool:
        return not self._parts


def _summed(blocks: np.ndarray, where: np.ndarray, counts: np.ndarray, values: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    summed = np.column_stack([np.bincount(where, values[:, k], len(blocks)) for k in range(values.shape[1])])
    return blocks, np.bincount(where, counts, len(blocks)), summed


def flight_means(name: str, t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray | None,
                 flying: np.ndarray) -> FlightMeans:
    """The per-second means of the samples in flight (a few numbers per second kept, not the samples)."""
    accel = SecondSums()
    accel.add(t_ns, accel_mps2, flying)
    blocks, accel_means = accel.means()
    gyro_means = None
    if gyro_radps is not None:
        gyro = SecondSums()
        gyro.add(t_ns, gyro_radps, flying)
        gyro_means = gyro.means()[1]
    return FlightMeans(name, blocks, accel_means, gyro_means)


def _pair(mine: FlightMeans, other: FlightMeans) -> tuple[np.ndarray, np.ndarray, np.ndarray | None,
                                                          np.ndarray | None, int] | None:
    """Mean difference mine - R other (accel, gyro) over their common seconds, with its 1 sigma."""
    from .imu_alignment import relative_rotation

    common, at_mine, at_other = np.intersect1d(mine.blocks, other.blocks, return_indices=True)
    if len(common) < MIN_BLOCKS:
        return None
    a, b = mine.accel_mps2[at_mine], other.accel_mps2[at_other]
    ua = b / np.linalg.norm(b, axis=1, keepdims=True)
    ub = a / np.linalg.norm(a, axis=1, keepdims=True)
    rotation = relative_rotation(ua, ub)  # maps the sibling's axes to this IMU's
    matrix = np.eye(3) if rotation is None else rotation.matrix
    differences = a - b @ matrix.T
    n = len(common)
    accel = np.mean(differences, axis=0)
    accel_sigma = np.std(differences, axis=0, ddof=1) / np.sqrt(n)
    gyro = gyro_sigma = None
    if mine.gyro_radps is not None and other.gyro_radps is not None:
        rates = mine.gyro_radps[at_mine] - other.gyro_radps[at_other] @ matrix.T
        gyro, gyro_sigma = np.mean(rates, axis=0), np.std(rates, axis=0, ddof=1) / np.sqrt(n)
    return accel, accel_sigma, gyro, gyro_sigma, n


def _triple(values: np.ndarray | None) -> tuple[float, float, float] | None:
    return None if values is None else (float(values[0]), float(values[1]), float(values[2]))


def agreement(imus: Mapping[int, FlightMeans]) -> dict[int, Agreement | str]:
    """Per IMU its agreement with the sibling it agrees with best, or why there is none."""
    out: dict[int, Agreement | str] = {}
    for key, mine in imus.items():
        others = [other for k, other in imus.items() if k != key]
        if not others:
            out[key] = "the log has one IMU: no sibling to compare with"
            continue
        pairs = [(other, _pair(mine, other)) for other in others]
        measured = [(other, p) for other, p in pairs if p is not None]
        if not measured:
            out[key] = f"fewer than {MIN_BLOCKS} seconds in flight logged by it and a sibling"
            continue
        other, (accel, sigma, gyro, gyro_sigma, n) = min(measured, key=lambda m: float(np.linalg.norm(m[1][0])))
        accel_t, sigma_t = _triple(accel), _triple(sigma)
        assert accel_t is not None and sigma_t is not None
        out[key] = Agreement(other.name, len(others), n, accel_t, sigma_t, _triple(gyro), _triple(gyro_sigma))
    return out
