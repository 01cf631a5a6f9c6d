"""Fast read of chosen topics from an MCAP rosbag2 file: chunk by chunk, a loop over runs of like
records (not over records), payloads gathered with numpy, no per-message objects. For bag replay,
which is bound by reading; anything this does not know (an unknown compression, a malformed record)
returns None and the caller falls back to rosbags' reader. Messages come in log_time order, as rosbag2
readers give them (replay sorts by header stamp anyway).

Format: https://mcap.dev/spec -- records are opcode u8, length u64, body; Schema 0x03 (id u16, name
string, encoding string, data u32 + bytes), Channel 0x04 (id u16, schema u16, topic string, ...),
Message 0x05 (channel u16, sequence u32, log_time u64, publish_time u64, data), Chunk 0x06 (start u64,
end u64, uncompressed size u64, crc u32, compression string, records u64 + bytes), Footer 0x02
(summary start u64, summary offset start u64, crc u32).

A hostile or damaged file never gets more than its chunks declare: decompression stops at the chunk's
stated size (no decompression bomb), and a chunk that does not decompress to it returns None."""
from __future__ import annotations

import os
import struct
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypedDict, overload

import numpy as np

from ..core.errors import AccelCalibrationError
from .progress import ProgressBar

MAGIC = b"\x89MCAP0\r\n"
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
MAX_CHUNK_BYTES = 1 << 30  # rosbag2 writes chunks of ~1-4 MiB; a larger declared size is damage


_Buffer = bytes | memoryview
_Schemas = dict[str, tuple[str, str, str]]  # {topic: (message type, encoding, definition text)}


class _Meta(TypedDict):
    schemas: dict[int, tuple[str, str, str]]  # schema id: (name, encoding, definition text)
    channel_schema: dict[int, int]  # channel id: schema id


class _ChunkError(Exception):
    """A chunk that does not decompress to its declared size."""


def _decompressor(name: str) -> Callable[[_Buffer, int], _Buffer] | None:
    """f(data, size) -> exactly `size` bytes, never more (raises _ChunkError otherwise); None if unknown."""
    if name == "":
        def plain(data: _Buffer, size: int) -> _Buffer:
            if len(data) != size:
                raise _ChunkError(f"a chunk holds {len(data)} bytes, not its declared size {size}")
            return data
        return plain
    if name == "zstd":
        try:
            from compression import zstd
        except ImportError:
            from backports import zstd

        def unzstd(data: _Buffer, size: int) -> _Buffer:
            return _bounded(zstd.ZstdDecompressor(), data, size)
        return unzstd
    if name == "lz4":
        from lz4.frame import LZ4FrameDecompressor

        def unlz4(data: _Buffer, size: int) -> _Buffer:
            return _bounded(LZ4FrameDecompressor(), data, size)
        return unlz4
    return None


def _bounded(decompressor: Any, data: _Buffer, size: int) -> bytes:
    if size > MAX_CHUNK_BYTES:
        raise _ChunkError(f"a chunk declares an impossible size, {size} bytes")
    try:
        raw: bytes = decompressor.decompress(bytes(data), max_length=size + 1)
    except Exception as error:  # noqa: BLE001 - zstd and lz4 raise their own types for damaged data
        raise _ChunkError(str(error)) from None
    if len(raw) > size:
        raise _ChunkError(f"a chunk decompresses to {len(raw)}+ bytes, past its declared size {size}")
    if len(raw) < size:
        raise _ChunkError(f"a chunk decompresses to {len(raw)} bytes, short of its declared size {size}")
    return raw


def _string(buf: _Buffer, at: int) -> tuple[str, int]:
    """A u32-prefixed UTF-8 string at `at`; (text, offset after it)."""
    length = _U32.unpack_from(buf, at)[0]
    if at + 4 + length > len(buf):
        raise ValueError("string beyond its record")
    return bytes(buf[at + 4:at + 4 + length]).decode("utf-8"), at + 4 + length


def _channel(buf: _Buffer, body: int, channels: dict[int, str], meta: _Meta | None = None) -> None:
    channel_id = _U16.unpack_from(buf, body)[0]
    topic, _ = _string(buf, body + 4)
    channels[channel_id] = topic
    if meta is not None:
        meta["channel_schema"][channel_id] = _U16.unpack_from(buf, body + 2)[0]


