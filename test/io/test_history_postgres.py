"""The calibration history on a real PostgreSQL server (a private one per test session, unix socket only,
see helpers/postgres_server.py): the same properties test_history.py shows on SQLite, and where the two differ
(integer widths, float round trips, row order under a server collation, concurrent schema creation,
lock order of concurrent writers, a server whose default isolation is serializable)."""
from __future__ import annotations

import datetime
import math
import os
import struct
import subprocess
import sys
from dataclasses import replace

import psycopg
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from sqlalchemy.engine import make_url

from accel_calibration.bag.replay import replay_bag
from accel_calibration.cli.dask_cluster import local_cluster
from accel_calibration.cli.main import main
from accel_calibration.core.units import MG
from accel_calibration.io.history import HistoryError, HistoryRecord, open_history

from helpers.fleet_sessions import WEEK_NS, assert_flags_the_stepped_sensor_only, two_vehicles
from helpers.history_records import START_NS, WRITERS, assert_round_trip, record

DAY_NS = 86_400 * 10**9


def _raw(postgres, url):
    """A plain psycopg connection to the database behind a URL (to look under the history's API)."""
    return psycopg.connect(postgres.conninfo(make_url(url).database), autocommit=True)


# --- the database --------------------------------------------------------------------------------------

def test_round_trip_and_rewriting_a_recording_updates_its_row(postgres, pg_url):
    rows = assert_round_trip(pg_url, residual_max_mg=math.inf)
    assert replace(rows[1], written_at=None) == record(2)
    written = datetime.datetime.fromisoformat(rows[1].written_at)
    assert written.utcoffset() is not None and written.utcoffset().total_seconds() == 0  # UTC, said so
    with _raw(postgres, pg_url) as raw:
        assert raw.execute("SELECT count(*) FROM calibrations").fetchone()[0] == 2
        # NaN and inf are no number a reader can use: NULL, as on SQLite.
        assert raw.execute("SELECT condition_number, residual_max_mg FROM calibrations ORDER BY recording_id"
                           ).fetchall() == [(None, None), (None, None)]
        types = dict(raw.execute("SELECT column_name, data_type FROM information_schema.columns "
                                 "WHERE table_name = 'calibrations'").fetchall())
    assert {types[c] for c in ("gravity", "residual_rms_mg", "duration_s")} == {"double precision"}
    assert {types[c] for c in ("start_ns", "size_bytes", "messages")} == {"bigint"}


# Every finite float64 (subnormals, extremes, -0.0) and every int64 where a count or a time goes.
FINITE = st.floats(allow_nan=False, allow_infinity=False)
TEXT = st.text(st.characters(exclude_categories=("Cs",), exclude_characters="\x00"), max_size=40)


@st.composite
def any_record(draw):
    def maybe(strategy):
        return draw(st.none() | strategy)

    return HistoryRecord(
        recording_id="prop", path=draw(TEXT), size_bytes=draw(st.integers(0, 2**63 - 1)), vehicle=draw(TEXT),
        vehicle_source="rule", sensor=draw(TEXT), status=draw(st.sampled_from(["calibrated", "refused", "failed"])),
        reason=maybe(TEXT), start_ns=maybe(st.integers(-2**63, 2**63 - 1)), duration_s=maybe(FINITE),
        messages=maybe(st.integers(0, 2**63 - 1)), gravity=maybe(FINITE), bias=maybe(st.tuples(*[FINITE] * 3)),
        bias_sigma=maybe(st.tuples(*[FINITE] * 3)), matrix=maybe(st.tuples(*[FINITE] * 9)),
        matrix_sigma=maybe(st.tuples(*[FINITE] * 9)), residual_rms_mg=maybe(FINITE),
        condition_number=maybe(FINITE), poses=maybe(st.integers(0, 2**31 - 1)),
        temperature_min_degc=maybe(FINITE), written_at="2026-11-22T21:00:00+00:00")


def _bits(values):
    """float64 bit patterns (so -0.0 != 0.0) of a tuple of numbers, a number, or None."""
    if values is None or isinstance(values, float):
        return None if values is None else struct.pack("<d", values)
    return [struct.pack("<d", v) for v in values]


@pytest.fixture(scope="module")
def both_backends(postgres, tmp_path_factory):
    targets = {"sqlite": str(tmp_path_factory.mktemp("roundtrip") / "h.sqlite"),
               "postgresql": postgres.create_database("roundtrip")}
    histories = {name: open_history(target) for name, target in targets.items()}
    yield histories
    for history in histories.values():
        history.close()


