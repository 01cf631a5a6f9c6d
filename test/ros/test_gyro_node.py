"""The node calibrates the gyro too: after /calibrate, a rotation at 2 rad/s about each axis
comes out of imu/data_calibrated within 0.1 % of the truth. In this process (the node's callbacks called
in order, what it publishes captured) and over DDS (the console script, closed-loop playback)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter

from accel_calibration.io.calibration_file import load_calibration
from msg_tools.conversions import make_imu
from msg_tools.synthetic_motion import GyroTruth, simulate_session

START_NS = 1_700_000_000 * 10**9
RATE_RADPS = 2.0


@dataclass
class Played:
    """A MotionSession in the shape CalibrationClient.play takes."""

    t_ns: np.ndarray
    accel_raw: np.ndarray
    gyro_raw: np.ndarray
    temperature_degc: np.ndarray


def hand_turned(seed: int = 11):
    rng = np.random.default_rng(seed)
    truth = GyroTruth.random(rng)
    sim = simulate_session(rng, poses=16, rate_hz=200.0, gyro=truth)
    t = sim.stamps_ns - sim.stamps_ns[0]
    return truth, Played(t, sim.accel_mps2, sim.gyro_radps, np.full(len(t), 25.0))


def turns(truth: GyroTruth) -> tuple[np.ndarray, np.ndarray]:
    """Raw rates of a turn at 2 rad/s about each true axis (noise-free: the calibration alone is judged)."""
    true = RATE_RADPS * np.eye(3)
    raw = np.linalg.solve(truth.matrix, true.T).T + truth.bias_radps
    return true, raw


def assert_within_a_thousandth(published_rates: np.ndarray, true: np.ndarray) -> None:
    error = np.abs(published_rates - true).max(axis=1) / RATE_RADPS
    assert np.all(error < 1e-3), error
    # Without the gyro matrix (its bias alone), the 1-3 % scale would show: the matrix is what did it.


def test_in_process_the_node_calibrates_the_gyro_at_calibrate(ros, tmp_path):
    from accel_calibration.ros.node import CalibrationNode

    truth, played = hand_turned()
    node = CalibrationNode(parameter_overrides=[Parameter("calibration_file", value=str(tmp_path / "cal.yaml"))])
    published = []
    node._publisher.publish = published.append
    try:
        for i, t in enumerate(played.t_ns.tolist()):
            node._imu.take(make_imu(START_NS + t, played.accel_raw[i], played.gyro_raw[i]))
        success, message = node._worker.submit("calibrate").result(timeout=120)
        assert success, message
        summary = yaml.safe_load(message)
        assert summary["gyro"]["applied"] is True and summary["gyro"]["motions"] >= 12, summary
        assert load_calibration(tmp_path / "cal.yaml").gyro_matrix is not None  # saved with it
        true, raw = turns(truth)
        published.clear()
        for k in range(3):
            node._imu.take(make_imu(START_NS + int(200e9) + k * 5_000_000, played.accel_raw[0], raw[k]))
        rates = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in published])
        assert_within_a_thousandth(rates, true)
        bias_only = raw - truth.bias_radps
        assert np.abs(bias_only - true).max() / RATE_RADPS > 5e-3  # what the bias alone would have given
    finally:
        node.close()
        node.destroy_node()


@pytest.mark.ros
def test_over_dds_the_node_calibrates_the_gyro_at_calibrate(tmp_path, tester):
    from msg_tools.node_process import NodeProcess

    truth, played = hand_turned()
    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        sent = tester.play(played, start_ns=START_NS, temperature=False)
        assert tester.settle(sent)
        answer = tester.call("calibrate")
        assert answer.success, answer.message
        assert yaml.safe_load(answer.message)["gyro"]["applied"] is True, answer.message
        true, raw = turns(truth)
        tester.corrected.clear()
        turn = Played(np.arange(3) * 5_000_000 + int(200e9), np.repeat(played.accel_raw[:1], 3, axis=0), raw,
                      np.full(3, 25.0))
        tester.play(turn, start_ns=START_NS, temperature=False)
        assert tester.settle(3)
        in_order = sorted(tester.corrected, key=lambda m: (m.header.stamp.sec, m.header.stamp.nanosec))
        rates = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in in_order])
        assert_within_a_thousandth(rates[-3:], true)
        # The corrected stream's angular_velocity_covariance carries the measured gyro noise (REP-145).
        cov = np.array(tester.corrected[-1].angular_velocity_covariance).reshape(3, 3)
        assert np.all(np.diag(cov) > 0)
    finally:
        assert node.stop() == 0, node.log()
