"""CSV tables of poses or samples: a header row, then numbers. `ax,ay,az` required; `temperature`,
`ref_x,ref_y,ref_z` and `sigma_mg` (each pose mean's own 1-sigma noise per axis, mg; 0 = unknown) optional.
Every problem is one CalibrationError naming the row and column."""
from __future__ import annotations

import csv
import io
import math
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import CalibrationError
from ..core.units import MG
from .calibration_file import read_regular_file

ACCEL_COLUMNS = ("ax", "ay", "az")
REFERENCE_COLUMNS = ("ref_x", "ref_y", "ref_z")
TEMPERATURE_COLUMN = "temperature"
SIGMA_COLUMN = "sigma_mg"
MAX_COLUMNS = 1000  # a pose table has 3 to 7 columns; a CSV for `apply` may carry some more
MAX_TABLE_BYTES = 256 << 20  # ~3 M rows of samples; parsing holds several times this in memory
# |value| beyond this is no acceleration in any unit (raw counts of a 24-bit part at 16 g: ~1e8), and
# keeps every product of the fit and of the correction far from overflow.
MAX_ACCEL = 1e12
TEMPERATURE_LIMITS_DEGC = (-273.15, 1000.0)  # physical: absolute zero to beyond any sensor


@dataclass(frozen=True)
class Table:
    header: list[str]
    rows: list[list[str]]  # as read, for columns passed through unchanged
    accel: np.ndarray  # (N, 3) in the file's units
    temperature_degc: np.ndarray | None
    reference: np.ndarray | None
    pose_sigma_mps2: np.ndarray | None = None  # from sigma_mg: the pose means' own noise, m/s^2


def read_text(path: str | os.PathLike[str]) -> str:
    path = Path(path)
    data = read_regular_file(path, MAX_TABLE_BYTES, "CSV file", error=CalibrationError)
    if b"\x00" in data:
        raise CalibrationError(f"{path}: binary content, expected a CSV text file")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise CalibrationError(f"{path}: not UTF-8 text, expected a CSV file") from None


def _numbers(rows: list[list[str]], header: list[str], names: tuple[str, ...], path: str | os.PathLike[str],
             limits: tuple[float, float] = (-MAX_ACCEL, MAX_ACCEL)) -> np.ndarray:
    indices = [header.index(name) for name in names]
    low, high = limits
    values = np.empty((len(rows), len(names)))
    for r, row in enumerate(rows):
        for c, index in enumerate(indices):
            cell = row[index].strip() if index < len(row) else ""
            try:
                number = float(cell)
            except ValueError:
                raise CalibrationError(
                    f"{path}: row {r + 2}, column {names[c]}: {cell[:20]!r} is not a number"
                ) from None
            if not math.isfinite(number):
                raise CalibrationError(f"{path}: row {r + 2}, column {names[c]}: {cell[:20]!r} is not finite")
            if not low <= number <= high:
                raise CalibrationError(f"{path}: row {r + 2}, column {names[c]}: {number:.3g} is outside "
                                       f"{low:g}..{high:g}: a corrupt value or the wrong units")
            values[r, c] = number
    return values


def read_table(path: str | os.PathLike[str]) -> Table:
    text = read_text(path)
    try:
        records = [row for row in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in row)]
    except csv.Error as error:
        raise CalibrationError(f"{path}: malformed CSV ({error})") from None
    if not records:
        raise CalibrationError(f"{path}: empty file, expected a header row with {','.join(ACCEL_COLUMNS)}")
    header = [cell.strip().lower() for cell in records[0]]
    if len(header) > MAX_COLUMNS:
        raise CalibrationError(f"{path}: {len(header)} columns in the header; a table of poses or samples has a "
                               f"handful (ax,ay,az [,temperature] [,ref_x,ref_y,ref_z]), at most {MAX_COLUMNS}")
    repeated = sorted(name for name, count in Counter(header).items() if name and count > 1)
    if repeated:
        raise CalibrationError(f"{path}: column {', '.join(repeated)} appears more than once in the header: "
                               "which one is meant is unclear; rename or drop the copy")
    missing = [name for name in ACCEL_COLUMNS if name not in header]
    if missing:
        raise CalibrationError(
            f"{path}: missing column(s) {','.join(missing)} in header {','.join(header)[:80]!r}; "
            f"expected {','.join(ACCEL_COLUMNS)}"
        )
    rows = records[1:]
    if not rows:
        raise CalibrationError(f"{path}: header only, no data rows")
    for r, row in enumerate(rows):
        if len(row) != len(header):
            raise CalibrationError(f"{path}: row {r + 2} has {len(row)} fields, header has {len(header)}")
    accel = _numbers(rows, header, ACCEL_COLUMNS, path)
    temperature = (_numbers(rows, header, (TEMPERATURE_COLUMN,), path, TEMPERATURE_LIMITS_DEGC)[:, 0]
                   if TEMPERATURE_COLUMN in header else None)
    reference = None
    present = [name in header for name in REFERENCE_COLUMNS]
    if any(present):
        if not all(present):
            raise CalibrationError(f"{path}: reference columns must be all of {','.join(REFERENCE_COLUMNS)}")
        reference = _numbers(rows, header, REFERENCE_COLUMNS, path)
    pose_sigma = None
    if SIGMA_COLUMN in header:
        pose_sigma = _numbers(rows, header, (SIGMA_COLUMN,), path, (0.0, MAX_ACCEL))[:, 0] * MG
    return Table(header, rows, accel, temperature, reference, pose_sigma)


def table_with_accel(table: Table, accel: np.ndarray) -> str:
    """CSV text of `table` with its ax,ay,az columns replaced by `accel`; other columns unchanged."""
    indices = [table.header.index(name) for name in ACCEL_COLUMNS]
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(table.header)
    for row, values in zip(table.rows, accel):
        row = list(row)
        for index, value in zip(indices, values):
            row[index] = repr(float(value))
        writer.writerow(row)
    return out.getvalue()
