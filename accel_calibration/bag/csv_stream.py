"""CSV streams of raw IMU samples (a logger, an Arduino reading an MPU-6050, a spreadsheet) as sample
arrays for the calibration session, and corrected copies of them.

Layout: a header row, then one sample per row. A time column, `t` (seconds) or `t_ns` (nanoseconds;
`time_unit` overrides either); `ax,ay,az` in `units` (mps2, g, or counts with `counts_per_g`); optional
`gx,gy,gz` (rad/s) and `temperature` (degC; empty cells where the logger had no new reading). Other columns
are ignored (and copied unchanged into a corrected copy). Comma, semicolon or tab separated.

Parsed by pyarrow's CSV reader (multithreaded, in blocks; only the columns used are converted). Every
problem is one `CsvStreamError` line naming the file, and the row and column where there is one.
"""
from __future__ import annotations

import csv
import io
import math
import os
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.units import STANDARD_GRAVITY, units_problem
from .bag_io import BagError, read_head

if TYPE_CHECKING:
    from .progress import ProgressBar

TIME_UNITS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
UNITS = ("mps2", "g", "counts")
ACCEL = ("ax", "ay", "az")
GYRO = ("gx", "gy", "gz")
TEMPERATURE = "temperature"
TIME_COLUMNS = {"t": "s", "t_ns": "ns"}  # column -> its unit unless time_unit says otherwise


class CsvStreamError(BagError):
    """A CSV stream that cannot give samples: the file, and the row and column where known."""


@dataclass(frozen=True)
class CsvLayout:
    """What a corrected copy needs to write the file back in its own shape and units."""

    delimiter: str
    header: list[str]  # as written in the file
    accel_index: tuple[int, int, int]  # column positions of ax, ay, az
    units_per_mps2: float  # file units per m/s^2 (1 for mps2, 1/g for g, counts_per_g/g for counts)
    gyro_index: tuple[int, int, int] | None = None  # column positions of gx, gy, gz (rad/s), when present


@dataclass
class CsvSamples:
    stream: str  # e.g. "ax,ay,az (g) at t"
    t_ns: np.ndarray
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray | None
    temperature: tuple[np.ndarray, np.ndarray] | None
    layout: CsvLayout


def units_scale(units: str, counts_per_g: float | None, path: str | os.PathLike[str]) -> float:
    """m/s^2 per file unit."""
    if units not in UNITS:
        raise CsvStreamError(f"{path}: --units must be one of {', '.join(UNITS)}, got {units!r}")
    if units == "counts":
        if counts_per_g is None:
            raise CsvStreamError(f"{path}: --units counts needs --counts-per-g (the sensor's counts per g, e.g. 16384 "
                                 "for an MPU-6050 at +-2 g): the detector and the gates work in m/s^2")
        if not (math.isfinite(counts_per_g) and counts_per_g > 0):
            raise CsvStreamError(f"{path}: --counts-per-g must be a positive number, got {counts_per_g!r}")
        return STANDARD_GRAVITY / counts_per_g
    if counts_per_g is not None:
        raise CsvStreamError(f"{path}: --counts-per-g applies to --units counts only (units are {units})")
    return STANDARD_GRAVITY if units == "g" else 1.0


MAX_HEADER_BYTES = 1 << 16


def _header(path: Path) -> tuple[list[str], str]:
    """(header cells as written, delimiter)."""
    first = read_head(path, lambda stream: stream.readline(MAX_HEADER_BYTES + 1), CsvStreamError, "a CSV file")
    if len(first) > MAX_HEADER_BYTES:
        raise CsvStreamError(f"{path}: the header row is longer than {MAX_HEADER_BYTES >> 10} KiB (thousands of "
                             "columns?); a sample stream has a handful, such as t,ax,ay,az,gx,gy,gz,temperature")
    if b"\x00" in first:
        raise CsvStreamError(f"{path}: binary content, expected a CSV text file with a header row")
    try:
        text = first.decode("utf-8-sig").rstrip("\r\n")
    except UnicodeDecodeError:
        raise CsvStreamError(f"{path}: not UTF-8 text, expected a CSV file with a header row") from None
    if not text.strip():
        raise CsvStreamError(f"{path}: empty first line; expected a header row such as t,ax,ay,az")
    delimiter = max((",", ";", "\t"), key=text.count)
    cells = next(csv.reader([text], delimiter=delimiter))
    return cells, delimiter


