"""calibration_node: the live shell over core.session. Imu in, corrected Imu out; services to calibrate,
inspect, reset, save and switch the correction; /diagnostics at 1 Hz.

Wiring only. The Imu callback corrects and publishes (io.in_force's Correction, core.correction's one
correction) and appends the raw sample, marked collecting or not, to a bounded buffer. One worker thread
hands the buffer every FEED_PERIOD_S to the session's live feed (the batch pipeline replay uses: live
equals replay by construction), takes the poses, refits, judges, and writes every file. Services that
need the worker answer when its job ends (ros/boundary.py), so the stream never waits for a fit or a
disk. No exception from a callback ends the process. SIGINT/SIGTERM set an event the spin loop checks.
"""
from __future__ import annotations

import collections
import math
import os
import signal
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from ..core.answers import calibrate_answer, face_of
from ..core.errors import AccelCalibrationError
from ..core.pose import Pose
from ..core.session import CalibrationSession
from ..io.calibration_file import calibration_to_yaml
from ..io.in_force import ERROR, OK, CalibrationInForce
from .boundary import LOG_THROTTLE_S, Boundary, failed_service
from .diagnostics import StreamHealth, diagnostic_status
from .parameters import NODE_PARAMETERS, NodeParameters, first_line, params_file_problem

__all__ = ["NODE_NAME", "NODE_PARAMETERS", "CalibrationNode", "main", "spin_until"]

NODE_NAME = "accel_calibration"
# Best effort (as drivers publish sensor data), depth 200 in: 50 ms at 4 kHz, so a worker batch or a busy
# machine loses nothing (bench_node_stream: 100 % delivered at 4 kHz; depth 50 lost 2-4 %).
INPUT_QOS = QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
SERVICE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
ARMED_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
# The worker takes the buffer this often. A batch costs ~1-1.5 ms of GIL whatever its size, and the messages
# arriving meanwhile wait: every 50 ms that was 3 % of them (p99 1.5-3 ms against the relay's ~1 ms), every
# 200 ms under 1 % (p99 1.2-1.5 ms, bench_node_stream). Poses are found within a fifth of a second.
FEED_PERIOD_S = 0.2
MAX_BUFFERED = 1 << 18  # raw samples waiting for the worker (~65 s at 4 kHz); beyond, the oldest are dropped
# A temperature reading stamped further than this ahead of the latest IMU stamp is another clock's: dropped
# and counted (temperature_future). Generous: an IMU stream that pauses for a while keeps its readings.
TEMPERATURE_AHEAD_NS = 60_000_000_000
GIL_SWITCH_INTERVAL_S = 0.0005
_LEVELS = {OK: DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN, ERROR: DiagnosticStatus.ERROR}


