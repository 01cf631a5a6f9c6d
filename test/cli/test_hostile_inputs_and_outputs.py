"""Hostile inputs and outputs: no result lost, nothing written where it must not be, no secret printed,
no hang. One test (or a few) per failure docs/failures.md lists."""
from __future__ import annotations

import os
import sqlite3
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import MAX_IDENTIFIER_CHARS, Calibration
from accel_calibration.core.errors import CalibrationError
from accel_calibration.io import calibration_file
from accel_calibration.io.calibration_file import load_calibration, save_calibration

from helpers.one_line import one_error_line

# --- 1. a file the loader refuses is never put in place --------------------------------------------------

@pytest.mark.parametrize("frame_id", ["imu_link" * 140_000, "imu\x00link\n\x1b[31m", "\udcff" * 300])
def test_a_huge_or_unprintable_frame_id_still_saves_a_file_that_loads(tmp_path, frame_id):
    path = tmp_path / "cal.yaml"
    calibration = Calibration.identity(frame_id=frame_id, sensor_id=frame_id)
    save_calibration(calibration, path)
    assert path.stat().st_size < 4096
    loaded = load_calibration(path)
    assert loaded == calibration
    for kept in (loaded.frame_id, loaded.sensor_id):
        assert len(kept) <= MAX_IDENTIFIER_CHARS and kept.isprintable()
    assert loaded.frame_id.startswith(frame_id[:3].replace("\x00", "?").replace("\udcff", "?"))


def test_a_calibration_whose_file_would_be_refused_is_not_written(tmp_path, monkeypatch):
    path = tmp_path / "cal.yaml"
    save_calibration(Calibration.identity(frame_id="old"), path)
    before = path.read_bytes()
    text = calibration_file.calibration_to_yaml(Calibration.identity())
    monkeypatch.setattr(calibration_file, "calibration_to_yaml",
                        lambda c, *sources: text + "#" + "x" * calibration_file.MAX_CALIBRATION_BYTES + "\n")
    with pytest.raises(CalibrationError, match="not written.*KiB"):
        save_calibration(Calibration.identity(frame_id="new"), path)
    monkeypatch.setattr(calibration_file, "calibration_to_yaml",
                        lambda c, *sources: text.replace("model: sphere9", "model: x"))
    with pytest.raises(CalibrationError, match="not written.*would not load back"):
        save_calibration(Calibration.identity(frame_id="new"), path)
    assert path.read_bytes() == before
    assert load_calibration(path).frame_id == "old"


# --- 2, 5, 7. replay's outputs: all work first, then the writes; only our own scratch is removed --------