def read_csv_stream(path: str | os.PathLike[str], *, time_unit: str | None = None, units: str = "mps2",
                    counts_per_g: float | None = None, progress: ProgressBar | None = None) -> CsvSamples:
    """The samples of a CSV stream (SI units, stamps in ns). `progress`: a tqdm bar counting bytes."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    path = Path(path)
    scale = units_scale(units, counts_per_g, path)
    if time_unit is not None and time_unit not in TIME_UNITS:
        raise CsvStreamError(f"{path}: --time-unit must be one of {', '.join(TIME_UNITS)}, got {time_unit!r}")
    cells, delimiter = _header(path)
    names = [cell.strip().lower() for cell in cells]
    duplicated = sorted(n for n, count in Counter(names).items() if count > 1 and n)
    if duplicated:
        raise CsvStreamError(f"{path}: column {duplicated[0]} appears twice in the header")
    time_column = next((c for c in ("t_ns", "t") if c in names), None)
    if time_column is None:
        raise CsvStreamError(f"{path}: no time column (t in seconds, or t_ns) in header "
                             f"{delimiter.join(cells)[:80]!r}; a sample stream needs one")
    missing = [c for c in ACCEL if c not in names]
    if missing:
        raise CsvStreamError(f"{path}: missing column(s) {','.join(missing)} in header {delimiter.join(cells)[:80]!r}")
    gyro_present = [c in names for c in GYRO]
    if any(gyro_present) and not all(gyro_present):
        raise CsvStreamError(f"{path}: gyro columns must be all of gx,gy,gz or none")
    unit = time_unit or TIME_COLUMNS[time_column]
    wanted = [time_column, *ACCEL, *(GYRO if all(gyro_present) else ()),
              *((TEMPERATURE,) if TEMPERATURE in names else ())]
    types = {name: pa.float64() for name in wanted}
    if unit == "ns":
        types[time_column] = pa.int64()  # 1.7e18 ns does not fit a double's 53 bits
    # Unnamed or repeated-blank columns get placeholder names; only `wanted` ones are converted.
    column_names = [n if n else f"_column{i}" for i, n in enumerate(names)]
    try:
        source = _Counting(path, progress)
        table = pacsv.read_csv(
            source,
            read_options=pacsv.ReadOptions(column_names=column_names, skip_rows=1, block_size=4 << 20),
            parse_options=pacsv.ParseOptions(delimiter=delimiter),
            convert_options=pacsv.ConvertOptions(column_types=types, include_columns=wanted,
                                                 strings_can_be_null=True, quoted_strings_can_be_null=True),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError) as error:
        raise CsvStreamError(_locate_problem(path, delimiter, column_names, wanted, types, error)) from None
    except OSError as error:
        raise CsvStreamError(f"{path}: cannot read ({error})") from None
    if table.num_rows == 0:
        raise CsvStreamError(f"{path}: header only, no samples")

    def column(name: str) -> np.ndarray:
        values: np.ndarray = table.column(name).to_numpy(zero_copy_only=False)
        return values

    t_ns = _stamps_ns(column(time_column), table.column(time_column).null_count, unit, path, time_column)
    steps = np.diff(t_ns)
    if len(steps) and not np.all(steps > 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise CsvStreamError(f"{path}: data row {row + 1}: time {_show(t_ns[row], unit)} does not increase over the "
                             f"row before ({_show(t_ns[row - 1], unit)}); a sample stream must be in time order")
    accel = np.column_stack([column(c) for c in ACCEL]).astype(float, copy=False)
    raw_accel = accel
    if scale != 1.0:
        accel = accel * scale
    problem = _units_problem(raw_accel, accel, units, counts_per_g)
    if problem is not None:
        raise CsvStreamError(f"{path}: {problem}")
    gyro = np.column_stack([column(c) for c in GYRO]).astype(float, copy=False) if all(gyro_present) else None
    temperature = None
    if TEMPERATURE in names:
        values = column(TEMPERATURE).astype(float, copy=False)
        have = ~np.isnan(values)
        if have.any():
            temperature = (t_ns[have], values[have])
    gyro_index = _positions(names, GYRO) if gyro is not None else None
    layout = CsvLayout(delimiter, cells, _positions(names, ACCEL), 1.0 / scale, gyro_index)
    stream = f"{','.join(ACCEL)} ({units}) at {time_column}"
    return CsvSamples(stream, t_ns, accel, gyro, temperature, layout)


def _positions(names: list[str], columns: tuple[str, str, str]) -> tuple[int, int, int]:
    x, y, z = (names.index(column) for column in columns)
    return x, y, z


class _Counting(io.RawIOBase):
    """The file, read in blocks, moving a tqdm bar by the bytes read."""

    def __init__(self, path: Path, progress: ProgressBar | None) -> None:
        self._file = open(path, "rb")  # noqa: SIM115 (closed by close(), pyarrow closes its source)
        self._progress = progress

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:  # a writable buffer (collections.abc.Buffer from Python 3.12)
        count = self._file.readinto(buffer)
        if self._progress is not None and count:
            self._progress.update(count)
        return count

    def close(self) -> None:
        self._file.close()
        super().close()


def _stamps_ns(values: np.ndarray, nulls: int, unit: str, path: Path, column: str) -> np.ndarray:
    if nulls or (values.dtype.kind == "f" and not np.all(np.isfinite(values))):
        row = int(np.flatnonzero(~np.isfinite(values.astype(float)))[0]) + 1
        raise CsvStreamError(f"{path}: data row {row}, column {column}: no time (empty or not finite)")
    factor = TIME_UNITS[unit]
    if values.dtype.kind in "iu":
        stamps = values.astype(np.int64)
        if factor != 1:
            stamps = stamps * factor
        return stamps
    # Whole and fractional units apart, so integral microseconds (PX4-style) stay exact in ns.
    whole = np.floor(values)
    limit = np.iinfo(np.int64).max / factor
    if np.any(np.abs(whole) >= limit):
        row = int(np.flatnonzero(np.abs(whole) >= limit)[0]) + 1
        raise CsvStreamError(f"{path}: data row {row}, column {column}: time {float(values[row - 1]):g} {unit} "
                             f"is out of range (a stamp in ns holds up to {limit:.3g} {unit})")
    stamps_ns: np.ndarray = whole.astype(np.int64) * factor + np.round((values - whole) * factor).astype(np.int64)
    return stamps_ns


def _show(t_ns: int, unit: str) -> str:
    return f"{int(t_ns)} ns" if unit == "ns" else f"{int(t_ns) / TIME_UNITS[unit]:.9g} {unit}"


def _units_problem(raw: np.ndarray, accel_mps2: np.ndarray, units: str, counts_per_g: float | None) -> str | None:
    """Whether the samples, read in these units, look like gravity (a calibration recording is mostly still)."""
    step = max(1, len(accel_mps2) // 200_000)  # the median of a spread subset is plenty
    accel_mps2, raw = accel_mps2[::step], raw[::step]
    finite = np.all(np.isfinite(accel_mps2), axis=1)
    if not finite.any():
        return "no finite acceleration sample"
    problem = units_problem(accel_mps2[finite], STANDARD_GRAVITY)
    if problem is None:
        return None
    typical_raw = float(np.median(np.linalg.norm(raw[finite], axis=1)))
    typical = float(np.median(np.linalg.norm(accel_mps2[finite], axis=1)))
    read_as = f"--units {units}" + (f" --counts-per-g {counts_per_g:g}" if units == "counts" else "")
    if 0.7 * STANDARD_GRAVITY <= typical_raw <= 1.3 * STANDARD_GRAVITY:
        hint = "the file looks like m/s^2: use --units mps2"
    elif 0.7 <= typical_raw <= 1.3:
        hint = "the file looks like g: use --units g"
    elif typical_raw > 30.0:
        hint = f"the file looks like raw counts (~{typical_raw:.0f} per g): use --units counts --counts-per-g N"
    else:
        hint = "check the logger's units and scaling"
    return (f"read with {read_as} the samples' median |a| is {typical:.4g} m/s^2, implausible for a recording "
            f"at rest (expected ~{STANDARD_GRAVITY:.2f}): {hint}")


def _locate_problem(path: Path, delimiter: str, column_names: list[str], wanted: list[str], types: dict[str, Any],
                    error: Exception) -> str:
    """The first cell pyarrow could not convert, found again row by row (only on this error path)."""
    indices = {name: column_names.index(name) for name in wanted}
    try:
        with open(path, encoding="utf-8-sig", newline="") as stream:
            rows = csv.reader(stream, delimiter=delimiter)
            next(rows, None)
            for line, row in enumerate(rows, start=2):
                if not row:
                    continue  # a blank line, skipped by pyarrow too
                if len(row) != len(column_names):
                    return (f"{path}: line {line} has {len(row)} fields, the header has {len(column_names)}")
                for name, index in indices.items():
                    cell = row[index].strip()
                    if not cell:
                        continue
                    try:
                        int(cell) if str(types[name]) == "int64" else float(cell)
                    except ValueError:
                        expected = "an integer" if str(types[name]) == "int64" else "a number"
                        return f"{path}: line {line}, column {name}: {cell[:20]!r} is not {expected}"
    except (OSError, UnicodeDecodeError, csv.Error) as reason:
        return f"{path}: not a readable CSV ({type(reason).__name__}: {str(reason)[:80]})"
    return f"{path}: not a readable CSV ({str(error).splitlines()[0][:120]})"


# ------------------------------------------------------------------------------------------- writing
def corrected_csv_text(path: str | os.PathLike[str], layout: CsvLayout, corrected_mps2: np.ndarray, valid: np.ndarray,
                       corrected_radps: np.ndarray | None = None) -> str:
    """The file again with ax,ay,az of each sample row replaced by `corrected_mps2` in the file's units, and
    gx,gy,gz by `corrected_radps` when given (rows where `valid` is False, e.g. non-finite samples, are
    copied unchanged; so are other columns)."""
    values = corrected_mps2 * layout.units_per_mps2
    out = io.StringIO()
    writer = csv.writer(out, delimiter=layout.delimiter, lineterminator="\n")
    writer.writerow(layout.header)
    ax, ay, az = layout.accel_index
    sample = 0
    with open(path, encoding="utf-8-sig", newline="") as stream:
        rows = csv.reader(stream, delimiter=layout.delimiter)
        next(rows, None)
        for row in rows:
            if not row:
                continue  # a blank line: pyarrow skipped it too, not a sample
            if valid[sample]:
                x, y, z = values[sample]
                row[ax], row[ay], row[az] = repr(float(x)), repr(float(y)), repr(float(z))
                if corrected_radps is not None and layout.gyro_index is not None:
                    gx, gy, gz = layout.gyro_index
                    u, v, w = corrected_radps[sample]
                    row[gx], row[gy], row[gz] = repr(float(u)), repr(float(v)), repr(float(w))
            writer.writerow(row)
            sample += 1
    return out.getvalue()


def samples_csv_text(t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray | None,
                     temperature_degc: np.ndarray | None) -> str:
    """A CSV stream this module reads back: t_ns,ax,ay,az[,gx,gy,gz][,temperature] (SI units)."""
    columns = [np.asarray(t_ns, dtype=np.int64).astype(str),
               *(np.char.mod("%.17g", accel_mps2[:, i]) for i in range(3))]
    header = ["t_ns", *ACCEL]
    if gyro_radps is not None:
        columns += [np.char.mod("%.17g", gyro_radps[:, i]) for i in range(3)]
        header += list(GYRO)
    if temperature_degc is not None:
        text = np.char.mod("%.17g", temperature_degc)
        columns.append(np.where(np.isnan(temperature_degc), "", text))
        header.append(TEMPERATURE)
    lines = columns[0]
    for column in columns[1:]:
        lines = np.char.add(np.char.add(lines, ","), column)
    return ",".join(header) + "\n" + "\n".join(lines.tolist()) + "\n"
