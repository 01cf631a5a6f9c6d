"""The data records of a few PX4 ULog topics, read a block of the file at a time: memory bounded by a block,
whatever the log's length. pyulog loads every record of a topic at once (all instances of sensor_accel and
sensor_gyro of a 1-hour, 1 kHz, three-IMU log: over 1.5 GB), so the high-rate topics are read here and the
rest (parameters, flight state, the filter's bias, a few thousand records) through pyulog as before
(ulog_reader._load, which also refuses a truncated or corrupt log before this reads a byte of it).

The format (PX4's ULog file format): a 16-byte header, then records of a uint16 size, a uint8 type and the
body: 'F' a format ("name:type field;..."), 'A' a subscription (uint8 multi_id, uint16 msg_id, name), 'D' a
data record (uint16 msg_id, then the fields packed, trailing padding possibly left out). The bodies of one
subscription are gathered with numpy into a structured array whose fields are named as pyulog names them
("x", "gyro_rad[0]", "nested.field"), so the readers take either alike. A log with data appended after its
end (flag bits) is read whole by pyulog (`NotStreamable`)."""
from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

BLOCK_BYTES = 8 << 20  # file bytes walked at a time (the results do not depend on it)
HEADER_BYTES = 16
_TYPES = {"int8_t": "i1", "uint8_t": "u1", "int16_t": "<i2", "uint16_t": "<u2", "int32_t": "<i4", "uint32_t": "<u4",
          "int64_t": "<i8", "uint64_t": "<u8", "float": "<f4", "double": "<f8", "bool": "u1", "char": "S1"}
_F, _A, _D, _B = ord("F"), ord("A"), ord("D"), ord("B")


class NotStreamable(Exception):
    """A log this reader does not take (data appended after its end): read it whole."""


class Corrupt(Exception):
    """A record that contradicts the log's own definitions: one line saying which, at which byte."""


class CutShort(Exception):
    """The file ends inside a record (cut short while logging): `args[0]` the bytes left over."""


@dataclass
class Subscription:
    """One logged instance of a topic: its rows so far (`rows`), its first and last stamps (us; the sample's
    stamp where the topic has one)."""

    name: str
    multi_id: int
    rows: int = 0
    first_us: int | None = None
    last_us: int | None = None


@dataclass
class _Walk:
    formats: dict[str, str] = field(default_factory=dict)  # name: "type field;..."
    subscriptions: dict[int, Subscription] = field(default_factory=dict)  # msg_id: subscription
    wanted: dict[int, str | None] = field(default_factory=dict)  # msg_id: its topic (None: not wanted)
    dtypes: dict[int, np.dtype] = field(default_factory=dict)  # msg_id: its rows, from its first data record
    sizes: dict[int, int] = field(default_factory=dict)  # msg_id: its data records' size (all alike)
    offset: int = HEADER_BYTES  # the file's byte at the start of the block walked


def stream_topics(path: str | os.PathLike[str], names: set[str], block_bytes: int | None = None
                  ) -> Iterator[list[tuple[Subscription, dict[str, np.ndarray]]]]:
    """The rows of every instance of the topics `names`, a block of the file at a time (`block_bytes`, default
    BLOCK_BYTES), in file order: per block [(subscription, {field: values})] of the subscriptions with rows in
    it. The subscription's `rows`, `first_us` and `last_us` count what has been read up to and including it."""
    block_bytes = block_bytes or BLOCK_BYTES
    walk = _Walk()
    pending = b""
    with open(path, "rb") as stream:
        stream.seek(HEADER_BYTES)
        while True:
            chunk = stream.read(block_bytes)
            if not chunk:
                break
            buffer = pending + chunk if pending else chunk
            positions, used = _walk_block(buffer, walk, names)
            walk.offset += used
            pending = buffer[used:]
            found = []
            array = np.frombuffer(buffer, dtype=np.uint8)
            for msg_id, at in positions.items():
                dtype = walk.dtypes.get(msg_id)
                if dtype is None:
                    body = struct.unpack_from("<H", buffer, at[0] - 5)[0]
                    dtype = walk.dtypes[msg_id] = _dtype(walk.subscriptions[msg_id].name, walk.formats, body)
                rows = _gather(array, np.asarray(at, dtype=np.int64), dtype)
                subscription = walk.subscriptions[msg_id]
                columns = _columns(rows)
                _count(subscription, columns)
                found.append((subscription, columns))
            if found:
                yield found
    if pending:
        raise CutShort(len(pending))


