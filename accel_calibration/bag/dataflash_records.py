"""ArduPilot DataFlash `.bin` records as numpy arrays, read a block of the file at a time.

The format: each record is 0xA3 0x95, a type byte, then a body of fixed length; the FMT record (type 128,
body Type u8, Length u8 (of the whole record, the 3-byte header included), Name 4s, Format 16s, Columns 64s)
defines each type before its first record. The format characters and their scaling are pymavlink's
(DFReader.FORMAT_TO_STRUCT): `c C e E` are integers of 100 x the value, `L` of 1e7 x degrees, divided on
read as pymavlink divides (float64); `n N Z` strings, cut at their first NUL and decoded as UTF-8 (Latin-1
where that fails); `a` int16[32]; `M` an int8 flight mode; `g` a half float. FMTU and MULT records change
no value (pymavlink takes only units from them); an FMTU unit `#` names a type's instance field.

Walking the records is a tight loop over their headers (a type byte and a table of lengths per step); the
bodies of one type are gathered with numpy fancy indexing into a structured dtype: no Python object per
record, and the memory of a read is one block whatever the log's length (`iter_records`).

Damage is refused in one line (DataflashError) where pymavlink would skip bytes it cannot take for a record
(bytes that are no record header, a type no FMT defined, a type whose FMT length its format contradicts),
except in the last 528 bytes of the log: pymavlink takes those for the end-of-log garbage an autopilot
leaves, and so do we. A record cut by the end of the file ends the log, as in pymavlink."""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .bag_io import BagError

HEAD1, HEAD2 = 0xA3, 0x95
FMT_TYPE = 0x80
FMT_LENGTH = 89  # the FMT record's own: 3 + Type, Length, Name[4], Format[16], Columns[64]
FMT_FORMAT = "BBnNZ"
TAIL_BYTES = 528  # pymavlink's: bad bytes this close to the end of a log of at least this size are its garbage
MAX_RECORD = 255  # a record's length is one byte
BLOCK_BYTES = 4 << 20
IMU_TYPES = ("IMU", "IMU2", "IMU3")  # the older logs' per-instance types; today's IMU has an instance field I

# format character -> (numpy dtype of its bytes, divisor applied on read or None); pymavlink's FORMAT_TO_STRUCT
CHARACTERS: dict[str, tuple[str, float | None]] = {
    "a": ("(32,)<i2", None), "b": ("i1", None), "B": ("u1", None), "g": ("<f2", None), "h": ("<i2", None),
    "H": ("<u2", None), "i": ("<i4", None), "I": ("<u4", None), "f": ("<f4", None), "n": ("(4,)u1", None),
    "N": ("(16,)u1", None), "Z": ("(64,)u1", None), "c": ("<i2", 1 / 0.01), "C": ("<u2", 1 / 0.01),
    "e": ("<i4", 1 / 0.01), "E": ("<u4", 1 / 0.01), "L": ("<i4", 1 / 1.0e-7), "d": ("<f8", None),
    "M": ("i1", None), "q": ("<i8", None), "Q": ("<u8", None),
}
STRINGS = "nNZ"


class DataflashError(BagError):
    """A DataFlash log that cannot be read: one line naming the file."""


@dataclass(frozen=True)
class RecordFormat:
    """One record type as its FMT record defines it. `problem`: why its records cannot be read (None: they
    can); `instance_field`: the column an FMTU record marks `#` (the instance of a multi-instance sensor)."""

    type_id: int
    name: str
    length: int
    format: str
    columns: tuple[str, ...]
    raw_dtype: np.dtype | None
    dtype: np.dtype | None  # as returned: scaled values float64, strings str
    problem: str | None = None
    instance_field: str | None = None


