"""calibration_node: the live shell over live.per_message (the stream side) and live.calibration_work (the
work), without ROS both. Imu in, corrected Imu out; services to calibrate, inspect, reset, save and switch
the correction; /diagnostics at 1 Hz.

Wiring only. The Imu callback (ros/imu_path.py) reads the message's serialised bytes, corrects and
publishes them patched (core.correction's one correction, as every corrected copy of a recording) and
pushes the raw sample into a shared ring. The work runs in a worker process
(live/worker_process.py): it feeds the ring to the session every FEED_PERIOD_S and runs the services' jobs,
which answer when the job ends (ros/boundary.py); so the stream never waits for a fit, a disk, or even
the lock of the interpreter doing them. No exception from a callback ends the process (ros/boundary.py);
signals end the spin loop (ros/process.py).
"""
from __future__ import annotations

import dataclasses
import functools
import multiprocessing
import pickle
import sys
import time
from concurrent.futures import Future
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import MarkerArray

from ..core.calibration import Calibration
from ..live.calibration_store import ERROR, OK, WARN, CalibrationStore
from ..live.calibration_work import (
    WorkSnapshot,
    diagnostic_values,
    file_status,
    open_calibration_file,
    starting_snapshot,
)
from ..live.per_message import LiveStream, imu_ring, temperature_ring
from ..live.worker_process import WorkerProcess, WorkerStart
from .boundary import Boundary, failed_service
from .diagnostics import SilenceReminders, StreamHealth, diagnostic_status, waiting_advice
from .imu_path import ImuPath
from .markers import pose_markers
from .namesakes import NamesakeLook
from .parameters import NODE_PARAMETERS, NodeParameters, calibration_path
from .process import run_node, spin_until

__all__ = ["NODE_NAME", "NODE_PARAMETERS", "CalibrationNode", "main", "spin_until"]

NODE_NAME = "accel_calibration"
# Best effort (as drivers publish sensor data), depth 200 in: 50 ms at 4 kHz, so a busy machine loses nothing
# (bench_node_stream: 100 % delivered at 4 kHz; depth 50 lost 2-4 %).
INPUT_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
SERVICE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
ARMED_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
# The pose map is latched: RViz or Foxglove opened later gets the latest at once.
MARKER_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
_LEVELS = {OK: DiagnosticStatus.OK, WARN: DiagnosticStatus.WARN, ERROR: DiagnosticStatus.ERROR}


