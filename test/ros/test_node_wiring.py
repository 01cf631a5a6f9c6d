"""The node as a ROS user drives it, over real rclpy / Fast DDS in its own process: services in any
order without dying, signals, start-up parameters, namespaces. Playback is closed-loop (each chunk
echoed before the next), so no test depends on how busy the machine is."""
from __future__ import annotations

import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from accel_calibration import load_calibration
from msg_tools.node_process import installed_command
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

pytestmark = pytest.mark.ros
START_NS = 1_700_000_000 * 10**9
REPO = Path(__file__).resolve().parents[2]


def good_session(seed=11, poses=16):
    errors = SensorErrors.mpu6050_like(np.random.default_rng(seed), noise_mps2=0.02)
    rng = np.random.default_rng(seed + 1)
    return errors, SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0,
                                seed=seed)


def test_calibrate_too_early_then_a_session_then_calibrate_reset_calibrate(tmp_path, tester, node_process):
    """A second /calibrate must not kill the node (one log call site used at two severities is what did)."""
    cal_file = tmp_path / "cal.yaml"
    node = node_process(cal_file)
    tester.wait_ready()
    early = tester.call("calibrate")
    assert not early.success and early.message.startswith("not calibrated (gate poses: have 0 poses")
    assert early.message.endswith("no calibration in force: raw passes through")
    errors, imu = good_session()
    tester.play(imu.samples(), start_ns=START_NS)
    answer = tester.call("calibrate")
    assert answer.success, answer.message
    saved = load_calibration(cal_file)
    np.testing.assert_allclose(saved.bias, errors.bias_mps2, atol=0.005)
    assert saved.frame_id == "imu_link"
    assert tester.call("calibration/reset").success
    again = tester.call("calibrate")
    assert not again.success and "gate poses" in again.message
    assert again.message.endswith("previous calibration kept in force")
    assert tester.call("calibration/get").success
    assert node.process.poll() is None
    assert node.stop() == 0 and "Traceback" not in node.log()


def test_sigterm_while_calibrate_is_served_exits_0_with_no_temp_file(tmp_path, tester, node_process):
    cal_file = tmp_path / "cal.yaml"
    (tmp_path / ".cal.yaml.stale123.tmp").write_text("left by a killed writer")
    node = node_process(cal_file)
    tester.wait_ready()
    assert not (tmp_path / ".cal.yaml.stale123.tmp").exists()  # stale temp files are removed at start-up
    _, imu = good_session(seed=5)
    tester.play(imu.samples(), start_ns=START_NS)
    futures = [tester.clients["calibrate"].call_async(
                   __import__("std_srvs.srv", fromlist=["Trigger"]).Trigger.Request())
               for _ in range(5)]
    assert tester.spin_until(lambda: any(f.done() for f in futures), 20)
    node.process.send_signal(signal.SIGTERM)
    assert node.process.wait(timeout=20) == 0, node.log()
    log = node.log()
    assert "Traceback" not in log and "context is invalid" not in log, log
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []
    load_calibration(cal_file)  # whole


def test_two_sigints_in_quick_succession_exit_0(tmp_path, tester, node_process):
    """A terminal under `ros2 launch` sends SIGINT twice, 0.02 s apart."""
    node = node_process(tmp_path / "cal.yaml")
    tester.wait_ready()
    node.process.send_signal(signal.SIGINT)
    tester.spin_until(lambda: False, 0.02)
    node.process.send_signal(signal.SIGINT)
    assert node.process.wait(timeout=20) == 0, node.log()
    assert "Traceback" not in node.log()


def test_sigints_until_it_has_exited_still_exit_0(tmp_path, tester, node_process):
    """SIGINT every few ms until the process is gone: some land in Python's finalisation, which puts
    SIG_DFL back for the handlers it installed (exit -2 before the fix, every time)."""
    node = node_process(tmp_path / "cal.yaml")
    tester.wait_ready()
    while node.process.poll() is None:
        node.process.send_signal(signal.SIGINT)
        tester.spin_until(lambda: node.process.poll() is not None, 0.003, poll_s=0.001)
    assert node.process.returncode == 0, node.log()
    assert "Traceback" not in node.log()


