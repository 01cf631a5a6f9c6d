"""accel-calib fleet on a real Dask cluster (2 worker processes, started once for the module) into a
real SQLite history: the rows equal the per-recording replays, a broken recording among good ones,
re-runs, and the drift flag on simulated sensors."""
from __future__ import annotations

import math
import shutil
import sqlite3
from types import SimpleNamespace

import numpy as np
import pytest

from accel_calibration.bag.replay import replay_bag
from accel_calibration.cli.dask_cluster import local_cluster, run_tasks
from accel_calibration.cli.fleet import _vehicle, calibrate_recording, find_recordings
from accel_calibration.cli.main import main
from accel_calibration.core.units import MG
from accel_calibration.io.history import open_history
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations
from msg_tools.ulog_writer import sensor_combined_array, write_ulog

from helpers.fleet_sessions import (
    PX4_UUID,
    START_NS,
    STEP_MG,
    WEEK_NS,
    assert_flags_the_stepped_sensor_only,
    two_vehicles,
    write_flight,
)


@pytest.fixture(scope="module")
def scheduler():
    """One local cluster for the module: the fleet joins it with --scheduler (starting one costs seconds)."""
    with local_cluster(2) as cluster:
        yield cluster.scheduler_address


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """Two vehicles (two_vehicles); uav09: a too-short session (refused) and a file that is no recording
    (failed); uav10, uav11: a CSV and a ULog."""
    root = tmp_path_factory.mktemp("fleet")
    sensor_a, sensor_b = two_vehicles(root)
    write_flight(root / "uav09" / "short", sensor_a, 5, START_NS, "mcap", poses=4)
    write_flight(root / "uav10" / "bench.csv", sensor_a, 6, START_NS, "csv")  # every format the replay reads
    write_flight(root / "uav11" / "flight.ulg", sensor_b, 7, START_NS, "ulog")
    (root / "uav09" / "broken.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 100)  # cut short after the magic
    truth = {"uav07/flight1": (sensor_a,), "uav07/flight2": (sensor_a,), "uav08/flight1": (sensor_b,),
             "uav08/flight2": (sensor_b,), "uav10/bench.csv": (sensor_a,), "uav11/flight.ulg": (sensor_b,)}
    return root, truth


def _fleet(root, scheduler, db, capsys, *extra):
    code = main(["fleet", str(root), "--scheduler", scheduler, "--history", str(db), *extra])
    return code, capsys.readouterr()


def test_history_after_a_fleet_run_equals_the_per_recording_replays(fleet, scheduler, tmp_path, capsys):
    root, truth = fleet
    db = tmp_path / "calibrations.sqlite"
    code, out = _fleet(root, scheduler, db, capsys)
    assert code == 1  # one refused, one failed
    errors = out.err.strip().splitlines()
    assert len(errors) == 2 and "Traceback" not in out.err
    assert any("uav09/short" in e and "too few static poses" in e for e in errors)
    assert any("uav09/broken.mcap" in e and "not a readable rosbag2" in e for e in errors)
    assert "8 recordings: 6 calibrated, 1 refused, 1 failed; 8 rows written" in out.out

    with open_history(db) as history:
        rows = {row.path: row for row in history.records()}
    assert len(rows) == 8
    for name in ("uav07/flight1", "uav07/flight2", "uav08/flight1", "uav08/flight2", "uav10/bench.csv",
                 "uav11/flight.ulg"):
        row = rows[str((root / name).resolve())]
        replayed = replay_bag(root / name)  # in this process: the same session, the same numbers
        cal = replayed.calibration
        assert row.status == "calibrated" and row.reason is None
        assert (row.vehicle, row.vehicle_source) == (("PX4 " + PX4_UUID, "metadata") if name.endswith(".ulg")
                                                     else (name.split("/")[0], "folder"))
        if "." not in name:
            assert (row.sensor, row.imu_topic) == ("imu_link", "/imu/data_raw")
        else:  # no frame_id: the stream read names the sensor
            assert row.sensor == replayed.source.imu_topic == row.imu_topic
        np.testing.assert_array_equal(row.bias, cal.bias)
        np.testing.assert_array_equal(row.bias_sigma, cal.bias_sigma)
        np.testing.assert_array_equal(np.reshape(row.matrix, (3, 3)), cal.matrix)
        np.testing.assert_array_equal(np.reshape(row.matrix_sigma, (3, 3)), cal.matrix_sigma)
        assert row.poses == cal.quality.poses >= 12 and row.residual_rms_mg == cal.quality.residual_rms_mg
        assert row.messages == replayed.source.messages and row.model == "sphere9"
        if not name.endswith(".ulg"):  # (this ULog has no temperature)
            assert row.temperature_min_degc == row.temperature_max_degc == pytest.approx(25.0)
        assert row.start_ns == (START_NS + WEEK_NS if name.endswith("2") else START_NS)
        # And right: within 4 sigma of the simulated sensor (flight 2 of uav08 has the stepped bias).
        expected = truth[name][0].bias_mps2 + ([0, 0, STEP_MG * MG] if name == "uav08/flight2" else 0)
        assert np.all(np.abs(np.array(row.bias) - expected) <= 4 * np.array(row.bias_sigma))
        assert max(row.bias_sigma) < 0.5 * MG
    refused = rows[str((root / "uav09" / "short").resolve())]
    assert refused.status == "refused" and "too few static poses" in refused.reason and refused.sensor == "imu_link"
    failed = rows[str((root / "uav09" / "broken.mcap").resolve())]
    assert failed.status == "failed" and failed.bias is None and "\n" not in failed.reason


def test_a_rerun_updates_rows_and_a_copied_recording_is_the_same_one(fleet, scheduler, tmp_path, capsys):
    root, _ = fleet
    db = tmp_path / "h.sqlite"
    _fleet(root / "uav07", scheduler, db, capsys)
    with sqlite3.connect(db) as raw:
        first = raw.execute("SELECT recording_id, bias, written_at FROM calibrations ORDER BY path").fetchall()
    copy = tmp_path / "archive" / "uav07_flight1"
    shutil.copytree(root / "uav07" / "flight1", copy)
    code, out = _fleet(root / "uav07", scheduler, db, capsys)
    assert code == 0 and "2 recordings: 2 calibrated" in out.out and out.err == ""
    code, out = _fleet(copy, scheduler, db, capsys, "--vehicle", r"archive/(?P<vehicle>uav\d+)_")
    assert code == 0
    with sqlite3.connect(db) as raw:
        again = raw.execute("SELECT recording_id, bias, vehicle, vehicle_source, path FROM calibrations "
                            "ORDER BY recording_id").fetchall()
    assert len(again) == 2 == len(first)  # no duplicates: keyed by content
    assert sorted(r[:2] for r in again) == sorted(r[:2] for r in first)
    moved = [r for r in again if r[4] == str(copy.resolve())]
    assert len(moved) == 1 and moved[0][2:4] == ("uav07", "rule")


def test_the_drift_flag_fires_on_the_stepped_sensor_only(fleet, scheduler, tmp_path, capsys):
    root, _ = fleet
    db = tmp_path / "h.sqlite"
    _fleet(root, scheduler, db, capsys)
    assert_flags_the_stepped_sensor_only(str(db), capsys)


def test_a_failing_task_is_one_reason_and_the_others_finish(scheduler):
    from distributed import Client

    with Client(scheduler) as client:
        results = {i: (value, error) for i, value, error in run_tasks(client, math.sqrt, [(4.0,), (-1.0,), (9.0,)])}
    assert results == {0: (2.0, None), 1: (None, "ValueError: math domain error"), 2: (3.0, None)}


def test_recordings_are_found_once_and_bag_directories_are_not_searched(fleet, tmp_path):
    root, _ = fleet
    found, problems = find_recordings([str(root), str(root / "uav07" / "flight1"), str(tmp_path / "absent")])
    names = [p.split(str(root.resolve()) + "/")[1] for p in found]
    assert names == ["uav07/flight1", "uav07/flight2", "uav08/flight1", "uav08/flight2", "uav09/broken.mcap",
                     "uav09/short", "uav10/bench.csv", "uav11/flight.ulg"]
    assert problems == [f"{tmp_path / 'absent'}: no such file or directory"]
    (tmp_path / "empty").mkdir()
    assert find_recordings([str(tmp_path / "empty")])[1][0].endswith("no recordings in it (rosbag2 directories, "
                                                                     ".mcap, .db3, .ulg, .csv)")


def test_vehicle_comes_from_the_rule_then_the_recording_then_its_folder(tmp_path):
    bag = tmp_path / "fleet" / "hangar2" / "2026-11-02"
    bag.mkdir(parents=True)
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  custom_data: {vehicle: uav42}\n")
    unread = SimpleNamespace(source=SimpleNamespace(recording=SimpleNamespace(vehicle="")))  # names no vehicle
    assert _vehicle(bag, unread, r"fleet/(?P<vehicle>hangar\d)") == ("hangar2", "rule")
    assert _vehicle(bag, unread, r"nomatch(\d)") == ("uav42", "metadata")
    assert _vehicle(bag, None, None) == ("hangar2", "folder")  # not read: nothing recorded is known


@pytest.mark.parametrize("info, vehicle", [
    ({"sys_name": "PX4", "sys_uuid": PX4_UUID}, ("PX4 " + PX4_UUID, "metadata")),
    ({"sys_uuid": PX4_UUID}, (PX4_UUID, "metadata")),
    ({"sys_name": "PX4"}, ("uav12", "folder")),  # every PX4 log says PX4: the firmware, not a vehicle
    ({}, ("uav12", "folder")),
])
def test_a_ulogs_vehicle_is_its_boards_uuid_read_from_the_log(tmp_path, info, vehicle):
    samples = SyntheticImu(SensorErrors.mpu6050_like(np.random.default_rng(12)),
                           spread_orientations(2, np.random.default_rng(12)), dwell_s=1.0, rate_hz=100.0,
                           seed=12).samples()
    path = tmp_path / "uav12" / "flight.ulg"
    path.parent.mkdir()
    t_us = (START_NS + samples.t_ns) // 1000
    write_ulog(path, [("sensor_combined", 0, sensor_combined_array(t_us, samples.accel_raw, samples.gyro_raw))],
               info=info)
    outcome = calibrate_recording(str(path))  # read for real (refused: two poses), its vehicle from the log
    assert outcome.status == "refused"
    assert (outcome.record.vehicle, outcome.record.vehicle_source) == vehicle


def test_fleet_refuses_bad_options_in_one_line(fleet, tmp_path, capsys):
    root, _ = fleet
    for args, message in [(["--workers", "0"], "--workers must be at least 1"),
                          (["--vehicle", "(unclosed"], "not a regular expression"),
                          (["--history", str(tmp_path / "no" / "h.sqlite")], "does not exist"),
                          (["-p", "min_poses:=3"], "min_poses")]:
        assert main(["fleet", str(root / "uav07"), *args]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, (args, err)
    assert main(["fleet", str(tmp_path / "absent"), "--history", str(tmp_path / "h.sqlite")]) == 1
    assert capsys.readouterr().err.splitlines()[-1].endswith("no recordings to calibrate")
