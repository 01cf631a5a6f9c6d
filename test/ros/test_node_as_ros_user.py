"""The node as a ROS user finds it, and against hostile inputs, in-process: a real
rclpy node whose callbacks the test calls, its log and diagnostics captured. No DDS timing decides."""
from __future__ import annotations

import os
import time

import numpy as np
import pytest
import yaml
from rclpy.parameter import Parameter

from accel_calibration.core.calibration import Calibration
from accel_calibration.io.calibration_file import save_calibration
from msg_tools.conversions import make_imu

pytestmark = pytest.mark.ros


@pytest.fixture
def log_lines(monkeypatch):
    """Every line the node logs (after rclpy's own throttling), as (severity, text)."""
    from rclpy.impl import rcutils_logger

    lines = []
    real = rcutils_logger._rclpy.rclpy_logging_rcutils_log

    def record(severity, name, message, *args):
        lines.append((int(severity), str(message)))
        return real(severity, name, message, *args)

    monkeypatch.setattr(rcutils_logger._rclpy, "rclpy_logging_rcutils_log", record)
    return lines


@pytest.fixture
def make_node(ros, tmp_path):
    made = []

    def make(*, cli_args=None, **parameters):
        from accel_calibration.ros.node import CalibrationNode

        overrides = [Parameter("calibration_file", value=str(tmp_path / "cal.yaml"))]
        overrides += [Parameter(name, value=value) for name, value in parameters.items()]
        node = CalibrationNode(parameter_overrides=overrides, cli_args=cli_args)
        made.append(node)
        return node

    yield make
    for node in made:
        node.close()
        node.destroy_node()


def diagnostics_of(node) -> dict:
    published = []
    real = node._diagnostics.publish
    node._diagnostics.publish = published.append
    try:
        node._publish_diagnostics()
    finally:
        node._diagnostics.publish = real
    status = published[-1].status[0]
    return {"level": int.from_bytes(status.level, "little") if isinstance(status.level, bytes) else status.level,
            "message": status.message, "hardware_id": status.hardware_id,
            **{kv.key: kv.value for kv in status.values}}


def test_a_dump_loads_back_quietly(make_node, log_lines, tmp_path):
    """Finding: a `ros2 param dump` given back as --params-file warned "unknown parameter
    'calibration.bias' ignored" for each read-only mirror and for rclpy's start_type_description_service,
    and `ros2 param load` of it failed 31 times (read-only)."""
    calibration = Calibration(bias=np.array([0.01, -0.02, 0.03]), matrix=np.eye(3) * 1.001)
    save_calibration(calibration, tmp_path / "cal.yaml")
    first = make_node()
    dump = {p.name: p.value for p in first.get_parameters(first.list_parameters([], 0).names)}
    assert "calibration.bias" in dump and "start_type_description_service" in dump
    overrides = {name: value for name, value in dump.items() if name != "calibration_file"}
    second = make_node(**overrides)
    warnings = [text for severity, text in log_lines if severity >= 30]
    assert not [w for w in warnings if "unknown parameter" in w], warnings
    # `ros2 param load`: every value of the dump set again, all accepted, nothing changed.
    # (start_type_description_service is rclpy's own, read-only by rclpy: `ros2 param load` skips nothing of ours.)
    results = second.set_parameters([Parameter(name, value=value) for name, value in dump.items()
                                     if name != "start_type_description_service"])
    assert [r.reason for r in results if not r.successful] == []
    # A real change of a fixed parameter or a mirror is still refused, with the reason.
    refused = second.set_parameters([Parameter("merge_angle_deg", value=17.0),
                                     Parameter("calibration.bias", value=[1.0, 2.0, 3.0])])
    assert "fixed at start-up" in refused[0].reason and "read-only mirror" in refused[1].reason
    assert list(second.get_parameter("calibration.bias").value) == pytest.approx([0.01, -0.02, 0.03])


def test_min_poses_set_at_run_time_shows_at_once(make_node):
    """Finding: after `ros2 param set ... min_poses 16`, poses_needed read 12 until the next pose came."""
    node = make_node()
    assert diagnostics_of(node)["poses_needed"] == "12"
    assert node.set_parameters([Parameter("min_poses", value=16)])[0].successful
    node._worker.submit("ping").result(timeout=30)  # the worker process has taken it
    assert diagnostics_of(node)["poses_needed"] == "16"


def test_silence_on_the_input_is_a_warning_naming_the_resolved_topic(make_node, log_lines):
    """Finding: with a wrong remap /diagnostics stayed OK for ever with samples 0; when the driver stopped it
    stayed OK with detector_state still."""
    node = make_node(cli_args=["--ros-args", "-r", "imu/data_raw:=/wrong/topic"], stream_timeout_s=0.5)
    assert "no messages" not in diagnostics_of(node)["message"]  # starting: not yet a silence
    node._started -= 1.0
    status = diagnostics_of(node)
    assert status["level"] == 1 and "no messages on /wrong/topic since start (1 s)" in status["message"]
    assert any("no messages on /wrong/topic" in text for severity, text in log_lines if severity == 30)
    # Data comes: OK; the driver stops: WARN again, with how long.
    node._imu.take(make_imu(1_000_000_000, [0.0, 0.0, 9.8], [0.0, 0.0, 0.0]))
    assert "no messages" not in diagnostics_of(node)["message"]
    node._imu.last_seen = time.monotonic() - 3.0
    status = diagnostics_of(node)
    assert status["level"] == 1 and "no messages on /wrong/topic for 3 s" in status["message"]
    assert status["hardware_id"] == "imu_link"  # no sensor_id: the frame names the hardware


