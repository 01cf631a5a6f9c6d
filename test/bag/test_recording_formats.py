"""One synthetic session recorded in every form a person may hold (CSV in s and ns, in g, m/s^2 and counts;
a single .mcap file; a single .db3 file; a bag directory) gives the same poses and calibration; the format
is found from the content; the pose table written by --poses-out reads back; corrected copies come out in
the input's own format."""
from __future__ import annotations

import csv
import io
import shutil

import numpy as np
import pytest

from accel_calibration import load_calibration
from accel_calibration.bag.recording import RecordingError, detect_format, open_recording
from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.cli.main import main
from accel_calibration.core.pose_map import PoseStatus
from accel_calibration.io.pose_table import read_table
from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

G = 9.80665
START_NS = 1_000_000_000_000  # 1000 s: seconds written with nine decimals are exact in a double


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """The session as a bag directory (sqlite3 and mcap), each bag's single storage file, and CSV streams
    carrying the bag's temperature readings on the rows they were recorded with."""
    rng = np.random.default_rng(21)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    samples = SyntheticImu(errors, spread_orientations(15, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0,
                           temperature_degc=lambda t: 24.0 + 0.01 * t, seed=21).samples()
    root = tmp_path_factory.mktemp("forms")
    forms = {}
    for storage in ("sqlite3", "mcap"):
        bag = root / f"bag_{storage}"
        write_session_bag(bag, samples, start_ns=START_NS, storage=storage)
        forms[f"{storage} directory"] = (bag, {})
        (single,) = [f for f in bag.iterdir() if f.suffix in (".db3", ".mcap")]
        forms[f"{storage} file"] = (shutil.copy(single, root / f"single{single.suffix}"), {})
    # Temperature on the rows the bag's 10 Hz Temperature messages carry (same stamps, same values).
    reader_temperature = open_recording(root / "bag_sqlite3").temperature
    on_row = np.isin(samples.t_ns + START_NS, reader_temperature[0])
    temperature = np.where(on_row, samples.temperature_degc, np.nan)
    t_ns = samples.t_ns + START_NS
    for time_column, units, per_mps2, flags in (
        ("t_ns", "mps2", 1.0, {}),
        ("t", "mps2", 1.0, {}),
        ("t", "g", 1 / G, {"units": "g"}),
        ("t_ns", "counts", 16384 / G, {"units": "counts", "counts_per_g": 16384.0}),
    ):
        path = root / f"{time_column}_{units}.csv"
        times = [str(v) for v in t_ns.tolist()] if time_column == "t_ns" else \
            [f"{v // 10**9}.{v % 10**9:09d}" for v in t_ns.tolist()]
        accel = (samples.accel_raw * per_mps2).tolist()
        lines = [f"{time_column},ax,ay,az,gx,gy,gz,temperature"]
        for i, (a, w) in enumerate(zip(accel, samples.gyro_raw.tolist())):
            temp = "" if np.isnan(temperature[i]) else repr(float(temperature[i]))
            lines.append(f"{times[i]},{a[0]!r},{a[1]!r},{a[2]!r},{w[0]!r},{w[1]!r},{w[2]!r},{temp}")
        path.write_text("\n".join(lines) + "\n")
        forms[f"csv {time_column} {units}"] = (path, flags)
    return errors, samples, forms


def test_every_form_gives_the_same_calibration(recorded):
    errors, samples, forms = recorded
    results = {name: replay_bag(path, ReplaySettings(**flags)) for name, (path, flags) in forms.items()}
    reference = results["sqlite3 directory"]
    assert reference.calibration is not None, reference.problem
    assert len(reference.poses) >= 13
    # Right, too: within 4 sigma of the part's true errors.
    assert np.all(np.abs(reference.calibration.bias - errors.bias_mps2) <= 4 * reference.calibration.bias_sigma)
    for name, replay in results.items():
        assert replay.source.messages == len(samples.t_ns), name
        assert [(p.start_ns, p.end_ns, p.samples) for p in replay.poses] == \
            [(p.start_ns, p.end_ns, p.samples) for p in reference.poses], name
        temps = [p.temperature_degc for p in replay.poses]
        np.testing.assert_allclose(temps, [p.temperature_degc for p in reference.poses], rtol=0, atol=1e-9)
        # g and counts are scaled back by one multiplication: a rounding of the last bit, no more.
        np.testing.assert_allclose(replay.calibration.bias, reference.calibration.bias, rtol=0, atol=1e-9)
        np.testing.assert_allclose(replay.calibration.matrix, reference.calibration.matrix, rtol=0, atol=1e-9)
    assert {r.source.recording.format for r in results.values()} == {"rosbag2", "sqlite3", "mcap", "csv"}


def test_the_format_is_found_from_the_content(recorded, tmp_path):
    _, _, forms = recorded
    for name, expected in (("sqlite3 file", "sqlite3"), ("mcap file", "mcap"), ("csv t g", "csv"),
                           ("mcap directory", "rosbag2")):
        path = forms[name][0]
        assert detect_format(path) == expected
        if path.is_file():  # whatever the file is called
            renamed = shutil.copy(path, tmp_path / f"renamed_{expected}.bin")
            assert detect_format(renamed) == expected
    junk = tmp_path / "junk.bin"
    junk.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(RecordingError, match=r"unknown recording format; known: rosbag2 .*ulog .*csv"):
        detect_format(junk)
    with pytest.raises(RecordingError, match="no such bag or file"):
        detect_format(tmp_path / "absent")
    with pytest.raises(RecordingError, match="--imu-topic does not apply to a csv recording"):
        open_recording(forms["csv t g"][0], imu_topic="/imu")


def test_named_format_that_does_not_fit_is_one_line(recorded, capsys):
    _, _, forms = recorded
    csv_path = forms["csv t_ns mps2"][0]
    assert main(["replay", str(csv_path), "--format", "ulog"]) == 1
    assert "not a PX4 ULog" in capsys.readouterr().err
    assert main(["replay", str(forms["mcap file"][0]), "--format", "rosbag2"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a directory; a single storage file is --format mcap or sqlite3" in err


def test_poses_out_reads_back_into_fit_and_report(recorded, tmp_path, capsys):
    _, _, forms = recorded
    poses, cal = tmp_path / "poses.csv", tmp_path / "cal.yaml"
    assert main(["replay", str(forms["csv t g"][0]), "--units", "g", "--poses-out", str(poses), "-o", str(cal)]) == 0
    replay = replay_bag(forms["csv t g"][0], ReplaySettings(units="g"))
    rows = list(csv.DictReader(io.StringIO(poses.read_text())))
    assert len(rows) == len(replay.poses) and {r["status"] for r in rows} <= {"used", "outlier"}
    assert [r["status"] == "outlier" for r in rows] == [s is PoseStatus.OUTLIER for s in replay.pose_status]
    for row, pose in zip(rows, replay.poses):
        assert (int(row["start_ns"]), int(row["end_ns"]), int(row["samples"])) == \
            (pose.start_ns, pose.end_ns, pose.samples)
        assert float(row["temperature"]) == pose.temperature_degc
        assert float(row["temperature_spread"]) == pose.temperature_spread_degc
        np.testing.assert_array_equal([float(row[a]) for a in ("gx", "gy", "gz")], pose.gyro_radps)
    table = read_table(poses)
    np.testing.assert_array_equal(table.accel, [p.accel_mps2 for p in replay.poses])
    # `fit` on the table: the same poses unmerged, so the same calibration to well within its sigma.
    refit = tmp_path / "refit.yaml"
    assert main(["fit", str(poses), "-o", str(refit)]) == 0
    a, b = load_calibration(cal), load_calibration(refit)
    assert np.all(np.abs(a.bias - b.bias) <= a.bias_sigma)
    assert main(["report", str(cal), "--poses", str(poses), "-o", str(tmp_path / "r.png")]) == 0
    assert (tmp_path / "r.png").read_bytes()[:4] == b"\x89PNG"


def test_poses_out_is_written_when_the_fit_is_refused(recorded, tmp_path, capsys):
    _, _, forms = recorded
    poses, cal = tmp_path / "poses.csv", tmp_path / "cal.yaml"
    # A gate no session passes: the fit runs, the gate refuses, the poses are still worth seeing.
    assert main(["replay", str(forms["mcap file"][0]), "-p", "max_residual_rms_mg:=0.01", "--poses-out", str(poses),
                 "-o", str(cal)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "gate residual" in err and f"(poses written to {poses})" in err
    assert not cal.exists()
    rows = list(csv.DictReader(io.StringIO(poses.read_text())))
    assert len(rows) >= 13 and all(r["status"] in ("used", "outlier") for r in rows)


def test_corrected_csv_keeps_the_file_and_its_units(recorded, tmp_path, capsys):
    _, samples, forms = recorded
    source = forms["csv t g"][0]
    out, cal = tmp_path / "corrected.csv", tmp_path / "cal.yaml"
    assert main(["replay", str(source), "--units", "g", "--corrected", str(out), "-o", str(cal)]) == 0
    calibration = load_calibration(cal)
    before = list(csv.reader(io.StringIO(source.read_text())))
    after = list(csv.reader(io.StringIO(out.read_text())))
    assert after[0] == before[0] and len(after) == len(before)
    for old, new in zip(before[1:], after[1:]):
        assert (old[0], old[7:]) == (new[0], new[7:])  # time and temperature cells as they were
        # The gyro corrected as the node does (its bias, and its matrix when the motions gave one; rad/s: the
        # file's gyro units).
        np.testing.assert_allclose([float(v) for v in new[4:7]],
                                   calibration.apply_gyro([float(v) for v in old[4:7]]), rtol=0, atol=1e-15)
    raw_g = np.array([[float(v) for v in row[1:4]] for row in before[1:]])
    new_g = np.array([[float(v) for v in row[1:4]] for row in after[1:]])
    replayed = replay_bag(source, ReplaySettings(units="g"))
    temps = replayed.temperatures.at(replayed.source.recording.t_ns)
    expected = calibration.apply(raw_g * G, temps) if calibration.temperature is not None else \
        calibration.apply(raw_g * G)
    np.testing.assert_allclose(new_g * G, expected, rtol=1e-15, atol=1e-12)  # still in g
    again = replay_bag(out, ReplaySettings(units="g"))
    assert np.abs(again.calibration.bias).max() < 1e-6


@pytest.mark.parametrize("name", ["mcap file", "sqlite3 file"])
def test_corrected_single_bag_file_is_a_single_file(recorded, tmp_path, name):
    _, _, forms = recorded
    source = forms[name][0]
    out = tmp_path / f"corrected{source.suffix}"
    assert main(["replay", str(source), "--corrected", str(out)]) == 0
    assert out.is_file() and detect_format(out) == detect_format(source)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".corrected-")]  # no scratch left
    before, after = open_recording(source), open_recording(out)
    np.testing.assert_array_equal(after.t_ns, before.t_ns)
    assert np.abs(after.gyro_radps - before.gyro_radps).max() > 0  # the gyro bias came off, as the node does
    assert not np.allclose(after.accel_mps2, before.accel_mps2)
    assert np.abs(replay_bag(out).calibration.bias).max() < 1e-6
    assert main(["replay", str(source), "--corrected", str(source)]) == 1  # never over the input


def test_poses_out_names_the_pose_the_fit_left_out(tmp_path):
    """One dwell read 5 % high (a cart accelerating along the pose's up direction): off the sphere by ~50 mg,
    which the fit leaves out (fit.FitResult.outliers) and the pose table says so."""
    rng = np.random.default_rng(8)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    imu = SyntheticImu(errors, spread_orientations(15, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=8)
    samples = imu.samples()
    start, end, _ = imu.static_intervals()[9]
    bad = (samples.t_ns >= start) & (samples.t_ns <= end)
    accel = samples.accel_raw.copy()
    accel[bad] *= 1.05
    path = tmp_path / "cart.csv"
    lines = ["t_ns,ax,ay,az,gx,gy,gz"] + [f"{t},{a[0]!r},{a[1]!r},{a[2]!r},{w[0]!r},{w[1]!r},{w[2]!r}"
                                          for t, a, w in zip(samples.t_ns.tolist(), accel.tolist(),
                                                             samples.gyro_raw.tolist())]
    path.write_text("\n".join(lines) + "\n")
    poses = tmp_path / "poses.csv"
    assert main(["replay", str(path), "--poses-out", str(poses), "-o", str(tmp_path / "cal.yaml")]) == 0
    rows = list(csv.DictReader(io.StringIO(poses.read_text())))
    flagged = [r for r in rows if r["status"] == "outlier"]
    assert len(flagged) == 1 and sum(r["status"] == "used" for r in rows) == len(rows) - 1
    assert start <= int(flagged[0]["start_ns"]) and int(flagged[0]["end_ns"]) <= end
    calibration = load_calibration(tmp_path / "cal.yaml")  # the fit of the others: a MEMS-grade answer again
    assert calibration.quality.residual_rms_mg < 1.0
    assert np.abs(calibration.bias - errors.bias_mps2).max() < 0.5 * 9.80665e-3  # < 0.5 mg


def test_a_fifo_is_refused_before_any_read(tmp_path, capsys):
    import os

    fifo = tmp_path / "stream.csv"
    os.mkfifo(fifo)  # reading it would block for ever
    for flags in ([], ["--format", "csv"], ["--format", "ulog"], ["--format", "mcap"]):
        assert main(["replay", str(fifo), *flags]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "not a regular file" in err, err