def _text(raw: bytes) -> str:
    """pymavlink's reading of a fixed-width string: UTF-8 (Latin-1 where that fails), cut at the first NUL."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("ISO-8859-1")
    return text.split("\0", 1)[0]


def record_format(type_id: int, name: str, length: int, format: str, columns: str) -> RecordFormat:
    """The format of one FMT record, with the numpy dtypes of its body (raw, and as returned)."""
    names = tuple(columns.split(",")) if columns else ()
    bad = [c for c in format if c not in CHARACTERS]
    problem = None
    if bad:
        problem = f"FMT of {name} has the format character {bad[0]!r}, which no DataFlash reader knows"
    elif len(names) != len(format) or len(set(names)) != len(names) or not all(names):
        problem = f"FMT of {name} names {len(names)} columns {columns[:40]!r} for {len(format)} fields"
    if problem is not None:
        return RecordFormat(type_id, name, length, format, names, None, None, problem)
    raw = np.dtype([(column, CHARACTERS[c][0]) for column, c in zip(names, format)])
    if raw.itemsize + 3 != length:
        return RecordFormat(type_id, name, length, format, names, None, None,
                            f"FMT of {name} says {length} bytes, its format {format} takes {raw.itemsize + 3}")
    returned = []
    for column, c in zip(names, format):
        if c in STRINGS and not (c == "Z" and name == "FILE"):  # pymavlink hands FILE's data over as bytes
            returned.append((column, f"<U{raw[column].shape[0]}"))
        elif c in STRINGS:
            returned.append((column, f"S{raw[column].shape[0]}"))
        elif CHARACTERS[c][1] is not None or c == "g":
            returned.append((column, "<f8"))
        else:
            returned.append((column, CHARACTERS[c][0]))
    return RecordFormat(type_id, name, length, format, names, raw, np.dtype(returned))


FMT_OF_FMT = record_format(FMT_TYPE, "FMT", FMT_LENGTH, FMT_FORMAT, "Type,Length,Name,Format,Columns")


def _strings(chars: np.ndarray, returned: np.dtype) -> np.ndarray:
    """(N, width) bytes as pymavlink reads them: UTF-8 of the whole field (Latin-1 where that fails), then cut
    at the first NUL. One vectorised decode; element by element only where some field is not UTF-8."""
    width = chars.shape[1]
    whole = np.ascontiguousarray(chars).view(f"S{width}").reshape(-1)
    if returned.kind == "S":
        return whole
    try:
        np.char.decode(whole, "utf-8")  # pymavlink decides UTF-8 or Latin-1 on the whole field
    except UnicodeDecodeError:
        return np.array([_text(bytes(row)) for row in chars], dtype=returned)
    nul = chars == 0
    first = np.where(nul.any(axis=1), nul.argmax(axis=1), width)
    kept = np.where(np.arange(width) < first[:, None], chars, 0).astype(np.uint8)  # NUL is in no UTF-8 sequence
    text = np.char.decode(np.ascontiguousarray(kept).view(f"S{width}").reshape(-1), "utf-8")
    return text.astype(returned)


def decoded(raw: np.ndarray, fmt: RecordFormat) -> np.ndarray:
    """Raw bodies of one type (its raw_dtype) as returned: scaled as pymavlink scales, strings as text."""
    assert fmt.dtype is not None and fmt.raw_dtype is not None
    if fmt.dtype == fmt.raw_dtype:
        return raw
    out = np.empty(len(raw), dtype=fmt.dtype)
    for column, c in zip(fmt.columns, fmt.format):
        divisor = CHARACTERS[c][1]
        if c in STRINGS:
            out[column] = _strings(raw[column], fmt.dtype[column])
        elif divisor is not None:  # pymavlink divides by 1/multiplier: the nearest float to the true value
            out[column] = raw[column].astype(np.float64) / divisor
        else:
            out[column] = raw[column]
    return out


@dataclass
class LogRecords:
    """What `read_records` read: the records of the types asked for, whole, and what every read learns."""

    records: dict[str, np.ndarray]
    params: dict[str, float]  # PARM Name -> Value, the last value logged of each (pymavlink's log.params)
    formats: dict[str, RecordFormat]
    counts: dict[str, int]  # records of each type in the log
    imu_instances: tuple[int, ...]  # every IMU instance with records (IMU's I, or IMU/IMU2/IMU3)
    bytes_read: int


@dataclass
class _State:
    formats: dict[int, RecordFormat] = field(default_factory=lambda: {FMT_TYPE: FMT_OF_FMT})
    lengths: list[int] = field(default_factory=lambda: [0] * 256)  # 0: stop the fast walk (FMT, unknown, bad)
    counts: np.ndarray = field(default_factory=lambda: np.zeros(256, dtype=np.int64))
    imu_instances: set[int] = field(default_factory=set)
    units: list[tuple[int, str]] = field(default_factory=list)  # FMTU (FmtType, UnitIds)
    params: dict[str, float] = field(default_factory=dict)
    bytes_read: int = 0


class RecordReader:
    """One walk through a log. `blocks()` yields {type name: its records of that block, as returned} for the
    types `names` asks for (PARM, FMTU and the IMU instances are followed whatever is asked); after the walk
    `params`, `counts`, `formats`, `imu_instances` hold what the whole log said."""

    def __init__(self, path: str | os.PathLike[str], names: Iterable[str], block_bytes: int = BLOCK_BYTES) -> None:
        self.path = Path(path)
        self.names = frozenset(names)
        self.block_bytes = max(1, int(block_bytes))
        self._state = _State()
        self.size = 0

    @property
    def params(self) -> dict[str, float]:
        return self._state.params

    @property
    def counts(self) -> dict[str, int]:
        return {f.name: int(self._state.counts[t]) for t, f in self._state.formats.items() if self._state.counts[t]}

    @property
    def imu_instances(self) -> tuple[int, ...]:
        return tuple(sorted(self._state.imu_instances))

    @property
    def bytes_read(self) -> int:
        return self._state.bytes_read

    @property
    def formats(self) -> dict[str, RecordFormat]:
        """Every type by name, with the instance field its FMTU record names."""
        by_id = dict(self._state.formats)
        for type_id, units in self._state.units:
            if type_id in by_id and "#" in units and units.index("#") < len(by_id[type_id].columns):
                by_id[type_id] = replace(by_id[type_id], instance_field=by_id[type_id].columns[units.index("#")])
        return {f.name: f for f in by_id.values()}

    def _fail(self, what: str) -> DataflashError:
        return DataflashError(f"{self.path}: {what}")

    def blocks(self) -> Iterator[dict[str, np.ndarray]]:
        try:
            with open(self.path, "rb") as stream:
                self.size = os.fstat(stream.fileno()).st_size
                carry, base = b"", 0
                while True:
                    chunk = stream.read(self.block_bytes)
                    buffer = carry + chunk
                    at_end = len(chunk) < self.block_bytes
                    offsets, stop = self._walk(buffer, base, at_end)
                    found = self._gather(buffer, offsets)
                    carry, base = buffer[stop:], base + stop
                    self._state.bytes_read = base
                    if found:
                        yield found
                    if at_end:
                        self._state.bytes_read = self.size
                        return
        except OSError as error:
            raise self._fail(f"cannot read ({error.strerror or error})") from None

    def _walk(self, buffer: bytes, base: int, at_end: bool) -> tuple[list[int], int]:
        """Offsets of the whole records in `buffer` (the file from `base`), and where the walk stopped: the
        start of a record not wholly in the buffer, or the buffer's end."""
        offsets: list[int] = []
        append = offsets.append
        lengths = self._state.lengths
        fast_limit = len(buffer) - MAX_RECORD  # a record starting before it lies wholly in the buffer
        end = len(buffer) if at_end else max(fast_limit, 0)
        pos = 0
        while True:
            run = len(offsets)
            while pos < fast_limit:  # the hot loop: one step per record, its length by its type byte
                length = lengths[buffer[pos + 2]]
                if not length:
                    break
                append(pos)
                pos += length
            pos = self._checked_run(buffer, offsets, run, pos)
            if pos >= end:
                return offsets, min(pos, len(buffer))
            step = self._one_record(buffer, base, pos, offsets)
            if step is None:  # a record cut by the end of the file: the log ends before it
                return offsets, len(buffer)
            pos = step

    @staticmethod
    def _checked_run(buffer: bytes, offsets: list[int], run: int, pos: int) -> int:
        """Where the fast walk really stopped: the first offset of its run that holds no record header
        (the walk beyond it followed garbage), dropped with those after it; else `pos`."""
        if len(offsets) == run:
            return pos
        data = np.frombuffer(buffer, dtype=np.uint8)
        at = np.asarray(offsets[run:], dtype=np.int64)
        bad = (data[at] != HEAD1) | (data[at + 1] != HEAD2)
        if not bad.any():
            return pos
        first = int(np.argmax(bad))
        del offsets[run + first:]
        return int(at[first])

    def _one_record(self, buffer: bytes, base: int, pos: int, offsets: list[int]) -> int | None:
        """The record at `pos` that the fast walk stops at: an FMT, damage, garbage at the log's end, or a
        record near the end of the buffer. The next position, or None where the file ends within it."""
        if pos + 3 > len(buffer):
            return None
        head1, head2, type_id = buffer[pos], buffer[pos + 1], buffer[pos + 2]
        fmt = self._state.formats.get(type_id)
        if head1 != HEAD1 or head2 != HEAD2 or fmt is None:
            return self._bad_bytes(buffer, base, pos, head1, head2, type_id)
        if fmt.problem is not None:
            raise self._fail(f"damaged DataFlash log: a record of {fmt.name} at offset {base + pos} cannot be read "
                             f"({fmt.problem}); its FMT records do not match its data")
        if pos + fmt.length > len(buffer):
            return None
        if type_id == FMT_TYPE:
            self._define(buffer[pos + 3:pos + FMT_LENGTH], base + pos, buffer, offsets)
        offsets.append(pos)
        return pos + fmt.length

    def _bad_bytes(self, buffer: bytes, base: int, pos: int, head1: int, head2: int, type_id: int) -> int:
        where = base + pos
        if self.size - where >= TAIL_BYTES or self.size < TAIL_BYTES:
            said = (f"a record of type {type_id} that no FMT record defines" if (head1, head2) == (HEAD1, HEAD2)
                    else f"bytes 0x{head1:02x} 0x{head2:02x} where a record header belongs")
            raise self._fail(f"damaged DataFlash log: {said} at offset {where} of {self.size}; its FMT records "
                             "may not match its data")
        following = buffer.find(bytes([HEAD1, HEAD2]), pos + 1)  # the end's garbage: skipped, as pymavlink does
        return following if following >= 0 else max(len(buffer) - 1, pos + 1)  # a header may straddle blocks

    def _define(self, body: bytes, where: int, buffer: bytes, offsets: list[int]) -> None:
        """An FMT record: the type it defines from now on."""
        (row,) = np.frombuffer(body, dtype=FMT_OF_FMT.raw_dtype)
        type_id, length = int(row["Type"]), int(row["Length"])
        name, format, columns = (_text(bytes(row[c])) for c in ("Name", "Format", "Columns"))
        fmt = record_format(type_id, name, length, format, columns)
        old = self._state.formats.get(type_id)
        if type_id == FMT_TYPE and (length, format) != (FMT_LENGTH, FMT_FORMAT):
            raise self._fail(f"damaged DataFlash log: the FMT record at offset {where} redefines FMT itself "
                             f"({length} bytes, format {format!r})")
        if old is not None and (old.name, old.length, old.format, old.columns) != (name, length, format,
                                                                                     fmt.columns):
            data = np.frombuffer(buffer, dtype=np.uint8)
            earlier = self._state.counts[type_id] or np.any(data[np.asarray(offsets, dtype=np.int64) + 2] == type_id)
            if earlier:  # the records before it would be read with another layout than those after
                raise self._fail(f"damaged DataFlash log: the FMT record at offset {where} redefines {old.name} "
                                 f"(type {type_id}) after records of it")
        self._state.formats[type_id] = fmt
        if type_id != FMT_TYPE:
            self._state.lengths[type_id] = fmt.length if fmt.problem is None else 0

    def _gather(self, buffer: bytes, offsets: list[int]) -> dict[str, np.ndarray]:
        """The records at `offsets` of the types asked for (and those every read follows), as returned."""
        if not offsets:
            return {}
        data = np.frombuffer(buffer, dtype=np.uint8)
        at = np.asarray(offsets, dtype=np.int64)
        types = data[at + 2]
        counts = np.bincount(types, minlength=256)
        self._state.counts += counts
        present = np.flatnonzero(counts)
        found: dict[str, np.ndarray] = {}
        for type_id in present.tolist():
            fmt = self._state.formats[type_id]
            asked, follow = fmt.name in self.names, _FOLLOWED.get(fmt.name)
            if not (asked or follow or fmt.name in IMU_TYPES):
                continue
            mine = at[types == type_id] + 3
            if fmt.name in IMU_TYPES:
                _imu_instances(self._state, fmt, data, mine)
            if not (asked or follow):
                continue
            assert fmt.raw_dtype is not None
            rows = decoded(_bodies(data, mine, fmt.raw_dtype), fmt)
            if follow is not None:
                follow(self._state, fmt, rows)
            if asked:
                found[fmt.name] = rows
        return found


