"""The calibration history database (a real SQLite file) and its drift rule; no cluster here."""
from __future__ import annotations

import math
import os
import random
import shutil
import sqlite3
import subprocess
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.cli.main import main
from accel_calibration.core.units import MG
from accel_calibration.io.history import (
    DriftRule,
    HistoryError,
    drift_flags,
    open_history,
    recording_identity,
)

from helpers.history_records import DAY_NS, START_NS, WRITERS, assert_round_trip, record

# --- the database ------------------------------------------------------------------------------------

def test_round_trip_and_rewriting_a_recording_updates_its_row(tmp_path):
    db = tmp_path / "h.sqlite"
    assert_round_trip(db)
    with sqlite3.connect(db) as raw:
        assert raw.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        assert raw.execute("SELECT count(*) FROM calibrations").fetchone()[0] == 2
        assert raw.execute("SELECT condition_number FROM calibrations").fetchall() == [(None,), (None,)]


def test_recording_identity_follows_content_not_location(tmp_path):
    bag = tmp_path / "a" / "flight1"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    (bag / "flight1_0.mcap").write_bytes(bytes(range(256)) * 1000)
    identity, size = recording_identity(bag)
    assert size == 256_000 + len("rosbag2_bagfile_information: {version: 9}\n")
    copy = tmp_path / "b" / "renamed"
    shutil.copytree(bag, copy)
    assert recording_identity(copy) == (identity, size)  # moved or copied: the same recording
    data = bytearray((bag / "flight1_0.mcap").read_bytes())
    data[-1] ^= 1  # the tail (summary, index) of another recording differs
    (copy / "flight1_0.mcap").write_bytes(bytes(data))
    assert recording_identity(copy)[0] != identity
    with pytest.raises(HistoryError, match="cannot read the recording"):
        recording_identity(tmp_path / "absent.mcap")


def test_concurrent_writers_in_several_processes_never_corrupt_it(tmp_path):
    db = tmp_path / "shared.sqlite"
    writers, rounds = 4, 25
    run = subprocess.run([sys.executable, "-c", WRITERS, str(db), str(writers), str(rounds)], capture_output=True,
                         text=True, timeout=300, env={**os.environ, "OPENBLAS_NUM_THREADS": "1"}, check=False)
    assert (run.returncode, run.stdout, run.stderr) == (0, " ".join(["0"] * writers) + "\n", "")
    with sqlite3.connect(db) as raw:
        assert raw.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    with open_history(db) as history:
        rows = history.records()
    assert sorted(r.recording_id for r in rows) == [f"rec{n:02d}" for n in range(20)]
    for row in rows:  # each row whole from one write: bias and sigma of the same writer and round
        writer, k, n = row.bias
        assert row.scale_sigma == (writer, k, n) and 1 <= writer <= writers
        assert row.recording_id == f"rec{int(n):02d}" and row.path == f"/fleet/v/flight{int(n)}"


def test_bad_targets_are_one_line(tmp_path):
    for target, message in [(str(tmp_path), "is a directory"),
                            (str(tmp_path / "no" / "h.sqlite"), "does not exist"),
                            ("nosuchdialect://x/y", "cannot open the history"),
                            ("postgresql+nosuchdriver://u@h/db", "cannot open the history")]:
        with pytest.raises(HistoryError, match=message) as caught:
            open_history(target)
        assert "\n" not in str(caught.value)
    db = tmp_path / "new.sqlite"
    open_history(db).close()
    with sqlite3.connect(db) as raw:
        raw.execute("UPDATE history_info SET value = '99' WHERE key = 'schema_version'")
    with pytest.raises(HistoryError, match="schema 99 is newer"):
        open_history(db)
    (tmp_path / "text.sqlite").write_text("not a database, " * 100)
    with pytest.raises(HistoryError, match="cannot open the history"):
        open_history(tmp_path / "text.sqlite")


# --- the drift rule ----------------------------------------------------------------------------------

def test_the_flag_reads_as_the_issue_says():
    before = record(0, start_ns=START_NS)
    after = record(7, start_ns=START_NS + 7 * DAY_NS, bias=(0.3, -0.2, 0.1 + 18 * MG),
                   bias_sigma=(1e-3, 1e-3, 2.0 * MG))
    flags = drift_flags([after, before])
    assert len(flags) == 1
    sigmas = 18 * MG / math.hypot(1e-3, 2.0 * MG)
    assert flags[0].sigmas == pytest.approx(sigmas) and flags[0].by_sigma and not flags[0].by_bound
    assert flags[0].message() == (f"vehicle uav07 imu0: bias z moved 18 mg ({sigmas:.1f} sigma) "
                                  "between 2026-11-02 and 2026-11-09")


def test_plausibility_bound_flags_what_large_sigmas_would_excuse():
    loose = (50 * MG,) * 3  # sigmas so large that the k-sigma rule explains anything
    a = record(0, bias_sigma=loose, scale_sigma=(0.05,) * 3)
    b = record(1, bias=(0.3 + 60 * MG, -0.2, 0.1), bias_sigma=loose, scale=(1.01, 0.99 * 1.02, 1.0),
               scale_sigma=(0.05,) * 3)
    flags = drift_flags([a, b])
    assert [(f.quantity, f.axis, f.by_sigma, f.by_bound) for f in flags] == [("bias", "x", False, True),
                                                                             ("scale", "y", False, True)]
    assert "beyond the plausibility bound" in flags[0].message() and "60 mg" in flags[0].message()
    assert drift_flags([a, b], DriftRule(max_bias_change_mg=100, max_scale_change=0.05)) == []


