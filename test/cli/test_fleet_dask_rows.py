"""`fleet` on a real Dask LocalCluster of 2 workers: flight logs (PX4 ULog), a damaged one among them, and
ordinary flights recorded as rosbag2 (sqlite3, mcap, with mavros's /mavros/state): every IMU a row of
evidence, the damaged log a failed row with its reason, a rerun updating the same rows."""
from __future__ import annotations

import numpy as np

from accel_calibration.cli.main import main
from accel_calibration.core.calibration import Calibration
from accel_calibration.io.calibration_file import calibration_to_yaml
from accel_calibration.io.history import open_history

from helpers.flight_logs import DEVICES, MG, fly, sensors, true_in_force, write_ulog_flight
from helpers.imu_bags import write_imu_bag


def write_fleet(root):
    truths = sensors(71)
    (root / "uavA").mkdir(parents=True)
    (root / "uavB").mkdir()
    for i in range(2):
        write_ulog_flight(root / "uavA" / f"log_{i}.ulg", fly(truths, 70 + i), [true_in_force(t) for t in truths])
    (root / "uavA" / "log_9.ulg").write_bytes(b"ULog\x01\x12\x35\x01" + b"\0" * 40)  # damaged
    for i, storage in enumerate(("sqlite3", "mcap")):
        flight = fly(truths, 80 + i)
        t_ns = flight.t_us * 1000
        stamps = t_ns[::100]
        armed = (stamps, (stamps >= flight.arm_us * 1000) & (stamps < flight.disarm_us * 1000))
        write_imu_bag(root / "uavB" / f"flight_{i}", t_ns, flight.raw[0], flight.gyro, storage, armed=armed,
                      mavros=True)
    return truths


def test_a_failed_log_is_a_row_and_a_rerun_updates_the_same_rows_on_two_workers(tmp_path, capsys):
    truths = write_fleet(tmp_path / "logs")
    calibration = tmp_path / "uavB.yaml"
    calibration.write_text(calibration_to_yaml(Calibration(bias=np.array(truths[0].bias_mps2, float),
                                                           matrix=np.array(truths[0].matrix, float), model="six")))
    target = str(tmp_path / "fleet.sqlite")
    seen = []
    for _ in range(2):  # the rerun updates the same rows
        assert main(["fleet", str(tmp_path / "logs"), "--history", target, "--workers", "2",
                     "--calibration", str(calibration)]) == 1
        assert "flight evidence: 7 IMU rows, 6 with evidence" in capsys.readouterr().out
        with open_history(target) as history:
            seen.append((sorted(r.recording_id for r in history.evidence()), len(history.records())))
    assert seen[0] == seen[1] and len(seen[0][0]) == 7
    with open_history(target) as history:
        rows = history.evidence()
    failed = [r for r in rows if r.status == "failed"]
    assert len(failed) == 1 and "log_9.ulg" in failed[0].reason and failed[0].vehicle == "uavA"
    logs = sorted((r.vehicle, r.device) for r in rows if r.status == "evidence" and r.path.endswith(".ulg"))
    assert logs == sorted([("uavA", str(d)) for d in DEVICES] * 2)
    bags = [r for r in rows if r.vehicle == "uavB"]
    assert len(bags) == 2 and all(r.status == "evidence" for r in bags)
    for row in bags:  # the calibration given is the truth: it holds, within 0.1 mg
        assert row.in_force.endswith("uavB.yaml (calibration file)") and abs(row.z_mps2) < 0.1 * MG


def test_a_log_whose_worker_died_is_a_failed_row_keyed_as_its_reading_would_be(tmp_path):
    """A worker lost (killed, out of memory) on a log: the command identifies the log itself, so the row is the
    one a later run that reads it updates."""
    from accel_calibration.cli.fleet import calibrate_recording, lost_recording

    truths = sensors(72)
    log = tmp_path / "uavC" / "log_0.ulg"
    log.parent.mkdir()
    write_ulog_flight(log, fly(truths, 90), [true_in_force(t) for t in truths])
    lost = lost_recording(str(log), f"{log}: worker lost (KilledWorker: ...)", None)
    read = calibrate_recording(str(log))
    assert lost.status == "failed" and "worker lost" in lost.reason
    assert lost.record.recording_id == read.record.recording_id and lost.record.vehicle == "uavC"
    assert lost.evidence.status == "failed" and lost.evidence.recording_id == read.evidence.recording_id
