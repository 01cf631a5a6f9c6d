"""One correction: a corrected copy of a recording is what the node publishes for the same messages
(acceleration, gyro bias and matrix, and both covariances alike), bit for bit, on any CPU (no BLAS in the
correction). The node runs in this process (a real rclpy node; its callbacks called in the recording's order, what it
publishes captured), so no message can be lost and no timing decides anything."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.parameter import Parameter

from accel_calibration.bag.corrected_copy import write_corrected_bag
from accel_calibration.bag.recording import open_recording
from accel_calibration.bag.replay import replay_bag
from accel_calibration.core.calibration import Calibration
from accel_calibration.core.correction import Correction
from accel_calibration.io.calibration_file import save_calibration
from msg_tools.bag_writer import write_session_bag
from msg_tools.conversions import make_imu, make_temperature
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers.sensors import calibration_with_drift

START_NS = 1_700_000_000 * 10**9
COVARIANCE = np.diag([1.6e-3, 1.6e-3, 1.6e-3]).ravel()  # what the driver reports, (m/s^2)^2
GYRO_COVARIANCE = np.diag([3e-6, 3e-6, 3e-6]).ravel()  # (rad/s)^2


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    rng = np.random.default_rng(8)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    samples = SyntheticImu(errors, spread_orientations(6, rng), dwell_s=1.0, move_s=0.5, rate_hz=200.0, seed=8,
                           temperature_degc=lambda t: 20.0 + 0.4 * t).samples()
    bag = tmp_path_factory.mktemp("one_correction") / "bag"
    write_session_bag(bag, samples, start_ns=START_NS, storage="mcap", accel_covariance=COVARIANCE,
                      gyro_covariance=GYRO_COVARIANCE)
    return samples, bag


def test_a_corrected_bag_is_what_the_node_publishes(ros, recording, tmp_path):
    from accel_calibration.ros.node import CalibrationNode

    samples, bag = recording
    calibration = calibration_with_drift()
    save_calibration(calibration, tmp_path / "cal.yaml")
    node = CalibrationNode(parameter_overrides=[Parameter("calibration_file", value=str(tmp_path / "cal.yaml"))])
    published = []
    node._publisher.publish = published.append  # what the node would send, in order
    try:
        # The recording's messages in its log order (a reading before the samples at its stamp).
        next_reading = -1
        for i, t in enumerate(samples.t_ns.tolist()):
            if t >= next_reading:
                node._on_temperature(make_temperature(START_NS + t, float(samples.temperature_degc[i])))
                next_reading = t + 100_000_000
            node._imu.take(make_imu(START_NS + t, samples.accel_raw[i], samples.gyro_raw[i],  # as recorded
                                  accel_cov=COVARIANCE, gyro_cov=GYRO_COVARIANCE))
    finally:
        node.close()
        node.destroy_node()
    replay = replay_bag(bag)
    write_corrected_bag(replay, calibration, tmp_path / "copy")
    copy = open_recording(tmp_path / "copy", through_rosbags=True)
    node_accel = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                           for m in published])
    node_gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in published])
    assert len(published) == len(copy.t_ns) == len(samples.t_ns)
    np.testing.assert_array_equal(copy.accel_mps2, node_accel)
    np.testing.assert_array_equal(copy.gyro_radps, node_gyro)
    # The drift moved the samples (the temperature took part), and the gyro bias and matrix were applied.
    assert np.abs(node_accel - calibration.replace(temperature=None).apply(samples.accel_raw)).max() > 1e-3
    np.testing.assert_allclose(node_gyro, calibration.apply_gyro(samples.gyro_raw), rtol=0, atol=1e-14)
    assert np.abs(node_gyro - (samples.gyro_raw - calibration.gyro_bias_radps)).max() > 1e-3
    # Covariances: the noise is not measured yet: the driver's plus the calibration's own part, in both
    # (test_covariance_... has the other cases); the gyro's own part grows with the rate (M_g's sigma).
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with AnyReader([tmp_path / "copy"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        imus = [c for c in reader.connections if c.topic == "/imu/data_raw"]
        messages = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=imus)]
    copied = np.array([np.asarray(m.linear_acceleration_covariance) for m in messages])
    copied_angular = np.array([np.asarray(m.angular_velocity_covariance) for m in messages])
    node_cov = np.array([np.asarray(m.linear_acceleration_covariance) for m in published])
    node_angular = np.array([np.asarray(m.angular_velocity_covariance) for m in published])
    np.testing.assert_array_equal(copied, node_cov)
    np.testing.assert_array_equal(copied_angular, node_angular)
    assert np.all(node_cov[:, 0] > COVARIANCE[0]) and np.all(node_angular[:, 0] > GYRO_COVARIANCE[0])
    rate = np.abs(samples.gyro_raw - calibration.gyro_bias_radps).sum(axis=1)
    assert node_angular[rate.argmax(), 0] > node_angular[rate.argmin(), 0]  # faster turns, less certain


def test_covariance_is_never_less_than_the_driver_said_until_the_noise_is_measured():
    """After a restart with a calibration file, the driver's 1.6e-3 (m/s^2)^2 must not give way to the
    calibration's sigma alone (2.6e-7, ~6,000x too little) before a still pose has measured the noise."""
    calibration = calibration_with_drift()
    before = Correction.build(calibration, 22.0)
    out = before.covariance_for(COVARIANCE)
    own = np.asarray(before.calibration_covariance)
    np.testing.assert_array_equal(out, COVARIANCE + own)
    assert out[0] >= COVARIANCE[0] and own[0] < 1e-3 * COVARIANCE[0]
    unknown, absent = np.zeros(9), np.r_[-1.0, np.zeros(8)]
    np.testing.assert_array_equal(before.covariance_for(unknown), unknown)
    np.testing.assert_array_equal(before.covariance_for(absent), absent)
    # Once measured: the sensor's noise through M plus the calibration's part, whatever the driver said.
    measured = Correction.build(calibration, 22.0, noise_var_per_axis=4e-4)
    np.testing.assert_allclose(measured.covariance_for(unknown)[0], 4e-4 * (calibration.matrix[0] ** 2).sum()
                               + own[0], rtol=1e-12)


