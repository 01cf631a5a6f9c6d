"""A dividing head's table of positions: the pose table's ax,ay,az plus each position's nominal angles,
either as `alpha_deg,beta_deg` or as a `pos` column `k-j` in the numbering of Gao et al. (2016): β = 45·k
and α = 45·(j − 1) degrees. Every problem is one CalibrationError naming the row and column."""
from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ..core.errors import CalibrationError
from .pose_table import read_table

ANGLE_COLUMNS = ("alpha_deg", "beta_deg")
POSITION_COLUMN = "pos"
PAPER_STEP_DEG = 45.0
MAX_ANGLE_DEG = 3600.0  # ten turns: beyond that a column holds something else
_POSITION = re.compile(r"^\s*(\d{1,3})\s*-\s*(\d{1,3})\s*$")


@dataclass(frozen=True)
class HeadTable:
    alpha_deg: np.ndarray  # (N,) nominal rotation of the head
    beta_deg: np.ndarray  # (N,) nominal tilt
    accel: np.ndarray  # (N, 3) in the file's units


def read_head_table(path: str | os.PathLike[str]) -> HeadTable:
    table = read_table(path)
    header = table.header
    has_angles = [name in header for name in ANGLE_COLUMNS]
    if POSITION_COLUMN in header and any(has_angles):
        raise CalibrationError(f"{path}: give the positions either as {','.join(ANGLE_COLUMNS)} or as a "
                               f"'{POSITION_COLUMN}' column, not both")
    if POSITION_COLUMN in header:
        column = header.index(POSITION_COLUMN)
        alpha, beta = np.empty(len(table.rows)), np.empty(len(table.rows))
        for r, row in enumerate(table.rows):
            match = _POSITION.match(row[column])
            if match is None or int(match.group(2)) < 1:
                raise CalibrationError(f"{path}: row {r + 2}, column {POSITION_COLUMN}: {row[column][:20]!r} is not "
                                       "a position k-j (β = 45·k, α = 45·(j-1) degrees, j from 1; e.g. 1-3)")
            beta[r] = PAPER_STEP_DEG * int(match.group(1))
            alpha[r] = PAPER_STEP_DEG * (int(match.group(2)) - 1)
        return HeadTable(alpha, beta, table.accel)
    if not all(has_angles):
        raise CalibrationError(f"{path}: model dividing-head needs the columns {','.join(ANGLE_COLUMNS)} (degrees) "
                               f"or a '{POSITION_COLUMN}' column k-j")
    angles = np.empty((len(table.rows), 2))
    for c, name in enumerate(ANGLE_COLUMNS):
        column = header.index(name)
        for r, row in enumerate(table.rows):
            cell = row[column].strip()
            try:
                value = float(cell)
            except ValueError:
                raise CalibrationError(f"{path}: row {r + 2}, column {name}: {cell[:20]!r} is not a number") from None
            if not (math.isfinite(value) and abs(value) <= MAX_ANGLE_DEG):
                raise CalibrationError(f"{path}: row {r + 2}, column {name}: {cell[:20]!r} is not an angle in degrees "
                                       f"(within ±{MAX_ANGLE_DEG:g})")
            angles[r, c] = value
    return HeadTable(angles[:, 0], angles[:, 1], table.accel)
