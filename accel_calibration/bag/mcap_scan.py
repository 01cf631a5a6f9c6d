"""Fast read of chosen topics from an MCAP rosbag2 file: chunk by chunk, one tight loop over the
message records, no per-message objects. For bag replay, which is bound by reading; anything this
does not know (an unknown compression, a malformed record) returns None and the caller falls back to
rosbags' reader. Messages come in file order (replay sorts by header stamp anyway).

Format: https://mcap.dev/spec -- records are opcode u8, length u64, body; Schema 0x03 (id u16, name
string, encoding string, data u32 + bytes), Channel 0x04 (id u16, schema u16, topic string, ...),
Message 0x05 (channel u16, sequence u32, log_time u64, publish_time u64, data), Chunk 0x06 (start u64,
end u64, uncompressed size u64, crc u32, compression string, records u64 + bytes), Footer 0x02
(summary start u64, summary offset start u64, crc u32).

A hostile or damaged file never gets more than its chunks declare: decompression stops at the chunk's
stated size (no decompression bomb), and a chunk that does not decompress to it returns None."""
from __future__ import annotations

import struct
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
MAX_CHUNK_BYTES = 1 << 30  # rosbag2 writes chunks of ~1-4 MiB; a larger declared size is damage


class _ChunkError(Exception):
    """A chunk that does not decompress to its declared size."""


def _decompressor(name: str):
    """f(data, size) -> exactly `size` bytes, never more (raises _ChunkError otherwise); None if unknown."""
    if name == "":
        def plain(data, size):
            if len(data) != size:
                raise _ChunkError(f"chunk holds {len(data)} bytes, declares {size}")
            return data
        return plain
    if name == "zstd":
        try:
            from compression import zstd  # type: ignore[import-not-found]
        except ImportError:
            from backports import zstd

        def unzstd(data, size):
            return _bounded(zstd.ZstdDecompressor(), data, size)
        return unzstd
    if name == "lz4":
        from lz4.frame import LZ4FrameDecompressor

        def unlz4(data, size):
            return _bounded(LZ4FrameDecompressor(), data, size)
        return unlz4
    return None


def _bounded(decompressor, data, size: int) -> bytes:
    if size > MAX_CHUNK_BYTES:
        raise _ChunkError(f"chunk declares {size} bytes")
    try:
        raw = decompressor.decompress(bytes(data), max_length=size + 1)
    except Exception as error:  # noqa: BLE001 - zstd and lz4 raise their own types for damaged data
        raise _ChunkError(str(error)) from None
    if len(raw) != size:
        raise _ChunkError(f"chunk decompresses to {len(raw)}+ bytes, declares {size}")
    return raw


def _string(buf, at) -> tuple[str, int]:
    """A u32-prefixed UTF-8 string at `at`; (text, offset after it)."""
    length = _U32.unpack_from(buf, at)[0]
    if at + 4 + length > len(buf):
        raise ValueError("string beyond its record")
    return bytes(buf[at + 4:at + 4 + length]).decode("utf-8"), at + 4 + length


def _channel(buf, body, channels, meta=None):
    channel_id = _U16.unpack_from(buf, body)[0]
    topic, _ = _string(buf, body + 4)
    channels[channel_id] = topic
    if meta is not None:
        meta["channel_schema"][channel_id] = _U16.unpack_from(buf, body + 2)[0]


def _schema(buf, body, meta) -> None:
    schema_id = _U16.unpack_from(buf, body)[0]
    name, at = _string(buf, body + 2)
    encoding, at = _string(buf, at)
    length = _U32.unpack_from(buf, at)[0]
    meta["schemas"][schema_id] = (name, encoding, bytes(buf[at + 4:at + 4 + length]).decode("utf-8", "replace"))


def _recorded(channels, meta) -> dict[str, tuple[str, str, str]]:
    """{topic: (schema name = message type, encoding, definition text)} of the channels seen."""
    found = {}
    for channel_id, topic in channels.items():
        schema = meta["schemas"].get(meta["channel_schema"].get(channel_id))
        if schema is not None:
            found[topic] = schema
    return found


