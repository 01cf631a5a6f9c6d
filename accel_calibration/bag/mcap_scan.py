"""Fast read of chosen topics from an MCAP rosbag2 file: chunk by chunk, one tight loop over the
message records, no per-message objects. For bag replay, which is bound by reading; anything this
does not know (an unknown compression, a malformed record) returns None and the caller falls back to
rosbags' reader. Messages come in file order (replay sorts by header stamp anyway).

Format: https://mcap.dev/spec -- records are opcode u8, length u64, body; Channel 0x04 (id u16,
schema u16, topic string, ...), Message 0x05 (channel u16, sequence u32, log_time u64, publish_time
u64, data), Chunk 0x06 (start u64, end u64, uncompressed size u64, crc u32, compression string,
records u64 + bytes)."""
from __future__ import annotations

import struct
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")


def _decompressor(name: str):
    if name == "":
        return lambda data, size: data
    if name == "zstd":
        try:
            from compression import zstd
        except ImportError:
            from backports import zstd
        return lambda data, size: zstd.decompress(data)
    if name == "lz4":
        from lz4.frame import decompress

        return lambda data, size: decompress(data)
    return None


def _channel(buf, body, channels):
    channel_id = _U16.unpack_from(buf, body)[0]
    topic_length = _U32.unpack_from(buf, body + 4)[0]
    channels[channel_id] = bytes(buf[body + 8:body + 8 + topic_length]).decode("utf-8")


def scan_topics(path, topics, progress=None) -> dict[str, list] | None:
    """{topic: [message data, ...]} for the wanted topics, or None when this file needs rosbags."""
    files = sorted(Path(path).glob("*.mcap")) if Path(path).is_dir() else [Path(path)]
    wanted = set(topics)
    out = {topic: [] for topic in wanted}
    times = {topic: [] for topic in wanted}  # log_time of each message: the order rosbag2 readers give
    try:
        for file in files:
            data = memoryview(file.read_bytes())
            if bytes(data[:8]) != MAGIC:
                return None
            channels: dict[int, str] = {}
            pos, end = 8, len(data) - 8
            while pos < end:
                op = data[pos]
                length = _U64.unpack_from(data, pos + 1)[0]
                body = pos + 9
                if op == 0x04:
                    _channel(data, body, channels)
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
                    count = _scan_records(chunk, channels, wanted, out, times)
                    if progress is not None:
                        progress.update(count)
                elif op == 0x05:
                    _scan_records(data[pos:pos + 9 + length], channels, wanted, out, times)
                elif op == 0x02:  # Footer: the summary that follows repeats what we have
                    break
                pos = body + length
    except (struct.error, IndexError, ValueError, OSError):
        return None
    for topic, stamps in times.items():
        if any(later < earlier for earlier, later in zip(stamps, stamps[1:])):
            order = sorted(range(len(stamps)), key=stamps.__getitem__)  # stable, as rosbags merges by log_time
            out[topic] = [out[topic][i] for i in order]
    return out


def _scan_records(buf, channels, wanted, out, times) -> int:
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
            _channel(buf, body, channels)
            targets.clear()
        pos = body + length
    return seen
