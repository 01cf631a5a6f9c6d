"""The calibration history: one row per recording in a SQL database (SQLAlchemy 2 Core), and the rule
that says when a sensor's calibration moved more than its uncertainty explains.

SQLite by default (one file, no server), any SQLAlchemy URL for a shared database (PostgreSQL through
psycopg 3; both tested on real databases). A row is keyed by the recording's content identity
(`recording_identity`), so writing the same recording again updates its row instead of adding one,
wherever the recording was moved or copied to. Writers may run in many processes at once: every write is
one transaction, an upsert (INSERT .. ON CONFLICT DO UPDATE) of its rows in key order. SQLite runs in WAL
mode with a busy timeout, so concurrent writers wait for each other instead of failing or corrupting the
file; PostgreSQL locks rows, so key order keeps two writers from deadlocking, and the schema is created
under an advisory lock (its CREATE .. IF NOT EXISTS alone races). Every float64 and int64 comes back as
written from either.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
import os
import re
import stat
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import unquote

from ..core.change_rule import ChangeRule
from ..core.errors import AccelCalibrationError
from ..core.text import printable_text
from ..core.units import AXES, MG

if TYPE_CHECKING:
    from .flight_history import EvidenceRecord

SCHEMA_VERSION = 1
SQLITE_BUSY_TIMEOUT_S = 60.0  # a writer waits this long for another one before giving up
_SCHEMA_LOCK = 0x616363656C5F6869  # PostgreSQL advisory lock key held while creating the schema ("accel_hi")
_IDENTITY_CHUNK = 1 << 20  # bytes read at a time for the identity digest
STATUSES = ("calibrated", "refused", "failed")


class HistoryError(AccelCalibrationError):
    """io: the history database cannot be opened, read or written; one line naming it."""


@dataclass(frozen=True)
class HistoryRecord:
    """What the history keeps of one recording. SI units (bias m/s^2) unless the name says otherwise;
    times are UTC nanoseconds of the recording's own clock (its first IMU header stamp)."""

    recording_id: str  # content identity (recording_identity), the row's unique key
    path: str  # where it was read from, resolved
    size_bytes: int
    vehicle: str
    vehicle_source: str  # "rule" (--vehicle), "metadata" (recorded in the recording) or "folder"
    sensor: str  # the IMU's frame_id, else its topic
    status: str  # calibrated | refused | failed
    reason: str | None = None  # why refused or failed, one line
    imu_topic: str | None = None
    frame_id: str | None = None
    start_ns: int | None = None
    duration_s: float | None = None
    messages: int | None = None
    model: str | None = None
    gravity: float | None = None
    bias: tuple[float, float, float] | None = None
    bias_sigma: tuple[float, float, float] | None = None
    matrix: tuple[float, ...] | None = None  # M row by row (9)
    matrix_sigma: tuple[float, ...] | None = None
    residual_rms_mg: float | None = None
    residual_max_mg: float | None = None
    condition_number: float | None = None
    poses: int | None = None
    outliers: int | None = None  # poses the fit set aside, where the fit reports them
    temperature_min_degc: float | None = None
    temperature_max_degc: float | None = None
    reference_temperature_degc: float | None = None
    temperature_model: str | None = None
    package_version: str | None = None
    written_at: str | None = None  # UTC, ISO 8601; set when written

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise HistoryError(f"status must be one of {', '.join(STATUSES)}, got {self.status!r}")

    @property
    def scale(self) -> tuple[float, float, float] | None:
        """Diagonal of M: the correction gain per axis."""
        return None if self.matrix is None else (self.matrix[0], self.matrix[4], self.matrix[8])

    @property
    def scale_sigma(self) -> tuple[float, float, float] | None:
        m = self.matrix_sigma
        return None if m is None else (m[0], m[4], m[8])

    @property
    def start(self) -> _dt.datetime | None:
        if self.start_ns is None:
            return None
        return _dt.datetime.fromtimestamp(self.start_ns / 1e9, tz=_dt.UTC)


