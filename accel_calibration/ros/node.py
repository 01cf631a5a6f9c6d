"""calibration_node: the live shell over core.session. Imu in, corrected Imu out; services to calibrate,
inspect, reset, save and switch the correction; /diagnostics at 1 Hz.

Threads: the executor thread runs the stream callbacks (screening + detector: plain floats) and
answers services; one worker thread owns the pose store, runs every fit and writes every file.
Services that need the worker answer when it is done (deferred responses), so the stream never
waits for a fit or a disk. The correction in force is one immutable value, swapped whole under a
lock by whoever rebuilds it (a new calibration on the worker, a new temperature on the stream).
No exception from a callback ends the process: each is caught at the boundary, logged
(throttled) and counted on /diagnostics. SIGINT/SIGTERM set an event the spin loop checks.
"""
from __future__ import annotations

import collections
import functools
import math
import os
import queue
import signal
import sys
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import Bool
from std_srvs.srv import SetBool, Trigger

from ..core.calibration import Calibration
from ..core.correction import Correction
from ..core.errors import AccelCalibrationError, CalibrationError, SettingsError
from ..core.fit import FitResult
from ..core.screening import Counters
from ..core.session import CalibrationSession
from ..core.settings import PARAMETERS, RELIABILITIES, Parameter, Settings, check_value
from ..io.calibration_file import (
    calibration_to_yaml,
    load_calibration,
    remove_stale_temp_files,
    save_calibration,
)

NODE_NAME = "accel_calibration"
# Best effort, depth 50 in: measured 0 % loss to 3 kHz here (PERF_NOTES) and matches drivers that
# publish with sensor-data QoS.
INPUT_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
SERVICE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
ARMED_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
MIRROR_PREFIX = "calibration."
# Parameters of the node itself (not of the session): fixed at start-up.
NODE_PARAMETERS = (
    Parameter("calibration_file", "", "calibration YAML loaded at start and written by /calibrate and "
              "calibration/save; empty = ~/.ros/accel_calibration/<namespace>/<node name>.yaml"),
    Parameter("output_reliability", "reliable", "QoS reliability of imu/data_calibrated: reliable (serves "
              "reliable and best-effort subscribers) or best_effort", choices=RELIABILITIES),
)
MIRRORS = (
    ("bias", [0.0, 0.0, 0.0], "bias b of the calibration in force, m/s^2"),
    ("matrix", [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "matrix M of the calibration in force, row-major"),
    ("residual_rms_mg", 0.0, "residual rms of the calibration in force, mg"),
    ("poses", 0, "poses the calibration in force was fitted to"),
)
LOG_THROTTLE_S = 5.0


def _descriptor(parameter: Parameter, read_only: bool) -> ParameterDescriptor:
    descriptor = ParameterDescriptor(description=parameter.description, read_only=read_only)
    if parameter.low is not None and parameter.high is not None:
        if type(parameter.default) is int:
            descriptor.integer_range = [IntegerRange(from_value=int(parameter.low), to_value=int(parameter.high),
                                                     step=0)]
        else:
            low = 0.0 if parameter.zero_means_auto else float(parameter.low)
            descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=float(parameter.high),
                                                                  step=0.0)]
    if parameter.choices:
        descriptor.additional_constraints = "one of: " + ", ".join(parameter.choices)
    return descriptor


