"""rosbag2 storage with the `rosbags` library (no ROS install): open a bag (directory, .mcap or .db3), its
topics and recorded message definitions, refuse what must not be read (special files, foreign SQLite
objects, definitions too large or not the ones the storage holds), and read the raw messages of the IMU
and temperature topics (whole or in groups). Decoding them: imu_messages.py; writing a corrected copy:
corrected_bag.py.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, Protocol, TypeVar

from ..core.errors import AccelCalibrationError

if TYPE_CHECKING:
    from .mcap_scan import PackedMessages
    from .progress import ProgressBar

IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"
MAX_METADATA_BYTES = 16 << 20  # a rosbag2 metadata.yaml is a few KB, ~1 KB more per topic or file
# A recorded message definition, with all it depends on: Imu's is ~3 KB, the largest common ones tens of KB.
# rosbags' parser is superlinear (a 740 KB one took 62 s and 650 MB), so a larger one is refused unparsed.
MAX_DEFINITION_BYTES = 128 << 10


class BagError(AccelCalibrationError):
    """A bag that cannot be used: the message names the bag and what was found."""


# Third-party modules whose pip name differs from the import name. (lz4, backports.zstd, pyulog, pyarrow,
# Dask, SQLAlchemy 2 and psycopg 3 have no rosdep key: a ROS install from rosdep alone lacks them.)
PIP_NAMES = {"backports": "backports.zstd", "yaml": "PyYAML", "sqlalchemy": "SQLAlchemy>=2",
             "dask": "dask[distributed]", "psycopg": "psycopg[binary]"}


def missing_module(error: ModuleNotFoundError, path: str | os.PathLike[str] | None = None) -> BagError | None:
    """What to install, for a third-party module that is not installed (None for one of ours: a bug, not
    an install to fix). Never read as a damaged recording: the recording was not looked at."""
    module = (error.name or "").split(".")[0]
    if not module or module in ("accel_calibration", "msg_tools"):
        return None
    where = f"{path}: cannot be read here: " if path is not None else ""
    install = PIP_NAMES.get(module, module)
    return BagError(f"{where}the Python module '{module}' is not installed: pip install '{install}' "
                    "(in a ROS 2 workspace: pip install -r requirements-ros.txt; README)")


def open_reader(path: str | os.PathLike[str]) -> Any:  # rosbags ships no types: its readers are Any here
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    refuse_special_files(path)
    if path.is_dir():
        metadata_topics(path)  # a damaged metadata.yaml in one line (rosbags: "TypeError: can only concatenate")
    refuse_large_definitions(path, recorded_definitions(path))  # rosbags parses every one on open
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as error:  # rosbags raises its own types per storage; one line for any of them
        first_line = str(error).splitlines()[0] if str(error) else ""
        raise BagError(f"{path}: not a readable rosbag2 ({type(error).__name__}: {first_line})") from None
    return reader


def storage_of(path: str | os.PathLike[str]) -> str:
    if Path(path).is_file():  # a single storage file given directly: its magic bytes say which
        with open(path, "rb") as stream:
            return "mcap" if stream.read(5) == b"\x89MCAP" else "sqlite3"
    return "mcap" if any(Path(path).glob("*.mcap")) else "sqlite3"


@dataclass(frozen=True)
class TopicInfo:
    """What metadata.yaml says of a topic (enough to choose and read it without opening the bag)."""

    topic: str
    msgtype: str
    msgcount: int
    digest: str = ""  # type_description_hash (RIHS01) of the recorded definition, where written


def read_head(path: Path, read: Callable[[BinaryIO], bytes], error: type[BagError], expected: str) -> bytes:
    """The first bytes of a recording file, as `read` takes them from the open file; a missing file, a
    directory or an unreadable file is one `error` line (`expected`: what the path should have been)."""
    try:
        with open(path, "rb") as stream:
            return read(stream)
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory, expected {expected}") from None
    except OSError as failure:
        raise error(f"{path}: cannot read ({failure.strerror})") from None


def refuse_large_definitions(path: str | os.PathLike[str], recorded: dict[str, tuple[str, str, str]] | None) -> None:
    """Refuse, before any parser sees it, a recorded message definition beyond MAX_DEFINITION_BYTES."""
    for topic, (msgtype, _encoding, text) in (recorded or {}).items():
        if len(text) > MAX_DEFINITION_BYTES:
            raise BagError(f"{path}: topic {topic}: its recorded definition of {msgtype} takes {len(text) >> 10} KiB, "
                           f"beyond the {MAX_DEFINITION_BYTES >> 10} KiB any ROS message needs: not read")


_ROSBAG2_SQLITE_OBJECTS = ("table", "index")  # what rosbag2's sqlite3 storage creates


def _refuse_foreign_sqlite_objects(path: Path, file: Path) -> None:
    """A .db3 is read only when `messages` and `topics` are tables and nothing in it is a view or a
    trigger (rosbag2 makes neither): a view named messages may be recursive (a query that never ends) or
    expand a 1 MB file to gigabytes."""
    import sqlite3
    from urllib.parse import quote

    try:
        with open(file, "rb") as stream:
            if stream.read(16) != b"SQLite format 3\x00":
                return  # not SQLite: its reader says what it is
        connection = sqlite3.connect(f"file:{quote(str(file))}?mode=ro", uri=True)
        try:
            objects = connection.execute("SELECT type, name FROM sqlite_master").fetchall()
        finally:
            connection.close()
    except (OSError, sqlite3.Error):
        return  # damaged or unreadable: the readers say how
    kinds = {str(name): str(kind) for kind, name in objects}
    foreign = sorted(f"{kind} {name}" for kind, name in objects if kind not in _ROSBAG2_SQLITE_OBJECTS)
    if foreign:
        raise BagError(f"{path}: {file.name} holds {', '.join(foreign)[:80]}, which rosbag2 never writes: "
                       "not a rosbag2 sqlite3 storage file")
    for table in ("messages", "topics"):
        if kinds.get(table) not in (None, "table"):
            raise BagError(f"{path}: {file.name}: {table} is not a table: not a rosbag2 sqlite3 storage file")


def refuse_special_files(path: str | os.PathLike[str]) -> None:
    """A bag's files must be regular files: a FIFO named *.db3 or metadata.yaml would block the reader
    for ever, a device would never end."""
    import os
    import stat

    path = Path(path)
    try:
        candidates = ([path / "metadata.yaml", *path.glob("*.mcap"), *path.glob("*.db3")] if path.is_dir()
                      else [path])
        for candidate in candidates:
            try:
                mode = os.stat(candidate).st_mode
            except FileNotFoundError:
                continue
            if not stat.S_ISREG(mode):
                raise BagError(f"{path}: {candidate.name} is not a regular file (a FIFO, device or directory): "
                               "not a recording")
            if candidate.name != "metadata.yaml":
                _refuse_foreign_sqlite_objects(path, candidate)
    except OSError as error:
        raise BagError(f"{path}: cannot read ({error.strerror or error})") from None


def metadata_topics(path: str | os.PathLike[str]) -> list[TopicInfo] | None:
    """Topics from the bag's metadata.yaml, or None when it is missing or unexpected (rosbags then
    reads the bag, or says what is wrong). Unsafe YAML (alias bombs, deep nesting, a FIFO, a huge file)
    is refused at once, in one line."""
    import os

    from ..io.calibration_file import read_regular_file, safe_yaml_load

    metadata = Path(path) / "metadata.yaml"
    if not os.path.lexists(metadata):
        return None
    raw = read_regular_file(metadata, MAX_METADATA_BYTES, "rosbag2 metadata.yaml", error=BagError)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise BagError(f"{metadata}: not a text file: not a rosbag2 metadata.yaml") from None
    document = safe_yaml_load(text, str(metadata), error=BagError)
    try:
        info = document["rosbag2_bagfile_information"]
        if info.get("compression_format"):  # whole-file compression: leave it to rosbags
            return None
        for entry in info.get("topics_with_message_count") or ():  # rosbags would fail on it with a TypeError
            count = entry.get("message_count") if isinstance(entry, dict) else None
            if count is not None and (isinstance(count, bool) or not isinstance(count, int) or count < 0):
                name = (entry.get("topic_metadata") or {}).get("name", "?")
                raise BagError(f"{metadata}: topic {str(name)[:80]}: message_count {str(count)[:40]!r} is not a "
                               "count of messages: a damaged metadata.yaml")
        return [TopicInfo(str(t["topic_metadata"]["name"]), str(t["topic_metadata"]["type"]),
                          int(t["message_count"]), str(t["topic_metadata"].get("type_description_hash") or ""))
                for t in info["topics_with_message_count"]]
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError):
        return None


_STANDARD_HASHES: dict[str, str] = {}
# ROS 2 Jazzy's Imu and Temperature: their RIHS01 and the sha256 of the ros2msg text rosbags writes for them,
# written out so that reading a bag does not import rosbags' Jazzy store (~0.2 s: it builds every message
# type of five distributions); test_flight_state checks them against rosbags.
JAZZY_DEFINITIONS = {
    IMU: ("RIHS01_7d9a00ff131080897a5ec7e26e315954b8eae3353c3f995c55faf71574000b5b",
          "f2f4c5b5c6c19cba83d23e3101a750aa1641112ba9839b0d7b2fcaea46f0961c"),
    TEMPERATURE: ("RIHS01_72514a14126ab9f8a9abec974c78e5610a367b59db5da355ff1fb982d5bad4b8",
                  "55d59d9879f124bc658dd9d0788320581c38391776907bd32493b2283f4899bd"),
}


def jazzy_deserialize(raw: bytes, msgtype: str) -> Any:
    """rosbags' ROS 2 Jazzy CDR deserializer, its store imported on first use (the fixed layout decodes
    standard messages without it)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(raw, msgtype)


