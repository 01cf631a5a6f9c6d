"""imu_tk's calibration files (CalibratedTriad_::save): the misalignment matrix T, the scale matrix K (both
row-major, 3 x 3) and the bias B (3), whitespace-separated, in the raw units; imu_tk applies them as
T K (raw - B)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def read_triad(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(T, K, B) of one imu_tk calibration file."""
    values = np.array(Path(path).read_text().split(), dtype=float)
    assert values.shape == (21,), f"{path}: {values.size} numbers, an imu_tk triad has 21"
    return values[:9].reshape(3, 3), values[9:18].reshape(3, 3), values[18:]


def in_our_units(path: Path, offset: float, counts_per_unit: float) -> tuple[np.ndarray, np.ndarray]:
    """imu_tk's T K (counts - B) for samples read as (counts - offset) / counts_per_unit: the matrix and bias
    that give the same output from our units, (T K counts_per_unit, (B - offset) / counts_per_unit)."""
    misalignment, scale, bias = read_triad(path)
    return misalignment @ scale * counts_per_unit, (bias - offset) / counts_per_unit