@pytest.mark.parametrize("backend", ["sqlite", "postgresql"])
@settings(max_examples=60, deadline=None)
@given(row=any_record())
@example(row=record(1, messages=3 * 10**9, recording_id="prop"))  # 35 days at 1 kHz: beyond 32 bits
def test_every_float64_and_int64_comes_back_exactly(both_backends, backend, row):
    """What is written is what is read, on both backends: every field, floats to the bit on PostgreSQL
    (SQLite may return -0.0 as 0.0, equal as a number). Rewriting the same recording each time."""
    history = both_backends[backend]
    history.write([row])
    (back,) = history.records()
    assert back == replace(row, written_at=back.written_at)  # == on floats: exact, -0.0 == 0.0
    if backend == "postgresql":
        for name in ("bias", "bias_sigma", "matrix", "matrix_sigma", "gravity", "duration_s", "residual_rms_mg",
                     "condition_number", "temperature_min_degc"):
            assert _bits(getattr(back, name)) == _bits(getattr(row, name)), name


def test_rows_come_back_in_the_same_order_from_every_backend(postgres, pg_url, tmp_path):
    """Time order, rows without a start last, then path by code point: the same whatever the server's
    collation (en-US here, which sorts '/_c' < '/a' < '/B') and wherever it puts NULLs."""
    rows = [replace(record(i), path=path, start_ns=start, recording_id=f"r{i}")
            for i, (path, start) in enumerate([("/b", None), ("/a", None), ("/B", START_NS), ("/_c", START_NS),
                                               ("/a", START_NS + DAY_NS), ("/A", START_NS)])]
    rows.append(replace(record(9, vehicle="UAV07"), recording_id="r9"))
    expected = ["r9", "r5", "r2", "r3", "r4", "r1", "r0"]
    for target in (pg_url, str(tmp_path / "h.sqlite")):
        with open_history(target) as history:
            history.write(rows[::-1])
            assert [r.recording_id for r in history.records()] == expected, target
            assert [r.recording_id for r in history.records(vehicle="uav07")] == expected[1:], target