def standard_hash(msgtype: str) -> str:
    """RIHS01 of the ROS 2 Jazzy definition of `msgtype` (what the fixed offsets assume)."""
    if msgtype in JAZZY_DEFINITIONS:
        return JAZZY_DEFINITIONS[msgtype][0]
    if msgtype not in _STANDARD_HASHES:
        from rosbags.typesys import Stores, get_typestore

        _STANDARD_HASHES[msgtype] = get_typestore(Stores.ROS2_JAZZY).hash_rihs01(msgtype)
    return _STANDARD_HASHES[msgtype]


_DEFINITION_HASHES: dict[tuple[str, str, str], str | None] = {}


def definition_hash(msgtype: str, encoding: str, text: str) -> str | None:
    """RIHS01 of a recorded definition (ros2msg or ros2idl text), or None when it cannot be parsed.
    The text rosbags itself writes is recognised without parsing (the parser costs ~0.1 s to build)."""
    from rosbags.typesys import Stores, get_typestore

    key = (msgtype, encoding, text)
    if key not in _DEFINITION_HASHES and encoding == "ros2msg" and msgtype in JAZZY_DEFINITIONS:
        import hashlib

        if hashlib.sha256(text.encode()).hexdigest() == JAZZY_DEFINITIONS[msgtype][1]:
            _DEFINITION_HASHES[key] = JAZZY_DEFINITIONS[msgtype][0]
    if key not in _DEFINITION_HASHES:
        standard = get_typestore(Stores.ROS2_JAZZY)
        try:
            same_text = encoding == "ros2msg" and text == standard.generate_msgdef(msgtype, ros_version=2)[0]
        except Exception:  # noqa: BLE001 - a type the standard store does not know
            same_text = False
        _DEFINITION_HASHES[key] = standard_hash(msgtype) if same_text else _parsed_hash(msgtype, encoding, text)
    return _DEFINITION_HASHES[key]