class CalibrationNode(Node):
    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        self._boundary = Boundary(self)
        guard = self._boundary.guard
        self._node_counts: collections.Counter[str] = collections.Counter()
        self._params = NodeParameters(self)
        self._session = CalibrationSession(self._params.settings)
        self._live = self._session.live_feed()
        node_values = self._params.node_values
        self._in_force = CalibrationInForce(self._resolve_calibration_path(node_values["calibration_file"]),
                                            self._session.settings)
        self._stream_timeout_s = float(node_values["stream_timeout_s"])
        self._calibrate_service = self.resolve_service_name("calibrate")
        self._imu_topic = self.resolve_topic_name("imu/data_raw")
        self._temperature_topic = self.resolve_topic_name("imu/temperature")
        self._enabled = True
        self._frame_id: str | None = None
        # The stream's thread appends, the worker pops: deque's append and popleft are atomic.
        self._samples: collections.deque[tuple[Any, ...]] = collections.deque()
        self._readings: collections.deque[tuple[int, float]] = collections.deque()
        self._feed_pending = False
        self._started = time.monotonic()
        self._last_imu: float | None = None
        self._latest_imu_ns = -1  # the latest IMU header stamp: temperature stamps are judged against it
        self._last_temperature: float | None = None
        self._still = False
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="accel_calibration_worker")

        removed = self._in_force.remove_stale_temp_files()
        if removed:
            self.get_logger().info(f"removed {removed} stale temporary file(s) beside {self._in_force.path}")
        level, text = self._in_force.load()
        log = {OK: self.get_logger().info, ERROR: self.get_logger().error}.get(level, self.get_logger().info)
        log(text if level != "warn" else f"{text} (call {self._calibrate_service} once poses are held)")
        self._status = (_LEVELS[level], "calibrated from file" if level == OK else
                        "uncalibrated: raw passes through" if level == "warn" else f"calibration file unusable: {text}")
        if self._in_force.calibration is not None:
            self._params.mirror(self._in_force.calibration)
        self._progress = self._session.progress(self._in_force.calibration, self._calibrate_service)
        self.add_on_set_parameters_callback(guard("parameters", self._on_set_parameters,
                                                  lambda args, error: SetParametersResult(
                                                      successful=False, reason=f"internal error: {error}")))

        reliability = (ReliabilityPolicy.RELIABLE if node_values["output_reliability"] == "reliable"
                       else ReliabilityPolicy.BEST_EFFORT)
        output_qos = QoSProfile(depth=50, reliability=reliability, history=HistoryPolicy.KEEP_LAST)
        self._publisher = self.create_publisher(Imu, "imu/data_calibrated", output_qos)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Imu, "imu/data_raw", guard("imu", self._on_imu), INPUT_QOS)
        # Optional: true while the vehicle is armed or flying (remap `armed` to the stack's state); nothing
        # is collected meanwhile. Reliable: one lost "true" would let a flight in.
        self.create_subscription(Bool, "armed", guard("armed", self._on_armed), ARMED_QOS)
        self.create_subscription(Temperature, "imu/temperature", guard("temperature", self._on_temperature),
                                 INPUT_QOS)
        # Services keep up to 100 requests (default 10): several tools may call /calibrate at once.
        deferred = self._boundary.deferred_service
        deferred(Trigger, "calibrate", lambda request: self._worker.submit(self._calibrate_job), SERVICE_QOS)
        deferred(Trigger, "calibration/reset", lambda request: self._worker.submit(self._reset_job), SERVICE_QOS)
        deferred(Trigger, "calibration/save", lambda request: self._worker.submit(self._save_job), SERVICE_QOS)
        self.create_service(Trigger, "calibration/get", guard("calibration/get", self._srv_get, failed_service),
                            qos_profile=SERVICE_QOS)
        self.create_service(SetBool, "calibration/pause", guard("calibration/pause", self._srv_pause, failed_service),
                            qos_profile=SERVICE_QOS)
        self.create_service(SetBool, "calibration/enable",
                            guard("calibration/enable", self._srv_enable, failed_service), qos_profile=SERVICE_QOS)
        self.create_timer(FEED_PERIOD_S, guard("feed", self._schedule_feed))
        self.create_timer(1.0, guard("diagnostics", self._publish_diagnostics))

    # ------------------------------------------------------------------ parameters
    def _resolve_calibration_path(self, configured: str) -> Path:
        if configured:
            return Path(os.path.expanduser(configured))
        # One file per node (namespace and name), so two instances never write the same file.
        relative = self.get_fully_qualified_name().lstrip("/")
        return Path(os.path.expanduser("~/.ros/accel_calibration")) / f"{relative}.yaml"

    def _on_set_parameters(self, parameters: list[RosParameter]) -> SetParametersResult:
        answer, settings = self._params.judge(parameters, self._session.settings)
        if settings is not None:
            self._session.update_settings(settings)
            # poses_needed and the advice follow at once, not at the next pose.
            self._worker.submit(self._boundary.guard("worker", self._refresh_progress))
        return answer

    # ------------------------------------------------------------------ stream (hot path)
    def _on_imu(self, msg: Imu) -> None:
        header = msg.header
        if header.frame_id != self._frame_id:
            self._on_frame_id(header.frame_id)
        self._last_imu = time.monotonic()
        a, w = msg.linear_acceleration, msg.angular_velocity
        ax, ay, az = a.x, a.y, a.z
        if len(self._samples) >= MAX_BUFFERED:
            self._samples.popleft()
            self._node_counts["samples_dropped_backlog"] += 1
        stamp_ns = header.stamp.sec * 1_000_000_000 + header.stamp.nanosec
        self._latest_imu_ns = stamp_ns if stamp_ns > self._latest_imu_ns else self._latest_imu_ns
        self._samples.append((stamp_ns, ax, ay, az, w.x, w.y, w.z, self._session.collecting))
        correction = self._in_force.correction
        if correction is not None and self._enabled and math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az):
            a.x, a.y, a.z = correction.apply(ax, ay, az)
            gx, gy, gz = w.x, w.y, w.z
            w.x, w.y, w.z = correction.apply_gyro(gx, gy, gz)
            if correction.covariance is not None or correction.calibration_covariance is not None:
                msg.linear_acceleration_covariance = correction.covariance_for(msg.linear_acceleration_covariance)
            if correction.gyro_covariance is not None or correction.gyro_calibration_covariance is not None:
                msg.angular_velocity_covariance = correction.angular_covariance_for(
                    msg.angular_velocity_covariance, np.array((gx, gy, gz)))
        self._publisher.publish(msg)  # non-finite samples pass on untouched: the stack sees what the driver sent

    def _on_temperature(self, msg: Temperature) -> None:
        stamp = msg.header.stamp
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        self._last_temperature = time.monotonic()
        # A reading stamped far ahead of the IMU stream (another publisher's clock) would take the
        # correction temperature with it, and leave the true readings after it none.
        if self._latest_imu_ns >= 0 and stamp_ns > self._latest_imu_ns + TEMPERATURE_AHEAD_NS:
            self._node_counts["temperature_future"] += 1
            return
        self._readings.append((stamp_ns, float(msg.temperature)))
        clamped = self._in_force.clamped_rebuilds
        if self._in_force.take_temperature(stamp_ns, float(msg.temperature)) \
                and self._in_force.clamped_rebuilds > clamped:
            self._node_counts["temperature_clamped"] += 1

    def _on_frame_id(self, frame_id: str) -> None:
        self._session.frame_id = frame_id  # a calibration is of the frame the samples were in
        if self._frame_id is not None:
            self._node_counts["frame_id_changes"] += 1
            self.get_logger().warning(f"{self._imu_topic} frame_id changed from {self._frame_id!r} to {frame_id!r}",
                                      throttle_duration_sec=LOG_THROTTLE_S)
        self._frame_id = frame_id
        self._check_frame()

    def _check_frame(self) -> None:
        calibration = self._in_force.calibration
        if calibration is not None and calibration.frame_id and self._frame_id is not None \
                and calibration.frame_id != self._frame_id:
            self._node_counts["frame_id_mismatch"] += 1
            self.get_logger().warning(
                f"the calibration in force was made for frame {calibration.frame_id!r} but {self._imu_topic} is "
                f"in {self._frame_id!r}: is this the same sensor?", throttle_duration_sec=LOG_THROTTLE_S)

    def _on_armed(self, msg: Bool) -> None:
        armed = bool(msg.data)
        if armed == ("armed" in self._session.pause_reasons):
            return
        self._session.set_collecting(not armed, "armed")  # marks the samples from the next one on
        # Throttled: an armed input flapping at 1 kHz must not flood the log.
        self.get_logger().info("armed: collection paused (nothing of a flight becomes a pose)" if armed
                               else "disarmed: collection resumed" + self._still_paused(),
                               throttle_duration_sec=LOG_THROTTLE_S)

    # ------------------------------------------------------------------ worker thread
    def _schedule_feed(self) -> None:
        if not self._feed_pending:
            self._feed_pending = True
            self._worker.submit(self._boundary.guard("worker", self._feed))

    def _feed(self) -> list[Pose]:
        """Worker: what the callbacks buffered into the live feed; new poses into the store, a refit."""
        self._feed_pending = False
        readings = [self._readings.popleft() for _ in range(len(self._readings))]
        rows = [self._samples.popleft() for _ in range(len(self._samples))]
        if readings:
            self._live.add_temperatures(np.fromiter((r[0] for r in readings), np.int64, len(readings)),
                                        np.fromiter((r[1] for r in readings), float, len(readings)))
        if rows:
            values = np.array([r[1:7] for r in rows], dtype=float)
            self._live.add_samples(np.fromiter((r[0] for r in rows), np.int64, len(rows)), values[:, :3],
                                   values[:, 3:], np.fromiter((r[7] for r in rows), bool, len(rows)))
        else:  # the stream is idle: no later reading will come for what waits on one
            self._live.drain()
        self._still = self._session.detector.holding_still
        poses = self._live.take_poses()
        if poses:
            self._absorb(poses)
        return poses

    def _absorb(self, poses: list[Pose]) -> None:
        log = self.get_logger()
        for pose in poses:
            event = self._session.add_pose(pose)
            verb = "refined" if event.merged else "accepted"
            log.info(f"pose {event.index + 1} {verb} ({face_of(pose.accel_mps2)}, {pose.duration_s:.1f} s still)")
            log.debug(f"pose {event.index + 1}: mean {np.round(pose.accel_mps2, 5).tolist()} m/s^2 over "
                      f"{pose.samples} samples, {'merged' if event.merged else 'new'}"
                      + (" (disagreed with the pose it would merge into: kept apart)" if event.disagreed else ""))
        # The covariances follow the noise measured at the still poses.
        self._in_force.set_noise(self._session.detector.noise_floor_accel_var, self._session.gyro_noise_var())
        result = self._session.refit()
        progress = self._refresh_progress()
        if result is not None and result.success and result.calibration is not None \
                and result.calibration.quality is not None:
            log.info(f"{progress.poses} poses, fit residual {result.calibration.quality.residual_rms_mg:.2f} mg rms: "
                     f"{progress.advice}")
            log.debug(f"refit: bias {np.round(result.calibration.bias, 6).tolist()} m/s^2, "
                      f"M {np.round(result.calibration.matrix, 7).tolist()}, {result.iterations} iterations")
        else:
            log.info(f"{progress.poses} poses held: {progress.advice}")
        verdict = self._session.auto_verdict(result)
        if verdict is not None and verdict.calibration is not None:
            applied, message = self._apply(verdict.calibration)
            (log.info if applied else log.warning)(("auto-calibrated: " if applied
                                                    else "auto-calibration not applied: ") + message)

    def _refresh_progress(self) -> Any:
        self._progress = self._session.progress(self._in_force.calibration, self._calibrate_service)
        return self._progress

    def _apply(self, calibration: Any) -> tuple[bool, str]:
        applied, message = self._in_force.save_then_apply(calibration)
        if applied:
            self._params.mirror(calibration)
            self._check_frame()
            self._status = (DiagnosticStatus.OK, "calibrated")
        elif not self._in_force.file_unreadable:
            self._status = (DiagnosticStatus.ERROR, f"save failed: {message}")
        return applied, message

    def _calibrate_job(self) -> tuple[bool, str]:
        self._feed()
        self._live.drain()  # what came up to the call counts, and the pose being held right now
        for pose in self._live.take_poses():
            self._session.add_pose(pose)
        verdict = self._session.calibrate(self._live.holding())
        self._refresh_progress()
        if not verdict.success or verdict.result is None or verdict.calibration is None:
            message = f"not calibrated ({verdict.message}); {self._in_force.kept()}"
            self.get_logger().warning(f"{self._calibrate_service}: {message}")
            return False, message
        applied, saved = self._apply(verdict.calibration)
        if not applied:
            self.get_logger().warning(f"{self._calibrate_service}: {saved}")
            return False, saved
        self.get_logger().info(f"{self._calibrate_service}: calibrated, {saved}")
        return True, calibrate_answer(verdict.result, saved, verdict.gyro_refusal)

    def _reset_job(self) -> tuple[bool, str]:
        self._feed()
        dropped = self._session.reset()
        self._refresh_progress()
        message = f"dropped {dropped} poses; the calibration in force is unchanged"
        self.get_logger().info("calibration/reset: " + message)
        return True, message

    def _save_job(self) -> tuple[bool, str]:
        return self._in_force.save()

    # ------------------------------------------------------------------ immediate services
    def _srv_get(self, request: Any, response: Any) -> Any:
        calibration = self._in_force.calibration
        if calibration is None:
            response.success, response.message = False, "no calibration in force: raw acceleration passes through"
        else:
            response.success, response.message = True, calibration_to_yaml(calibration)
        return response

    def _srv_pause(self, request: Any, response: Any) -> Any:
        pause = bool(request.data)
        self._session.set_collecting(not pause, "calibration/pause")
        response.success = True
        response.message = ("collection paused: the corrected stream goes on, no poses are collected" if pause
                            else "collection resumed" + self._still_paused())
        self.get_logger().info("calibration/pause: " + response.message)
        return response

    def _still_paused(self) -> str:
        reasons = self._session.pause_reasons
        return f" (still paused: {', '.join(reasons)})" if reasons else ""

    def _srv_enable(self, request: Any, response: Any) -> Any:
        self._enabled = bool(request.data)
        response.success = True
        response.message = "correction on" if self._enabled else "correction off: raw passes through"
        self.get_logger().info("calibration/enable: " + response.message)
        return response

    # ------------------------------------------------------------------ diagnostics
    def counters(self) -> dict[str, int]:
        """Everything set aside or gone wrong, by name: the session's screening and the node's own."""
        counts = self._session.counters.as_dict()
        counts.update(self._node_counts)
        counts["callback_errors"] = sum(self._boundary.errors.values())
        return counts

    def _health(self) -> StreamHealth:
        now = time.monotonic()
        return StreamHealth(self._imu_topic, self._temperature_topic,
                            None if self._last_imu is None else now - self._last_imu,
                            None if self._last_temperature is None else now - self._last_temperature,
                            self._stream_timeout_s, now - self._started)

    def _publish_diagnostics(self) -> None:
        level, message = self._status
        calibration = self._in_force.calibration
        health = self._health()
        for problem in health.problems():
            self.get_logger().warning(problem, throttle_duration_sec=LOG_THROTTLE_S)
        temperature = self._in_force.temperature_degc
        values = {
            "detector_state": "still" if self._still else "moving",
            # "yes", or why not: "paused (armed)", "paused (calibration/pause)" -- the stream is corrected still
            "collecting": ("yes" if self._session.collecting
                           else "paused (" + ", ".join(self._session.pause_reasons) + ")"),
            "correction": "on" if self._enabled and calibration is not None else "off",
            "calibration_file": str(self._in_force.path),
            "frame_id": self._frame_id or "",
            "temperature_degc": "" if temperature is None else f"{temperature:.2f}",
        }
        hardware_id = (calibration.sensor_id if calibration is not None and calibration.sensor_id
                       else self._session.settings.sensor_id or self._frame_id or "")
        status = diagnostic_status(f"accel_calibration: {self.get_fully_qualified_name()}", level, message,
                                   self._progress, values, self.counters(), dict(self._boundary.errors), calibration,
                                   hardware_id, health, self._session.pause_reasons, calibration is not None)
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def close(self) -> None:
        """Let a fit or save in flight finish (the file is then the old or the new one, whole); requests
        still queued are answered 'not done'."""
        self._worker.shutdown(wait=True, cancel_futures=True)