class CalibrationNode(Node):
    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        self._boundary = Boundary(self)
        guard = self._boundary.guard
        self._params = NodeParameters(self)
        node_values = self._params.node_values
        self._stream_timeout_s = float(node_values["stream_timeout_s"])
        settings = self._params.settings
        self._gravity_text = f"{settings.gravity:.5f} ({settings.gravity_source})"
        self.get_logger().info(f"gravity {settings.gravity:.5f} m/s^2 in use ({settings.gravity_source})")
        self._imu_topic = self.resolve_topic_name("imu/data_raw")
        self._temperature_topic = self.resolve_topic_name("imu/temperature")
        path = calibration_path(node_values["calibration_file"], self.get_fully_qualified_name())
        calibrate_service = self._calibrate_service = self.resolve_service_name("calibrate")
        context = multiprocessing.get_context("spawn")  # not fork: this process runs DDS threads
        self._stream = LiveStream(self._params.settings, self.get_logger(), imu_ring(context),
                                  temperature_ring(context), imu_topic=self._imu_topic)
        # The file's calibration in force from the first message on; the work loads it again for itself.
        store = CalibrationStore(path, self._params.settings)
        opened = file_status(*open_calibration_file(store, self.get_logger(), calibrate_service))
        if store.calibration is not None:
            self._stream.in_force.install(store.calibration)
            self._params.mirror(store.calibration)
        debug_logged = self.get_logger().get_effective_level() <= LoggingSeverity.DEBUG
        self._worker = WorkerProcess(WorkerStart(self._params.settings, path, calibrate_service, self._imu_topic,
                                                 debug_logged),
                                     (self._stream.samples, self._stream.readings), self.get_logger(),
                                     self._install, self._stream.set_noise, context)
        self._stream.on_frame_id = self._worker.set_frame_id
        self._starting = starting_snapshot(self._params.settings, path, calibrate_service, opened)
        self._started = time.monotonic()
        self._last_temperature: float | None = None
        self._silence_reminders = SilenceReminders()
        self.add_on_set_parameters_callback(guard("parameters", self._on_set_parameters,
                                                  lambda args, error: SetParametersResult(
                                                      successful=False, reason=f"internal error: {error}")))

        reliability = (ReliabilityPolicy.RELIABLE if node_values["output_reliability"] == "reliable"
                       else ReliabilityPolicy.BEST_EFFORT)
        output_qos = QoSProfile(depth=50, reliability=reliability, history=HistoryPolicy.KEEP_LAST)
        self._publisher = self.create_publisher(Imu, "imu/data_calibrated", output_qos)
        self._imu = ImuPath(self._stream, self._publisher)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._markers = self.create_publisher(MarkerArray, "calibration/markers", MARKER_QOS)
        self._markers_of = b""  # the pose map last published, pickled
        # Raw: the message's CDR bytes, read and patched in place (ros/imu_path.py).
        self.create_subscription(Imu, "imu/data_raw", guard("imu", self._imu.take_cdr), INPUT_QOS, raw=True)
        # Optional: true while the vehicle is armed or flying (remap `armed` to the stack's state); nothing
        # is collected meanwhile. Reliable: one lost "true" would let a flight in.
        self.create_subscription(Bool, "armed", guard("armed", self._on_armed), ARMED_QOS)
        self.create_subscription(Temperature, "imu/temperature", guard("temperature", self._on_temperature),
                                 INPUT_QOS)
        # Services keep up to 100 requests (default 10): several tools may call /calibrate at once.
        for name in ("calibrate", "calibration/reset", "calibration/save"):
            self._boundary.deferred_service(Trigger, name, functools.partial(self._submit, name), SERVICE_QOS)
        for srv_type, name, answer in ((Trigger, "calibration/get", self._srv_get),
                                       (SetBool, "calibration/pause", self._srv_pause),
                                       (SetBool, "calibration/enable", self._srv_enable)):
            self.create_service(srv_type, name, guard(name, answer, failed_service), qos_profile=SERVICE_QOS)
        self.create_timer(1.0, guard("diagnostics", self._publish_diagnostics))
        self._namesakes = NamesakeLook(self, calibrate_service, self._started, guard)

    def _submit(self, job: str, request: Any) -> Future[tuple[bool, str]]:
        return self._worker.submit(job)

    def _install(self, calibration: Calibration | None) -> None:
        """The work put a calibration in force (saved first): the stream corrects with it from now on."""
        self._stream.install(calibration)
        if calibration is not None:
            self._params.mirror(calibration)

    def set_parameters_atomically(self, parameter_list: list[RosParameter]) -> SetParametersResult:
        """A parameter fixed at start-up is read-only in its descriptor: its change is refused here with the
        reason, and setting it to its value (a `ros2 param load` of a dump) is accepted, before rclpy would
        refuse both in its own words."""
        refusal, rest = self._params.screen(parameter_list)
        if refusal is not None:
            return refusal
        return super().set_parameters_atomically(rest) if rest else SetParametersResult(successful=True)

    def set_parameters(self, parameter_list: list[RosParameter]) -> list[SetParametersResult]:
        return [self.set_parameters_atomically([parameter]) for parameter in parameter_list]

    def _on_set_parameters(self, parameters: list[RosParameter]) -> SetParametersResult:
        answer, settings = self._params.judge(parameters, self._stream.settings)
        if settings is not None:
            self._stream.settings = settings
            self._worker.update_settings(settings)
            # poses_needed and the advice follow at once, not at the next pose.
            self._worker.submit("refresh_progress")
        return answer

    # ------------------------------------------------------------------ inputs besides the Imu (ros/imu_path.py)
    def _on_temperature(self, msg: Temperature) -> None:
        self._last_temperature = time.monotonic()
        stamp = msg.header.stamp
        self._stream.take_temperature(stamp.sec * 1_000_000_000 + stamp.nanosec, float(msg.temperature))

    def _on_armed(self, msg: Bool) -> None:
        self._stream.set_armed(bool(msg.data))

    # ------------------------------------------------------------------ immediate services
    def _srv_get(self, request: Any, response: Any) -> Any:
        response.success, response.message = self._stream.calibration_text()
        return response

    def _srv_pause(self, request: Any, response: Any) -> Any:
        response.success, response.message = True, self._stream.set_paused(bool(request.data))
        self.get_logger().info("calibration/pause: " + response.message)
        return response

    def _srv_enable(self, request: Any, response: Any) -> Any:
        response.success, response.message = True, self._stream.enable(bool(request.data))
        self.get_logger().info("calibration/enable: " + response.message)
        return response

    # ------------------------------------------------------------------ diagnostics
    def counters(self) -> dict[str, int]:
        """Everything set aside or gone wrong, by name: the work's (the session's screening and its own), the
        stream side's, the callbacks'."""
        counts = dict(self._work().counts)
        for name, count in self._stream.set_aside.items():
            counts[name] = counts.get(name, 0) + count
        counts["worker_restarts"] = self._worker.restarts
        return {**counts, "callback_errors": sum(self._boundary.errors.values())}

    def _work(self) -> WorkSnapshot:
        """The work's latest snapshot."""
        return self._worker.snapshot or self._starting

    def _publish_diagnostics(self) -> None:
        self._stream.flush()
        now = time.monotonic()
        health = StreamHealth(self._imu_topic, self._temperature_topic,
                              None if self._imu.last_seen is None else now - self._imu.last_seen,
                              None if self._last_temperature is None else now - self._last_temperature,
                              self._stream_timeout_s, now - self._started)
        for line in self._silence_reminders.due(health.problem_by_input(), now):
            self.get_logger().warning(line)
        work = self._work()
        level, message = work.status
        if self._namesakes.found is not None:
            level, message = (WARN if level == OK else level), f"{message}; {self._namesakes.found}".lstrip("; ")
        stream = self._stream
        calibration = stream.in_force.calibration
        if not self._worker.alive:
            level, message = ERROR, f"calibration worker not running (restarted {self._worker.restarts} times)"
        stream_values = {**stream.values(), "gravity_mps2": self._gravity_text}
        status = diagnostic_status(f"accel_calibration: {self.get_fully_qualified_name()}", _LEVELS[level], message,
                                   work.progress, diagnostic_values(stream_values, work.values), self.counters(),
                                   dict(self._boundary.errors), calibration, stream.hardware_id(), health,
                                   stream.pause.reasons)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)
        self._publish_markers(work.pose_map, array.header.stamp)

    def _publish_markers(self, current: Any, stamp: Any) -> None:
        """The pose map on calibration/markers, when the work has made a new one; before any Imu, no way to
        turn: the text says what it waits for."""
        if self._imu.last_seen is None:
            current = dataclasses.replace(current, next_direction=None, advice=waiting_advice(self._imu_topic))
        pickled = pickle.dumps(current)  # each snapshot is a new object: compare what it holds
        if pickled != self._markers_of:
            self._markers_of = pickled
            self._markers.publish(pose_markers(current, self._stream.frame_id or "imu_link", stamp))

    def close(self) -> None:
        """Let a fit or save in flight finish (the file is then the old or the new one, whole); requests
        still queued are answered 'not done'."""
        self._worker.close()


def main(args: list[str] | None = None) -> int:
    return run_node("calibration_node", CalibrationNode, args)


if __name__ == "__main__":
    sys.exit(main())