def _parsed_hash(msgtype: str, encoding: str, text: str) -> str | None:
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    try:
        if encoding == "ros2msg":
            types = get_types_from_msg(text, msgtype)
        elif encoding == "ros2idl":
            types = {}
            separator = "=" * 80 + "\n"
            parts = text.split(separator)[1:] if text.startswith(separator + "IDL: ") else [text]
            for part in parts:
                types.update(get_types_from_idl(part.split("\n", 1)[1] if part.startswith("IDL: ") else part))
        else:
            return None
        store = get_typestore(Stores.EMPTY)
        store.register(types)
        return store.hash_rihs01(msgtype)
    except Exception:  # noqa: BLE001 - a damaged definition is just "not the standard one"
        return None


def recorded_definitions(path: str | os.PathLike[str]) -> dict[str, tuple[str, str, str]] | None:
    """{topic: (message type, definition encoding, definition text)} as the storage files record them
    (not as metadata.yaml says); encoding "" where the storage holds no definition. None when the
    storage cannot be read this way (rosbags then reads it, or says what is wrong)."""
    import sqlite3

    from .mcap_scan import recorded_types

    path = Path(path)
    found: dict[str, tuple[str, str, str]] = {}
    if storage_of(path) == "mcap":
        for file in sorted(path.glob("*.mcap")) if path.is_dir() else [path]:
            types = recorded_types(file)
            if types is None:
                return None
            found.update(types)
        return found
    try:
        for file in [path] if path.is_file() else sorted(path.glob("*.db3")):
            connection = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
            try:
                tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type='table'")}
                definitions = {}
                if "message_definitions" in tables:
                    definitions = {name: (encoding, text) for name, encoding, text in connection.execute(
                        "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions")}
                for name, msgtype in connection.execute("SELECT name, type FROM topics"):
                    encoding, text = definitions.get(msgtype, ("", ""))
                    found[str(name)] = (str(msgtype), str(encoding), str(text))
            finally:
                connection.close()
    except sqlite3.Error:
        return None
    return found