def _bodies(data: np.ndarray, starts: np.ndarray, raw_dtype: np.dtype) -> np.ndarray:
    """The bodies at `starts` (each raw_dtype.itemsize bytes) as one structured array: a gather of rows of
    a sliding window over the block (no index per byte)."""
    width = raw_dtype.itemsize
    windows = np.lib.stride_tricks.sliding_window_view(data, width)
    return np.ascontiguousarray(windows[starts]).view(raw_dtype).reshape(-1)


def _follow_params(state: _State, fmt: RecordFormat, rows: np.ndarray) -> None:
    if "Name" in fmt.columns and "Value" in fmt.columns:
        state.params.update(zip(rows["Name"].tolist(), (float(v) for v in rows["Value"].tolist())))


def _follow_units(state: _State, fmt: RecordFormat, rows: np.ndarray) -> None:
    if "FmtType" in fmt.columns and "UnitIds" in fmt.columns:
        state.units.extend(zip((int(v) for v in rows["FmtType"].tolist()), rows["UnitIds"].tolist()))


def _imu_instances(state: _State, fmt: RecordFormat, data: np.ndarray, starts: np.ndarray) -> None:
    """The instances of IMU records at `starts`: today's field I (read alone, not the whole bodies), or the
    older logs' type IMU, IMU2, IMU3."""
    if fmt.name == "IMU" and fmt.raw_dtype is not None and "I" in fmt.columns:
        kind, offset = fmt.raw_dtype.fields["I"][:2]  # type: ignore[index]
        values = data[starts + offset].view(kind) if kind.itemsize == 1 else _bodies(data, starts, fmt.raw_dtype)["I"]
        state.imu_instances.update(int(v) for v in np.unique(values).tolist())
    else:
        state.imu_instances.add(IMU_TYPES.index(fmt.name))