finite = st.floats(-200, 200, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=40), st.integers(1, 40),
       st.sampled_from([None, 10.0, 22.0, 40.0]))
def test_one_sample_alone_and_in_any_group_are_corrected_to_the_same_bits(rows, split, temperature):
    """The correction is elementwise arithmetic in a fixed order: a message's floats and a group's arrays
    give the same bits (what makes a corrected copy independent of its group size and of the CPU)."""
    correction = Correction.build(calibration_with_drift(), temperature)
    accel = np.array(rows)
    alone = np.array([correction.apply(*(float(v) for v in row)) for row in accel])
    for rows_ in (slice(0, split), slice(split, None)):
        part = accel[rows_]
        if len(part):
            grouped = np.column_stack(correction.apply(part[:, 0], part[:, 1], part[:, 2]))
            np.testing.assert_array_equal(grouped, alone[rows_])


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(finite, finite, finite), min_size=1, max_size=40), st.integers(1, 40),
       st.sampled_from([None, 1e-6]))
def test_a_rate_alone_and_in_any_group_gets_the_same_bits_and_covariance(rows, split, gyro_noise_var):
    """The gyro's correction (bias, then M_g) and its covariance (REP-145: noise through M_g, the bias sigma,
    M_g's sigma at the rate) are elementwise too; they agree with Calibration.apply_gyro and
    gyro_rate_covariance (BLAS, so within a stated 1e-12 relative)."""
    calibration = calibration_with_drift()
    correction = Correction.build(calibration, 22.0, gyro_noise_var_per_axis=gyro_noise_var)
    rates = np.array(rows) * 0.01  # up to 2 rad/s
    alone = np.array([correction.apply_gyro(*(float(v) for v in row)) for row in rates])
    alone_cov = np.array([correction.angular_covariance_for(GYRO_COVARIANCE, row) for row in rates])
    for part in (slice(0, split), slice(split, None)):
        if len(rates[part]):
            grouped = np.column_stack(correction.apply_gyro(rates[part, 0], rates[part, 1], rates[part, 2]))
            np.testing.assert_array_equal(grouped, alone[part])
            driver = np.broadcast_to(GYRO_COVARIANCE, (len(rates[part]), 9))
            np.testing.assert_array_equal(correction.angular_covariance_for(driver, rates[part]), alone_cov[part])
    np.testing.assert_allclose(alone, calibration.apply_gyro(rates), rtol=1e-12, atol=1e-15)
    noise = np.sqrt(gyro_noise_var) if gyro_noise_var is not None else 0.0
    for row, cov in zip(rates, alone_cov):
        expected = calibration.gyro_rate_covariance(row, noise)
        if gyro_noise_var is None:  # not measured: the driver's plus the calibration's own part
            expected = expected + GYRO_COVARIANCE.reshape(3, 3)
            # Calibration's covariance holds M_g's sigma on the diagonal only, as Correction does.
        np.testing.assert_allclose(cov.reshape(3, 3), expected, rtol=1e-12, atol=1e-20)


driver_rows = st.sampled_from([COVARIANCE, GYRO_COVARIANCE, np.zeros(9), np.r_[-1.0, np.zeros(8)],
                               np.r_[0.0, 2e-5, np.zeros(7)]])


@settings(max_examples=150, deadline=None)
@given(driver=driver_rows, rates=st.tuples(finite, finite, finite), accel_noise=st.sampled_from([None, 4e-4]),
       gyro_noise=st.sampled_from([None, 2e-6]), gyro_quality=st.booleans())
def test_the_streams_in_place_covariances_are_the_groups_bit_for_bit(driver, rates, accel_noise, gyro_noise,
                                                                     gyro_quality):
    """The node writes the covariances over the message's own arrays (~1 us); a corrected copy makes them
    for a group (covariance_for): the same values, for every kind of driver report and noise state."""
    calibration = calibration_with_drift()
    if not gyro_quality:
        calibration = Calibration(bias=calibration.bias, matrix=calibration.matrix, bias_sigma=calibration.bias_sigma,
                                  matrix_sigma=calibration.matrix_sigma, gyro_bias_radps=calibration.gyro_bias_radps)
    correction = Correction.build(calibration, 22.0, accel_noise, gyro_noise)
    linear, angular = driver.copy(), driver.copy()
    correction.covariance_into(linear)
    correction.angular_covariance_into(angular, *rates)
    np.testing.assert_array_equal(linear, correction.covariance_for(driver))
    np.testing.assert_array_equal(angular, correction.angular_covariance_for(driver, np.array(rates)))