def check_recorded_types(path: str | os.PathLike[str], topics: Iterable[TopicInfo | None],
                         recorded: dict[str, tuple[str, str, str]] | None) -> None:
    """Refuse a bag whose metadata.yaml (or reader) gives a topic another type than its storage records:
    reading it would decode one message type as another."""
    if not recorded:
        return
    for topic in topics:
        if topic is None:
            continue
        stored = recorded.get(topic.topic)
        if stored is not None and stored[0] != topic.msgtype:
            raise BagError(f"{path}: metadata.yaml says {topic.topic} is {topic.msgtype}, but the recording holds "
                           f"{stored[0]} messages on it: the metadata does not belong to this recording")


def is_standard_definition(topic: TopicInfo, recorded: dict[str, tuple[str, str, str]] | None) -> bool:
    """True when every record of `topic`'s definition (the metadata's hash, the storage's definition)
    is the ROS 2 Jazzy one, or absent (older bags: the standard is what they were recorded with)."""
    standard = standard_hash(topic.msgtype)
    if topic.digest and topic.digest != standard:
        return False
    stored = (recorded or {}).get(topic.topic)
    if stored is not None and len(stored[2]) > MAX_DEFINITION_BYTES:
        refuse_large_definitions("the recording", {topic.topic: stored})
    if stored is not None and stored[1]:
        return definition_hash(topic.msgtype, stored[1], stored[2]) == standard
    return True


def declares_other_definition(topics: Iterable[TopicInfo]) -> bool:
    """Whether the metadata declares another definition (type hash) than ROS 2 Jazzy's for any of `topics`."""
    return any(topic.digest and topic.digest != standard_hash(topic.msgtype) for topic in topics)


class TopicLike(Protocol):
    """A TopicInfo or a rosbags connection: what choose_topic looks at."""

    @property
    def topic(self) -> str: ...

    @property
    def msgtype(self) -> str: ...


TopicT = TypeVar("TopicT", bound=TopicLike)


def choose_topic(connections: Sequence[TopicT], msgtype: str, wanted: str | None, label: str,
                 path: str | os.PathLike[str]) -> TopicT | None:
    """The connection (or TopicInfo) of `msgtype` to use; None when there is none and none was asked for."""
    found = [c for c in connections if c.msgtype == msgtype]
    if wanted is not None:
        chosen = [c for c in found if c.topic == wanted]
        if not chosen:
            have = ", ".join(sorted({f"{c.topic} ({c.msgtype})" for c in connections})) or "no topics"
            raise BagError(f"{path}: no {msgtype} topic {wanted}; the bag has {have}")
        return chosen[0]
    if len(found) > 1:
        raise BagError(f"{path}: several {msgtype} topics ({', '.join(c.topic for c in found)}): "
                       f"choose one with --{label}-topic")
    return found[0] if found else None