def _schema(buf: _Buffer, body: int, meta: _Meta) -> None:
    schema_id = _U16.unpack_from(buf, body)[0]
    name, at = _string(buf, body + 2)
    encoding, at = _string(buf, at)
    length = _U32.unpack_from(buf, at)[0]
    meta["schemas"][schema_id] = (name, encoding, bytes(buf[at + 4:at + 4 + length]).decode("utf-8", "replace"))


def _recorded(channels: dict[int, str], meta: _Meta) -> _Schemas:
    """{topic: (schema name = message type, encoding, definition text)} of the channels seen."""
    found = {}
    for channel_id, topic in channels.items():
        schema_id = meta["channel_schema"].get(channel_id)
        schema = None if schema_id is None else meta["schemas"].get(schema_id)
        if schema is not None:
            found[topic] = schema
    return found


def scan_topics(path: str | os.PathLike[str], topics: Iterable[str], progress: ProgressBar | None = None,
                schemas: _Schemas | None = None) -> dict[str, PackedMessages] | None:
    """{topic: [message data, ...]} for the wanted topics, or None when this file needs rosbags (or is
    damaged: rosbags then says how). `schemas`, when given, is filled with {topic: (message type,
    encoding, definition)} as recorded in the file's Schema and Channel records. The whole bag, in
    log_time order (one sort over every chunk's messages)."""
    wanted = set(topics)
    out: dict[str, list[np.ndarray]] = {topic: [] for topic in wanted}  # runs of payloads, file order
    times: dict[str, list[np.ndarray]] = {topic: [] for topic in wanted}  # log_times: rosbag2 readers' order
    try:
        for runs, log_times in _chunk_runs(path, wanted, progress, None, schemas):
            for topic in wanted:
                out[topic] += runs[topic]
                times[topic] += log_times[topic]
    except NotStreamable:
        return None
    return {topic: PackedMessages(out[topic], times[topic]) for topic in wanted}


class DamagedChunk(AccelCalibrationError):
    """A chunk that does not decompress to its declared size: the file is damaged."""


class NotStreamable(Exception):
    """The file cannot be streamed as the whole-file read would give it (log times going back across
    chunks, damage, an unknown compression): the caller reads it whole instead."""


def stream_topics(path: str | os.PathLike[str], topics: Iterable[str], progress: ProgressBar | None = None,
                  group_messages: int = 1 << 16, schemas: _Schemas | None = None
                  ) -> Iterator[dict[str, PackedMessages]]:
    """The wanted topics' messages as scan_topics gives them, in groups of about `group_messages`
    ({topic: PackedMessages} per group, each in log_time order), reading one chunk at a time: memory is
    bounded by a group, not the file. `schemas` is kept filled with {topic: (message type, encoding,
    definition)} of the channels seen so far (a group's channels are seen before it is yielded). Raises
    NotStreamable where the whole-file read would differ (a chunk whose messages were logged before the
    previous group's latest: the whole file is sorted by log time) or this reader cannot go on."""
    wanted = set(topics)
    latest = -1  # the latest log time yielded
    for runs, log_times in _chunk_runs(path, wanted, progress, group_messages, schemas):
        stamps = [t for topic in wanted for t in log_times[topic] if len(t)]
        if stamps:
            if min(int(t.min()) for t in stamps) < latest:
                raise NotStreamable("messages logged out of order across chunks")
            latest = max(latest, max(int(t.max()) for t in stamps))
        yield {topic: PackedMessages(runs[topic], log_times[topic]) for topic in wanted}