@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A short calibration session as a rosbag2 directory (mcap storage)."""
    from msg_tools.bag_writer import write_session_bag
    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    rng = np.random.default_rng(25)
    imu = SyntheticImu(SensorErrors.mpu6050_like(rng, noise_mps2=0.02), spread_orientations(15, rng), dwell_s=2.0,
                       move_s=0.8, rate_hz=100.0, seed=25)
    path = tmp_path_factory.mktemp("hostile") / "session"
    write_session_bag(path, imu.samples(), start_ns=1_700_000_000 * 10**9, storage="mcap")
    return path


def _leftovers(directory):
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


def test_replay_refuses_an_unwritable_output_before_replacing_another(bag, tmp_path, capsys):
    cal = tmp_path / "cal.yaml"
    cal.write_text("old\n")
    assert main(["replay", str(bag), "-o", str(cal), "--report", str(tmp_path / "missing" / "r.png")]) == 1
    assert "does not exist" in one_error_line(capsys)
    existing = tmp_path / "existing"
    existing.mkdir()
    assert main(["replay", str(bag), "-o", str(cal), "--corrected", str(existing)]) == 1
    assert "already exists" in one_error_line(capsys)
    assert cal.read_text() == "old\n" and list(existing.iterdir()) == []


def test_a_corrected_copy_that_fails_leaves_every_output_as_it_was(bag, tmp_path, capsys, monkeypatch):
    from accel_calibration.bag import bag_io, corrected_bag

    def fails(*_args, **_kwargs):
        raise bag_io.BagError(f"{bag}: topic /other: its recorded definition cannot be written")

    monkeypatch.setattr(corrected_bag, "write_corrected", fails)
    cal = tmp_path / "cal.yaml"
    cal.write_text("old\n")
    assert main(["replay", str(bag), "-o", str(cal), "--corrected", str(tmp_path / "out"),
                 "--report", str(tmp_path / "r.png")]) == 1
    assert "recorded definition" in one_error_line(capsys)
    assert cal.read_text() == "old\n" and sorted(p.name for p in tmp_path.iterdir()) == ["cal.yaml"]


def test_the_loser_of_two_replays_on_one_corrected_directory_keeps_the_winners_bag(bag, tmp_path, capsys,
                                                                                   monkeypatch):
    from accel_calibration.bag import corrected_copy

    out = tmp_path / "out"
    real = corrected_copy.write_corrected_bag

    def winner_finishes_meanwhile(replay, calibration, destination, **groups):
        written = real(replay, calibration, destination, **groups)
        out.mkdir()  # the other run's rename lands between our check and ours
        (out / "out_0.mcap").write_bytes(b"the winner's bag")
        return written

    monkeypatch.setattr(corrected_copy, "write_corrected_bag", winner_finishes_meanwhile)
    assert main(["replay", str(bag), "--corrected", str(out)]) == 1
    assert "out" in one_error_line(capsys)
    assert (out / "out_0.mcap").read_bytes() == b"the winner's bag" and len(list(out.iterdir())) == 1
    assert _leftovers(tmp_path) == []


def test_a_corrected_copy_through_a_symlink_is_written_at_its_target(bag, tmp_path, capsys):
    recording = next(bag.glob("*.mcap"))
    target = tmp_path / "target.mcap"
    target.write_bytes(b"old")
    link = tmp_path / "link.mcap"
    link.symlink_to(target)
    assert main(["replay", str(recording), "--corrected", str(link)]) == 0, capsys.readouterr().err
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert target.read_bytes()[:5] == b"\x89MCAP"
    assert _leftovers(tmp_path) == []


def finishes_within(seconds, function, *args, **kwargs):
    """function(*args) run in a thread; fails the test (instead of hanging it) when it takes longer."""
    import threading

    result = {}

    def target():
        try:
            result["value"] = function(*args, **kwargs)
        except BaseException as error:  # noqa: BLE001 - handed back to the test
            result["error"] = error

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    thread.join(seconds)
    assert not thread.is_alive(), f"{getattr(function, '__name__', function)} still running after {seconds} s"
    if "error" in result:
        raise result["error"]
    return result["value"]


# --- 3, 4, 10. the history's rows: whole-content identity, true counts, each row alone ------------------

def test_recordings_that_differ_only_in_the_middle_are_two_rows(tmp_path):
    from accel_calibration.io.history import open_history, recording_identity

    from helpers.history_records import record

    head, tail = os.urandom(1 << 17), os.urandom(1 << 17)
    for name, middle in (("a.mcap", b"A"), ("b.mcap", b"B")):
        (tmp_path / name).write_bytes(head + middle * 1000 + tail)
    (tmp_path / "copy").mkdir()
    (tmp_path / "copy" / "a.mcap").write_bytes((tmp_path / "a.mcap").read_bytes())
    ids = [recording_identity(tmp_path / name)[0] for name in ("a.mcap", "b.mcap", "copy/a.mcap")]
    assert ids[0] != ids[1] and ids[0] == ids[2]
    with open_history(tmp_path / "h.sqlite") as history:
        for i, identity in enumerate(ids[:2]):
            history.write([record(i, recording_id=identity)])
        assert len(history.records()) == 2


def test_a_fifo_is_not_opened_for_its_identity(tmp_path):
    from accel_calibration.cli.fleet import calibrate_recording

    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    outcome = finishes_within(10, calibrate_recording, str(fifo))
    assert outcome.status == "failed" and "not a regular file" in outcome.reason


def test_history_text_is_the_same_on_every_backend(tmp_path):
    from accel_calibration.io.history import open_history

    from helpers.history_records import record

    with open_history(tmp_path / "h.sqlite") as history:
        history.write([record(1, recording_id="long", vehicle="v" * 300, sensor="imu\x00link", frame_id="f\x00" * 200,
                              path="/fleet/bad\udcff.csv", reason="x\x00y")])
        row, = history.records()
    assert row.vehicle == "v" * 200 and row.sensor == "imu\\0link" and row.path == "/fleet/bad\ufffd.csv"
    assert row.reason == "x\\0y" and row.frame_id.startswith("f\\0f\\0")


def test_history_rows_are_sanitised_alike_on_postgresql(pg_url):  # noqa: F811 - the imported fixture
    from accel_calibration.io.history import open_history

    from helpers.history_records import record

    with open_history(pg_url) as history:
        history.write([record(1, recording_id="long", vehicle="v" * 300, sensor="imu\x00link", frame_id="f\x00" * 200,
                              path="/fleet/bad\udcff.csv")])
        history.write([record(2)])
        rows = history.records()
    assert [r.vehicle for r in rows] == ["uav07", "v" * 200] and rows[1].sensor == "imu\\0link"


@pytest.fixture(scope="module")
def scheduler():
    from accel_calibration.cli.dask_cluster import local_cluster

    with local_cluster(1) as cluster:
        yield cluster.scheduler_address


def test_fleet_prints_the_true_row_count_and_a_bad_file_costs_only_itself(scheduler, bag, tmp_path, capsys):
    import shutil

    root = tmp_path / "fleet"
    shutil.copytree(bag, root / "uav1" / "flight")
    (root / "uav2").mkdir()
    for i in range(3):
        (root / "uav2" / f"empty{i}.csv").write_bytes(b"")
    head, tail = b"t_ns,ax,ay,az\n" + b"0,0,0,9.8\n" * 8000, b"1,0,0,9.8\n" * 8000
    (root / "uav2" / "a.csv").write_bytes(head + b"5,0,0,1\n" + tail)
    (root / "uav2" / "b.csv").write_bytes(head + b"6,0,0,1\n" + tail)
    (root / "uav3").mkdir()
    with open(os.path.join(os.fsencode(root / "uav3"), b"bad\xff.csv"), "wb") as stream:
        stream.write(b"t_ns,ax,ay,az\n0,0,0,9.8\n")
    os.mkfifo(root / "uav3" / "pipe.mcap")
    db = tmp_path / "h.sqlite"
    code = finishes_within(120, main, ["fleet", str(root), "--scheduler", scheduler, "--history", str(db)])
    out, err = capsys.readouterr()
    assert code == 1 and "Traceback" not in err
    assert all(line.startswith("accel-calib: error: ") for line in err.strip().splitlines()), err
    with sqlite3.connect(db) as connection:
        rows = connection.execute("SELECT count(*) FROM calibrations").fetchone()[0]
        calibrated = connection.execute("SELECT count(*) FROM calibrations WHERE status = 'calibrated'").fetchone()[0]
    # 8 recordings: the bag, 3 empty files (one content), a.csv, b.csv, bad\xff.csv; the FIFO has no row
    assert (rows, calibrated) == (5, 1)
    assert "5 rows written (2 recordings with the content of another: one row each)" in out


# --- 6. read-only commands open read-only; another application's database is refused untouched ----------

def _state(db):
    with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as connection:
        tables = sorted(r[0] for r in connection.execute("SELECT name FROM sqlite_master"))
        mode = connection.execute("PRAGMA journal_mode").fetchone()[0]
    return db.read_bytes(), tables, mode, sorted(p.name for p in db.parent.iterdir())


def test_another_applications_sqlite_file_is_refused_untouched(tmp_path, capsys):
    other = tmp_path / "app.sqlite"
    with sqlite3.connect(other) as connection:
        connection.execute("CREATE TABLE users (name TEXT)")
        connection.execute("INSERT INTO users VALUES ('ada')")
    connection.close()
    before = _state(other)
    for argv in (["history", "--history", str(other)],
                 ["report", "--history", str(other), "-o", str(tmp_path / "r.png")],
                 ["fleet", str(tmp_path / "none.csv"), "--history", str(other), "--workers", "1"]):
        (tmp_path / "none.csv").write_text("t,ax,ay,az\n")
        assert main(argv) == 1
        assert "not a calibration history" in one_error_line(capsys)
        (tmp_path / "none.csv").unlink()
        assert _state(other) == before


def test_reading_a_history_changes_nothing_in_it(tmp_path, capsys):
    from accel_calibration.io.history import open_history

    from helpers.history_records import record

    db = tmp_path / "h.sqlite"
    with open_history(db) as history:
        history.write([record(1), record(2)])
    with sqlite3.connect(db) as connection:
        connection.execute("PRAGMA journal_mode=DELETE")  # as a copy on read-only media would be
    connection.close()
    before = _state(db)
    assert main(["history", "--history", str(db)]) == 0
    assert main(["report", "--history", str(db), "-o", str(tmp_path / "r.png")]) == 0
    assert "flight1" in capsys.readouterr().out
    after = _state(db)
    assert after[:3] == before[:3] and set(after[3]) - set(before[3]) == {"r.png"}


# --- 8. no credential printed ---------------------------------------------------------------------------

@pytest.mark.parametrize("url", ["postgresql://u@127.0.0.1:1/db?password=SECRET",
                                 "postgresql://127.0.0.1:1/db?user=u&password=SECRET",
                                 "postgresql:///db?host=/nonexistent&password=SECRET",
                                 "postgresql://u:SECRET@127.0.0.1:1/db?sslpassword=SECRET"])
def test_a_password_in_a_url_is_never_printed(url, tmp_path, capsys):
    for argv in (["history", "--history", url], ["report", "--history", url, "-o", str(tmp_path / "r.png")]):
        assert main(argv) == 1
        line = one_error_line(capsys)
        assert "SECRET" not in line and "***" in line


def test_the_fleet_prints_its_history_url_masked(scheduler, tmp_path, capsys, pg_url):  # noqa: F811
    (tmp_path / "x.csv").write_text("t,ax,ay,az\n0,0,0,9.8\n")
    assert main(["fleet", str(tmp_path / "x.csv"), "--scheduler", scheduler,
                 "--history", pg_url + "&password=SECRET"]) == 1
    out, err = capsys.readouterr()
    assert "rows written" not in out or "1 row written to" in out
    assert "SECRET" not in out + err and "password=***" in out


# --- 17. off-schema rows and broken URLs are one line ------------------------------------------------------

def test_history_rows_written_off_the_schema_are_left_out_in_one_line(tmp_path, capsys):
    from accel_calibration.io.history import open_history

    from helpers.history_records import record

    db = tmp_path / "h.sqlite"
    with open_history(db) as history:
        history.write([record(i, recording_id=f"r{i}") for i in range(5)])
    with sqlite3.connect(db) as connection:
        connection.execute("UPDATE calibrations SET start_ns = 'yesterday' WHERE recording_id = 'r1'")
        connection.execute("UPDATE calibrations SET matrix = '[1, 0, 0]' WHERE recording_id = 'r2'")
        connection.execute("UPDATE calibrations SET bias = '{not json' WHERE recording_id = 'r3'")
        connection.execute("UPDATE calibrations SET residual_rms_mg = 'low' WHERE recording_id = 'r4'")
    connection.close()
    assert main(["history", "--history", str(db)]) in (0, 3)
    out, err = capsys.readouterr()
    assert err.startswith("accel-calib: warning:") and len(err.strip().splitlines()) == 1
    assert "4 rows" in err and "flight0" in out and "flight1" not in out


@pytest.mark.parametrize("url", ["postgresql://u@host:abc/db", "postgresql://u@host:99999999/db"])
def test_a_url_with_a_broken_port_is_one_line(url, capsys):
    assert main(["history", "--history", url]) == 1
    assert "accel-calib: error:" in one_error_line(capsys)


# --- 9. the dashboard of a local cluster listens on the loopback only --------------------------------------

def test_a_local_clusters_sockets_listen_on_the_loopback_only():
    import psutil

    from accel_calibration.cli.dask_cluster import local_cluster

    with local_cluster(1) as cluster:
        processes = [psutil.Process(), *psutil.Process().children(recursive=True)]
        listening = {(c.laddr.ip, c.laddr.port) for p in processes for c in p.net_connections(kind="inet")
                     if c.status == psutil.CONN_LISTEN}
        dashboard = cluster.dashboard_link
    assert listening and all(ip in ("127.0.0.1", "::1") for ip, _ in listening), listening
    assert dashboard.startswith("http://127.0.0.1:")


# --- 15. --scheduler at something that is not a Dask scheduler ---------------------------------------------

@pytest.fixture
def listener():
    """A TCP listener on the loopback that either says nothing or sends garbage to whoever connects."""
    import socket
    import threading

    server = socket.create_server(("127.0.0.1", 0))
    behaviour = {"send": b""}
    stop = threading.Event()
    held = []

    def serve():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                connection, _ = server.accept()
            except OSError:
                continue
            held.append(connection)
            if behaviour["send"]:
                try:
                    connection.sendall(behaviour["send"])
                except OSError:
                    pass

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}", behaviour
    stop.set()
    thread.join()
    for connection in held:
        connection.close()
    server.close()


@pytest.mark.parametrize("sends", [b"", np.random.default_rng(15).bytes(4096),
                                   b"\xff" * 8 + b"\x00" * 4088])
def test_a_scheduler_address_where_no_dask_answers_is_one_line_in_time(listener, sends, tmp_path, capsys,
                                                                        monkeypatch):
    from accel_calibration.cli import dask_cluster

    monkeypatch.setattr(dask_cluster, "SCHEDULER_TIMEOUT_S", 1.0)
    address, behaviour = listener
    behaviour["send"] = sends
    (tmp_path / "x.csv").write_text("t,ax,ay,az\n0,0,0,9.8\n")
    started = time.monotonic()
    code = finishes_within(30, main, ["fleet", str(tmp_path / "x.csv"), "--scheduler", address,
                                      "--history", str(tmp_path / "h.sqlite")])
    assert code == 1 and time.monotonic() - started < 15
    assert "scheduler" in one_error_line(capsys)


@pytest.mark.parametrize("address", ["tls://127.0.0.1:1", "ucx://127.0.0.1:1", "inproc://x"])
def test_a_scheduler_of_another_scheme_is_one_line(address, tmp_path, capsys):
    (tmp_path / "x.csv").write_text("t,ax,ay,az\n0,0,0,9.8\n")
    assert main(["fleet", str(tmp_path / "x.csv"), "--scheduler", address, "--history",
                 str(tmp_path / "h.sqlite")]) == 1
    assert "tcp://HOST:PORT" in one_error_line(capsys)


# --- 16. a --vehicle rule that backtracks without end -------------------------------------------------------

def test_a_catastrophic_vehicle_rule_is_refused_in_one_line_within_its_limit(tmp_path, capsys, monkeypatch):
    from accel_calibration.cli.fleet import calibrate_recording
    from accel_calibration.io import history

    monkeypatch.setattr(history, "VEHICLE_RULE_TIMEOUT_S", 0.2)

    recording = tmp_path / ("a" * 40 + "!") / "x.csv"
    recording.parent.mkdir()
    recording.write_text("t,ax,ay,az\n0,0,0,9.8\n")
    # A catastrophic rule: Python's re backtracks for minutes on this path; the regex engine sees through it.
    outcome = finishes_within(10, calibrate_recording, str(recording), None, "(a+)+$")
    assert outcome.record.vehicle == recording.parent.name and outcome.record.vehicle_source == "folder"
    # One that backtracks in any engine: refused before any work, in one line, within its time limit.
    started = time.monotonic()
    code = finishes_within(20, main, ["fleet", str(recording), "--vehicle", "(a|aa)+$", "--workers", "1",
                                      "--history", str(tmp_path / "h.sqlite")])
    assert code == 1 and "took longer than" in one_error_line(capsys)
    outcome = finishes_within(20, calibrate_recording, str(recording), None, "(a|aa)+$")
    assert outcome.status == "failed" and "took longer than" in outcome.reason
    assert time.monotonic() - started < 15
    assert not (tmp_path / "h.sqlite").exists()


# --- 11, 12. a .db3 whose messages is a view; message definitions too large to parse -------------------------

def _sqlite_bag(directory, name="s"):
    from msg_tools.bag_writer import write_session_bag
    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    rng = np.random.default_rng(11)
    imu = SyntheticImu(SensorErrors.mpu6050_like(rng, noise_mps2=0.02), spread_orientations(15, rng), dwell_s=1.5,
                       move_s=0.6, rate_hz=100.0, seed=11)
    path = directory / name
    write_session_bag(path, imu.samples(), start_ns=1_700_000_000 * 10**9, storage="sqlite3")
    return path, next(path.glob("*.db3"))


@pytest.mark.parametrize("view", [
    "WITH RECURSIVE r(x) AS (SELECT 1 UNION ALL SELECT x + 1 FROM r) "
    "SELECT x AS id, 1 AS topic_id, x AS timestamp, zeroblob(100) AS data FROM r",
    "SELECT 1 AS id, 1 AS topic_id, 1 AS timestamp, randomblob(50000000) AS data"])
def test_a_db3_whose_messages_is_a_view_is_refused_at_once(tmp_path, capsys, view):
    from accel_calibration.bag.replay import ReplayError, replay_bag

    directory, db3 = _sqlite_bag(tmp_path)
    with sqlite3.connect(db3) as connection:
        connection.execute("DROP TABLE messages")
        connection.execute(f"CREATE VIEW messages AS {view}")
    connection.close()
    for path in (directory, db3):
        with pytest.raises(ReplayError, match="view messages.*not a rosbag2"):
            finishes_within(20, replay_bag, path)
    assert finishes_within(20, main, ["replay", str(db3)]) == 1
    assert "not a rosbag2 sqlite3 storage file" in one_error_line(capsys)


@pytest.mark.parametrize("topic", ["/imu/data_raw", "/other"])
def test_a_huge_recorded_definition_is_refused_before_parsing(tmp_path, capsys, topic):
    from rosbags.typesys import Stores, get_typestore

    from accel_calibration.bag.bag_io import IMU, MAX_DEFINITION_BYTES

    directory, db3 = _sqlite_bag(tmp_path)
    standard = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(IMU, ros_version=2)[0]
    huge = "".join(f"float64 pad{i}\n" for i in range(MAX_DEFINITION_BYTES // 14)) + standard
    with sqlite3.connect(db3) as connection:
        if topic == "/imu/data_raw":
            connection.execute("UPDATE message_definitions SET encoded_message_definition = ? WHERE topic_type = ?",
                               (huge, IMU))
        else:
            connection.execute("INSERT INTO topics (id, name, type, serialization_format, offered_qos_profiles, "
                               "type_description_hash) VALUES (99, '/other', 'custom_msgs/msg/Big', 'cdr', '', '')")
            connection.execute("INSERT INTO message_definitions (topic_type, encoding, encoded_message_definition, "
                               "type_description_hash) VALUES ('custom_msgs/msg/Big', 'ros2msg', ?, '')",
                               (huge.replace("sensor_msgs", "custom_msgs"),))
    connection.close()
    cal = tmp_path / "cal.yaml"
    cal.write_text("old\n")
    started = time.monotonic()
    assert finishes_within(60, main, ["replay", str(directory), "-o", str(cal),
                                      "--corrected", str(tmp_path / "out")]) == 1
    assert "KiB" in one_error_line(capsys) and time.monotonic() - started < 10
    assert cal.read_text() == "old\n" and not (tmp_path / "out").exists()  # item 2: nothing replaced


# --- 14 and an unclear message: tables of a million columns ---------------------------------------------

def test_a_pose_table_of_a_million_columns_is_refused_at_once(tmp_path, capsys):
    header = ["ax", "ay", "az", *(f"c{i}" for i in range(1_000_000))]
    path = tmp_path / "poses.csv"
    path.write_text(",".join(header) + "\n" + ",".join(["0"] * len(header)) + "\n")
    started = time.monotonic()
    assert finishes_within(60, main, ["fit", str(path), "-o", str(tmp_path / "cal.yaml")]) == 1
    assert "1000003 columns" in one_error_line(capsys) and time.monotonic() - started < 10
    # Below the limit the duplicate check is linear: 1000 columns, one repeated, found at once.
    header = ["ax", "ay", "az", *(f"c{i}" for i in range(996)), "c5"]
    path.write_text(",".join(header) + "\n" + ",".join(["0"] * len(header)) + "\n")
    assert main(["fit", str(path), "-o", str(tmp_path / "cal.yaml")]) == 1
    assert "column c5 appears more than once" in one_error_line(capsys)


def test_a_sample_stream_of_a_million_columns_says_so(tmp_path, capsys):
    header = ["t", "ax", "ay", "az", *(f"c{i}" for i in range(1_000_000))]
    path = tmp_path / "samples.csv"
    path.write_text(",".join(header) + "\n" + ",".join(["0"] * len(header)) + "\n")
    assert finishes_within(60, main, ["replay", str(path)]) == 1
    line = one_error_line(capsys)
    assert "header row is longer than 64 KiB" in line and "10952" not in line


# --- 21 and an unclear message: ULog stamps that would wrap, a broken format ---------------------------------

def _ulog(path, t_us):
    from msg_tools.ulog_writer import sensor_combined_array, write_ulog

    rng = np.random.default_rng(21)
    accel = np.array([0.0, 0.0, 9.80665]) + rng.normal(0, 0.02, (len(t_us), 3))
    write_ulog(path, [("sensor_combined", 0, sensor_combined_array(t_us, accel, np.zeros((len(t_us), 3))))])


@pytest.mark.parametrize("start_us", [2**63 - 10**6, 2**64 - 10**6, (2**63 - 1) // 1000 + 1])
def test_ulog_stamps_that_would_wrap_as_nanoseconds_are_refused(tmp_path, capsys, start_us):
    path = tmp_path / "log.ulg"
    _ulog(path, np.uint64(start_us) + np.arange(200, dtype=np.uint64) * np.uint64(1000))
    assert main(["replay", str(path), "--corrected", str(tmp_path / "out.csv")]) == 1
    assert "a nanosecond stamp holds" in one_error_line(capsys)
    assert not (tmp_path / "out.csv").exists()


def test_ulog_stamps_just_within_the_limit_are_read(tmp_path):
    from accel_calibration.bag.ulog_reader import MAX_STAMP_US, read_ulog

    path = tmp_path / "log.ulg"
    t_us = np.uint64(MAX_STAMP_US - 10**6) + np.arange(200, dtype=np.uint64) * np.uint64(1000)
    _ulog(path, t_us)
    assert np.array_equal(read_ulog(path).t_ns, t_us.astype(np.int64) * 1000)


@pytest.mark.parametrize("good, bad, says", [(b"sensor_combined:uint64_t", b"sensor_combined;uint64_t",
                                              "is not 'name:type field;...'"),
                                             (b"sensor_combined:uint64_t", b"sensor_combined:uint64_q",
                                              "unknown type 'uint64_q'")])
def test_a_ulog_with_a_broken_format_says_so(tmp_path, capsys, good, bad, says):
    path = tmp_path / "log.ulg"
    _ulog(path, np.arange(200, dtype=np.uint64) * np.uint64(1000) + np.uint64(10**6))
    path.write_bytes(path.read_bytes().replace(good, bad))
    assert main(["replay", str(path)]) == 1
    line = one_error_line(capsys)
    assert says in line and "corrupt ULog" in line and "no sensor topics" not in line


# --- 20. params files matched as rcl matches them; 13 (file side): read safely before any parser ---------

# (key, namespace of the node, applies?) as rclpy 7.1.6 (Jazzy) applies a file, measured.
RCL_MATCHES = [
    ("/**", "", True), ("/*", "", True), ("*", "", True), ("**", "", True), ("accel_calibration", "", True),
    ("/accel_calibration", "", True), ("/uav1/accel_calibration", "", False), ("/uav1/*", "", False),
    ("/*/accel_calibration", "", False), ("/**/accel_calibration", "", True), ("/uav1/**", "", False),
    ("/*/*", "", False), ("/**/*", "", True),
    ("/**", "/uav1", True), ("/*", "/uav1", False), ("*", "/uav1", False), ("accel_calibration", "/uav1", False),
    ("/uav1/accel_calibration", "/uav1", True), ("uav1/accel_calibration", "/uav1", True),
    ("/uav1/*", "/uav1", True), ("/*/accel_calibration", "/uav1", True), ("/uav1/**", "/uav1", True),
    ("/*/*", "/uav1", True), ("/**/accel_calibration", "/uav1", True),
    ("/**/accel_calibration", "/a/b", True), ("/*/*", "/a/b", False), ("/uav1/**", "/a/b", False),
    ("/**/*", "/a/b", True)]


@pytest.mark.parametrize("key, namespace, applies", RCL_MATCHES)
def test_a_params_file_block_applies_where_rcl_applies_it(key, namespace, applies):
    from accel_calibration.io.params_file import fully_qualified, node_parameters

    document = {key: {"ros__parameters": {"static": {"window_s": 0.3}}}}
    if applies:
        assert node_parameters(document, fully_qualified(namespace)) == {"static.window_s": 0.3}
    else:
        with pytest.raises(CalibrationError, match="no block for node"):
            node_parameters(document, fully_qualified(namespace))


def test_later_blocks_win_and_a_repeated_name_keeps_its_first_place():
    from accel_calibration.io.params_file import node_parameters

    def p(*blocks):
        return node_parameters({k: {"ros__parameters": {"p": i}} for i, k in enumerate(blocks)})["p"]

    assert p("/accel_calibration", "/**") == 1 and p("/**", "/accel_calibration") == 1
    assert p("/*", "/**") == 1 and p("/**", "*") == 1
    # 'accel_calibration' is '/accel_calibration': merged at its first place, before '/**'
    document = {"/accel_calibration": {"ros__parameters": {"p": 0}}, "/**": {"ros__parameters": {"p": 1}},
                "accel_calibration": {"ros__parameters": {"p": 2, "q": 2}}}
    assert node_parameters(document) == {"p": 1, "q": 2}
    for bad in ("accel_*", "/uav*/accel_calibration", "/accel_calibration/", "//x"):
        with pytest.raises(CalibrationError, match="not a node name rcl accepts"):
            node_parameters({bad: {"ros__parameters": {"p": 1}}})
    assert node_parameters({"/**" * 2000 + "/*": {"ros__parameters": {"p": 1}}}) == {"p": 1}  # linear


@pytest.mark.ros
def test_the_matching_table_is_what_rclpy_applies(tmp_path):
    import json

    import rclpy
    from rclpy.node import Node

    from accel_calibration.io.params_file import fully_qualified, node_parameters

    for i, (key, namespace, _) in enumerate(RCL_MATCHES[::3]):
        path = tmp_path / f"p{i}.yaml"
        document = {key: {"ros__parameters": {"p": 1}}, "/other_node": {"ros__parameters": {"q": 2}}}
        path.write_text(json.dumps(document))
        rclpy.init(args=["--ros-args", "--params-file", str(path)])
        try:
            node = Node("accel_calibration", namespace=namespace or None,
                        automatically_declare_parameters_from_overrides=True)
            applied = {n: node.get_parameter(n).value for n in ("p", "q") if node.has_parameter(n)}
            node.destroy_node()
        finally:
            rclpy.shutdown()
        try:
            ours = node_parameters(document, fully_qualified(namespace))
        except CalibrationError:
            ours = {}
        assert ours == applied, (key, namespace)


def test_replay_applies_a_star_block_as_the_node_does(bag, tmp_path, capsys):
    for key in ("/*", "*"):
        params = tmp_path / "params.yaml"
        params.write_text(f'"{key}":\n  ros__parameters:\n    min_poses: 40\n')
        assert main(["replay", str(bag), "--params-file", str(params)]) == 1
        assert "min_poses=40" in one_error_line(capsys)
    params.write_text('"/uav1/accel_calibration":\n  ros__parameters:\n    min_poses: 40\n')
    assert main(["replay", str(bag), "--params-file", str(params)]) == 1
    assert "no block for node /accel_calibration" in one_error_line(capsys)
    assert main(["replay", str(bag), "--params-file", str(params), "--node", "/uav1/accel_calibration"]) == 1
    assert "min_poses=40" in one_error_line(capsys)


def test_a_params_file_is_checked_before_any_parser_sees_it(tmp_path):
    from accel_calibration.io.params_file import MAX_PARAMS_FILE_BYTES, read_params_file

    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    deep = tmp_path / "deep.yaml"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"/**:\n  ros__parameters: {a: \xff\xfe}\n")
    big = tmp_path / "big.yaml"
    big.write_text("#" * (MAX_PARAMS_FILE_BYTES + 1))
    for path, says in ((fifo, "FIFO"), (deep, "nested deeper"), (binary, "not UTF-8"), (big, "larger than")):
        with pytest.raises(CalibrationError, match=says) as caught:
            finishes_within(10, read_params_file, path)
        assert "\n" not in str(caught.value) and str(path) in str(caught.value)


# --- unclear messages: message_count: abc, a time of 1e30 ----------------------------------------------

@pytest.mark.parametrize("through", ["stream", "rosbags"])
def test_a_metadata_message_count_that_is_no_count_is_named(tmp_path, capsys, through):
    copy, _ = _sqlite_bag(tmp_path)
    metadata = copy / "metadata.yaml"
    text = metadata.read_text()
    assert "message_count: " in text
    import re

    metadata.write_text(re.sub(r"(- message_count: )\d+", r"\1abc", text, count=1))  # a topic's count
    if through == "rosbags":
        from accel_calibration.bag.replay import ReplayError, replay_bag

        with pytest.raises(ReplayError) as caught:
            replay_bag(copy, through_rosbags=True)
        line = str(caught.value)
    else:
        assert main(["replay", str(copy)]) == 1
        line = one_error_line(capsys)
    assert "message_count 'abc' is not a count" in line and "TypeError" not in line


def test_a_time_beyond_any_stamp_is_printed_as_a_number(tmp_path, capsys):
    path = tmp_path / "s.csv"
    path.write_text("t,ax,ay,az\n0,0,0,9.8\n1e30,0,0,9.8\n")
    assert main(["replay", str(path)]) == 1
    line = one_error_line(capsys)
    assert "time 1e+30 s is out of range" in line and "np.float64" not in line


def test_a_wal_history_on_read_only_media_is_listed(tmp_path, capsys, monkeypatch):
    """Read-only media, as SQLite meets them (its -shm cannot be made: 'unable to open database file'
    for a WAL file unless opened immutable), stood in for by the driver (the tests run as root)."""
    from accel_calibration.io.history import open_history

    from helpers.history_records import record

    db = tmp_path / "h.sqlite"
    with open_history(db) as history:
        history.write([record(1), record(2)])
    real = sqlite3.connect

    def read_only_media(target, *args, **kwargs):
        if "immutable=1" not in str(target):
            raise sqlite3.OperationalError("unable to open database file")
        return real(target, *args, **kwargs)

    monkeypatch.setattr(sqlite3, "connect", read_only_media)
    assert main(["history", "--history", str(db)]) == 0
    assert "flight1" in capsys.readouterr().out


def test_a_read_only_postgresql_history_reads_and_cannot_write(pg_url, capsys):  # noqa: F811
    from accel_calibration.io.history import HistoryError, open_history

    from helpers.history_records import record

    assert main(["history", "--history", pg_url]) == 1  # an empty database: nothing made in it
    assert "not a calibration history" in one_error_line(capsys)
    with open_history(pg_url) as history:
        history.write([record(1), record(2)])
    assert main(["history", "--history", pg_url]) == 0 and "flight2" in capsys.readouterr().out
    with open_history(pg_url, read_only=True) as history, pytest.raises(HistoryError, match="read-only"):
        history.write([record(3)])


@settings(max_examples=200, deadline=None)
@given(secret=st.text("abcdefghijklmnopqrstuvwxyz0123456789%-._~!$'()*+,", min_size=8, max_size=30),
       key=st.sampled_from(["password", "PASSWORD", "sslpassword", "passwd"]),
       form=st.sampled_from(["postgresql://u:{s}@h:5432/db", "postgresql://u@h/db?{k}={s}",
                             "postgresql://h/db?user=u&{k}={s}&sslmode=require", "postgresql:///db?{k}={s}",
                             "postgresql+psycopg://u:{s}@/db?host=/tmp/x&{k}={s}"]))
def test_no_credential_survives_masking(secret, key, form):
    from accel_calibration.io.history import masked_url

    secret = "S3CR" + secret  # text no URL part holds: only the credential itself can carry it
    masked = masked_url(form.format(s=secret, k=key))
    assert secret not in masked and "***" in masked
