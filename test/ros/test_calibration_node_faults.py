"""calibration_node failure paths, over real rclpy / DDS with the node in its own process: nothing
crashes, nothing bad reaches the fit, the calibration in force and its file are never lost."""
from __future__ import annotations

import math

import numpy as np
import pytest

pytestmark = pytest.mark.ros
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters

from accel_calibration import Calibration, load_calibration, save_calibration
from msg_tools.conversions import make_imu
from msg_tools.node_process import NodeProcess
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

START_NS = 1_700_000_000 * 10**9
ERROR, WARN = b"\x02", b"\x01"



def preloaded(path):
    cal = Calibration(bias=[0.1, -0.2, 0.3], matrix=[[1.01, 0, 0], [0.01, 0.99, 0], [0.0, 0.02, 1.02]])
    save_calibration(cal, path)
    return cal


def few_poses_session(errors, count=4):
    rng = np.random.default_rng(5)
    return SyntheticImu(errors, spread_orientations(count, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=5)


def test_calibrate_with_too_few_poses_keeps_the_calibration_in_force(tmp_path, tester):
    cal_file = tmp_path / "cal.yaml"
    before = preloaded(cal_file)
    before_bytes = cal_file.read_bytes()
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        errors = SensorErrors.mpu6050_like(np.random.default_rng(1), noise_mps2=0.02)
        sent = tester.play(few_poses_session(errors).samples(), start_ns=START_NS)
        assert tester.settle(int(0.99 * sent))
        answer = tester.call("calibrate")
        assert not answer.success
        assert "poses" in answer.message and "previous calibration kept" in answer.message
        got = tester.call("calibration/get")
        assert got.success and load_calibration(cal_file) == before
        assert cal_file.read_bytes() == before_bytes
        # Diagnostics tell the person what to do next, and that a calibration is in force meanwhile.
        assert tester.spin_until(lambda: tester.diagnostics and tester.diagnostics[-1]["advice"].startswith(
            "calibration in force; more poses would refine it (turn"), 5)
    finally:
        assert node.stop() == 0, node.log()


@pytest.mark.parametrize("content", [
    b"\x00\x01binary junk\xff",
    b"imu_calibration: {bias: [1, 2, 3]}\n",
    b"accel_calibration: {model: sphere9, bias: [0, 0, 0], matrix: [[1e12, 0, 0], [0, 1, 0], [0, 0, 1]]}\n",
])
def test_corrupt_or_foreign_file_is_reported_left_untouched_and_never_overwritten(tmp_path, tester, content):
    cal_file = tmp_path / "cal.yaml"
    cal_file.write_bytes(content)
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        assert tester.spin_until(lambda: tester.diagnostics and tester.diagnostics[-1]["level"] == ERROR, 5)
        assert "unusable" in tester.diagnostics[-1]["message"]
        # Raw passes through.
        tester.corrected.clear()
        tester.imu_pub.publish(make_imu(START_NS, (0.5, 0.25, 9.5), (0.0, 0.0, 0.0)))
        assert tester.settle(1)
        assert tester.corrected[0].linear_acceleration.x == 0.5
        # A full session and /calibrate: the fit is fine, but the unreadable file is not clobbered.
        errors = SensorErrors.mpu6050_like(np.random.default_rng(2), noise_mps2=0.02)
        rng = np.random.default_rng(3)
        imu = SyntheticImu(errors, spread_orientations(14, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=3)
        tester.play(imu.samples(), start_ns=START_NS + 10**9)
        assert tester.spin_until(lambda: int(tester.diagnostics[-1]["poses"]) >= 12, 10)
        answer = tester.call("calibrate")
        assert not answer.success and "left untouched" in answer.message
        assert not tester.call("calibration/save").success
        assert cal_file.read_bytes() == content
        assert node.process.poll() is None
    finally:
        assert node.stop() == 0, node.log()
    assert "calibration file unusable" in node.log()


def test_missing_file_means_pass_through_said_once(tmp_path, tester):
    node = NodeProcess(tmp_path / "absent.yaml")
    try:
        tester.wait_ready()
        got = tester.call("calibration/get")
        assert not got.success and "raw" in got.message
        assert not tester.call("calibration/save").success
    finally:
        assert node.stop() == 0
    assert node.log().count("no calibration file at") == 1


def test_bad_messages_are_counted_and_never_reach_the_fit(tmp_path, tester):
    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        errors = SensorErrors.mpu6050_like(np.random.default_rng(4), noise_mps2=0.02)
        rng = np.random.default_rng(6)
        imu = SyntheticImu(errors, spread_orientations(14, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=6)
        samples = imu.samples()
        # Interleave poison into a real session: NaN and Inf, a saturated axis (stuck at +16 g), and
        # stamps that go backwards -- inside still dwells, where they would do the most harm.
        poisoned = 0
        for start in range(0, len(samples.t_ns), 400):
            tester.play(samples, start_ns=START_NS,
                 indices=range(start, min(start + 400, len(samples.t_ns))))
            t = START_NS + int(samples.t_ns[min(start + 399, len(samples.t_ns) - 1)])
            tester.imu_pub.publish(make_imu(t + 1000, (math.nan, 0.0, 9.8), (0.0, 0.0, 0.0)))
            tester.imu_pub.publish(make_imu(t + 2000, (0.0, math.inf, 9.8), (0.0, 0.0, 0.0)))
            tester.imu_pub.publish(make_imu(t + 3000, (16 * 9.80665, 0.0, 9.8), (0.0, 0.0, 0.0)))
            tester.imu_pub.publish(make_imu(t - 10**9, (50.0, 50.0, 50.0), (0.0, 0.0, 0.0)))
            poisoned += 1
        assert tester.spin_until(
            lambda: tester.diagnostics and int(tester.diagnostics[-1]["non_finite"]) >= 2 * poisoned - 2, 10)
        last = tester.diagnostics[-1]
        assert int(last["saturated"]) >= poisoned - 1 and int(last["stamp_backwards"]) >= poisoned - 1
        assert last["level"] in (WARN, ERROR)
        answer = tester.call("calibrate")
        assert answer.success, answer.message
        cal = load_calibration(cal_file)
        np.testing.assert_allclose(cal.bias, errors.bias_mps2, atol=0.005)
        assert node.process.poll() is None
    finally:
        assert node.stop() == 0, node.log()


def still_samples(seconds, rate_hz=100.0, seed=0):
    """A sensor lying still (with its noise: a repeated bit-identical value is a frozen sensor)."""
    from msg_tools.synthetic_imu import SyntheticSamples

    rng = np.random.default_rng(seed)
    n = int(seconds * rate_hz)
    accel = np.array([0.0, 0.0, 9.8]) + rng.normal(0, 0.02, (n, 3))
    gyro = rng.normal(0, 0.002, (n, 3))
    return SyntheticSamples(np.arange(n, dtype=np.int64) * int(1e9 / rate_hz), accel, gyro, np.full(n, 30.0),
                            accel, np.ones(n, dtype=bool))


def test_temperature_that_stops_is_reported_stale_and_used_again_when_it_resumes(tmp_path, tester):
    node = NodeProcess(tmp_path / "cal.yaml", "temperature_timeout_s:=1.0")
    try:
        tester.wait_ready()
        # 2 s of a driver publishing both (a reading is judged against the IMU stream's stamps: one far
        # ahead of it is another clock's, test_node_as_ros_user).
        tester.play(still_samples(2.0, seed=2), start_ns=START_NS, temperature_period_s=0.1)
        assert tester.spin_until(
            lambda: tester.diagnostics and tester.diagnostics[-1]["temperature_degc"] == "30.00", 5)
        # IMU goes on for 3 s of header time, the temperature does not.
        tester.play(still_samples(3.0), start_ns=START_NS + 2 * 10**9, temperature=False)
        assert tester.spin_until(lambda: int(tester.diagnostics[-1]["temperature_stale"]) > 100, 5)
        # It resumes: the new readings are used again and nothing more is counted stale.
        resumed = still_samples(2.0, seed=1)
        resumed = type(resumed)(resumed.t_ns, resumed.accel_raw, resumed.gyro_raw, np.full(len(resumed.t_ns), 35.0),
                                resumed.accel_true, resumed.static)
        tester.play(resumed, start_ns=START_NS + 5 * 10**9, temperature_period_s=0.01)
        assert tester.spin_until(lambda: abs(float(tester.diagnostics[-1]["temperature_degc"] or 0) - 35.0) < 0.3, 5)
        stale = int(tester.diagnostics[-1]["temperature_stale"])
        tester.play(resumed, start_ns=START_NS + 8 * 10**9, temperature_period_s=0.01)
        seen = len(tester.diagnostics)
        assert tester.spin_until(lambda: len(tester.diagnostics) >= seen + 2, 5)  # a period after the last message
        assert int(tester.diagnostics[-1]["temperature_stale"]) == stale
        assert node.process.poll() is None
    finally:
        assert node.stop() == 0


def _parameter_call(tester, service_type, name, request):
    client = tester.node.create_client(service_type, f"/accel_calibration/{name}")
    assert client.wait_for_service(timeout_sec=10)
    future = client.call_async(request)
    assert tester.spin_until(future.done, 10)
    return future.result()


def test_parameters_mirror_the_calibration_and_are_validated(tmp_path, tester):
    cal_file = tmp_path / "cal.yaml"
    cal = preloaded(cal_file)
    node = NodeProcess(cal_file, "min_poses:=14")
    try:
        tester.wait_ready()
        got = _parameter_call(tester, GetParameters, "get_parameters",
                              GetParameters.Request(names=["calibration.bias", "calibration.matrix", "min_poses",
                                                           "model"]))
        bias, matrix, min_poses, model = got.values
        np.testing.assert_allclose(bias.double_array_value, cal.bias)
        np.testing.assert_allclose(matrix.double_array_value, cal.matrix.ravel())
        assert min_poses.integer_value == 14 and model.string_value == "sphere9"

        def set_(name, value):
            request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=value)])
            return _parameter_call(tester, SetParameters, "set_parameters", request).results[0]

        refused = set_("calibration.bias", ParameterValue(type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                                          double_array_value=[0.0, 0.0, 0.0]))
        assert not refused.successful and "read-only" in refused.reason
        refused = set_("min_poses", ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=3))
        assert not refused.successful and "min_poses" in refused.reason
        refused = set_("model", ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="six"))
        assert not refused.successful  # fixed at start-up
        accepted = set_("auto_calibrate", ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True))
        assert accepted.successful
    finally:
        assert node.stop() == 0


