"""A log's calibration parameters that are there but invalid (an ArduPilot scale of 0 or 5, an offset beyond
its range, NaN) are told from parameters that are absent: absent, the stream is fitted as logged and said so;
invalid, that IMU is refused in one line naming the parameter and its value (it was fitted as if the log
held no correction, with exit 0). `fleet` and `replay --all-imus` say every IMU they could not calibrate."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.cli.fleet import calibrate_recording
from accel_calibration.cli.main import main
from accel_calibration.io.calibration_file import load_calibration
from msg_tools.dataflash_writer import FORMATS_4X, imu_records, parameter_records, write_dataflash

from helpers.autopilot_logs import MG, START_US, logged, simulate, write_ardupilot_log, write_px4_log


@pytest.mark.parametrize("name, value, said", [
    ("INS_ACCSCAL_X", 0.0, "INS_ACCSCAL_X = 0"),
    ("INS_ACCSCAL_Y", 5.0, "INS_ACCSCAL_Y = 5 is outside the range the autopilot accepts, 0.8..1.2"),
    ("INS_ACCOFFS_Z", 4.2, "INS_ACCOFFS_Z = 4.2 is outside the range the autopilot accepts, -3.5..3.5"),
    ("INS_ACCOFFS_X", float("nan"), "INS_ACCOFFS_X = nan"),
])
def test_an_invalid_logged_calibration_parameter_refuses_that_imu_naming_it(tmp_path, capsys, name, value, said):
    log = tmp_path / "00000007.BIN"
    write_ardupilot_log(log, simulate(31), changed={name: value})
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("accel-calib: error: ") and said in err, err
    assert not out.exists()


def test_fleet_reports_an_imu_whose_parameters_are_invalid_as_a_row_with_its_reason(tmp_path):
    board = simulate(33)
    log = tmp_path / "00000009.BIN"
    write_ardupilot_log(log, board, changed={"INS_ACC2SCAL_X": 0.0})
    first = calibrate_recording(str(log))
    rows = [first, *first.others]
    assert [r.status for r in rows] == ["calibrated", "failed"], [r.summary for r in rows]
    assert np.max(np.abs(np.array(first.record.bias) - board.imus[0].truth.bias_mps2)) < 0.3 * MG
    assert "INS_ACC2SCAL_X = 0" in rows[1].reason and rows[1].record.sensor == "IMU instance 1", rows[1].reason


def test_replay_all_imus_writes_the_good_imu_and_says_the_refused_one(tmp_path, capsys):
    log = tmp_path / "00000010.BIN"
    write_ardupilot_log(log, simulate(34), changed={"INS_ACC2OFFS_Y": float("nan")})
    out = tmp_path / "cals"
    assert main(["replay", str(log), "--all-imus", "-o", str(out)]) == 1
    captured = capsys.readouterr()
    assert [p.name for p in sorted(out.iterdir())] == ["imu0.yaml"]
    errors = captured.err.splitlines()
    assert len(errors) == 1 and "IMU 1" in errors[0] and "INS_ACC2OFFS_Y = nan" in errors[0], captured.err


def test_a_px4_scale_px4_ignores_is_undone_as_px4_applied_it_and_said(tmp_path, capsys):
    """PX4's Accelerometer::set_scale takes a scale only when all three are positive and finite: with
    CAL_ACC0_XSCALE = 0 the sensor kept scale 1, and the logged stream is corrected by that."""
    board = simulate(35)
    board.imus[0].stale_scale = np.ones(3)  # what PX4 applied
    log = tmp_path / "ignored.ulg"
    write_px4_log(log, board, changed={"CAL_ACC0_XSCALE": 0.0, "CAL_ACC0_YSCALE": 1.02})
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 0
    said = capsys.readouterr().out
    assert "CAL_ACC0_XSCALE = 0 ignored by PX4 (it keeps scale 1 on every axis)" in said, said
    calibration = load_calibration(out)
    assert np.max(np.abs(calibration.bias - board.imus[0].truth.bias_mps2)) < 0.3 * MG


def test_fleet_still_calibrates_the_other_imus_when_the_first_is_refused(tmp_path):
    board = simulate(36)
    log = tmp_path / "00000011.BIN"
    write_ardupilot_log(log, board, changed={"INS_ACCSCAL_Z": 0.0})
    first = calibrate_recording(str(log))
    rows = [first, *first.others]
    assert [r.status for r in rows] == ["failed", "calibrated"], [r.summary for r in rows]
    assert "INS_ACCSCAL_Z = 0" in first.reason
    assert rows[1].record.sensor == "IMU instance 1"
    assert np.max(np.abs(np.array(rows[1].record.bias) - board.imus[1].truth.bias_mps2)) < 0.3 * MG


def test_a_px4_scale_outside_its_range_is_refused_naming_it(tmp_path, capsys):
    log = tmp_path / "scale5.ulg"
    write_px4_log(log, simulate(37), changed={"CAL_ACC0_YSCALE": 5.0})
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "CAL_ACC0_YSCALE = 5 is outside the range the autopilot accepts, 0.1..3" in err
    assert not out.exists()


def test_absent_parameters_are_fitted_as_logged_and_said_so(tmp_path, capsys):
    board = simulate(38)
    log = tmp_path / "00000012.BIN"
    accel, gyro = logged(board.imus[0])
    write_dataflash(log, FORMATS_4X, parameter_records(START_US - 1000, {"AHRS_ORIENTATION": 2.0})
                    + imu_records(board.t_us, accel, gyro, board.temperature))
    out = tmp_path / "cal.yaml"
    assert main(["replay", str(log), "-o", str(out)]) == 0
    assert "as logged, corrected by a calibration the log does not hold" in capsys.readouterr().out