def _writers(url, writers=4, rounds=25):
    # The driver imported once before the fork, not in each writer (seconds each on 2 cores).
    script = "import psycopg, sqlalchemy.dialects.postgresql.psycopg" + WRITERS
    return subprocess.Popen([sys.executable, "-c", script, url, str(writers), str(rounds)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"})


def test_concurrent_writers_in_several_processes_never_corrupt_it(postgres):
    """test_history's 4 writer processes (batches in shuffled order, overlapping keys), at once on two
    databases: one with the server's default isolation (read committed) and one whose default is
    serializable, as a DBA may set it. No writer fails (no deadlock, no serialization failure), every
    row is whole from one write, and PostgreSQL's own checker finds the table and its index sound."""
    urls = [postgres.create_database("writers_default"),
            postgres.create_database("writers_serializable", default_transaction_isolation="serializable")]
    runs = [_writers(url) for url in urls]
    outputs = [run.communicate(timeout=300) for run in runs]
    for url, run, (out, err) in zip(urls, runs, outputs):
        assert (run.returncode, out, err) == (0, "0 0 0 0\n", ""), url
        with open_history(url) as history:
            rows = history.records()
        assert sorted(r.recording_id for r in rows) == [f"rec{n:02d}" for n in range(20)]
        for row in rows:  # each row whole from one write: bias and sigma of the same writer and round
            writer, k, n = row.bias
            assert row.scale_sigma == (writer, k, n) and 1 <= writer <= 4
            assert row.recording_id == f"rec{int(n):02d}" and row.path == f"/fleet/v/flight{int(n)}"
        with _raw(postgres, url) as raw:
            raw.execute("CREATE EXTENSION IF NOT EXISTS amcheck")
            raw.execute("SELECT bt_index_check('calibrations_pkey', true)")  # every heap row in the index
            assert raw.execute("SELECT * FROM verify_heapam('calibrations')").fetchall() == []


# Several processes opening one new database at once (forked from one helper, as WRITERS): each creates
# the schema if it is missing, which PostgreSQL's CREATE .. IF NOT EXISTS alone does not make safe.
OPENERS = """
import multiprocessing, sys
import psycopg, sqlalchemy.dialects.postgresql.psycopg  # imported once here, not in each child (seconds)
from accel_calibration.io.history import open_history


def open_it(url, barrier):
    try:
        barrier.wait(timeout=60)
        open_history(url).close()
    except BaseException:
        barrier.abort()
        raise


if __name__ == "__main__":
    context = multiprocessing.get_context("fork")
    codes = []
    for url in sys.argv[1:]:
        barrier = context.Barrier(8)
        processes = [context.Process(target=open_it, args=(url, barrier)) for _ in range(8)]
        for process in processes:
            process.start()
        for process in processes:
            process.join(timeout=120)
        codes.append("".join(str(p.exitcode) for p in processes))
    print(" ".join(codes))
"""


def test_many_processes_creating_the_history_at_once(postgres):
    urls = [postgres.create_database(f"opened{i}") for i in range(4)]
    run = subprocess.run([sys.executable, "-c", OPENERS, *urls], capture_output=True, text=True, timeout=300,
                         check=False)
    assert (run.returncode, run.stdout, run.stderr) == (0, " ".join(["0" * 8] * 4) + "\n", "")
    for url in urls:
        with _raw(postgres, url) as raw:
            assert raw.execute("SELECT key, value FROM history_info").fetchall() == [("schema_version", "1")]


def test_bad_targets_are_one_line(postgres, pg_url, tmp_path, capsys):
    socketless = tmp_path / "nosocket"
    socketless.mkdir()
    missing_db = make_url(pg_url).set(database="absent").render_as_string(hide_password=False)
    for target in (f"postgresql+psycopg://postgres@/db?host={socketless}", missing_db):
        with pytest.raises(HistoryError, match="cannot open the history") as caught:
            open_history(target)
        assert "\n" not in str(caught.value) and "%2F" not in str(caught.value)
    assert main(["history", "--history", missing_db]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot open the history" in err and "does not exist" in err
    open_history(pg_url).close()
    with _raw(postgres, pg_url) as raw:
        raw.execute("UPDATE history_info SET value = '99' WHERE key = 'schema_version'")
    with pytest.raises(HistoryError, match="schema 99 is newer"):
        open_history(pg_url)


# --- a fleet into PostgreSQL ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fleet_run(postgres, tmp_path_factory):
    """uav07: sensor A over two flights; uav08: sensor B whose bias z steps between its two flights; a
    file that is no recording. One fleet run (a local cluster of 2 workers) into a fresh PostgreSQL
    database and one into SQLite."""
    root = tmp_path_factory.mktemp("pgfleet")
    two_vehicles(root)
    (root / "uav09").mkdir()
    (root / "uav09" / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 100)
    url = postgres.create_database("fleet")
    sqlite = tmp_path_factory.mktemp("pgfleet_sqlite") / "h.sqlite"
    with local_cluster(2) as cluster:
        codes = [main(["fleet", str(root), "--scheduler", cluster.scheduler_address, "--history", target])
                 for target in (url, str(sqlite))]
        yield root, url, sqlite, codes, cluster.scheduler_address


def test_history_after_a_fleet_run_equals_the_per_recording_replays(fleet_run, capsys):
    root, url, sqlite, codes, _ = fleet_run
    assert codes == [1, 1]  # the broken file failed, on both runs
    with open_history(url) as history:
        rows = history.records()
    with open_history(sqlite) as history:
        on_sqlite = history.records()
    assert len(rows) == 5
    # Row for row what the same fleet wrote to SQLite, bit for bit but the time of writing.
    assert [replace(r, written_at=None) for r in rows] == [replace(r, written_at=None) for r in on_sqlite]
    by_path = {row.path: row for row in rows}
    for name in ("uav07/flight1", "uav07/flight2", "uav08/flight1", "uav08/flight2"):
        row = by_path[str((root / name).resolve())]
        cal = replay_bag(root / name).calibration  # in this process: the same session, the same numbers
        assert row.status == "calibrated" and row.vehicle == name.split("/")[0] and row.sensor == "imu_link"
        assert _bits(row.bias) == _bits(cal.bias) and _bits(row.bias_sigma) == _bits(cal.bias_sigma)
        assert _bits(row.matrix) == _bits(cal.matrix.ravel()) and _bits(row.matrix_sigma) == _bits(
            cal.matrix_sigma.ravel())
        assert row.residual_rms_mg == cal.quality.residual_rms_mg and row.poses == cal.quality.poses >= 12
        assert row.start_ns == (START_NS + WEEK_NS if name.endswith("2") else START_NS)
        assert max(row.bias_sigma) < 0.5 * MG
    failed = by_path[str((root / "uav09" / "broken.mcap").resolve())]
    assert failed.status == "failed" and failed.bias is None and "\n" not in failed.reason
    capsys.readouterr()


def test_a_rerun_does_not_duplicate_rows(fleet_run, postgres, capsys):
    root, url, _, _, scheduler = fleet_run
    with open_history(url) as history:
        before = history.records()
    assert main(["fleet", str(root / "uav07"), str(root / "uav08"), "--scheduler", scheduler,
                 "--history", url]) == 0
    # (the database named as the user wrote it, not URL-quoted)
    assert f"4 recordings: 4 calibrated, 0 refused, 0 failed; 4 rows written to {url};" in capsys.readouterr().out
    with open_history(url) as history:
        after = history.records()
    assert [replace(r, written_at=None) for r in after] == [replace(r, written_at=None) for r in before]
    with _raw(postgres, url) as raw:
        assert raw.execute("SELECT count(*), count(DISTINCT path) FROM calibrations").fetchone() == (5, 5)


def test_history_command_flags_the_stepped_sensor_only(fleet_run, tmp_path, capsys):
    _, url, _, _, _ = fleet_run
    url = url.replace("postgresql+psycopg://", "postgresql://")  # the plain form: psycopg 3 is the default
    assert_flags_the_stepped_sensor_only(url, capsys)
    figure = tmp_path / "history.png"
    assert main(["report", "--history", url, "-o", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "2 sensors, 1 changes flagged" in capsys.readouterr().out

