"""calibration_node: the live shell over io.live_calibration (the node's work without ROS). Imu in,
corrected Imu out; services to calibrate, inspect, reset, save and switch the correction; /diagnostics
at 1 Hz.

Wiring only. The Imu callback corrects and publishes (core.correction's one correction, as every corrected
copy of a recording) and buffers the raw sample. One worker thread feeds the buffer every FEED_PERIOD_S
to the session's live feed, and runs the services' jobs: those services answer when the job ends
(ros/boundary.py), so the stream never waits for a fit or a disk. No exception from a callback ends the
process (ros/boundary.py); signals end the spin loop (ros/process.py).
"""
from __future__ import annotations

import functools
import math
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ..io.in_force import ERROR, OK, WARN
from ..io.live_calibration import LiveCalibration
from .boundary import Boundary, failed_service
from .diagnostics import NAMESAKE_CHECKS_S, SilenceReminders, StreamHealth, diagnostic_status, namesake_problem
from .markers import pose_markers
from .parameters import NODE_PARAMETERS, NodeParameters
from .process import run_node, spin_until

__all__ = ["NODE_NAME", "NODE_PARAMETERS", "CalibrationNode", "main", "spin_until"]

NODE_NAME = "accel_calibration"
# Best effort (as drivers publish sensor data), depth 200 in: 50 ms at 4 kHz, so a worker batch or a busy
# machine loses nothing (bench_node_stream: 100 % delivered at 4 kHz; depth 50 lost 2-4 %).
INPUT_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
SERVICE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
ARMED_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
# The pose map is latched: RViz or Foxglove opened later gets the latest at once.
MARKER_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
# The worker takes the buffer this often. A batch costs ~1-1.5 ms of GIL whatever its size, and the messages
# arriving meanwhile wait: every 50 ms that was 3 % of them (p99 1.5-3 ms against the relay's ~1 ms), every
# 200 ms under 1 % (p99 1.2-1.5 ms, bench_node_stream). Poses are found within a fifth of a second.
FEED_PERIOD_S = 0.2
_LEVELS = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN, ERROR: DiagnosticStatus.ERROR}