def _regular_file_bytes(file: Path, digest: Any) -> int:
    """Feed the whole content of a regular file to `digest` (streamed, 1 MiB at a time); returns its size.
    A FIFO, device or socket is refused from its stat, before it is opened (opening a FIFO blocks)."""
    info = os.stat(file)
    if not stat.S_ISREG(info.st_mode):
        raise HistoryError(f"{printable_text(str(file))}: not a regular file (a FIFO, device or socket?), "
                           "not a recording")
    fd = os.open(file, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as stream:
        if not stat.S_ISREG(os.fstat(stream.fileno()).st_mode):  # replaced between the stat and the open
            raise HistoryError(f"{printable_text(str(file))}: not a regular file: not a recording")
        size = 0
        while chunk := stream.read(_IDENTITY_CHUNK):
            digest.update(chunk)
            size += len(chunk)
    return size


def recording_identity(path: str | Path) -> tuple[str, int]:
    """(content identity, total size in bytes) of a recording: a file, or a directory (rosbag2) whose
    regular files all count. The identity is a BLAKE2b digest of each file's name (relative to the
    recording), size and whole content, streamed, so two recordings share a row exactly when they hold
    the same bytes, wherever they lie. Raises HistoryError naming the path when unreadable."""
    path = Path(path)
    try:
        files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
        digest = hashlib.blake2b(digest_size=20)
        total = 0
        for file in files:
            name = str(file.relative_to(path)) if file != path else file.suffix
            part = hashlib.blake2b(digest_size=32)
            size = _regular_file_bytes(file, part)
            total += size
            digest.update(name.encode("utf-8", "surrogateescape") + f"\0{size}\0".encode() + part.digest())
    except OSError as error:
        raise HistoryError(f"{printable_text(str(path))}: cannot read the recording "
                           f"({error.strerror or error})") from None
    return digest.hexdigest(), total


def masked_url(target: str) -> str:
    """A database URL or path as it may be printed: every credential in it (user:PASSWORD@, and
    password=, sslpassword=, ... in the query string) replaced by ***."""
    if "://" not in target:
        return target
    scheme, rest = target.split("://", 1)
    location, mark, query = rest.partition("?")
    if "@" in location.split("/", 1)[0]:
        user_info, at, after = location.partition("@") if location.count("@") == 1 else location.rpartition("@")
        if ":" in user_info:
            location = user_info.split(":", 1)[0] + ":***" + at + after
    if mark:
        parts = re.split(r"([&;])", query)
        for i, part in enumerate(parts):
            key, equals, _value = part.partition("=")
            if equals and unquote(key).strip().lower() in SECRET_KEYS:
                parts[i] = f"{key}=***"
        query = "".join(parts)
    return f"{scheme}://{location}{mark}{query}"


SECRET_KEYS = frozenset({"password", "passwd", "pass", "pwd", "sslpassword", "secret", "token", "access_token",
                         "api_key", "apikey", "auth_token"})


# --- the database -----------------------------------------------------------------------------------

_TEXT_LIMITS = {"vehicle": 200, "sensor": 200, "vehicle_source": 16, "status": 16, "model": 32,
                "temperature_model": 32, "package_version": 64, "written_at": 40}  # String(n) columns


def _tables() -> tuple[Any, Any, Any, Any]:
    from sqlalchemy import JSON, BigInteger, Column, Float, Integer, MetaData, String, Table, Text

    short, text, real, whole = String(200), Text, Float, Integer
    kinds: dict[str, Any] = {"recording_id": String(64), "path": text, "size_bytes": BigInteger, "vehicle": short,
             "vehicle_source": String(16), "sensor": short, "status": String(16), "reason": text,
             "imu_topic": text, "frame_id": text, "start_ns": BigInteger, "duration_s": real,
             "messages": BigInteger,  # 2^31 messages are 25 days at 1 kHz; PostgreSQL's INTEGER is 32 bits
             "model": String(32), "gravity": real, "bias": JSON, "bias_sigma": JSON, "matrix": JSON,
             "matrix_sigma": JSON, "residual_rms_mg": real, "residual_max_mg": real, "condition_number": real,
             "poses": whole, "outliers": whole, "temperature_min_degc": real, "temperature_max_degc": real,
             "reference_temperature_degc": real, "temperature_model": String(32), "package_version": String(64),
             "written_at": String(40)}
    required = {"path", "size_bytes", "vehicle", "vehicle_source", "sensor", "status"}
    metadata = MetaData()
    info = Table("history_info", metadata,
                 Column("key", String(64), primary_key=True),
                 Column("value", Text, nullable=False))
    columns = [Column(f.name, kinds[f.name], primary_key=f.name == "recording_id",
                      nullable=f.name != "recording_id" and f.name not in required)
               for f in fields(HistoryRecord)]
    calibrations = Table("calibrations", metadata, *columns)
    from .flight_history import evidence_table

    return metadata, info, calibrations, evidence_table(metadata)


def _url(target: str) -> Any:
    """A SQLAlchemy URL from a URL or a plain file path (SQLite)."""
    from sqlalchemy.engine import make_url
    from sqlalchemy.exc import ArgumentError

    if "://" in target:
        try:
            url = make_url(target)
            _ = url.port  # a port that is not a number is refused here, not at connect time
            return url
        except (ArgumentError, ValueError, TypeError):
            raise HistoryError(f"{masked_url(target)}: not a database URL (e.g. postgresql://user@host:5432/db) "
                               "or a file path") from None
    path = Path(target).expanduser().resolve()
    if path.is_dir():
        raise HistoryError(f"{target}: is a directory; give a database file, "
                           f"e.g. {Path(target) / 'calibrations.sqlite'}")
    if not path.parent.is_dir():
        raise HistoryError(f"{target}: directory {path.parent} does not exist")
    return make_url(f"sqlite:///{path}")


def _sqlite_uri(path: str, *options: str) -> str:
    from urllib.parse import quote

    return f"file:{quote(path)}?" + "&".join(("mode=ro", *options))


def _refuse_foreign_sqlite(name: str, path: str | None, read_only: bool) -> None:
    """Look at an existing SQLite file read-only, before any statement that would change it (WAL, tables):
    one that is not a SQLite database, or holds tables but not ours (another application's), is refused
    untouched. A read-only command also refuses a file that is missing."""
    import sqlite3

    if not path or path == ":memory:":
        return
    if not os.path.exists(path) or os.path.getsize(path) == 0:
        if read_only:
            raise HistoryError(f"{name}: no such history (write one with 'accel-calib fleet')")
        return
    try:
        connection = sqlite3.connect(_sqlite_uri(path), uri=True, timeout=SQLITE_BUSY_TIMEOUT_S)
        try:
            tables = {row[0] for row in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            connection.close()
    except sqlite3.Error as error:
        if "unable to open" in str(error) and read_only:
            return  # a WAL file on read-only media: _read_only_sqlite opens it as immutable
        raise HistoryError(f"{name}: cannot open the history ({type(error).__name__}: {error})") from None
    ours = {"history_info", "calibrations"}
    if tables and "history_info" not in tables:
        raise HistoryError(f"{name}: not a calibration history (it holds other tables: "
                           f"{', '.join(sorted(tables - ours))[:80]}); give another file, left untouched")


def _read_only_sqlite(path: str) -> Any:
    """An engine that can only read the file (mode=ro): no journal switch, no tables made. A WAL history on
    read-only media (whose -shm cannot be made) is read as immutable: nobody can be writing it there."""
    import sqlite3

    from sqlalchemy import create_engine

    def connect() -> sqlite3.Connection:
        try:
            connection = sqlite3.connect(_sqlite_uri(path), uri=True, timeout=SQLITE_BUSY_TIMEOUT_S)
            connection.execute("SELECT count(*) FROM sqlite_master").fetchone()
            return connection
        except sqlite3.OperationalError:
            return sqlite3.connect(_sqlite_uri(path, "immutable=1"), uri=True)

    return create_engine("sqlite://", creator=connect)


def _one_line(error: BaseException) -> str:
    original = getattr(error, "orig", None) or error
    text = str(original).strip().splitlines()
    return f"{type(original).__name__}: {text[0] if text else ''}"


class History:
    """An open history database. `with open_history(...) as history:`; every method is one transaction."""

    def __init__(self, target: str | Path, read_only: bool = False):
        from sqlalchemy import create_engine, event
        from sqlalchemy.exc import SQLAlchemyError

        self.target = str(target)
        self.read_only = read_only
        # As the user wrote it, every credential hidden (user:***@, ?password=***), a socket path unquoted.
        self.name = unquote(masked_url(self.target)) if "://" in self.target else self.target
        self.unreadable: list[str] = []  # rows records() left out: "recording_id: why", one each
        self.unreadable_evidence: list[str] = []  # the same of evidence()
        url = _url(self.target)
        self._metadata, self._info, self._table, self._evidence = _tables()
        try:
            if url.get_backend_name() == "sqlite":
                _refuse_foreign_sqlite(self.name, url.database, read_only)
            if url.get_backend_name() == "sqlite" and read_only:
                self.engine = _read_only_sqlite(url.database)
            elif url.get_backend_name() == "sqlite":
                # timeout: the driver's busy timeout, which also covers switching the journal to WAL.
                self.engine = create_engine(url, connect_args={"timeout": SQLITE_BUSY_TIMEOUT_S})

                @event.listens_for(self.engine, "connect")
                def _sqlite_pragmas(connection: Any, _record: Any) -> None:
                    connection.isolation_level = None  # transactions begun below, not by the driver
                    cursor = connection.cursor()
                    cursor.execute("PRAGMA journal_mode=WAL")  # readers never block the writer
                    cursor.execute("PRAGMA synchronous=NORMAL")  # WAL stays consistent on power loss
                    cursor.close()

                @event.listens_for(self.engine, "begin")
                def _write_lock_first(connection: Any) -> None:
                    # A deferred transaction that reads and then writes cannot wait for another writer
                    # (SQLite answers "database is locked" at once); taking the write lock at BEGIN
                    # makes concurrent writers queue on the busy timeout instead.
                    connection.exec_driver_sql("BEGIN IMMEDIATE")
            elif url.get_backend_name() == "postgresql":
                # READ COMMITTED whatever the server's default: under it an upsert waits for a concurrent one
                # on the same row and then applies; under a SERIALIZABLE default it would fail instead.
                options = {"options": "-c default_transaction_read_only=on"} if read_only else {}
                self.engine = create_engine(url, pool_pre_ping=True, isolation_level="READ COMMITTED",
                                            connect_args=options)
            else:
                self.engine = create_engine(url, pool_pre_ping=True)
            if read_only:
                self._check_schema()
            else:
                self._create_schema()
        except SQLAlchemyError as error:
            raise HistoryError(f"{self.name}: cannot open the history ({_one_line(error)})") from None
        except ImportError as error:  # a URL whose driver is not installed (psycopg, ...)
            raise HistoryError(f"{self.name}: database driver not installed ({error})") from None
        except (ValueError, TypeError) as error:  # a URL part the driver cannot take (a port, an option)
            raise HistoryError(f"{self.name}: cannot open the history ({type(error).__name__}: "
                               f"{str(error)[:120]})") from None

    def _check_schema(self) -> None:
        """Read-only: the history's tables are there and of a schema this version reads; nothing is created."""
        from sqlalchemy import inspect, select

        with self.engine.connect() as connection:
            tables = set(inspect(connection).get_table_names())
            if not {"history_info", "calibrations"} <= tables:
                raise HistoryError(f"{self.name}: not a calibration history (no history_info and calibrations "
                                   "tables; write one with 'accel-calib fleet')")
            stored = connection.execute(select(self._info.c.value).where(self._info.c.key == "schema_version")
                                        ).scalar_one_or_none()
        if stored is None or not str(stored).isdigit() or int(stored) > SCHEMA_VERSION:
            raise HistoryError(f"{self.name}: history schema {stored} is not one this accel_calibration reads "
                               f"({SCHEMA_VERSION}); upgrade the package")

    def _create_schema(self) -> None:
        from sqlalchemy import select, text
        from sqlalchemy.schema import CreateIndex, CreateTable, Index

        # IF NOT EXISTS: many processes may open a new file at once; checking first would race. On
        # PostgreSQL two concurrent CREATE .. IF NOT EXISTS still collide (unique violation in its catalog):
        # there a transaction-scoped advisory lock makes them take turns.
        with self.engine.begin() as connection:
            if connection.dialect.name == "postgresql":
                connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": _SCHEMA_LOCK})
            for table in (self._info, self._table, self._evidence):
                connection.execute(CreateTable(table, if_not_exists=True))
            self._add_missing_columns(connection, self._evidence)
            for columns in (("vehicle", "sensor", "start_ns"),):
                index = Index("ix_calibrations_" + "_".join(columns), *(self._table.c[c] for c in columns))
                connection.execute(CreateIndex(index, if_not_exists=True))
            stored = connection.execute(select(self._info.c.value).where(self._info.c.key == "schema_version")
                                        ).scalar_one_or_none()
            if stored is None:
                self._upsert(connection, self._info, [{"key": "schema_version", "value": str(SCHEMA_VERSION)}],
                             "key", update=False)
            elif not stored.isdigit() or int(stored) > SCHEMA_VERSION:
                raise HistoryError(f"{self.name}: history schema {stored} is newer than this accel_calibration "
                                   f"reads ({SCHEMA_VERSION}); upgrade the package")

    @staticmethod
    def _add_missing_columns(connection: Any, table: Any) -> None:
        """Columns a later version added to a table (all nullable): a history written before gains them, its
        rows reading NULL there. Under the schema lock above on PostgreSQL; SQLite's writers queue."""
        from sqlalchemy import inspect
        from sqlalchemy.schema import CreateColumn

        present = {c["name"] for c in inspect(connection).get_columns(table.name)}
        for column in table.columns:
            if column.name not in present:
                definition = CreateColumn(column).compile(dialect=connection.dialect)
                connection.exec_driver_sql(f"ALTER TABLE {table.name} ADD COLUMN {definition}")

    @staticmethod
    def _upsert(connection: Any, table: Any, rows: list[dict[str, Any]], key: str, update: bool = True) -> None:
        name = connection.dialect.name
        if name in ("sqlite", "postgresql"):
            statement: Any  # the two dialects' Insert classes share on_conflict_do_update/nothing, not a base
            if name == "sqlite":
                from sqlalchemy.dialects.sqlite import insert as sqlite_insert
                statement = sqlite_insert(table)
            else:
                from sqlalchemy.dialects.postgresql import insert as postgresql_insert
                statement = postgresql_insert(table)
            if update:
                statement = statement.on_conflict_do_update(
                    index_elements=[table.c[key]],
                    set_={c.name: statement.excluded[c.name] for c in table.columns if c.name != key})
            else:
                statement = statement.on_conflict_do_nothing(index_elements=[table.c[key]])
            connection.execute(statement, rows)
            return
        # Other databases: replace inside the same transaction (the caller's), which is atomic there too.
        keys = [row[key] for row in rows]
        if update:
            connection.execute(table.delete().where(table.c[key].in_(keys)))
            connection.execute(table.insert(), rows)
        else:
            have = {r[0] for r in connection.execute(table.select().with_only_columns(table.c[key])
                                                     .where(table.c[key].in_(keys)))}
            fresh = [row for row in rows if row[key] not in have]
            if fresh:
                connection.execute(table.insert(), fresh)

    def write(self, records: Iterable[HistoryRecord]) -> int:
        """Insert or update (by recording_id) in one transaction; returns rows written."""
        now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        rows = []
        for record in records:
            row = asdict(record)
            row["written_at"] = row["written_at"] or now
            for name in ("bias", "bias_sigma", "matrix", "matrix_sigma"):
                if row[name] is not None:
                    row[name] = [float(v) for v in row[name]]
            for name, value in row.items():  # NaN is not JSON and not portable SQL: store NULL
                if isinstance(value, float) and not math.isfinite(value):
                    row[name] = None
                elif isinstance(value, str):  # the same text on every backend: no NUL, within the column
                    row[name] = printable_text(value)[:_TEXT_LIMITS.get(name, len(value) + 1)]
            rows.append(row)
        return self._write_rows(self._table, rows, "the history")

    def _write_rows(self, table: Any, rows: list[dict[str, Any]], what: str) -> int:
        """Rows inserted or updated by recording_id, in one transaction."""
        from sqlalchemy.exc import SQLAlchemyError

        if not rows:
            return 0
        # Key order: where a database locks rows one by one (PostgreSQL), writers that lock in the same order
        # queue instead of deadlocking. Stable, so of one recording given twice the last one wins.
        rows.sort(key=lambda row: str(row["recording_id"]))
        try:
            with self.engine.begin() as connection:
                self._upsert(connection, table, rows, "recording_id")
        except SQLAlchemyError as error:
            raise HistoryError(f"{self.name}: cannot write {what} ({_one_line(error)})") from None
        return len(rows)

    def records(self, vehicle: str | None = None, sensor: str | None = None) -> list[HistoryRecord]:
        """Rows by vehicle and sensor, each in time order (rows without a start last), then by path;
        optionally of one vehicle and/or sensor. Sorted here, not by the database: a server's collation
        and its place for NULLs differ (PostgreSQL en_US: '/_c' < '/a' < '/B'); this is code point order."""
        from sqlalchemy import Text, select, type_coerce
        from sqlalchemy.exc import SQLAlchemyError

        table = self._table
        # JSON columns read as text and parsed here: one bad value leaves its row out, not the whole read.
        query = select(*[type_coerce(c, Text).label(c.name) if c.name in _VECTORS else c for c in table.columns])
        if vehicle is not None:
            query = query.where(table.c.vehicle == vehicle)
        if sensor is not None:
            query = query.where(table.c.sensor == sensor)
        try:
            with self.engine.connect() as connection:
                rows = connection.execute(query).mappings().all()
        except SQLAlchemyError as error:
            raise HistoryError(f"{self.name}: cannot read the history ({_one_line(error)})") from None
        out = []
        self.unreadable = []
        for row in rows:
            try:
                out.append(_record_from_row(dict(row)))
            except (HistoryError, ValueError, TypeError) as error:
                self.unreadable.append(f"{printable_text(str(row.get('recording_id')))[:40]}: {error}")
        out.sort(key=lambda r: (r.vehicle, r.sensor, r.start_ns is None, r.start_ns or 0, r.path, r.recording_id))
        return out

    def write_evidence(self, records: Iterable[EvidenceRecord]) -> int:
        """Flight evidence rows (io/flight_history.py), inserted or updated by key in one transaction."""
        from .flight_history import evidence_rows

        return self._write_rows(self._evidence, evidence_rows(records), "the flight evidence")

    def evidence(self, vehicle: str | None = None, sensor: str | None = None) -> list[EvidenceRecord]:
        """Flight evidence rows, optionally of one vehicle and/or sensor; none from a history written before
        the table was (read only: nothing created)."""
        from sqlalchemy import inspect, select
        from sqlalchemy.exc import SQLAlchemyError

        from .flight_history import evidence_from_row

        table = self._evidence
        try:
            with self.engine.connect() as connection:
                if not inspect(connection).has_table(table.name):
                    return []
                # A history written before later columns were added: what it has (read only: nothing added).
                present = {c["name"] for c in inspect(connection).get_columns(table.name)}
                query = select(*(c for c in table.columns if c.name in present))
                if vehicle is not None:
                    query = query.where(table.c.vehicle == vehicle)
                if sensor is not None:
                    query = query.where(table.c.sensor == sensor)
                rows = connection.execute(query).mappings().all()
        except SQLAlchemyError as error:
            raise HistoryError(f"{self.name}: cannot read the flight evidence ({_one_line(error)})") from None
        out = []
        self.unreadable_evidence = []
        for row in rows:
            try:
                out.append(evidence_from_row(dict(row)))
            except (ValueError, TypeError) as error:
                self.unreadable_evidence.append(f"{printable_text(str(row.get('recording_id')))[:40]}: {error}")
        return out

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> History:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


_VECTORS = {"bias": 3, "bias_sigma": 3, "matrix": 9, "matrix_sigma": 9}
_KINDS = {f.name: f.type for f in fields(HistoryRecord)}


def _record_from_row(values: dict[str, Any]) -> HistoryRecord:
    """A row as a HistoryRecord, each value checked against its field's type: a row another program
    wrote off the schema (text where a number belongs, a short matrix, bad JSON) raises one line."""
    for name, value in values.items():
        if value is None:
            continue
        if name in _VECTORS:
            vector = json.loads(value) if isinstance(value, str) else value
            if vector is None:  # SQLAlchemy's JSON stores None as JSON null
                values[name] = None
                continue
            if (not isinstance(vector, list) or len(vector) != _VECTORS[name]
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vector)):
                raise HistoryError(f"{name} is not {_VECTORS[name]} numbers")
            values[name] = tuple(float(v) for v in vector)
            continue
        kind = str(_KINDS[name])
        if "int" in kind and (isinstance(value, bool) or not isinstance(value, int)):
            raise HistoryError(f"{name} is not an integer: {str(value)[:30]!r}")
        if "float" in kind and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise HistoryError(f"{name} is not a number: {str(value)[:30]!r}")
        if "float" in kind:
            values[name] = float(value)
        if kind.startswith("str") and not isinstance(value, str):
            values[name] = str(value)
    for name in ("path", "vehicle", "vehicle_source", "sensor", "status"):
        if values.get(name) is None:
            raise HistoryError(f"{name} is missing")
    return HistoryRecord(**values)


def open_history(target: str | Path, read_only: bool = False) -> History:
    """A history database: a file path (SQLite, created when missing) or a SQLAlchemy URL. `read_only`:
    for commands that only read it (opened read-only, nothing created or switched)."""
    return History(target, read_only=read_only)


# --- when a calibration moved -------------------------------------------------------------------------

@dataclass(frozen=True)
class DriftRule(ChangeRule):
    """A change between consecutive calibrations of one sensor is flagged when it exceeds what their
    sigmas explain, |delta| > k_sigma * sqrt(s1^2 + s2^2), or a plausibility bound whatever the sigmas
    (core/change_rule.py, the rule `accel-calib check` applies too)."""

    error = HistoryError


@dataclass(frozen=True)
class DriftFlag:
    vehicle: str
    sensor: str
    quantity: str  # "bias" or "scale"
    axis: str
    change: float  # after - before: m/s^2 for bias, unitless for scale
    sigmas: float  # |change| / sqrt(s1^2 + s2^2); inf when both sigmas are zero or unknown
    by_sigma: bool
    by_bound: bool
    before: HistoryRecord
    after: HistoryRecord

    def message(self) -> str:
        """'vehicle uav07 imu0: bias z moved 18 mg (6.2 sigma) between 2026-11-02 and 2026-11-09'."""
        amount = (f"{abs(self.change) / MG:.3g} mg" if self.quantity == "bias"
                  else f"{abs(self.change) * 100:.3g} %")
        sigma = f"{self.sigmas:.1f} sigma" if math.isfinite(self.sigmas) else "no sigma"
        why = "" if self.by_sigma else ", beyond the plausibility bound"
        first, second = _when(self.before, self.after)
        return (f"vehicle {self.vehicle} {self.sensor}: {self.quantity} {self.axis} moved {amount} "
                f"({sigma}{why}) between {first} and {second}")


def _when(before: HistoryRecord, after: HistoryRecord) -> tuple[str, str]:
    a, b = before.start, after.start
    if a is None or b is None:
        return Path(before.path).name, Path(after.path).name
    form = "%Y-%m-%d" if a.date() != b.date() else "%Y-%m-%d %H:%M"
    if a.strftime(form) == b.strftime(form):
        form = "%Y-%m-%d %H:%M:%S"
    return a.strftime(form), b.strftime(form)


def sensor_series(records: Iterable[HistoryRecord]) -> dict[tuple[str, str], list[HistoryRecord]]:
    """Calibrated rows per (vehicle, sensor), each in time order (rows without a start last, by path)."""
    series: dict[tuple[str, str], list[HistoryRecord]] = {}
    for record in records:
        if record.status == "calibrated" and record.bias is not None and record.matrix is not None:
            series.setdefault((record.vehicle, record.sensor), []).append(record)
    for rows in series.values():
        rows.sort(key=lambda r: (r.start_ns is None, r.start_ns or 0, r.path))
    return dict(sorted(series.items()))


def _pairs(values: Sequence[float], sigmas: Sequence[float] | None) -> Iterator[tuple[float, float]]:
    yield from zip(values, sigmas if sigmas is not None else [math.nan] * len(values))


def drift_flags(records: Iterable[HistoryRecord], rule: DriftRule | None = None) -> list[DriftFlag]:
    """Every change between consecutive calibrations of a sensor that the rule flags (bias and scale,
    per axis). Refused and failed recordings are not compared."""
    rule = rule or DriftRule()
    flags = []
    for (vehicle, sensor), rows in sensor_series(records).items():
        for before, after in zip(rows, rows[1:]):
            quantities = (("bias", before.bias, before.bias_sigma, after.bias, after.bias_sigma,
                           rule.max_bias_change_mg * MG),
                          ("scale", before.scale, before.scale_sigma, after.scale, after.scale_sigma,
                           rule.max_scale_change))
            for quantity, v1, s1, v2, s2, bound in quantities:
                if v1 is None or v2 is None:  # sensor_series keeps rows with both; for the type checker
                    continue
                for axis, (a, sa), (b, sb) in zip(AXES, _pairs(v1, s1), _pairs(v2, s2)):
                    change = b - a
                    combined = math.hypot(sa, sb) if math.isfinite(sa) and math.isfinite(sb) else math.nan
                    judged = rule.judge(change, combined, bound)
                    if judged.flagged:
                        flags.append(DriftFlag(vehicle, sensor, quantity, axis, change, judged.sigmas,
                                               judged.by_sigma, judged.by_bound, before, after))
    return flags


VEHICLE_RULE_TIMEOUT_S = 1.0  # a --vehicle rule on one path; a sane one takes microseconds


def vehicle_from_rule(rule: str, path: str) -> str | None:
    """The vehicle a --vehicle rule (a regular expression, Python syntax) finds in a path: its `vehicle`
    group, else its first group, else the whole match; None when it does not match. Matched by the
    `regex` engine under a time limit: a rule that backtracks without end ('(a+)+$') is one HistoryError."""
    import regex

    try:
        pattern = regex.compile(rule, flags=regex.VERSION0)
    except (regex.error, TypeError, ValueError, OverflowError, RecursionError) as error:
        raise HistoryError(f"--vehicle {rule!r:.80}: not a regular expression ({error})") from None
    try:
        match = pattern.search(path, timeout=VEHICLE_RULE_TIMEOUT_S)
    except TimeoutError:
        raise HistoryError(f"--vehicle {rule!r:.80}: took longer than {VEHICLE_RULE_TIMEOUT_S:g} s on "
                           f"{printable_text(path)[-120:]} (a rule that backtracks without end?); "
                           "simplify it") from None
    if match is None:
        return None
    if "vehicle" in pattern.groupindex:
        found = match.group("vehicle")
    elif pattern.groups:
        found = match.group(1)
    else:
        found = match.group(0)
    return found or None