def _chunk_runs(path: str | os.PathLike[str], wanted: set[str], progress: ProgressBar | None,
                group_messages: int | None, schemas: _Schemas | None
                ) -> Iterator[tuple[dict[str, list[np.ndarray]], dict[str, list[np.ndarray]]]]:
    """The one walk over a bag's .mcap files, a record at a time from the file (chunks decompressed one
    at a time): yields ({topic: payload runs}, {topic: log_time runs}) of the wanted topics in file order,
    about `group_messages` messages at a time (None: the whole file at once). `schemas` is kept filled as
    scan_topics says. Raises NotStreamable on anything this reader does not know (an unknown compression,
    a malformed or cut-short record)."""
    files = sorted(Path(path).glob("*.mcap")) if Path(path).is_dir() else [Path(path)]
    meta: _Meta = {"schemas": {}, "channel_schema": {}}
    try:
        for file in files:
            with open(file, "rb") as stream:
                if stream.read(8) != MAGIC:
                    raise NotStreamable("not an mcap file")
                channels: dict[int, str] = {}
                meta["schemas"], meta["channel_schema"] = {}, {}
                out: dict[str, list[np.ndarray]] = {topic: [] for topic in wanted}
                times: dict[str, list[np.ndarray]] = {topic: [] for topic in wanted}
                pending = 0
                while True:
                    head = stream.read(9)
                    if len(head) < 9:
                        raise NotStreamable("cut short: no footer")
                    op, length = head[0], _U64.unpack_from(head, 1)[0]
                    if op == 0x02:  # Footer: the summary before it repeats what we have
                        break
                    if op not in (0x03, 0x04, 0x05, 0x06):
                        stream.seek(length, 1)
                        continue
                    if length > MAX_CHUNK_BYTES:
                        raise NotStreamable("a record larger than any chunk rosbag2 writes")
                    body = stream.read(length)
                    if len(body) != length:
                        raise NotStreamable("cut short: the file was truncated")
                    if op == 0x03:
                        _schema(body, 0, meta)
                    elif op == 0x04:
                        _channel(body, 0, channels, meta)
                    elif op == 0x06:
                        size = _U64.unpack_from(body, 16)[0]
                        name_length = _U32.unpack_from(body, 28)[0]
                        decompress = _decompressor(bytes(body[32:32 + name_length]).decode())
                        if decompress is None:
                            raise NotStreamable("unknown chunk compression")
                        records_at = 32 + name_length
                        records_length = _U64.unpack_from(body, records_at)[0]
                        view = memoryview(body)[records_at + 8:records_at + 8 + records_length]
                        chunk = memoryview(decompress(view, size))
                        count = _scan_records(chunk, channels, wanted, out, times, meta)
                        pending += count
                        if progress is not None:
                            progress.update(count)
                    else:
                        pending += _scan_records(memoryview(head + body), channels, wanted, out, times, meta)
                    if group_messages is not None and pending >= group_messages:
                        if schemas is not None:
                            schemas.update(_recorded(channels, meta))
                        yield out, times
                        out = {topic: [] for topic in wanted}
                        times = {topic: [] for topic in wanted}
                        pending = 0
                if schemas is not None:
                    schemas.update(_recorded(channels, meta))
                if group_messages is None or any(out[topic] for topic in wanted):
                    yield out, times
    except _ChunkError as error:
        # Damage, not a layout to read otherwise: never handed to another reader (rosbags' decompresses a
        # chunk whole, whatever it declares).
        raise DamagedChunk(f"{Path(path).name}: {error}") from None
    except (struct.error, IndexError, ValueError, OSError) as error:
        raise NotStreamable(str(error)) from None


class PackedMessages(Sequence[bytes]):
    """Message payloads of one topic, kept as the uint8 matrices of runs of equal-length records (no
    per-message objects), in file order, then stably sorted by log_time when the file was not. A
    Sequence of bytes for callers that want one message at a time; decode_imus takes `block()`."""

    def __init__(self, runs: list[np.ndarray], log_times: list[np.ndarray]) -> None:
        self._runs = runs
        counts = np.array([run.shape[0] for run in runs], dtype=np.int64)
        widths = np.array([run.shape[1] for run in runs], dtype=np.int64)
        self._starts = np.concatenate([[0], np.cumsum(counts)])
        file_lengths = np.repeat(widths, counts)
        times = np.concatenate(log_times) if log_times else np.empty(0, dtype=np.uint64)
        self._order: np.ndarray | None = None
        if np.any(times[1:] < times[:-1]):
            self._order = np.argsort(times, kind="stable")  # as rosbags merges by log_time
        self.lengths = file_lengths if self._order is None else file_lengths[self._order]
        self._by_width: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    @classmethod
    def from_payloads(cls, payloads: list[bytes]) -> PackedMessages:
        """From a list of bytes already in order (one SELECT of a sqlite3 table): one joined buffer per
        run of equal lengths (one run for a usual recording)."""
        lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
        bounds = [0, *(np.flatnonzero(np.diff(lengths)) + 1).tolist(), len(payloads)]
        runs = [np.frombuffer(b"".join(payloads[a:b]), dtype=np.uint8).reshape(b - a, int(lengths[a]))
                for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        return cls(runs, [])

    def __len__(self) -> int:
        return int(self._starts[-1])

    def _file_index(self, i: int) -> int:
        return int(self._order[i]) if self._order is not None else i

    @overload
    def __getitem__(self, i: int) -> bytes: ...

    @overload
    def __getitem__(self, i: slice) -> list[bytes]: ...

    def __getitem__(self, i: int | slice) -> bytes | list[bytes]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(len(self)))]
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        f = self._file_index(i)
        run = int(np.searchsorted(self._starts, f, side="right")) - 1
        row: np.ndarray = self._runs[run][f - int(self._starts[run])]
        return row.tobytes()

    def __iter__(self) -> Iterator[bytes]:
        if self._order is None:
            for run in self._runs:
                for row in run:
                    yield row.tobytes()
        else:
            yield from (self[i] for i in range(len(self)))

    def block(self, index: np.ndarray) -> np.ndarray:
        """(len(index), width) uint8 matrix of the messages at `index` (all of one length)."""
        width = int(self.lengths[index[0]])
        if width not in self._by_width:
            same = [run for run in self._runs if run.shape[1] == width]
            matrix = same[0] if len(same) == 1 else np.concatenate(same)
            row_in_matrix = np.full(len(self), -1, dtype=np.int64)
            for run, start in zip(self._runs, self._starts[:-1]):
                if run.shape[1] == width:
                    row_in_matrix[start:start + run.shape[0]] = -2  # mark; numbered below in file order
            marked = np.flatnonzero(row_in_matrix == -2)
            row_in_matrix[marked] = np.arange(len(marked))
            self._by_width[width] = (matrix, row_in_matrix)
        matrix, row_in_matrix = self._by_width[width]
        file_index = self._order[index] if self._order is not None else index
        rows = row_in_matrix[file_index]
        if len(rows) == len(matrix) and np.array_equal(rows, np.arange(len(matrix))):
            return matrix
        picked: np.ndarray = matrix[rows]
        return picked


