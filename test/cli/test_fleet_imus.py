"""fleet writes a history row per IMU of an autopilot log: each row's sensor is the IMU's device, its key
the log's content and the instance (a rerun updates the same rows)."""
from __future__ import annotations

import numpy as np

from accel_calibration.cli.fleet import _imu_identity, calibrate_recording
from accel_calibration.cli.main import main
from accel_calibration.io.history import open_history, recording_identity

from helpers.autopilot_logs import DEVICES, MG, simulate, write_ardupilot_log, write_px4_log


def test_a_dataflash_log_gives_a_row_per_imu(tmp_path):
    board = simulate(21)
    log = tmp_path / "00000003.BIN"
    write_ardupilot_log(log, board)
    first = calibrate_recording(str(log))
    rows = [first, *first.others]
    assert [r.status for r in rows] == ["calibrated", "calibrated"]
    assert [r.record.sensor for r in rows] == ["IMU instance 0", "IMU instance 1"]
    assert len({r.record.recording_id for r in rows}) == 2
    for row, imu in zip(rows, board.imus):  # each row is its own IMU's raw calibration
        assert np.max(np.abs(np.array(row.record.bias) - imu.truth.bias_mps2)) < 0.3 * MG
    identity, _ = recording_identity(log)  # the log's own key for its first IMU; a key derived from it for the next
    assert first.record.recording_id == identity and first.others[0].record.recording_id == _imu_identity(identity, 1)


def test_fleet_run_on_a_ulog_writes_each_imu_by_its_device(tmp_path, capsys):
    board = simulate(22)
    log = tmp_path / "bench.ulg"
    write_px4_log(log, board)
    db = tmp_path / "history.sqlite"
    assert main(["fleet", str(log), "--workers", "1", "--history", str(db)]) == 0
    assert "1 recordings (2 sensors: a row per IMU of an autopilot log): 2 calibrated" in capsys.readouterr().out
    with open_history(db) as history:
        rows = sorted(history.records(), key=lambda row: row.sensor)
    assert [row.sensor for row in rows] == [f"px4 device {DEVICES[0]}", f"px4 device {DEVICES[1]}"]
    for row, imu in zip(rows, board.imus):
        assert np.max(np.abs(np.array(row.bias) - imu.truth.bias_mps2)) < 0.3 * MG