def test_bad_startup_parameters_exit_with_one_line(tmp_path):
    node = NodeProcess(tmp_path / "cal.yaml", "model:=ellipsoid")
    assert node.process.wait(timeout=20) != 0
    log = node.log()
    assert "model must be one of six, sphere9" in log and "Traceback" not in log
    assert len(log.strip().splitlines()) == 1, log
    node.stop()


def good_session(seed=11, poses=16):
    errors = SensorErrors.mpu6050_like(np.random.default_rng(seed), noise_mps2=0.02)
    rng = np.random.default_rng(seed + 1)
    return errors, SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0,
                                seed=seed)


def test_auto_calibrate_applies_and_saves_by_itself(tmp_path, tester):
    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file, "auto_calibrate:=true")
    try:
        tester.wait_ready()
        errors, imu = good_session()
        tester.play(imu.samples(), start_ns=START_NS)
        assert tester.spin_until(cal_file.exists, 10), node.log()
        cal = load_calibration(cal_file)
        np.testing.assert_allclose(cal.bias, errors.bias_mps2, atol=0.005)
        assert cal.quality.poses >= 12
        # Logged by the worker process after its save, through the node: it follows the file by a moment.
        assert tester.spin_until(lambda: "auto-calibrated" in node.log(), 10), node.log()
        # calibration/save rewrites the calibration in force whole.
        cal_file.unlink()
        saved = tester.call("calibration/save")
        assert saved.success and load_calibration(cal_file).bias.tolist() == bias_in_force(tester)
    finally:
        assert node.stop() == 0, node.log()


