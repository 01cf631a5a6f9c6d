"""`fleet` on ordinary flight logs in the real formats: a row of flight evidence per vehicle, IMU (by its
device) and flight, beside the calibrations' rows; a log that fails is a row with its reason; a rerun
updates the same rows; `history` then follows each IMU (too few flights here: it cannot tell, exit 1)."""
from __future__ import annotations

import json

import numpy as np

from accel_calibration.cli.main import main
from accel_calibration.io.history import open_history
from msg_tools.synthetic_imu import SensorErrors

from helpers.flight_logs import (
    DEVICES,
    MG,
    FilterBias,
    fly,
    sensors,
    true_in_force,
    write_dataflash_flight,
    write_ulog_flight,
)

STEP_MG = 5.0
FILTER_BIASES = [FilterBias(np.array([2.0, -1.0, 4.0]) * MG, np.array([1e-3, 0.0, -5e-4])),
                 FilterBias(np.array([-3.0, 1.0, -2.0]) * MG, np.array([0.0, 2e-3, 5e-4]))]


def stepped(truth: SensorErrors) -> SensorErrors:
    return SensorErrors(bias_mps2=truth.bias_mps2 + [0.0, 0.0, STEP_MG * MG], matrix=truth.matrix)


def write_fleet(root):
    """uavA: three ULog flights, IMU 2's raw z bias 5 mg up in the third (its calibration in force as before);
    uavB: two DataFlash flights; a damaged ULog among uavA's."""
    truths = sensors(31)
    in_force = [true_in_force(t) for t in truths]
    (root / "uavA").mkdir(parents=True)
    (root / "uavB").mkdir()
    for i in range(3):
        flown = truths if i < 2 else [truths[0], stepped(truths[1])]
        write_ulog_flight(root / "uavA" / f"flight_{i}.ulg", fly(flown, 40 + i), in_force)
    for i in range(2):  # ArduPilot's EKF3 logs its bias estimates
        write_dataflash_flight(root / "uavB" / f"{i:08d}.bin", fly(truths, 50 + i), in_force, FILTER_BIASES, 60 + i)
    (root / "uavA" / "flight_9.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + b"\0" * 40)
    return truths


def test_fleet_writes_a_row_of_evidence_per_imu_and_flight(tmp_path, capsys):
    truths = write_fleet(tmp_path / "logs")
    target = str(tmp_path / "fleet.sqlite")
    logs = tmp_path / "logs"
    named = [str(logs / "uavA"), *sorted(str(p) for p in (logs / "uavB").glob("*.bin"))]  # a .bin is taken when named
    for _ in range(2):  # the rerun updates the same rows
        assert main(["fleet", *named, "--history", target, "--workers", "1"]) == 1
        out = capsys.readouterr().out
        assert ("flight evidence: 11 IMU rows, 10 with evidence from the still moments on the ground, 1 without; in "
                "flight, 4 with the filter's settled bias, 10 with their agreement with their siblings") in out
    with open_history(target) as history:
        rows = history.evidence()
    assert len(rows) == 11
    failed = [r for r in rows if r.status != "evidence"]
    assert len(failed) == 1 and failed[0].status == "failed" and "flight_9.ulg" in failed[0].reason
    good = [r for r in rows if r.status == "evidence"]
    assert sorted((r.vehicle, r.device) for r in good) == sorted(
        [("uavA", str(d)) for d in DEVICES] * 3 + [("uavB", str(d)) for d in DEVICES] * 2)
    assert {r.imu for r in good} == {0, 1}
    assert all(r.imu == DEVICES.index(int(r.device)) for r in good)
    for row in good:
        expected = STEP_MG * MG * truths[1].matrix[2, 2] if row.path.endswith("flight_2.ulg") and row.imu == 1 else 0.0
        assert abs(row.z_mps2 - expected) < 0.1 * MG, (row.path, row.imu, row.z_mps2 / MG)
        assert list(json.loads(row.changes)) == ["bias z or scale z"]  # level ground: nothing of x or y
    assert main(["history", "--history", target]) == 1  # two or three flights an IMU: cannot tell
    out = capsys.readouterr().out
    # Each IMU's ground moments, its agreement in flight and (uavB's DataFlash logs) its filter's bias.
    assert out.count(": cannot tell: ") == 4 + 4 + 2
    assert out.count(": agreement with its siblings: cannot tell: ") == 4
    assert out.count(": the filter's bias: cannot tell: 2 flights with evidence") == 2
    assert out.count(": the filter's bias: none: ") == 2  # uavA's ULogs carry no estimator_sensor_bias
    for row in good:  # in flight, each flight's row: the filter's settled bias (1 cm/s^2 as logged), the agreement
        estimator, agreement = json.loads(row.estimator), json.loads(row.agreement)
        if row.path.endswith(".bin"):
            truth = FILTER_BIASES[row.imu].accel_mps2
            assert np.all(np.abs(np.array(estimator["accel"]) - truth) < 0.6 * MG), (estimator, truth)
        else:
            assert "no estimator_sensor_bias topic" in estimator["reason"]
        other = DEVICES[1 - row.imu]
        assert agreement["against"] == f"IMU {2 - row.imu} (device {other})"
        moved = STEP_MG * truths[1].matrix[2, 2] * (1 if row.imu == 1 else -1)
        expected = moved if row.path.endswith("flight_2.ulg") else 0.0
        assert abs(agreement["accel"][2] / MG - expected) < 0.3, (row.path, row.imu, agreement)
    assert "vehicle uavA IMU 2 (device 1442060): cannot tell: 3 flights with evidence" in out
    assert np.isfinite([r.z_sigma_mps2 for r in good]).all()