def spin_until(node: Node, stop: threading.Event) -> None:
    """EventsExecutor costs ~2.4x less CPU per message than the SingleThreadedExecutor here; its
    spin() without a timeout busy-loops in the PyPI wheel, so spin in slices (PERF_NOTES), which
    also lets the loop see `stop` (set by a signal) within 0.1 s."""
    from rclpy.experimental import EventsExecutor

    executor = EventsExecutor()
    executor.add_node(node)
    never: rclpy.task.Future = rclpy.task.Future()
    try:
        while not stop.is_set() and rclpy.ok():
            try:
                executor.spin_until_future_complete(never, timeout_sec=0.1)
            except Exception as error:  # noqa: BLE001 - a callback that escaped its guard must not end the node
                node.get_logger().error(f"executor: {type(error).__name__}: {error}; carrying on",
                                        throttle_duration_sec=LOG_THROTTLE_S)
    finally:
        executor.remove_node(node)


def main(args: list[str] | None = None) -> int:
    stop = threading.Event()
    problem = params_file_problem(sys.argv[1:] if args is None else args)
    if problem is not None:
        print(f"calibration_node: error: {problem}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # noqa: BLE001 - a broken --ros-args / --params-file: one line, exit 2
        print(f"calibration_node: error: cannot start ROS: {first_line(error)}", file=sys.stderr)
        return 2

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()  # the spin loop ends; a second signal (a terminal under ros2 launch) changes nothing

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    # The worker's numpy batches hold the GIL up to the switch interval (5 ms by default) while a message
    # waits for its callback: 0.5 ms keeps the added p99 latency near the bare relay's.
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    node = None
    try:
        try:
            node = CalibrationNode()
        except AccelCalibrationError as error:
            print(f"calibration_node: error: {error}", file=sys.stderr)
            return 2
        except Exception as error:  # noqa: BLE001 - rclpy's own refusals (e.g. a value outside a range)
            print(f"calibration_node: error: {first_line(error)}", file=sys.stderr)
            return 2
        if not stop.is_set():
            spin_until(node, stop)
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
        # Python's finalisation puts SIG_DFL back for every handler it installed, so a second SIGINT
        # in the last milliseconds (a terminal under ros2 launch) would kill the process (-2): ignored
        # handlers are left alone, and there is nothing left to stop.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return 0


if __name__ == "__main__":
    sys.exit(main())