def bias_in_force(tester):
    import yaml

    return yaml.safe_load(tester.call("calibration/get").message)["accel_calibration"]["bias"]


def test_use_sim_time_with_a_clock_as_bag_play_gives(tmp_path, tester):
    """`ros2 bag play --clock` into a running node: /clock drives the node's clock (diagnostics stamps);
    the poses follow header stamps, so the session calibrates as it would live."""
    from rosgraph_msgs.msg import Clock

    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file, "use_sim_time:=true")
    clock_pub = tester.node.create_publisher(Clock, "/clock", 10)
    try:
        tester.wait_ready()
        errors, imu = good_session(seed=21)
        samples = imu.samples()
        for first in range(0, len(samples.t_ns), 200):
            clock_pub.publish(Clock(clock=make_imu(START_NS + int(samples.t_ns[first]), (0, 0, 0),
                                                   (0, 0, 0)).header.stamp))
            tester.play(samples, start_ns=START_NS,
                 indices=range(first, min(first + 200, len(samples.t_ns))))
        answer = tester.call("calibrate")
        assert answer.success, answer.message
        np.testing.assert_allclose(load_calibration(cal_file).bias, errors.bias_mps2, atol=0.005)
        assert tester.spin_until(lambda: len(tester.diagnostics) > 0, 10)
    finally:
        assert node.stop() == 0, node.log()


def test_a_stream_in_g_is_reported_not_calibrated(tmp_path, tester):
    from msg_tools.synthetic_imu import SyntheticSamples

    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        _, imu = good_session(seed=31)
        s = imu.samples()
        in_g = SyntheticSamples(s.t_ns, s.accel_raw / 9.80665, s.gyro_raw, s.temperature_degc, s.accel_true, s.static)
        tester.play(in_g, start_ns=START_NS)
        answer = tester.call("calibrate")
        assert not answer.success and "looks like g, not m/s^2" in answer.message
        assert not cal_file.exists()
    finally:
        assert node.stop() == 0, node.log()