class CalibrationNode(Node):
    def __init__(self, **kwargs: Any):
        super().__init__(NODE_NAME, **kwargs)
        self._errors: collections.Counter[str] = collections.Counter()  # callback failures, by callback
        self._node_counts: collections.Counter[str] = collections.Counter()
        settings, node_values = self._declare_parameters()
        self._session = CalibrationSession(settings)
        self._calibration_path = self._resolve_calibration_path(node_values["calibration_file"])
        self._calibrate_service = self.resolve_service_name("calibrate")

        self._calibration: Calibration | None = None
        self._correction: Correction | None = None
        self._correction_lock = threading.Lock()
        self._enabled = True
        self._file_unreadable = False  # a file we could not read is never overwritten
        self._status = (DiagnosticStatus.OK, "starting")
        self._progress = self._session.progress(None, self._calibrate_service)
        self._frame_id: str | None = None
        self._pending_poses: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="accel_calibration_worker")
        self._deferred: dict[int, Future[tuple[bool, str]]] = {}

        removed = remove_stale_temp_files(self._calibration_path)
        if removed:
            self.get_logger().info(f"removed {removed} stale temporary file(s) beside {self._calibration_path}")
        self._load_calibration_at_start()
        self.add_on_set_parameters_callback(self._guard("parameters", self._on_set_parameters,
                                                        lambda args, error: SetParametersResult(
                                                            successful=False, reason=f"internal error: {error}")))

        reliability = (ReliabilityPolicy.RELIABLE if node_values["output_reliability"] == "reliable"
                       else ReliabilityPolicy.BEST_EFFORT)
        output_qos = QoSProfile(depth=50, reliability=reliability, history=HistoryPolicy.KEEP_LAST)
        self._publisher = self.create_publisher(Imu, "imu/data_calibrated", output_qos)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Imu, "imu/data_raw", self._guard("imu", self._on_imu), INPUT_QOS)
        # Optional: true while the vehicle is armed or flying (remap `armed` to the stack's state); nothing
        # is collected meanwhile. Reliable: one lost "true" would let a flight in.
        self.create_subscription(Bool, "armed", self._guard("armed", self._on_armed), ARMED_QOS)
        self.create_subscription(Temperature, "imu/temperature", self._guard("temperature", self._on_temperature),
                                 INPUT_QOS)
        # Services keep up to 100 requests (default 10): several tools may call /calibrate at once.
        self._deferred_service(Trigger, "calibrate", self._calibrate_request)
        self._deferred_service(Trigger, "calibration/reset", lambda request: self._worker.submit(self._reset_job))
        self._deferred_service(Trigger, "calibration/save", lambda request: self._worker.submit(self._save_job))
        self.create_service(Trigger, "calibration/get", self._guard("calibration/get", self._srv_get, _failed_trigger),
                            qos_profile=SERVICE_QOS)
        self.create_service(SetBool, "calibration/pause",
                            self._guard("calibration/pause", self._srv_pause, _failed_set_bool),
                            qos_profile=SERVICE_QOS)
        self.create_service(SetBool, "calibration/enable",
                            self._guard("calibration/enable", self._srv_enable, _failed_set_bool),
                            qos_profile=SERVICE_QOS)
        self.create_timer(1.0, self._guard("diagnostics", self._publish_diagnostics))

    # ------------------------------------------------------------------ the boundary
    def _guard(self, name: str, callback: Callable[..., Any],
               fallback: Callable[[tuple[Any, ...], Exception], Any] | None = None) -> Callable[..., Any]:
        """No exception from a callback may end the node: log it (throttled), count it, carry on."""

        @functools.wraps(callback)
        def guarded(*args: Any) -> Any:
            try:
                return callback(*args)
            except Exception as error:  # noqa: BLE001 - the boundary itself
                self._errors[name] += 1
                self.get_logger().error(f"{name} callback failed ({type(error).__name__}: {error}); "
                                        "the node carries on", throttle_duration_sec=LOG_THROTTLE_S)
                if fallback is not None:
                    return fallback(args, error)
                return None

        return guarded

    def _deferred_service(self, srv_type: Any, name: str, start: Callable[[Any], Future[tuple[bool, str]]]) -> None:
        """A service answered when its worker job ends, so the executor (and the stream) never waits.
        rclpy sends what the callback returns through `send_response`; the response object is held
        back and sent from the job's completion instead."""

        def callback(request: Any, response: Any) -> Any:
            try:
                job = start(request)
            except Exception as error:  # noqa: BLE001 - the boundary itself
                self._errors[name] += 1
                response.success, response.message = False, f"{name} failed: {type(error).__name__}: {error}"
                return response
            self._deferred[id(response)] = job
            return response

        service = self.create_service(srv_type, name, callback, qos_profile=SERVICE_QOS)
        send_now = service.send_response

        def send_response(response: Any, header: Any) -> None:
            job = self._deferred.pop(id(response), None)
            if job is None:
                send_now(response, header)
                return

            def answer(done: Future[tuple[bool, str]]) -> None:
                try:
                    response.success, response.message = done.result()
                except Exception as error:  # noqa: BLE001 - cancelled at shutdown, or a job that failed
                    self._errors[name] += 1
                    response.success, response.message = False, f"{name} not done: {type(error).__name__}: {error}"
                try:
                    send_now(response, header)
                except Exception:  # noqa: BLE001 - the context is gone at shutdown; nobody to answer
                    pass

            job.add_done_callback(answer)

        service.send_response = send_response  # type: ignore[method-assign]

    # ------------------------------------------------------------------ parameters
    def _declare_parameters(self) -> tuple[Settings, dict[str, Any]]:
        """Declare every parameter with its type and range; a value given at start-up that does not
        fit is refused with one line naming the parameter as the user typed it."""
        overrides = self._parameter_overrides
        values: dict[str, Any] = {}
        for parameter in PARAMETERS + NODE_PARAMETERS:
            if parameter.name in overrides:
                values[parameter.name] = check_value(parameter, overrides[parameter.name].value)
            read_only = not parameter.dynamic
            self.declare_parameter(parameter.name, values.get(parameter.name, parameter.default),
                                   _descriptor(parameter, read_only), ignore_override=True)
        for name, default, text in MIRRORS:
            # Mirrors of the calibration in force: read-only, never taken from a params file.
            self.declare_parameter(MIRROR_PREFIX + name, default,
                                   ParameterDescriptor(description=text + " (read-only mirror)", read_only=True),
                                   ignore_override=True)
        known = {p.name for p in PARAMETERS + NODE_PARAMETERS} | {"use_sim_time"}
        unknown = sorted(name for name in overrides if name not in known and not name.startswith("qos_overrides."))
        for name in unknown:
            self.get_logger().warning(f"unknown parameter {name!r} ignored (typo?)")
        node_values = {p.name: values.get(p.name, p.default) for p in NODE_PARAMETERS}
        session_values = {p.name: values[p.name] for p in PARAMETERS if p.name in values}
        return Settings.from_parameters(session_values), node_values

    def _resolve_calibration_path(self, configured: str) -> Path:
        if configured:
            return Path(os.path.expanduser(configured))
        # One file per node (namespace and name), so two instances never write the same file.
        relative = self.get_fully_qualified_name().lstrip("/")
        return Path(os.path.expanduser("~/.ros/accel_calibration")) / f"{relative}.yaml"

    def _on_set_parameters(self, parameters: list[RosParameter]) -> SetParametersResult:
        changes = {}
        for parameter in parameters:
            if parameter.name.startswith(MIRROR_PREFIX) or parameter.name == "use_sim_time":
                continue  # read-only mirrors are refused by rclpy itself; use_sim_time is rclpy's
            changes[parameter.name] = parameter.value
        if not changes:
            return SetParametersResult(successful=True)
        try:
            settings = Settings.from_parameters(changes, base=self._session.settings)
            self._session.update_settings(settings)
        except SettingsError as error:
            return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _mirror(self, calibration: Calibration) -> None:
        """Update the read-only mirrors. rclpy refuses set_parameters on read-only parameters, even from
        the node itself, so the stored values are replaced directly (no parameter event)."""
        quality = calibration.quality
        values = {
            "bias": [float(v) for v in calibration.bias],
            "matrix": [float(v) for v in calibration.matrix.ravel()],
            "residual_rms_mg": (float(quality.residual_rms_mg)
                                if quality and math.isfinite(quality.residual_rms_mg) else 0.0),
            "poses": int(quality.poses) if quality else 0,
        }
        for name, value in values.items():
            self._parameters[MIRROR_PREFIX + name] = RosParameter(MIRROR_PREFIX + name, value=value)

    # ------------------------------------------------------------------ calibration in force
    def _load_calibration_at_start(self) -> None:
        path = self._calibration_path
        if not path.exists():
            self.get_logger().info(f"no calibration file at {path}: passing raw acceleration through until calibrated "
                                   f"(call {self._calibrate_service} once poses are held)")
            self._status = (DiagnosticStatus.WARN, "uncalibrated: raw passes through")
            return
        try:
            from ..core.plausibility import plausibility_problem

            calibration = load_calibration(path)
            settings = self._session.settings
            implausible = plausibility_problem(calibration, max_bias_mps2=settings.max_bias_mps2,
                                               scale_band=(settings.scale_min, settings.scale_max))
            if implausible is not None:
                raise CalibrationError(f"{path}: implausible for an accelerometer in m/s^2 ({implausible})")
        except CalibrationError as error:
            self._file_unreadable = True
            self.get_logger().error(f"calibration file unusable, left untouched, raw passes through: {error}")
            self._status = (DiagnosticStatus.ERROR, f"calibration file unusable: {error}")
            return
        self._install(calibration)
        self.get_logger().info(f"loaded calibration from {path} ({calibration.model}, {_quality_text(calibration)})")
        self._status = (DiagnosticStatus.OK, "calibrated from file")

    def _install(self, calibration: Calibration | None) -> None:
        """Put a calibration in force: the correction is rebuilt and swapped whole."""
        with self._correction_lock:
            self._calibration = calibration
            self._rebuild_correction()
        if calibration is not None:
            self._mirror(calibration)

    def _rebuild_correction(self) -> None:
        """Caller holds _correction_lock: calibration and temperature are read together."""
        temperature = self._session.temperature.value
        noise = self._session.detector.noise_floor_accel_var
        self._correction = Correction.build(self._calibration, temperature, noise)

    # ------------------------------------------------------------------ stream (hot path)
    def _on_temperature(self, msg: Temperature) -> None:
        stamp = msg.header.stamp
        if not self._session.add_temperature(stamp.sec * 1_000_000_000 + stamp.nanosec, msg.temperature):
            return
        calibration = self._calibration
        if calibration is None or calibration.temperature is None:
            return
        correction = self._correction
        filtered = self._session.temperature.value
        last = None if correction is None else correction.temperature_degc
        if filtered is not None and (last is None or abs(filtered - last) >= 0.05):
            # Re-derive the plain-float terms only when the temperature has moved, so the per-message
            # path stays a 3x3 multiply.
            with self._correction_lock:
                self._rebuild_correction()
            if self._correction is not None and self._correction.temperature_clamped:
                self._node_counts["temperature_clamped"] += 1

    def _on_imu(self, msg: Imu) -> None:
        header = msg.header
        if header.frame_id != self._frame_id:
            self._on_frame_id(header.frame_id)
        a = msg.linear_acceleration
        w = msg.angular_velocity
        ax, ay, az = a.x, a.y, a.z
        pose = self._session.add_sample(header.stamp.sec * 1_000_000_000 + header.stamp.nanosec,
                                        ax, ay, az, w.x, w.y, w.z)
        if pose is not None:
            self._pending_poses.put(pose)
            self._worker.submit(self._guard("worker", self._absorb_poses))
        correction = self._correction
        if correction is not None and self._enabled and math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az):
            a.x, a.y, a.z = correction.apply(ax, ay, az)
            gyro_bias = correction.gyro_bias_radps
            if gyro_bias is not None:
                w.x -= gyro_bias[0]
                w.y -= gyro_bias[1]
                w.z -= gyro_bias[2]
            if correction.covariance is not None:
                msg.linear_acceleration_covariance = correction.covariance
        self._publisher.publish(msg)  # non-finite samples pass on untouched: the stack sees what the driver sent

    def _on_frame_id(self, frame_id: str) -> None:
        self._session.frame_id = frame_id  # a calibration is of the frame the samples were in
        if self._frame_id is not None:
            self._node_counts["frame_id_changes"] += 1
            self.get_logger().warning(f"imu/data_raw frame_id changed from {self._frame_id!r} to {frame_id!r}",
                                      throttle_duration_sec=LOG_THROTTLE_S)
        self._frame_id = frame_id
        self._check_frame(self._calibration)

    def _check_frame(self, calibration: Calibration | None) -> None:
        if calibration is not None and calibration.frame_id and self._frame_id is not None \
                and calibration.frame_id != self._frame_id:
            self._node_counts["frame_id_mismatch"] += 1
            self.get_logger().warning(
                f"the calibration in force was made for frame {calibration.frame_id!r} but imu/data_raw is in "
                f"{self._frame_id!r}: is this the same sensor?", throttle_duration_sec=LOG_THROTTLE_S)

    # ------------------------------------------------------------------ worker thread
    def _drain(self) -> list[Any]:
        poses = []
        while True:
            try:
                poses.append(self._pending_poses.get_nowait())
            except queue.Empty:
                return poses

    def _absorb_poses(self) -> None:
        """Worker: take new poses into the store and refit (warm-started)."""
        poses = self._drain()
        if not poses:
            return
        log = self.get_logger()
        for pose in poses:
            event = self._session.add_pose(pose)
            verb = "refined" if event.merged else "accepted"
            log.info(f"pose {event.index + 1} {verb} ({_face_of(pose.accel_mps2)}, {pose.duration_s:.1f} s still)")
        with self._correction_lock:
            self._rebuild_correction()  # the noise floor (covariance) may have moved
        result = self._session.refit()
        progress = self._session.progress(self._calibration, self._calibrate_service)
        self._progress = progress
        if result is not None and result.success and result.calibration is not None:
            log.info(f"{progress.poses} poses, fit residual {result.calibration.quality.residual_rms_mg:.2f} mg rms: "
                     f"{progress.advice}")
        else:
            log.info(f"{progress.poses} poses held: {progress.advice}")
        if self._session.settings.auto_calibrate and result is not None and self._session.gates.check(result) is None:
            verdict = self._session.calibrate()
            if verdict.success and verdict.result is not None:
                applied, message = self._apply_and_save(verdict.result, verdict.calibration)
                if applied:
                    log.info("auto-calibrated: " + message)
                else:
                    log.warning("auto-calibration not applied: " + message)

    def _apply_and_save(self, result: FitResult, calibration: Calibration | None) -> tuple[bool, str]:
        """Save first, then put in force: a calibration that could not be saved is not applied, so
        what runs is always what the file says."""
        if calibration is None:
            return False, "no calibration in the result"
        if self._file_unreadable:
            return False, (f"{self._calibration_path} holds a file this node could not read (foreign or corrupt); "
                           "it is left untouched: move it away or set calibration_file")
        try:
            self._save(calibration)
        except CalibrationError as error:
            self._status = (DiagnosticStatus.ERROR, f"save failed: {error}")
            return False, f"not applied: {error}; {self._kept()}"
        self._install(calibration)
        self._check_frame(calibration)
        self._status = (DiagnosticStatus.OK, "calibrated")
        return True, f"saved to {self._calibration_path}"

    def _save(self, calibration: Calibration) -> None:
        try:
            self._calibration_path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise CalibrationError(f"cannot create {self._calibration_path.parent}: {error.strerror}") from None
        save_calibration(calibration, self._calibration_path)

    def _kept(self) -> str:
        return "previous calibration kept in force" if self._calibration is not None else \
            "no calibration in force: raw passes through"

    def _calibrate_request(self, request: Any) -> Future[tuple[bool, str]]:
        # The pose being held right now counts too (taken here, on the thread that owns the detector).
        holding = self._session.holding()
        return self._worker.submit(self._calibrate_job, holding)

    def _calibrate_job(self, holding: Any) -> tuple[bool, str]:
        for pose in self._drain():
            self._session.add_pose(pose)
        verdict = self._session.calibrate(holding)
        self._progress = self._session.progress(self._calibration, self._calibrate_service)
        if not verdict.success or verdict.result is None:
            message = f"not calibrated ({verdict.message}); {self._kept()}"
            self.get_logger().warning(f"{self._calibrate_service}: {message}")
            return False, message
        applied, saved = self._apply_and_save(verdict.result, verdict.calibration)
        if not applied:
            self.get_logger().warning(f"{self._calibrate_service}: {saved}")
            return False, saved
        self.get_logger().info(f"{self._calibrate_service}: calibrated, {saved}")
        return True, _summary_yaml(verdict.result, saved)

    def _reset_job(self) -> tuple[bool, str]:
        self._drain()
        dropped = self._session.reset()
        self._progress = self._session.progress(self._calibration, self._calibrate_service)
        message = f"dropped {dropped} poses; the calibration in force is unchanged"
        self.get_logger().info("calibration/reset: " + message)
        return True, message

    def _save_job(self) -> tuple[bool, str]:
        calibration = self._calibration
        if calibration is None:
            return False, "no calibration in force to save"
        if self._file_unreadable:
            return False, f"{self._calibration_path} holds a file this node could not read; left untouched"
        try:
            self._save(calibration)
        except CalibrationError as error:
            return False, str(error)
        return True, f"saved to {self._calibration_path}"

    # ------------------------------------------------------------------ immediate services
    def _srv_get(self, request: Any, response: Any) -> Any:
        calibration = self._calibration
        if calibration is None:
            response.success, response.message = False, "no calibration in force: raw acceleration passes through"
        else:
            response.success, response.message = True, calibration_to_yaml(calibration)
        return response

    def _on_armed(self, msg: Bool) -> None:
        armed = bool(msg.data)
        if armed == ("armed" in self._session.pause_reasons):
            return
        self._session.set_collecting(not armed, "armed")  # on the stream's thread, as add_sample
        self.get_logger().info("armed: collection paused (nothing of a flight becomes a pose)" if armed
                               else "disarmed: collection resumed" + self._still_paused())

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
        counts["callback_errors"] = sum(self._errors.values())
        return counts

    def _publish_diagnostics(self) -> None:
        progress = self._progress
        level, message = self._status
        counts = self.counters()
        if level == DiagnosticStatus.OK and any(v for k, v in counts.items() if k not in Counters.INFORMATIONAL):
            level = DiagnosticStatus.WARN
        temperature = self._session.temperature.value
        values = {
            "poses": str(progress.poses),
            "poses_needed": str(progress.min_poses),
            "missing_directions": ", ".join(progress.missing) or "none",
            "advice": progress.advice,
            "fit_residual_rms_mg": "" if progress.residual_rms_mg is None else f"{progress.residual_rms_mg:.3f}",
            "fit_bias_sigma_max_mg": "" if progress.max_bias_sigma_mg is None else f"{progress.max_bias_sigma_mg:.3f}",
            "detector_state": str(self._session.detector.state),
            # "yes", or why not: "paused (armed)", "paused (calibration/pause)" -- the stream is corrected still
            "collecting": ("yes" if self._session.collecting
                           else "paused (" + ", ".join(self._session.pause_reasons) + ")"),
            "correction": "on" if self._enabled and self._calibration is not None else "off",
            "calibration_file": str(self._calibration_path),
            "frame_id": self._frame_id or "",
            "temperature_degc": "" if temperature is None else f"{temperature:.2f}",
        }
        span = progress.temperature_span_degc
        values["temperature_span_degc"] = ("" if span is None
                                           else f"{span[0]:.1f}..{span[1]:.1f} ({span[1] - span[0]:.1f})")
        values["temperature_model"] = progress.temperature_status
        values.update({key: str(value) for key, value in counts.items()})
        for name, count in self._errors.items():
            values[f"callback_errors.{name}"] = str(count)
        calibration = self._calibration
        if calibration is not None and calibration.quality is not None:
            values["calibration_residual_rms_mg"] = f"{calibration.quality.residual_rms_mg:.3f}"
        reasons = self._session.pause_reasons
        paused = f" (collection paused: {', '.join(reasons)})" if reasons else ""
        status = DiagnosticStatus(
            level=level,
            name=f"accel_calibration: {self.get_fully_qualified_name()}",
            message=f"{message}; {progress.advice}" + paused,
            hardware_id=calibration.sensor_id if calibration is not None else self._session.settings.sensor_id,
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def close(self) -> None:
        """Let a fit or save in flight finish (the file is then the old or the new one, whole); requests
        still queued are answered 'not done'."""
        self._worker.shutdown(wait=True, cancel_futures=True)


def _fail(response: Any, error: Exception) -> Any:
    response.success, response.message = False, f"internal error ({type(error).__name__}: {error}); the node carries on"
    return response


def _failed_service(args: tuple[Any, ...], error: Exception) -> Any:
    """Fallback of a guarded service callback (request, response): the response says what failed."""
    return _fail(args[-1], error)


# Trigger and SetBool services alike answer through the response rclpy handed the callback.
_failed_trigger = _failed_set_bool = _failed_service


def _quality_text(calibration: Calibration) -> str:
    q = calibration.quality
    return f"residual {q.residual_rms_mg:.2f} mg rms over {q.poses} poses" if q else "no quality recorded"


def _face_of(accel: np.ndarray) -> str:
    axis = int(np.argmax(np.abs(accel)))
    return f"{'xyz'[axis]} {'up' if accel[axis] > 0 else 'down'}"


def _summary_yaml(result: FitResult, saved_message: str) -> str:
    c = result.calibration
    if c is None or c.quality is None or result.sigma is None:
        return f"saved: {saved_message}"
    lines = [
        f"model: {c.model}",
        f"poses: {result.poses}",
        f"residual_rms_mg: {c.quality.residual_rms_mg:.3f}",
        f"residual_max_mg: {c.quality.residual_max_mg:.3f}",
        "bias_mps2: [" + ", ".join(f"{v:.6f}" for v in c.bias) + "]",
        "bias_sigma_mps2: [" + ", ".join(f"{v:.2e}" for v in result.sigma.bias) + "]",
        "matrix: [" + ", ".join("[" + ", ".join(f"{v:.7f}" for v in row) + "]" for row in c.matrix) + "]",
        f"frame_id: '{c.frame_id}'",
    ]
    if c.temperature is not None:
        t = c.temperature
        lines.append(f"temperature_model: {{kind: {t.kind}, reference_degc: {t.reference_degc:.2f}, "
                     f"range_degc: [{t.range_degc[0]:.2f}, {t.range_degc[1]:.2f}]}}")
    if result.outliers:  # poses left out of the fit, numbered from 1 as the log numbers accepted poses
        lines.append("outliers: [" + ", ".join(
            f"{{pose: {o.index + 1}, residual_mg: {o.residual_mg:.1f}, orientation: '{o.orientation}'}}"
            for o in result.outliers) + "]")
    lines.append(f"saved: {saved_message}")
    return "\n".join(lines)


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
    problem = _params_file_problem(sys.argv[1:] if args is None else args)
    if problem is not None:
        print(f"calibration_node: error: {problem}", file=sys.stderr)
        return 2
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as error:  # noqa: BLE001 - a broken --ros-args / --params-file: one line, exit 2
        print(f"calibration_node: error: cannot start ROS: {_first_line(error)}", file=sys.stderr)
        return 2

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()  # the spin loop ends; a second signal (a terminal under ros2 launch) changes nothing

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    try:
        try:
            node = CalibrationNode()
        except AccelCalibrationError as error:
            print(f"calibration_node: error: {error}", file=sys.stderr)
            return 2
        except Exception as error:  # noqa: BLE001 - rclpy's own refusals (e.g. a value outside a range)
            print(f"calibration_node: error: {_first_line(error)}", file=sys.stderr)
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


def _params_file_problem(argv: list[str]) -> str | None:
    """rcl reports a missing or broken --params-file in several lines of its own; say it in one first."""
    import yaml

    for flag, path in zip(argv, argv[1:]):
        if flag != "--params-file":
            continue
        try:
            with open(path, encoding="utf-8") as stream:
                yaml.safe_load(stream)
        except OSError as error:
            return f"cannot read --params-file {path}: {error.strerror}"
        except yaml.YAMLError as error:
            return f"--params-file {path} is not valid YAML ({_first_line(error)})"
    return None


def _first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__


if __name__ == "__main__":
    sys.exit(main())
