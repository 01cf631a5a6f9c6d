"""Flight evidence from ordinary flights recorded as rosbag2 (sqlite3, mcap): the still moments on the ground
(the bag's flight state keeps the flight out) checked against a calibration file given, else against the
nominal sensor, each named in the row; a bag without a flight state says its moments are the detector's."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.bag.flight_evidence import Z_GROUP
from accel_calibration.bag.flight_evidence_bag import NO_FLIGHT_STATE, NOMINAL, GivenCalibration
from accel_calibration.bag.flight_evidence_bag import bag_evidence as evidence_of
from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.core.calibration import Calibration
from msg_tools.synthetic_imu import SensorErrors

from helpers.flight_logs import MG, fly, sensors
from helpers.imu_bags import write_imu_bag

STEP_MG = 5.0


def flight_bag(path, truth: SensorErrors, seed: int, storage: str, with_state: bool = True):
    """IMU 0 of a simulated flight (still, armed, a flight of turns and vibration, landed, still) as its raw
    output on /imu/data_raw, the arming state on /armed (std_msgs/Bool)."""
    flight = fly([truth, truth], seed)
    t_ns = flight.t_us * 1000
    armed = None
    if with_state:
        stamps = t_ns[::100]
        armed = (stamps, (stamps >= flight.arm_us * 1000) & (stamps < flight.disarm_us * 1000))
    write_imu_bag(path, t_ns, flight.raw[0], flight.gyro, storage, armed=armed)
    return path


def calibration_of(truth: SensorErrors) -> GivenCalibration:
    return GivenCalibration(Calibration(bias=np.array(truth.bias_mps2, float), matrix=np.array(truth.matrix, float),
                                        model="six"), "truth.yaml")


def stepped(truth: SensorErrors) -> SensorErrors:
    return SensorErrors(bias_mps2=truth.bias_mps2 + [0.0, 0.0, STEP_MG * MG], matrix=truth.matrix)


ARMED = ReplaySettings(armed_topic="/armed")


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_bag_flight_is_checked_against_the_calibration_given(tmp_path, storage):
    truth = sensors(61)[0]
    held = evidence_of(replay_bag(flight_bag(tmp_path / "held", truth, 1, storage), ARMED), calibration_of(truth))
    moved = evidence_of(replay_bag(flight_bag(tmp_path / "moved", stepped(truth), 2, storage), ARMED),
                        calibration_of(truth))
    for evidence in (held, moved):
        assert evidence.verdict != "none" and evidence.poses >= 1 and evidence.reason is None
        assert evidence.in_force == "truth.yaml (calibration file)"
        assert [name for name, _, _ in evidence.changes] == [Z_GROUP]  # level ground: nothing of x or y
    assert abs(held.z[0]) < 0.1 * MG, held.z[0] / MG
    assert abs(moved.z[0] - STEP_MG * MG * truth.matrix[2, 2]) < 0.1 * MG, moved.z[0] / MG
    assert moved.verdict == "moved" and held.verdict != "moved"  # level ground cannot see x, y: not "holds"


def test_without_a_calibration_a_bag_is_checked_against_the_nominal_sensor(tmp_path):
    """The raw stream against no bias and unit gains: its own offset from 1 g, whose change over flights is
    what moved (5 mg of raw z bias reads 5 mg more)."""
    truth = sensors(62)[0]
    before = evidence_of(replay_bag(flight_bag(tmp_path / "before", truth, 3, "mcap"), ARMED))
    after = evidence_of(replay_bag(flight_bag(tmp_path / "after", stepped(truth), 4, "mcap"), ARMED))
    assert before.in_force == after.in_force == NOMINAL
    level_raw_mg = (np.linalg.norm(truth.raw_from_true([0.0, 0.0, 9.80665])) - 9.80665) / MG
    assert abs(before.z[0] / MG - level_raw_mg) < 0.1, (before.z[0] / MG, level_raw_mg)
    assert abs((after.z[0] - before.z[0]) / MG - STEP_MG) < 0.1


def test_a_bag_without_a_flight_state_says_its_moments_are_the_detectors(tmp_path):
    truth = sensors(63)[0]
    evidence = evidence_of(replay_bag(flight_bag(tmp_path / "bare", truth, 5, "sqlite3", with_state=False)),
                           calibration_of(truth))
    assert evidence.verdict != "none" and evidence.poses >= 1
    assert evidence.reason is not None and NO_FLIGHT_STATE in evidence.reason
    assert abs(evidence.z[0]) < 0.1 * MG
