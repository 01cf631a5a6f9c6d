"""Samples on a grid: the step (LSB) a sensor's output is quantised to, and what it does to a still pose's mean.

Quantisation adds an error uniform over one LSB to each sample: variance LSB^2/12. Where the noise is well
above the LSB that error changes from sample to sample and averages down like the noise. Where the noise is
below the LSB the samples sit on one or two levels and the error of their mean stays up to half an LSB
however many there are: the mean cannot be trusted beyond the LSB's resolution, so its variance is at least
LSB^2/12, not divided by the sample count. The sample scatter, near 0 there, says nothing of it."""
from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from .pose import Pose

MAX_SAMPLES = 200_000  # enough to see the grid of any axis; the rest need not be sorted
MIN_LEVELS = 3  # fewer distinct values say nothing of a grid
GRID_TOLERANCE = 0.05  # of a step: a float32 log holds a 0.06 mg LSB near 1 g to ~0.2 % of it


def quantisation_steps(accel: np.ndarray) -> np.ndarray:
    """(3,) per axis the step the samples lie on a grid of (m/s^2 for m/s^2 samples), 0 where they do not."""
    values = np.asarray(accel, dtype=float).reshape(-1, 3)
    values = values[:: max(1, len(values) // MAX_SAMPLES)]
    steps = np.zeros(3)
    for axis in range(3):
        levels = np.unique(values[np.isfinite(values[:, axis]), axis])
        if len(levels) < MIN_LEVELS:
            continue
        gaps = np.diff(levels)
        smallest = float(gaps.min())
        if not smallest > 1e-9 * float(np.max(np.abs(levels))):
            continue
        step = float(np.mean(gaps[gaps < 1.5 * smallest]))  # one LSB: the float32 rounding of each averaged out
        multiples = gaps / step
        if np.all(np.abs(multiples - np.round(multiples)) < GRID_TOLERANCE):
            steps[axis] = step
    return steps


def with_quantisation(poses: Sequence[Pose], steps: np.ndarray) -> list[Pose]:
    """The poses with the quantisation error of their means in their covariance (see the module): per axis
    LSB^2/12 per sample where the scatter is an LSB or more, LSB^2/12 on the mean where it is less."""
    steps = np.asarray(steps, dtype=float)
    if not np.any(steps > 0):
        return list(poses)
    out = []
    for pose in poses:
        cov = np.array(pose.accel_cov, dtype=float)
        spread = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        per_sample = np.square(steps) / 12.0
        cov[np.diag_indices(3)] += np.where(spread < steps, per_sample * max(pose.samples, 1), per_sample)
        out.append(dataclasses.replace(pose, accel_cov=cov))
    return out
