"""Evidence from ordinary flight logs: the still moments on the ground before arming and after landing,
checked against the calibration in force read from the log itself, per IMU by its device. Simulated logs
in the real formats with known truth: the IMU whose calibration in force is its truth holds within its
sigma, the one whose z offset in force is 5 mg off reads 5 mg (times its z scale) on the z axis, named as
what level ground sees: the z bias and z scale together, nothing of x or y."""
from __future__ import annotations

import pytest
from scipy.spatial.transform import Rotation

from accel_calibration.bag.flight_evidence import Z_GROUP, log_evidence

from helpers.flight_logs import (
    DEVICES,
    MG,
    InForce,
    fly,
    sensors,
    true_in_force,
    write_dataflash_flight,
    write_ulog_flight,
)

OFF_MG = 5.0


@pytest.fixture(scope="module")
def flight():
    truths = sensors(11)
    in_force = [true_in_force(t) for t in truths]
    in_force[1] = InForce(in_force[1].offset - [0.0, 0.0, OFF_MG * MG], in_force[1].scale)
    return truths, in_force, fly(truths, 12)


@pytest.mark.parametrize("suffix, write", [("ulg", write_ulog_flight), ("bin", write_dataflash_flight)])
def test_ground_moments_check_each_imus_calibration_in_force(flight, tmp_path, suffix, write):
    truths, in_force, log = flight
    path = tmp_path / f"flight.{suffix}"
    write(path, log, in_force)
    held, off = log_evidence(str(path))
    assert (held.device, off.device) == tuple(str(d) for d in DEVICES)
    for evidence in (held, off):
        assert evidence.reason is None and evidence.poses >= 1
        # Level ground: the z bias and z scale together, never x or y (their effect on |a| is second order).
        assert [name for name, _, _ in evidence.changes] == [Z_GROUP]
    z, sigma = held.z
    assert abs(z) < 5 * sigma + 0.05 * MG and sigma < 0.1 * MG
    assert held.verdict == "cannot tell"  # nothing moved, and x, y not observed from level ground
    z, sigma = off.z
    expected = OFF_MG * MG * truths[1].matrix[2, 2]  # the raw z reads 5 mg more, scaled by the z gain in force
    assert abs(z - expected) < 0.1 * MG and abs(z) / sigma > 50
    assert off.verdict == "moved"


def test_parked_tilted_the_ground_moments_see_more_than_z(tmp_path):
    truths = sensors(21)
    in_force = [true_in_force(t) for t in truths]
    in_force[0] = InForce(in_force[0].offset + [0.0, 3 * MG, 0.0], in_force[0].scale)
    log = fly(truths, 22, parked=Rotation.from_euler("x", 30, degrees=True))
    path = tmp_path / "tilted.ulg"
    write_ulog_flight(path, log, in_force)
    tilted, _ = log_evidence(str(path))
    names = [name for name, _, _ in tilted.changes]
    # One attitude sees one combination: now of the y bias too (tilted about x), named with the z terms.
    assert names == ["bias y, bias z or scale z"]
    assert tilted.verdict == "moved"


def test_a_log_without_evidence_says_why(tmp_path):
    csv = tmp_path / "imu.csv"
    csv.write_text("t_ns,ax,ay,az\n0,0,0,9.8\n10000000,0,0,9.8\n")
    (evidence,) = log_evidence(str(csv))
    assert evidence.verdict == "none" and "not an autopilot log" in evidence.reason
    broken = tmp_path / "broken.ulg"
    broken.write_bytes(b"ULog\x01\x12\x35\x01" + b"\0" * 20)
    (evidence,) = log_evidence(str(broken))
    assert evidence.verdict == "none" and str(broken.name) in evidence.reason


@pytest.mark.parametrize("relative, devices, reason", [
    ("real/px4_ulog/sample.ulg", [""], "the log holds no calibration of this IMU"),
    ("real/px4_ulog/sample_logging_tagged_and_default_params.ulg", ["1310988", "1310996", "1311004"],
     "no still moment on the ground"),
    ("real/ardupilot/test.BIN", ["1246730", "1442826"], "no flight state in the log"),
])
def test_every_imu_of_the_real_logs_gets_its_evidence_or_the_reason(shared, relative, devices, reason):
    found = log_evidence(str(shared(relative)))
    assert [e.device for e in found] == devices
    assert all(e.verdict == "none" and reason in e.reason for e in found)
