"""What a flight log says of each IMU in flight: the autopilot filter's own settled bias (PX4
estimator_sensor_bias per device, ArduPilot EKF3 XKF2/XKF1 and EKF2 NKF2/NKF1 per core) in SI units, and each
IMU's agreement with its siblings after the rotation between them. Simulated logs in the real formats with
known truth; the real logs give each IMU its values or the reason none can be had."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from accel_calibration.bag.flight_evidence import log_evidence
from accel_calibration.bag.imu_agreement import agreement, flight_means
from msg_tools.synthetic_imu import SensorErrors

from helpers.flight_logs import (
    ALL_DEVICES,
    MG,
    FilterBias,
    fly,
    sensors,
    true_in_force,
    write_dataflash_flight,
    write_ulog_flight,
)

ACCEL_BIAS_MG = np.array([[1.5, -2.5, 3.5], [-0.7, 0.4, 6.0]])
GYRO_BIAS_RADPS = np.array([[1e-3, -2e-3, 5e-4], [-4e-4, 3e-4, 2e-3]])
OFF_MG = 5.0


@pytest.fixture(scope="module")
def flown():
    truths = sensors(61)
    biases = [FilterBias(a * MG, g) for a, g in zip(ACCEL_BIAS_MG, GYRO_BIAS_RADPS)]
    return truths, [true_in_force(t) for t in truths], fly(truths, 62), biases


@pytest.mark.parametrize("suffix, write, ekf, old_style", [
    ("ulg", write_ulog_flight, None, False), ("bin", write_dataflash_flight, 3, False),
    ("bin", write_dataflash_flight, 2, False), ("bin", write_dataflash_flight, 3, True),
    ("bin", write_dataflash_flight, 2, True)])
def test_the_filters_settled_bias_is_read_per_imu_in_si_units(flown, tmp_path, suffix, write, ekf, old_style):
    truths, in_force, log, biases = flown
    path = tmp_path / f"flight.{suffix}"
    write(path, log, in_force, biases, 7, **({} if ekf is None else {"ekf": ekf, "old_style": old_style}))
    found = log_evidence(str(path))
    assert [e.device for e in found] == [str(d) for d in ALL_DEVICES[:2]]
    resolution_mg = 0.0 if suffix == "ulg" else 1.02  # ArduPilot logs 100 x m/s^2 as an integer
    for k, evidence in enumerate(found):
        said = evidence.estimator
        accel = np.array([np.nan if v is None else v for v in said["accel"]]) / MG
        if ekf == 2:  # EKF2 learns the z bias alone: x and y are not known, not zero
            assert np.isnan(accel[:2]).all() and said["source"].startswith("ArduPilot EKF2 NKF")
            accel, truth = accel[2:], ACCEL_BIAS_MG[k, 2:]
        else:
            truth = ACCEL_BIAS_MG[k]
        # The settled value: the ground and the filter's first seconds left out (it starts at 0).
        assert np.all(np.abs(accel - truth) < 0.1 + resolution_mg / 2), (accel, truth)
        sigma = np.array([v for v in said["accel_sigma"] if v is not None]) / MG
        assert np.all(sigma < 0.3 + resolution_mg / 2)  # the wander, the resolution where it is coarse
        gyro = np.array(said["gyro"])
        assert np.all(np.abs(gyro - GYRO_BIAS_RADPS[k]) < 5e-5 + (np.radians(0.01) if suffix == "bin" else 0.0))


def test_an_imu_that_disagrees_is_named_and_its_siblings_agree(tmp_path):
    truths = sensors(71, 3)
    in_force = [true_in_force(t) for t in truths]
    moved = SensorErrors(bias_mps2=truths[1].bias_mps2 + [0.0, 0.0, OFF_MG * MG], matrix=truths[1].matrix)
    path = tmp_path / "three.ulg"
    write_ulog_flight(path, fly([truths[0], moved, truths[2]], 72), in_force)
    found = log_evidence(str(path))
    by_device = {e.device: e.agreement for e in found}
    drifted = by_device[str(ALL_DEVICES[1])]
    # Its z reads 5 mg high through its z gain; the rotation fit cannot take a difference along the force.
    assert abs(drifted["accel"][2] / MG - OFF_MG * truths[1].matrix[2, 2]) < 0.3
    assert drifted["siblings"] == 2
    for device in (ALL_DEVICES[0], ALL_DEVICES[2]):
        sibling = by_device[str(device)]
        assert abs(sibling["accel"][2]) / MG < 0.2 and sibling["against"] != f"IMU 2 (device {ALL_DEVICES[1]})"


def test_gyros_are_compared_after_their_calibration_in_force(tmp_path):
    """Each gyro's own output off by its CAL_GYROn offset (0.5 deg/s apart), the offsets in force: they agree."""
    truths = sensors(81)
    offsets = [np.radians([0.5, -0.3, 0.2]), np.radians([-0.2, 0.4, -0.3])]
    path = tmp_path / "gyros.ulg"
    write_ulog_flight(path, fly(truths, 82), [true_in_force(t) for t in truths], gyro_offsets=offsets)
    for evidence in log_evidence(str(path)):
        assert np.all(np.abs(evidence.agreement["gyro"]) < np.radians(0.005)), evidence.agreement