def reader_is_standard(reader: Any) -> bool:
    """The reader's typestore (built from the bag's recorded definitions where it has them, checked
    against their hashes) holds the standard Imu: only then do the fixed offsets apply."""
    try:
        return bool(reader.typestore.hash_rihs01(IMU) == standard_hash(IMU))
    except Exception:  # noqa: BLE001 - no Imu type at all in a bag's definitions: not the standard one
        return False


def scan_sqlite(path: str | os.PathLike[str], topics: Sequence[str], progress: ProgressBar | None = None
                ) -> dict[str, PackedMessages] | None:
    """{topic: PackedMessages} straight from rosbag2's sqlite3 tables (one SELECT of the data column
    per topic and file, in the order rosbag2 readers give, joined into one buffer), or None when the
    layout or the values are not the expected ones (the caller falls back to rosbags)."""
    import sqlite3

    from .mcap_scan import PackedMessages

    payloads: dict[str, list[bytes]] = {topic: [] for topic in topics}
    try:
        for file in [Path(path)] if Path(path).is_file() else sorted(Path(path).glob("*.db3")):
            connection = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
            try:
                ids = dict(connection.execute("SELECT id, name FROM topics").fetchall())
                for topic_id, name in ids.items():
                    if name in payloads:
                        rows = connection.execute("SELECT data FROM messages WHERE topic_id = ? ORDER BY timestamp, id",
                                                  (topic_id,)).fetchall()
                        payloads[name].extend([data for (data,) in rows])
                        if progress is not None:
                            progress.update(len(rows))
            finally:
                connection.close()
        return {topic: PackedMessages.from_payloads(payloads[topic]) for topic in topics}
    except (sqlite3.Error, TypeError, ValueError):  # a data value that is not a blob: damage, rosbags says how
        return None


def stream_sqlite(path: str | os.PathLike[str], topics: Sequence[str], progress: ProgressBar | None = None,
                  group_messages: int = 1 << 16) -> Iterator[dict[str, PackedMessages]]:
    """The wanted topics' messages from rosbag2's sqlite3 tables ({topic: PackedMessages} per group),
    in the order rosbag2 readers give (timestamp, id): the first topic (the IMU) fetched a group of rows
    at a time, memory bounded by a group; the others (a temperature topic, ~100 times fewer messages)
    whole, with the first group. Raises NotStreamable where the tables are not as expected (the whole
    read, then rosbags, says what is wrong)."""
    import sqlite3

    from .mcap_scan import NotStreamable, PackedMessages

    select = "SELECT data FROM messages WHERE topic_id = ? ORDER BY timestamp, id"
    try:
        for file in [Path(path)] if Path(path).is_file() else sorted(Path(path).glob("*.db3")):
            connection = sqlite3.connect(f"file:{file}?mode=ro", uri=True)
            try:
                ids = {name: topic_id for topic_id, name in connection.execute("SELECT id, name FROM topics")}
                # In the table's own order: a scan, not ~150k lookups through the timestamp index (readings
                # are taken in stamp order by the temperature filter whatever order they come in).
                others = {topic: [data for (data,) in connection.execute(
                    "SELECT data FROM messages WHERE topic_id = ? ORDER BY id", (ids[topic],)).fetchall()]
                    for topic in topics[1:] if topic in ids}
                if progress is not None:
                    progress.update(sum(map(len, others.values())))
                cursor = connection.execute(select, (ids[topics[0]],)) if topics[0] in ids else None
                while True:
                    rows = cursor.fetchmany(group_messages) if cursor is not None else []
                    if not rows and not others:
                        break
                    group = {topic: PackedMessages.from_payloads(others.get(topic, [])) for topic in topics[1:]}
                    group[topics[0]] = PackedMessages.from_payloads([data for (data,) in rows])
                    others = {}
                    if progress is not None:
                        progress.update(len(rows))
                    yield group
            finally:
                connection.close()
    except (sqlite3.Error, TypeError, ValueError) as error:  # a data value that is not a blob: damage
        raise NotStreamable(str(error)) from None