def _walk_block(buffer: bytes, walk: _Walk, names: set[str]) -> tuple[dict[int, list[int]], int]:
    """The body offsets of the wanted data records of each msg_id in `buffer`, and the bytes walked (a record
    cut by the block's end is left for the next)."""
    header = struct.Struct("<HB").unpack_from
    msg_id_of = struct.Struct("<H").unpack_from
    positions: dict[int, list[int]] = {}
    wanted = walk.wanted
    pos, end = 0, len(buffer)
    while pos + 3 <= end:
        size, kind = header(buffer, pos)
        after = pos + 3 + size
        if after > end:
            break
        if kind == _D and size >= 2:
            msg_id = msg_id_of(buffer, pos + 3)[0]
            if wanted.get(msg_id) is not None:
                if walk.sizes.setdefault(msg_id, size) != size:
                    raise Corrupt(f"corrupt ULog: a data record of {_said(str(wanted[msg_id]))} at byte "
                                  f"{walk.offset + pos} is {size} bytes, its earlier ones {walk.sizes[msg_id]}")
                positions.setdefault(msg_id, []).append(pos + 5)
        elif kind == _A and size >= 3:
            multi_id, msg_id = struct.unpack_from("<BH", buffer, pos + 3)
            name = buffer[pos + 6:after].decode("ascii", "replace")
            if msg_id in walk.subscriptions and (positions.get(msg_id) or msg_id in walk.dtypes):
                raise Corrupt(f"corrupt ULog: msg_id {msg_id} subscribed again at byte {walk.offset + pos} "
                              f"({_said(walk.subscriptions[msg_id].name)}, then {_said(name)})")
            walk.subscriptions[msg_id] = Subscription(name, multi_id)
            wanted[msg_id] = name if name in names else None
        elif kind == _F:
            text = buffer[pos + 3:after].decode("ascii", "replace")
            name, _, fields = text.partition(":")
            walk.formats[name] = fields
        elif kind == _B and size >= 40 and buffer[pos + 3 + 8] & 1:
            raise NotStreamable("data appended after the log's end")
        pos = after
    return positions, pos


def _dtype(name: str, formats: dict[str, str], body: int) -> np.dtype:
    """The packed numpy dtype of a topic's data body (`body` bytes less the msg_id; trailing padding that the
    logger left out is not in it), fields named as pyulog names them."""
    names: list[str] = []
    kinds: list[str] = []
    offsets: list[int] = []
    try:
        _flatten(name, formats, "", 0, names, kinds, offsets)
    except (KeyError, ValueError, RecursionError) as error:
        raise Corrupt(f"corrupt ULog: the format of {_said(name)} cannot be read ({type(error).__name__}: "
                      f"{_said(str(error))})") from None
    kept = [(n, k, o) for n, k, o in zip(names, kinds, offsets, strict=True)
            if not n.split(".")[-1].startswith("_padding") and o + np.dtype(k).itemsize <= body - 2]
    if not any(n == "timestamp" for n, _, _ in kept):
        raise Corrupt(f"corrupt ULog: the data records of {_said(name)} ({body} bytes) hold no timestamp field")
    return np.dtype({"names": [n for n, _, _ in kept], "formats": [k for _, k, _ in kept],
                     "offsets": [o for _, _, o in kept], "itemsize": body - 2})


def _flatten(name: str, formats: dict[str, str], prefix: str, offset: int, names: list[str], kinds: list[str],
             offsets: list[int]) -> int:
    """Append the fields of format `name` at `offset` (nested formats and arrays element by element, as
    pyulog names them); returns the offset after them."""
    for entry in filter(None, formats.get(name, "").split(";")):
        kind, _, field_name = entry.partition(" ")
        count = 1
        if kind.endswith("]"):
            kind, _, size = kind[:-1].partition("[")
            count = int(size)
        for index in range(count):
            label = prefix + field_name + (f"[{index}]" if kind in formats or count > 1 else "")
            if kind in formats:
                offset = _flatten(kind, formats, label + ".", offset, names, kinds, offsets)
                continue
            names.append(label)
            kinds.append(_TYPES[kind])
            offsets.append(offset)
            offset += np.dtype(_TYPES[kind]).itemsize
    return offset


def _said(name: str) -> str:
    """A name read from a damaged log as one short line of printable ASCII (its other bytes escaped)."""
    return ascii(name[:40] + ("..." if len(name) > 40 else ""))


def _gather(array: np.ndarray, at: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """The records' bodies at `at` (after their msg_id) as rows of `dtype`."""
    windows = np.lib.stride_tricks.as_strided(array, (len(array) - dtype.itemsize + 1, dtype.itemsize), (1, 1),
                                              writeable=False)  # every byte's next itemsize bytes: no copy
    return np.ascontiguousarray(windows[at]).view(dtype).reshape(-1)


def _columns(rows: np.ndarray) -> dict[str, np.ndarray]:
    names = rows.dtype.names or ()
    return {name: np.ascontiguousarray(rows[name]) for name in names}


def _count(subscription: Subscription, columns: dict[str, np.ndarray]) -> None:
    stamps = columns.get("timestamp_sample", columns.get("timestamp"))
    subscription.rows += len(next(iter(columns.values()))) if columns else 0
    if stamps is not None and len(stamps):
        if subscription.first_us is None:
            subscription.first_us = int(stamps[0])
        subscription.last_us = int(stamps[-1])


@dataclass
class KeptRows:
    """A subscription's rows kept by a read (`kept`), and how many the whole log holds."""

    subscription: Subscription
    columns: dict[str, np.ndarray]