def test_refused_and_failed_recordings_are_not_compared():
    rows = [record(0), record(1, bias=(9.0, 9.0, 9.0), status="refused", reason="gate residual"),
            record(2, status="failed", reason="unreadable", bias=None, matrix=None), record(3)]
    assert drift_flags(rows) == []


@settings(max_examples=60, deadline=None)
@given(n=st.integers(2, 8), step_at=st.integers(1, 7), axis=st.integers(0, 2),
       quantity=st.sampled_from(["bias", "scale"]), step_in_sigmas=st.floats(0.0, 12.0),
       sigma=st.floats(1e-5, 1e-3), k=st.floats(2.0, 8.0), seed=st.integers(0, 2**16))
def test_a_step_is_flagged_exactly_where_and_when_the_rule_says(n, step_at, axis, quantity, step_in_sigmas, sigma,
                                                                k, seed):
    """A sensor constant but for one step between two calibrations: flagged at that step, on that axis
    and quantity only, exactly when |step| > k sqrt(2) sigma (bounds set out of reach), in any input order."""
    step_at = min(step_at, n - 1)
    step = step_in_sigmas * math.sqrt(2) * sigma * (-1) ** seed
    rows = []
    for i in range(n):
        bias, scale = [0.3, -0.2, 0.1], [1.01, 0.99, 1.0]
        if i >= step_at:
            (bias if quantity == "bias" else scale)[axis] += step
        rows.append(record(i, bias=bias, bias_sigma=(sigma,) * 3, scale=scale, scale_sigma=(sigma,) * 3))
    random.Random(seed).shuffle(rows)
    rule = DriftRule(k_sigma=k, max_bias_change_mg=1e6, max_scale_change=1e6)
    flags = drift_flags(rows, rule)
    expected = abs(step) > k * math.hypot(sigma, sigma)
    if math.isclose(abs(step), k * math.hypot(sigma, sigma), rel_tol=1e-9):
        return  # on the edge: either answer is right
    assert len(flags) == int(expected)
    if expected:
        flag = flags[0]
        assert (flag.quantity, flag.axis) == (quantity, "xyz"[axis])
        assert flag.before.recording_id == record(step_at - 1).recording_id
        assert flag.after.recording_id == record(step_at).recording_id
        assert flag.change == pytest.approx(step, rel=1e-6, abs=1e-15)
        assert flag.sigmas == pytest.approx(step_in_sigmas, rel=1e-6)


def test_sensors_are_kept_apart():
    rows = [record(0, vehicle="uav07"), record(1, vehicle="uav08", bias=(1.0, 1.0, 1.0)),
            record(2, vehicle="uav07", sensor="imu1", bias=(-1.0, 0, 0)), record(3, vehicle="uav07")]
    assert drift_flags(rows) == []


def test_drift_rule_refuses_nonsense():
    for bad in (dict(k_sigma=0.0), dict(k_sigma=math.nan), dict(max_bias_change_mg=-1.0), dict(max_scale_change=0)):
        with pytest.raises(HistoryError, match="must be a positive number"):
            DriftRule(**bad)


# --- the commands on a history ----------------------------------------------------------------------

def test_history_command_and_figure(tmp_path, capsys):
    db = tmp_path / "h.sqlite"
    rows = [record(i, bias=(0.3, -0.2, 0.1 + (5 * MG if i >= 2 else 0.0))) for i in range(4)]
    rows += [record(i, vehicle="uav08") for i in range(3)]
    rows.append(record(9, vehicle="uav08", status="refused", reason="/fleet/uav08/flight9: too few static poses"))
    with open_history(db) as history:
        history.write(rows)
    assert main(["history", "--history", str(db)]) == 3  # a change flagged
    out = capsys.readouterr().out
    flagged = [line.strip() for line in out.splitlines() if " moved " in line]
    sigmas = 5 * MG / math.hypot(1e-3, 1e-3)
    assert flagged == [f"vehicle uav07 imu0: bias z moved 5 mg ({sigmas:.1f} sigma) between 2026-11-03 and 2026-11-04"]
    assert "vehicle uav08 imu0: 3 calibrations" in out and "refused  uav08 imu0" in out
    assert main(["history", "--history", str(db), "--vehicle", "uav08"]) == 0
    assert "no change beyond what the sigmas explain" in capsys.readouterr().out
    assert main(["history", "--history", str(db), "--k-sigma", "1e5", "--vehicle", "uav07"]) == 0
    capsys.readouterr()

    figure = tmp_path / "history.png"
    assert main(["report", "--history", str(db), "-o", str(figure)]) == 0
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 30_000
    assert "2 sensors, 1 changes flagged" in capsys.readouterr().out

    for args, message in [(["history", "--history", str(tmp_path / "absent.sqlite")], "no such history"),
                          (["history", "--history", str(db), "--sensor", "imu9"], "no recordings of sensor imu9"),
                          (["history", "--history", str(db), "--k-sigma", "-1"], "k_sigma must be a positive"),
                          (["report", "--history", str(db), "-o", str(db)], "--output"),
                          (["report", "-o", str(figure)], "one of the arguments")]:
        assert main(args) == 1, args
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, (args, err)