def test_agreement_sees_a_gyro_offset_after_the_rotation_between_imus():
    rng = np.random.default_rng(5)
    t_ns = np.arange(60_000) * 2_000_000  # 2 min at 500 Hz, all in flight
    from scipy.spatial.transform import Rotation

    attitude = Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.002, (len(t_ns), 3)), axis=0))
    force = attitude.inv().apply([0.0, 0.0, 9.80665]) + rng.normal(0, 0.3, (len(t_ns), 3))
    rate = rng.normal(0, 0.2, (len(t_ns), 3))
    mounted = Rotation.from_euler("z", 90, degrees=True)  # the second IMU turned a quarter about z
    flying = np.ones(len(t_ns), dtype=bool)
    offset = np.array([0.0, 0.0, 0.002])
    imus = {0: flight_means("IMU 1", t_ns, force, rate, flying),
            1: flight_means("IMU 2", t_ns, mounted.apply(force), mounted.apply(rate) + offset, flying)}
    said = agreement(imus)
    second = said[1]
    assert not isinstance(second, str) and second.gyro_radps is not None
    assert np.allclose(second.gyro_radps, offset, atol=3e-4)
    assert np.allclose(second.accel_mps2, 0.0, atol=0.3 * MG)


@pytest.mark.parametrize("relative, reason", [
    ("real/px4_ulog/sample.ulg", "no flight in the log (the vehicle was never armed or airborne)"),
    ("real/px4_ulog/sample_logging_tagged_and_default_params.ulg",
     "no flight in the log (the vehicle was never armed or airborne)"),
    ("real/ardupilot/test.BIN", "no flight state in the log"),
])
def test_every_imu_of_the_real_logs_gets_its_in_flight_evidence_or_the_reason(shared, relative, reason):
    found = log_evidence(str(shared(relative)))
    assert found
    for evidence in found:
        assert reason in evidence.estimator["reason"] and reason in evidence.agreement["reason"]


@settings(max_examples=15, deadline=None)
@given(moved=st.integers(0, 2), offset_mg=st.floats(2.0, 10.0), sign=st.sampled_from([-1.0, 1.0]),
       mounts=st.lists(st.tuples(*[st.floats(-0.05, 0.05)] * 3), min_size=3, max_size=3), seed=st.integers(0, 99))