def scan_topics(path, topics, progress=None, schemas: dict | None = None) -> dict[str, list] | None:
    """{topic: [message data, ...]} for the wanted topics, or None when this file needs rosbags (or is
    damaged: rosbags then says how). `schemas`, when given, is filled with {topic: (message type,
    encoding, definition)} as recorded in the file's Schema and Channel records."""
    files = sorted(Path(path).glob("*.mcap")) if Path(path).is_dir() else [Path(path)]
    wanted = set(topics)
    out = {topic: [] for topic in wanted}
    times = {topic: [] for topic in wanted}  # log_time of each message: the order rosbag2 readers give
    meta: dict = {"schemas": {}, "channel_schema": {}}
    try:
        for file in files:
            data = memoryview(file.read_bytes())
            if bytes(data[:8]) != MAGIC:
                return None
            channels: dict[int, str] = {}
            meta["schemas"], meta["channel_schema"] = {}, {}
            pos, end = 8, len(data) - 8
            while pos < end:
                op = data[pos]
                length = _U64.unpack_from(data, pos + 1)[0]
                body = pos + 9
                if body + length > len(data):
                    return None  # cut short: the file was truncated
                if op == 0x03:
                    _schema(data, body, meta)
                elif op == 0x04:
                    _channel(data, body, channels, meta)
                elif op == 0x06:
                    size = _U64.unpack_from(data, body + 16)[0]
                    name_length = _U32.unpack_from(data, body + 28)[0]
                    name = bytes(data[body + 32:body + 32 + name_length]).decode()
                    decompress = _decompressor(name)
                    if decompress is None:
                        return None
                    records_at = body + 32 + name_length
                    records_length = _U64.unpack_from(data, records_at)[0]
                    chunk = decompress(data[records_at + 8:records_at + 8 + records_length], size)
                    chunk = memoryview(chunk)
                    count = _scan_records(chunk, channels, wanted, out, times, meta)
                    if progress is not None:
                        progress.update(count)
                elif op == 0x05:
                    _scan_records(data[pos:pos + 9 + length], channels, wanted, out, times, meta)
                elif op == 0x02:  # Footer: the summary that follows repeats what we have
                    break
                pos = body + length
            if schemas is not None:
                schemas.update(_recorded(channels, meta))
    except (struct.error, IndexError, ValueError, OSError, _ChunkError):
        return None
    for topic, stamps in times.items():
        if any(later < earlier for earlier, later in zip(stamps, stamps[1:])):
            order = sorted(range(len(stamps)), key=stamps.__getitem__)  # stable, as rosbags merges by log_time
            out[topic] = [out[topic][i] for i in order]
    return out


def _scan_records(buf, channels, wanted, out, times, meta=None) -> int:
    """Collect message data of wanted topics from a run of records; returns messages seen."""
    pos, end, seen = 0, len(buf), 0
    u64, u16 = _U64.unpack_from, _U16.unpack_from
    targets = {}
    while pos < end:
        op = buf[pos]
        length = u64(buf, pos + 1)[0]
        body = pos + 9
        if op == 0x05:
            seen += 1
            channel_id = u16(buf, body)[0]
            target = targets.get(channel_id)
            if target is None and channel_id in channels:
                topic = channels[channel_id]
                target = targets[channel_id] = (out[topic], times[topic]) if topic in wanted else False
            if target is not None and target is not False:
                target[0].append(buf[body + 22:body + length])
                target[1].append(u64(buf, body + 6)[0])
        elif op == 0x04:
            _channel(buf, body, channels, meta)
            targets.clear()
        elif op == 0x03 and meta is not None:
            _schema(buf, body, meta)
        pos = body + length
    return seen


def recorded_types(file) -> dict[str, tuple[str, str, str]] | None:
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
                meta: dict = {"schemas": {}, "channel_schema": {}}
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