class CalibrationNode(Node):
    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        self._boundary = Boundary(self)
        guard = self._boundary.guard
        self._params = NodeParameters(self)
        node_values = self._params.node_values
        self._stream_timeout_s = float(node_values["stream_timeout_s"])
        self._imu_topic = self.resolve_topic_name("imu/data_raw")
        self._temperature_topic = self.resolve_topic_name("imu/temperature")
        self._live = LiveCalibration(self._params.settings, self._calibration_path(node_values["calibration_file"]),
                                     self.get_logger(), calibrate_service=self.resolve_service_name("calibrate"),
                                     imu_topic=self._imu_topic, on_applied=self._params.mirror)
        self._session, self._in_force = self._live.session, self._live.in_force
        self._started = time.monotonic()
        self._last_imu: float | None = None
        self._last_temperature: float | None = None
        self._silence_reminders = SilenceReminders()
        self._feed_pending = False
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="accel_calibration_worker")
        self._live.start()
        self.add_on_set_parameters_callback(guard("parameters", self._on_set_parameters,
                                                  lambda args, error: SetParametersResult(
                                                      successful=False, reason=f"internal error: {error}")))

        reliability = (ReliabilityPolicy.RELIABLE if node_values["output_reliability"] == "reliable"
                       else ReliabilityPolicy.BEST_EFFORT)
        output_qos = QoSProfile(depth=50, reliability=reliability, history=HistoryPolicy.KEEP_LAST)
        self._publisher = self.create_publisher(Imu, "imu/data_calibrated", output_qos)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._markers = self.create_publisher(MarkerArray, "calibration/markers", MARKER_QOS)
        self._markers_of: object = None  # the pose map last published (the worker replaces it whole)
        self.create_subscription(Imu, "imu/data_raw", guard("imu", self._on_imu), INPUT_QOS)
        # Optional: true while the vehicle is armed or flying (remap `armed` to the stack's state); nothing
        # is collected meanwhile. Reliable: one lost "true" would let a flight in.
        self.create_subscription(Bool, "armed", guard("armed", self._on_armed), ARMED_QOS)
        self.create_subscription(Temperature, "imu/temperature", guard("temperature", self._on_temperature),
                                 INPUT_QOS)
        # Services keep up to 100 requests (default 10): several tools may call /calibrate at once.
        jobs: dict[str, Callable[[], tuple[bool, str]]] = {
            "calibrate": self._live.calibrate, "calibration/reset": self._live.reset,
            "calibration/save": self._live.save}
        for name, job in jobs.items():
            self._boundary.deferred_service(Trigger, name, functools.partial(self._submit, job), SERVICE_QOS)
        for srv_type, name, answer in ((Trigger, "calibration/get", self._srv_get),
                                       (SetBool, "calibration/pause", self._srv_pause),
                                       (SetBool, "calibration/enable", self._srv_enable)):
            self.create_service(srv_type, name, guard(name, answer, failed_service), qos_profile=SERVICE_QOS)
        self.create_timer(FEED_PERIOD_S, guard("feed", self._schedule_feed))
        self.create_timer(1.0, guard("diagnostics", self._publish_diagnostics))
        self._namesake: str | None = None
        self._namesake_looks = 0  # of NAMESAKE_CHECKS_S done
        self._namesake_timer = self.create_timer(1.0, guard("namesakes", self._look_for_namesakes))

    def _submit(self, job: Callable[[], tuple[bool, str]], request: Any) -> Future[tuple[bool, str]]:
        return self._worker.submit(job)

    def _calibration_path(self, configured: str) -> Path:
        if configured:
            return Path(os.path.expanduser(configured))
        # One file per node (namespace and name), so two instances never write the same file.
        relative = self.get_fully_qualified_name().lstrip("/")
        return Path(os.path.expanduser("~/.ros/accel_calibration")) / f"{relative}.yaml"

    def _on_set_parameters(self, parameters: list[RosParameter]) -> SetParametersResult:
        answer, settings = self._params.judge(parameters, self._session.settings)
        if settings is not None:
            self._live.update_settings(settings)
            # poses_needed and the advice follow at once, not at the next pose.
            self._worker.submit(self._boundary.guard("worker", self._live.refresh_progress))
        return answer

    # ------------------------------------------------------------------ stream (hot path)
    def _on_imu(self, msg: Imu) -> None:
        header = msg.header
        if header.frame_id != self._live.frame_id:
            self._live.set_frame_id(header.frame_id)
        self._last_imu = time.monotonic()
        a, w = msg.linear_acceleration, msg.angular_velocity
        ax, ay, az, gx, gy, gz = a.x, a.y, a.z, w.x, w.y, w.z
        self._live.buffer_imu(header.stamp.sec * 1_000_000_000 + header.stamp.nanosec, ax, ay, az, gx, gy, gz)
        correction = self._in_force.correction
        if correction is not None and self._live.enabled and math.isfinite(ax) and math.isfinite(ay) \
                and math.isfinite(az):
            a.x, a.y, a.z = correction.apply(ax, ay, az)
            w.x, w.y, w.z = correction.apply_gyro(gx, gy, gz)
            if correction.covariance is not None or correction.calibration_covariance is not None:
                msg.linear_acceleration_covariance = correction.covariance_for(msg.linear_acceleration_covariance)
            if correction.gyro_covariance is not None or correction.gyro_calibration_covariance is not None:
                msg.angular_velocity_covariance = correction.angular_covariance_for(
                    msg.angular_velocity_covariance, np.array((gx, gy, gz)))
        self._publisher.publish(msg)  # non-finite samples pass on untouched: the stack sees what the driver sent

    def _on_temperature(self, msg: Temperature) -> None:
        self._last_temperature = time.monotonic()
        stamp = msg.header.stamp
        self._live.take_temperature(stamp.sec * 1_000_000_000 + stamp.nanosec, float(msg.temperature))

    def _on_armed(self, msg: Bool) -> None:
        self._live.set_armed(bool(msg.data))

    def _schedule_feed(self) -> None:
        if not self._feed_pending:
            self._feed_pending = True
            self._worker.submit(self._boundary.guard("worker", self._feed))

    def _feed(self) -> None:
        self._feed_pending = False
        self._live.feed()

    # ------------------------------------------------------------------ immediate services
    def _srv_get(self, request: Any, response: Any) -> Any:
        response.success, response.message = self._live.calibration_text()
        return response

    def _srv_pause(self, request: Any, response: Any) -> Any:
        response.success, response.message = True, self._live.pause(bool(request.data))
        self.get_logger().info("calibration/pause: " + response.message)
        return response

    def _srv_enable(self, request: Any, response: Any) -> Any:
        response.success, response.message = True, self._live.enable(bool(request.data))
        self.get_logger().info("calibration/enable: " + response.message)
        return response

    # ------------------------------------------------------------------ diagnostics
    def counters(self) -> dict[str, int]:
        """Everything set aside or gone wrong, by name: the session's screening, the node's, the callbacks'."""
        return {**self._live.all_counts(), "callback_errors": sum(self._boundary.errors.values())}

    def _look_for_namesakes(self) -> None:
        """At NAMESAKE_CHECKS_S after start: another node of this fully qualified name is a WARN (once)."""
        looks_due = sum(1 for at in NAMESAKE_CHECKS_S if time.monotonic() - self._started >= at)
        if looks_due <= self._namesake_looks:
            return
        self._namesake_looks = looks_due
        if looks_due == len(NAMESAKE_CHECKS_S):
            self._namesake_timer.cancel()
        problem = namesake_problem(self.get_fully_qualified_name(), self.get_node_names_and_namespaces())
        if problem is not None and self._namesake is None:
            self.get_logger().warning(problem)
        self._namesake = problem or self._namesake

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        health = StreamHealth(self._imu_topic, self._temperature_topic,
                              None if self._last_imu is None else now - self._last_imu,
                              None if self._last_temperature is None else now - self._last_temperature,
                              self._stream_timeout_s, now - self._started)
        for line in self._silence_reminders.due(health.problem_by_input(), now):
            self.get_logger().warning(line)
        level, message = self._live.reported_status()
        if self._namesake is not None:
            level, message = (WARN if level == OK else level), f"{message}; {self._namesake}".lstrip("; ")
        calibration = self._in_force.calibration
        status = diagnostic_status(f"accel_calibration: {self.get_fully_qualified_name()}", _LEVELS[level], message,
                                   self._live.progress, self._live.diagnostic_values(), self.counters(),
                                   dict(self._boundary.errors), calibration, self._live.hardware_id(), health,
                                   self._session.pause_reasons, calibration is not None)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)
        self._publish_markers(array.header.stamp)

    def _publish_markers(self, stamp: Any) -> None:
        """The pose map on calibration/markers, when the worker has made a new one."""
        current = self._live.pose_map
        if current is not self._markers_of:
            self._markers_of = current
            self._markers.publish(pose_markers(current, self._live.frame_id or "imu_link", stamp))

    def close(self) -> None:
        """Let a fit or save in flight finish (the file is then the old or the new one, whole); requests
        still queued are answered 'not done'."""
        self._worker.shutdown(wait=True, cancel_futures=True)


def main(args: list[str] | None = None) -> int:
    return run_node("calibration_node", CalibrationNode, args)


if __name__ == "__main__":
    sys.exit(main())
