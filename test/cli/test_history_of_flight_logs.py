"""A small fleet of flight logs in PX4's format, read for their in-flight evidence and followed by `history`:
three IMUs over 16 flights; IMU 2's filter learns a z bias that grows 1 mg a flight from the 9th to 5 mg and
stays, IMU 3's raw z is 4 mg up from the 12th (its calibration in force as before), IMU 1 steady.
`history` names IMU 2 as the one whose filter keeps learning and IMU 3 as the one that disagrees with its
siblings (its ground moments see the step too), IMU 1 holds."""
from __future__ import annotations

import json

import numpy as np
import pytest

from accel_calibration.bag.flight_evidence import log_evidence
from accel_calibration.cli.main import main
from accel_calibration.io.flight_history import evidence_record
from accel_calibration.io.history import open_history
from msg_tools.synthetic_imu import SensorErrors

import helpers.flight_logs as logs
from helpers.history_records import DAY_NS, START_NS

FLIGHTS = 16
LEARNING_FROM, LEARNING_MG, LEARNT_MG = 8, 1.0, 5.0
STEP_AT, STEP_MG = 11, 4.0


@pytest.fixture
def short_flights(monkeypatch):
    """Flights of 8 s on the ground and 14 s armed at 50 Hz: the test reads 16 logs in seconds."""
    monkeypatch.setattr(logs, "RATE_HZ", 50.0)
    monkeypatch.setattr(logs, "GROUND_S", 8.0)
    monkeypatch.setattr(logs, "FLIGHT_S", 14.0)


def write_and_read(tmp_path) -> list:
    truths = logs.sensors(91, 3)
    in_force = [logs.true_in_force(t) for t in truths]
    records = []
    for flight in range(FLIGHTS):
        grown = min(max(flight - LEARNING_FROM + 1, 0) * LEARNING_MG, LEARNT_MG)
        biases = [logs.FilterBias(np.array([1.0, -1.0, 2.0 + grown * (k == 1)]) * logs.MG, np.array([1e-3, 0.0, 0.0]))
                  for k in range(3)]
        flown = list(truths)
        if flight >= STEP_AT:
            flown[2] = SensorErrors(bias_mps2=truths[2].bias_mps2 + [0.0, 0.0, STEP_MG * logs.MG],
                                    matrix=truths[2].matrix)
        path = tmp_path / f"{flight:04d}.ulg"
        logs.write_ulog_flight(path, logs.fly(flown, 900 + flight), in_force, biases, 100 * flight)
        for imu, evidence in enumerate(log_evidence(str(path))):
            record = evidence_record(evidence, f"{flight}-{imu}", str(path), "uav20",
                                     f"px4 device {evidence.device}", imu, START_NS + flight * DAY_NS)
            records.append(record)
    return records


def test_history_of_flight_logs_names_the_learning_and_the_disagreeing_imu(tmp_path, short_flights, capsys):
    records = write_and_read(tmp_path)
    target = str(tmp_path / "fleet.sqlite")
    with open_history(target) as history:
        history.write_evidence(records)
    # What each flight read: IMU 2's filter bias as it grew, IMU 3's 4 mg against its siblings.
    last = {r.imu: r for r in records if r.path.endswith(f"{FLIGHTS - 1:04d}.ulg")}
    grown = LEARNT_MG
    # (the simulated filter converges in 3 s: at the end of a 14 s flight it is within a few % of the bias)
    assert abs(json.loads(last[1].estimator)["accel"][2] / logs.MG - (2.0 + grown)) < 0.2 + 0.05 * (2.0 + grown)
    assert abs(json.loads(last[2].agreement)["accel"][2] / logs.MG - STEP_MG * 1.0) < 0.3 + 0.02 * STEP_MG
    capsys.readouterr()
    assert main(["history", "--history", target]) == 3
    out = [line.strip() for line in capsys.readouterr().out.splitlines()]
    moved = [line for line in out if line.endswith(": recalibrate")]
    assert len(moved) == 3, out  # IMU 3's raw step shows on its ground moments too
    assert moved[0].startswith("vehicle uav20 IMU 2 (device 1442060): the filter keeps learning a bias: accel bias z +")
    assert moved[1].startswith("vehicle uav20 IMU 3 (device 3801122): bias z or scale z +")
    assert moved[2].startswith("vehicle uav20 IMU 3 (device 3801122) disagrees with its siblings: accel z +")
    steady = [line for line in out if line.startswith("vehicle uav20 IMU 1 (device 1310988)")]
    assert any("the filter's bias holds: 16 flights" in line for line in steady)
    assert any("agreement with its siblings holds: 16 flights" in line for line in steady)