def test_armed_flapping_at_1_khz_does_not_flood_the_log(make_node, log_lines):
    """An armed input flipping at 1 kHz must not flood the log (a line per change was 1,564 INFO lines in 6 s)."""
    from std_msgs.msg import Bool

    node = make_node()
    before = len(log_lines)
    for k in range(2000):
        node._on_armed(Bool(data=k % 2 == 0))
    armed_lines = [text for _, text in log_lines[before:] if "armed" in text]
    assert 1 <= len(armed_lines) <= 2
    assert node._stream.pause.collecting  # ended disarmed


@pytest.mark.parametrize("kind", ["fifo", "deep", "binary", "huge"])
def test_a_params_file_that_would_hang_or_crash_rcl_is_one_line(kind, tmp_path, capsys):
    """Left to rcl, a FIFO hangs the node before it starts, 100,000-deep nesting gives a RecursionError
    traceback, a non-UTF-8 file a UnicodeDecodeError traceback (exit 1), a 50 MB file has not started the
    node after 140 s. So all are refused before rcl parses anything: exit 2, one line."""
    from accel_calibration.ros.node import main

    path = tmp_path / "params.yaml"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "deep":
        path.write_text("/**:\n  ros__parameters:\n    x: " + "[" * 100_000 + "]" * 100_000 + "\n")
    elif kind == "binary":
        path.write_bytes(b"/**:\n  ros__parameters:\n    sensor_id: \xff\xfe\n")
    else:
        with open(path, "w") as stream:
            stream.write("/**:\n  ros__parameters:\n")
            stream.write("    # padding\n" * 5_000_000)
    started = time.monotonic()
    assert main(["--ros-args", "--params-file", str(path)]) == 2
    assert time.monotonic() - started < 5
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("calibration_node: error:") and str(path) in err[0]
    assert yaml  # (the checks parse YAML themselves only after these)


def test_a_temperature_stamped_an_hour_ahead_is_screened_and_counted(make_node, tmp_path):
    """Two temperature publishers, one stamped an hour ahead, could drive the live correction temperature
    to 60 degC while the sensor read 25 (and the true readings after it get no weight), with no counter
    moving. A reading stamped more than a minute ahead of the IMU stream is dropped and
    counted (60 s: a pause of the IMU stream keeps its readings)."""
    from accel_calibration.core.temperature_models import TemperatureModel
    from msg_tools.conversions import make_temperature

    calibration = Calibration(bias=np.zeros(3), matrix=np.eye(3), temperature=TemperatureModel(
        "polynomial", 25.0, (0.0, 70.0), bias_coefficients=[[0.001, 0.0, 0.0]]))
    save_calibration(calibration, tmp_path / "cal.yaml")
    node = make_node()
    start = 1_700_000_000 * 10**9
    for k in range(200):
        t = start + k * 5_000_000
        node._imu.take(make_imu(t, [0.0, 0.0, 9.81], [0.0, 0.0, 0.0]))
        if k % 20 == 0:
            node._on_temperature(make_temperature(t, 25.0))
        if k == 100:
            node._on_temperature(make_temperature(t + 3600 * 10**9, 60.0))  # the other publisher's clock
    assert abs(node._stream.in_force.temperature_degc - 25.0) < 0.1
    assert node.counters()["temperature_future"] == 1
    assert diagnostics_of(node)["temperature_future"] == "1"


def test_the_gravity_in_use_is_the_gravity_parameter_on_diagnostics_and_in_the_log(make_node, log_lines):
    """Finding: with latitude_deg given, `ros2 param get gravity` said 9.80665 while the normal gravity there
    was used, and neither /diagnostics nor the log said which."""
    from accel_calibration.core.gravity import normal_gravity

    used = normal_gravity(0.0, 1000.0)  # 9.7772 m/s^2
    node = make_node(latitude_deg=0.0, height_m=1000.0)
    assert node._params.settings.gravity == used
    assert node.get_parameter("gravity").value == used
    assert diagnostics_of(node)["gravity_mps2"].startswith(f"{used:.5f} (WGS84 normal gravity")
    assert any(f"gravity {used:.5f} m/s^2" in text for severity, text in log_lines if severity == 20), log_lines
    standard = make_node()
    assert diagnostics_of(standard)["gravity_mps2"] == "9.80665 (standard)"


def test_a_start_up_parameter_changed_at_run_time_is_refused_as_fixed(make_node):
    """Finding: latitude_deg set at run time was refused as "gravity and latitude_deg exclude each other"."""
    node = make_node(latitude_deg=45.0)
    for name, value in (("latitude_deg", 47.0), ("height_m", 100.0), ("gravity", 9.79), ("model", "six")):
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and result.reason.startswith(f"{name} is fixed at start-up"), result.reason
    plain = make_node()
    result = plain.set_parameters([Parameter("latitude_deg", value=47.0)])[0]
    assert not result.successful and result.reason.startswith("latitude_deg is fixed at start-up"), result.reason
    assert plain.set_parameters([Parameter("min_poses", value=16)])[0].successful  # a run-time one still changes


def test_descriptors_say_read_only_and_the_range_enforced(make_node):
    """`ros2 param describe`: every start-up-only parameter is read-only, every run-time one is not, and every
    parameter whose values are bounded shows its range."""
    from accel_calibration.core.settings import PARAMETERS
    from accel_calibration.ros.parameters import NODE_PARAMETERS

    node = make_node()
    for parameter in PARAMETERS + NODE_PARAMETERS:
        descriptor = node.describe_parameter(parameter.name)
        assert descriptor.read_only == (not parameter.dynamic), parameter.name
        if parameter.low is not None:
            ranges = list(descriptor.floating_point_range) + list(descriptor.integer_range)
            assert len(ranges) == 1, parameter.name
            low = 0.0 if parameter.zero_means_auto else parameter.low
            assert (ranges[0].from_value, ranges[0].to_value) == (low, parameter.high), parameter.name