_RUN_PROBE_MAX = 1 << 14  # records compared at once when looking for the end of a run


def _scan_records(buf: _Buffer, channels: dict[int, str], wanted: set[str], out: dict[str, list[np.ndarray]],
                  times: dict[str, list[np.ndarray]], meta: _Meta | None = None) -> int:
    """Collect message data of wanted topics from a run of records; returns messages seen. Records
    come in runs (same opcode, length and channel: a topic's messages between other topics'), so each
    run is found with numpy on a strided view and its payloads copied as one matrix. A record that
    does not fit in `buf` is damage (ValueError)."""
    data = np.frombuffer(buf, dtype=np.uint8)
    pos, end, seen = 0, len(buf), 0
    u64, u16 = _U64.unpack_from, _U16.unpack_from
    probes: dict[int, int] = {}  # channel: records to compare next time (twice its last run)
    found: dict[str, list[tuple[int, int, int, int]]] = {}  # topic: [(first record, records, stride, width)]
    while pos < end:
        if pos + 9 > end:
            raise ValueError("record header beyond its chunk")
        op = buf[pos]
        length = u64(buf, pos + 1)[0]
        body = pos + 9
        if body + length > end:
            raise ValueError("record beyond its chunk")
        if op != 0x05:
            if op == 0x04:
                _channel(buf, body, channels, meta)
            elif op == 0x03 and meta is not None:
                _schema(buf, body, meta)
            pos = body + length
            continue
        if length < 22:
            raise ValueError("message record shorter than its header")
        stride = 9 + length
        channel_id = u16(buf, body)[0]
        count = min((end - pos) // stride, probes.get(channel_id, 16))
        if count < 2 or buf[pos:pos + 11] != buf[pos + stride:pos + stride + 11]:
            run = 1  # a lone record (another topic's, at a lower rate): no numpy for it
        else:
            heads = np.ndarray((count, 11), dtype=np.uint8, buffer=data, offset=pos, strides=(stride, 1))
            differs = np.flatnonzero((heads != heads[0]).any(axis=1))
            run = int(differs[0]) if len(differs) else count
        probes[channel_id] = min(_RUN_PROBE_MAX, max(16, 2 * run))
        seen += run
        topic = channels.get(channel_id)
        if topic is not None and topic in wanted:
            found.setdefault(topic, []).append((pos, run, stride, length - 22))
        pos += run * stride
    for topic, runs in found.items():
        firsts, counts, strides, _ = np.array(runs, dtype=np.int64).T
        within = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        starts = np.repeat(firsts, counts) + np.repeat(strides, counts) * within
        times[topic].append(_gather(data, starts + 15, 8).view("<u8").ravel())
        widths = {width for *_, width in runs}
        if len(widths) == 1:  # the usual case: one matrix for the chunk's messages of this topic
            out[topic].append(_gather(data, starts + 31, widths.pop()))
        else:  # lengths vary: one matrix per run keeps file order
            out[topic].extend(np.ndarray((count, width), dtype=np.uint8, buffer=data, offset=first + 31,
                                         strides=(stride, 1)).copy() for first, count, stride, width in runs)
    return seen


def _gather(data: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """(len(starts), width) copy of data[start:start + width] for each start (all inside data)."""
    if width == 0:
        return np.zeros((len(starts), 0), dtype=np.uint8)
    gathered: np.ndarray = np.lib.stride_tricks.sliding_window_view(data, width)[starts]
    return gathered


def recorded_types(file: str | os.PathLike[str]) -> _Schemas | None:
    """{topic: (message type, encoding, definition)} as one .mcap file records them: from its summary
    section (a few records at the end) when it has one, else from a scan of the whole file; None when
    the file cannot be parsed (damage: the caller's reader will say how)."""
    file = Path(file)
    try:
        with open(file, "rb") as stream:
            stream.seek(0, 2)
            size = stream.tell()
            if size < 8 + 9 + 20 + 8:
                return None
            stream.seek(size - 8 - 29)
            footer = stream.read(29)
            if footer[0] != 0x02:
                return None
            summary_start = _U64.unpack_from(footer, 9)[0]
            if summary_start and 8 <= summary_start < size - 37:
                stream.seek(summary_start)
                summary = memoryview(stream.read(size - 37 - summary_start))
                channels: dict[int, str] = {}
                meta: _Meta = {"schemas": {}, "channel_schema": {}}
                pos = 0
                while pos + 9 <= len(summary):
                    op = summary[pos]
                    length = _U64.unpack_from(summary, pos + 1)[0]
                    body = pos + 9
                    if body + length > len(summary):
                        return None
                    if op == 0x03:
                        _schema(summary, body, meta)
                    elif op == 0x04:
                        _channel(summary, body, channels, meta)
                    pos = body + length
                if channels:
                    return _recorded(channels, meta)
    except (OSError, struct.error, IndexError, ValueError):
        return None
    found: dict[str, tuple[str, str, str]] = {}
    return found if scan_topics(file, [], schemas=found) is not None else None


def summary_topics(file: str | os.PathLike[str]) -> list[tuple[str, str, int]] | None:
    """[(topic, message type, message count)] of one .mcap file from its summary section's Schema, Channel
    and Statistics records (a few records at the end: no rosbags reader, whose import and open cost
    ~0.3 s); None when the summary lacks any of them or a topic has two channels (rosbags then reads it)."""
    file = Path(file)
    try:
        with open(file, "rb") as stream:
            size = stream.seek(0, 2)
            if size < 8 + 9 + 20 + 8:
                return None
            stream.seek(size - 8 - 29)
            footer = stream.read(29)
            if footer[0] != 0x02:
                return None
            summary_start = _U64.unpack_from(footer, 9)[0]
            if not summary_start or not 8 <= summary_start < size - 37:
                return None
            stream.seek(summary_start)
            summary = memoryview(stream.read(size - 37 - summary_start))
        channels: dict[int, str] = {}
        meta: _Meta = {"schemas": {}, "channel_schema": {}}
        counts: dict[int, int] | None = None
        pos = 0
        while pos + 9 <= len(summary):
            op = summary[pos]
            length = _U64.unpack_from(summary, pos + 1)[0]
            body = pos + 9
            if body + length > len(summary):
                return None
            if op == 0x03:
                _schema(summary, body, meta)
            elif op == 0x04:
                _channel(summary, body, channels, meta)
            elif op == 0x0B:  # Statistics: 42 bytes of totals, then map<channel id u16, count u64>
                end = body + 46 + _U32.unpack_from(summary, body + 42)[0]
                counts = {_U16.unpack_from(summary, at)[0]: _U64.unpack_from(summary, at + 2)[0]
                          for at in range(body + 46, end, 10)}
            pos = body + length
    except (OSError, struct.error, IndexError, ValueError):
        return None
    if counts is None or not channels or len(set(channels.values())) != len(channels):
        return None
    types = {channel_id: schema[0] for channel_id, schema_id in meta["channel_schema"].items()
             if (schema := meta["schemas"].get(schema_id)) is not None}
    if any(channel_id not in types for channel_id in channels):
        return None
    return [(topic, types[channel_id], int(counts.get(channel_id, 0))) for channel_id, topic in channels.items()]