@pytest.mark.parametrize("args, says", [
    (["-p", "gravity:=10"], "gravity must be a floating-point number (write 10.0)"),
    (["-p", "min_poses:=3.5"], "min_poses must be an integer"),
    (["-p", "temperature_timeout_s:=.nan"], "temperature_timeout_s must be a finite number"),
    (["-p", "accel_range_mps2:=-1.0"], "accel_range_mps2 must be within"),
    (["-p", "temperature_timeout_s:=-1.0"], "temperature_timeout_s must be within"),
    (["-p", "static.window_s:=0.0"], "static.window_s must be within"),
    (["--params-file", "/nonexistent/params.yaml"],
     "/nonexistent/params.yaml: --params-file (a ROS 2 parameters YAML) not found"),
])
def test_bad_startup_parameters_are_one_line_and_exit_2(tmp_path, args, says):
    process = subprocess.run([*installed_command("calibration_node"), "--ros-args", *args],
                             capture_output=True, text=True, timeout=30)
    output = (process.stdout + process.stderr).strip()
    assert process.returncode == 2 and says in output and len(output.splitlines()) == 1, output


def test_params_file_applies_under_a_namespace_with_a_per_node_file(tmp_path, ros, node_process):
    """`/**:` keys apply whatever the namespace; the default calibration file is per node; the advice
    names the service as resolved; mirrors are read-only and never taken from a params file. (`ros`: its
    own client needs rclpy, never borrowed from the test before it, which under pytest -n may be elsewhere.)"""
    import rclpy
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.parameter import Parameter

    from msg_tools.calibration_client import CalibrationClient

    params = yaml.safe_load((REPO / "config" / "accel_calibration.yaml").read_text())
    assert list(params) == ["/**"]
    params["/**"]["ros__parameters"]["max_poses"] = 37
    params["/**"]["ros__parameters"]["calibration"] = {"bias": [9.0, 9.0, 9.0]}
    params["/**"]["ros__parameters"].pop("calibration_file", None)
    params_file = tmp_path / "params.yaml"
    params_file.write_text(yaml.safe_dump(params))
    node = node_process(None, log_path=tmp_path / "node.log", env={"HOME": str(tmp_path)},
                        ros_args=["-r", "__ns:=/uav1", "--params-file", str(params_file)])
    client = CalibrationClient(namespace="/uav1")
    try:
        client.wait_ready()
        getter = client.node.create_client(GetParameters, "/uav1/accel_calibration/get_parameters")
        assert getter.wait_for_service(timeout_sec=10)
        future = getter.call_async(GetParameters.Request(names=["max_poses", "calibration.bias", "calibration_file"]))
        assert client.spin_until(future.done, 10)
        values = future.result().values
        assert values[0].integer_value == 37
        assert list(values[1].double_array_value) == [0.0, 0.0, 0.0]
        assert values[2].string_value == ""
        setter = client.node.create_client(SetParameters, "/uav1/accel_calibration/set_parameters")
        assert setter.wait_for_service(timeout_sec=10)
        future = setter.call_async(SetParameters.Request(parameters=[
            Parameter("calibration.bias", value=[1.0, 1.0, 1.0]).to_parameter_msg()]))
        assert client.spin_until(future.done, 10)
        assert not future.result().results[0].successful
        _, imu = good_session(seed=8)
        client.play(imu.samples(), start_ns=START_NS)
        assert client.spin_until(
            lambda: client.diagnostics and client.diagnostics[-1]["advice"] == "ready: call /uav1/calibrate", 10), \
            client.diagnostics[-1]
        assert client.call("calibrate").success
        assert (tmp_path / ".ros" / "accel_calibration" / "uav1" / "accel_calibration.yaml").exists()
    finally:
        client.destroy()
    assert node.stop() == 0, node.log()
    del rclpy