# What every read follows, asked for or not: the parameters, the FMTU units (and the IMU instances).
_FOLLOWED: dict[str, Callable[[_State, RecordFormat, np.ndarray], None]] = {
    "PARM": _follow_params, "FMTU": _follow_units}


def iter_records(path: str | os.PathLike[str], names: Iterable[str], block_bytes: int = BLOCK_BYTES
                 ) -> Iterator[dict[str, np.ndarray]]:
    """{type name: structured array of its records in this block} for the types `names` asks for, block by
    block in file order (a block: `block_bytes` of the file; a type without records in it is left out).
    Fields are the FMT columns: scaled values float64, strings str, `a` int16[32], the rest as logged.
    Raises DataflashError (one line) on damage; the memory is one block's whatever the log's length."""
    return RecordReader(path, names, block_bytes).blocks()


def read_records(path: str | os.PathLike[str], names: Iterable[str], block_bytes: int = BLOCK_BYTES) -> LogRecords:
    """The records of the types `names` asks for, whole (for the small types: PARM, ARM, EV, the filter's
    XKF/NKF records), and what the walk learnt of the whole log: parameters, counts, formats, IMU instances."""
    reader = RecordReader(path, names, block_bytes)
    parts: dict[str, list[np.ndarray]] = {}
    for block in reader.blocks():
        for name, rows in block.items():
            parts.setdefault(name, []).append(rows)
    records = {}
    for name, pieces in parts.items():
        try:
            records[name] = np.concatenate(pieces)
        except (TypeError, ValueError):  # two types of one name with other layouts
            raise DataflashError(f"{path}: damaged DataFlash log: two FMT records define {name} with other "
                                 "layouts") from None
    return LogRecords(records, dict(reader.params), reader.formats, reader.counts, reader.imu_instances,
                      reader.bytes_read)