def test_of_three_imus_the_one_offset_along_the_force_is_the_one_that_disagrees(moved, offset_mg, sign, mounts, seed):
    """Whatever each IMU's small mounting rotation, one IMU's z offset shows on it alone: it differs from
    both siblings by the offset, and they agree with each other. Tilted in flight, the part of the offset
    across the force is taken as a tilt by the rotation fit (at 10 degrees, up to 1 - cos 10 deg of it)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t_ns = np.arange(12_000) * 10_000_000  # 2 min at 100 Hz
    seconds = t_ns[:, None] / 1e9  # turns of up to 10 degrees about every axis, as a multirotor flies
    attitude = Rotation.from_euler("xyz", np.radians(10.0) * np.sin(2 * np.pi * rng.uniform(0.05, 0.3, 3) * seconds
                                                                    + rng.uniform(0, 2 * np.pi, 3)))
    force = attitude.inv().apply([0.0, 0.0, 9.80665]) + rng.normal(0, 0.3, (len(t_ns), 3))
    flying = np.ones(len(t_ns), dtype=bool)
    imus = {}
    for k, mount in enumerate(mounts):
        accel = Rotation.from_rotvec(mount).apply(force) + rng.normal(0, 0.01, force.shape)
        accel[:, 2] += sign * offset_mg * MG * (k == moved)
        imus[k] = flight_means(f"IMU {k + 1}", t_ns, accel, None, flying)
    said = agreement(imus)
    for k, found in said.items():
        assert not isinstance(found, str)
        if k == moved:
            assert abs(found.accel_mps2[2] / MG - sign * offset_mg) < 0.3 + 0.03 * offset_mg
        else:
            assert abs(found.accel_mps2[2]) / MG < 0.3 and found.against != f"IMU {moved + 1}"


def test_the_real_ardupilot_logs_filter_records_read_per_core(shared):
    """test.BIN (ArduPilot before 4.1: EKF2's cores in NKF1/NKF2 and NKF6/NKF7, no core field) logs no flight
    state; taken whole as one flight, each of its two IMUs gets the z bias and gyro bias its core learnt,
    magnitudes a MEMS part has (|z| < 0.5 m/s^2, gyro < 1 deg/s), x and y of the accel unknown (EKF2)."""
    from accel_calibration.bag.estimator_bias import ardupilot_biases
    from accel_calibration.core.flight_state import EARLIEST, LATEST, FlightState

    whole = FlightState(np.array([[EARLIEST, LATEST]], dtype=np.int64), ("the whole log",))
    found = ardupilot_biases(str(shared("real/ardupilot/test.BIN")), whole)
    assert not isinstance(found, str) and sorted(found) == [0, 1]
    for core, bias in found.items():
        assert bias.source == f"ArduPilot EKF2 NKF{2 + 5 * core}/NKF{1 + 5 * core} core {core}"
        assert bias.accel_mps2 is not None and np.isnan(bias.accel_mps2[:2]).all()
        assert 0.0 < abs(bias.accel_mps2[2]) < 0.5
        assert bias.gyro_radps is not None and np.all(np.abs(bias.gyro_radps) < np.radians(1.0))


def test_a_log_whose_flight_cannot_be_read_gives_every_imu_that_reason(tmp_path, monkeypatch):
    """Not "no IMU instance of this device" for the IMUs after the first: the one reason the log gave."""
    import accel_calibration.bag.in_flight_evidence as in_flight
    from accel_calibration.bag.dataflash import DataflashError

    truths = sensors(64)
    path = tmp_path / "flight.bin"
    write_dataflash_flight(path, fly(truths, 64), [true_in_force(t) for t in truths])

    def unreadable(where):
        raise DataflashError(f"{where}: damaged DataFlash log: the flight's records cannot be read")

    monkeypatch.setattr(in_flight, "_dataflash_flight_means", unreadable)
    in_flight._log_wide.cache_clear()
    found = log_evidence(str(path))
    assert len(found) == 2
    for evidence in found:
        assert evidence.estimator == evidence.agreement
        assert "the flight's records cannot be read" in evidence.estimator["reason"]
