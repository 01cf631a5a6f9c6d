"""A flight recorded as a rosbag2 (sqlite3, mcap) gets in-flight evidence as an autopilot log does: the
agreement of its replayed Imu topic with the bag's other Imu topics (per second in flight, after the rotation
between them), and the settled bias of PX4's filter where the bag records /fmu/out/estimator_sensor_bias
(decoded with the definition the bag records); each its reason where the bag gives none. Simulated flights
with known truth."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.bag.flight_evidence_bag import GivenCalibration, bag_evidence
from accel_calibration.bag.replay import ReplaySettings, replay_bag
from accel_calibration.core.calibration import Calibration
from msg_tools.synthetic_imu import SensorErrors

from helpers.flight_bags import write_flight_bag
from helpers.flight_logs import ALL_DEVICES, MG, FilterBias, fly, sensors

OFF_MG = 5.0
FILTER_BIAS = FilterBias(np.array([1.5, -2.5, 3.5]) * MG, np.array([1e-3, -2e-3, 5e-4]))
TOPICS = ("/imu0", "/imu1", "/imu2")


def in_force(truth: SensorErrors) -> Calibration:
    return Calibration(bias=np.array(truth.bias_mps2, float), matrix=np.array(truth.matrix, float), model="six")


def moved(truth: SensorErrors) -> SensorErrors:
    return SensorErrors(bias_mps2=truth.bias_mps2 + [0.0, 0.0, OFF_MG * MG], matrix=truth.matrix)


def evidence(path, topic: str, given: Calibration | None = None):
    replay = replay_bag(path, ReplaySettings(imu_topic=topic))
    return bag_evidence(replay, None if given is None else GivenCalibration(given, "truth.yaml"))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_the_imu_off_on_z_disagrees_with_its_siblings_by_its_offset(tmp_path, storage):
    """/imu1's raw z bias 5 mg up, its calibration in force (given) as before; /imu0 raw with its own given,
    /imu2 recorded corrected: /imu1 reads 5 mg x its z gain against them, /imu0 agrees with /imu2."""
    truths = sensors(91, 3)
    flight = fly([truths[0], moved(truths[1]), truths[2]], 92)
    streams = {TOPICS[0]: flight.raw[0], TOPICS[1]: flight.raw[1], TOPICS[2]: in_force(truths[2]).apply(flight.raw[2])}
    path = write_flight_bag(tmp_path / "three", flight, streams, storage)
    drifted = evidence(path, TOPICS[1], in_force(truths[1])).agreement
    assert drifted is not None and "reason" not in drifted, drifted
    assert abs(drifted["accel"][2] / MG - OFF_MG * truths[1].matrix[2, 2]) < 0.3, drifted
    assert drifted["siblings"] == 2 and drifted["against"] in (TOPICS[0], TOPICS[2])
    assert drifted["in_force"] == "/imu1 truth.yaml (calibration file); its siblings as recorded"
    steady = evidence(path, TOPICS[0], in_force(truths[0])).agreement
    assert steady["against"] == TOPICS[2] and np.all(np.abs(steady["accel"]) < 0.2 * MG), steady


def test_steady_imus_agree_within_their_noise(tmp_path):
    truths = sensors(93, 2)
    flight = fly(truths, 94)
    streams = {topic: in_force(t).apply(raw) for topic, t, raw in zip(TOPICS, truths, flight.raw)}
    path = write_flight_bag(tmp_path / "two.mcap", flight, streams, "mcap")
    for topic in TOPICS[:2]:
        said = evidence(path, topic).agreement
        assert said["siblings"] == 1 and said["seconds"] >= 10
        assert np.all(np.abs(said["accel"]) < 3 * np.array(said["accel_sigma"]) + 0.05 * MG), said
        assert np.all(np.abs(said["gyro"]) < 1e-4), said  # one gyro recorded on both topics
        assert said["in_force"] == f"{topic} as recorded; its siblings as recorded"


def test_one_imu_topic_has_no_sibling_and_no_flight_state_says_so(tmp_path):
    truth = sensors(95, 1)
    flight = fly(truth, 96)
    alone = write_flight_bag(tmp_path / "alone", flight, {"/imu": flight.raw[0]}, "sqlite3")
    said = evidence(alone, "/imu")
    assert said.agreement == {"reason": "alone: the bag records one Imu topic (/imu): no sibling to compare with"}
    two = fly(sensors(97, 2), 98)
    bare = write_flight_bag(tmp_path / "bare.mcap", two, {TOPICS[0]: two.raw[0], TOPICS[1]: two.raw[1]}, "mcap",
                            with_state=False)
    said = evidence(bare, TOPICS[0])
    reason = "bare.mcap: no flight state in the bag: the flight cannot be told from the ground"
    assert said.agreement == said.estimator == {"reason": reason}
    assert said.verdict != "none"  # the ground's evidence stays (the detector's moments, said in its reason)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_the_filters_settled_bias_is_read_from_estimator_sensor_bias(tmp_path, storage):
    truths = sensors(99, 1)
    flight = fly(truths, 100)
    path = write_flight_bag(tmp_path / "px4", flight, {"/imu": flight.raw[0]}, storage,
                            estimator=(FILTER_BIAS, ALL_DEVICES[0]), seed=7)
    said = evidence(path, "/imu").estimator
    assert said["source"] == "PX4 estimator_sensor_bias" and said["device"] == ALL_DEVICES[0], said
    assert said["topic"] == "/fmu/out/estimator_sensor_bias"
    assert np.all(np.abs(np.array(said["accel"]) - FILTER_BIAS.accel_mps2) < 0.1 * MG), said
    assert np.all(np.abs(np.array(said["gyro"]) - FILTER_BIAS.gyro_radps) < 5e-5), said
    assert np.all(np.array(said["accel_sigma"]) < 0.3 * MG)


def test_a_bag_without_estimator_sensor_bias_says_why(tmp_path):
    flight = fly(sensors(101, 1), 102)
    path = write_flight_bag(tmp_path / "plain.mcap", flight, {"/imu": flight.raw[0]}, "mcap")
    said = evidence(path, "/imu").estimator
    assert said == {"reason": "plain.mcap: the bag records no estimator_sensor_bias (the filter's bias estimates: "
                              "px4_msgs/msg/EstimatorSensorBias, e.g. /fmu/out/estimator_sensor_bias)"}


def test_a_bag_without_the_definition_of_estimator_sensor_bias_says_so(tmp_path):
    """A sqlite3 bag from before Iron records no message definitions: px4_msgs cannot be decoded here."""
    import sqlite3

    flight = fly(sensors(103, 1), 104)
    path = write_flight_bag(tmp_path / "old", flight, {"/imu": flight.raw[0]}, "sqlite3",
                            estimator=(FILTER_BIAS, ALL_DEVICES[0]))
    connection = sqlite3.connect(next(path.glob("*.db3")))
    try:
        connection.execute("DELETE FROM message_definitions WHERE topic_type = 'px4_msgs/msg/EstimatorSensorBias'")
        connection.commit()
    finally:
        connection.close()
    said = evidence(path, "/imu").estimator
    assert said["reason"].startswith("old: cannot decode /fmu/out/estimator_sensor_bias "
                                     "(px4_msgs/msg/EstimatorSensorBias) with the definitions recorded in the bag")
