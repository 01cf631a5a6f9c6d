"""calibration_node: the live adapter. Imu in, corrected Imu out; static poses found in the stream feed
the core's online calibrator; services to calibrate, inspect, reset, save and switch correction.

Threads: the executor thread runs the per-message callback (kept to plain-float arithmetic) and
the services; one worker thread owns the pose store and runs every fit, so a refit never stalls
the stream. Results cross over as immutable tuples, swapped by one assignment.
"""
from __future__ import annotations

import collections
import math
import os
import queue
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import SetBool, Trigger

from ..core.calibration import MG, STANDARD_GRAVITY, Calibration
from ..io.calibration_file import calibration_to_yaml, load_calibration, save_calibration
from ..core.errors import CalibrationError
from ..core.models import parameter_count
from ..core.online_calibrator import OnlineCalibrator, QualityGates
from ..core.pose_store import PoseStore
from ..core.static_detector import StaticDetector
from ..core.temperature_filter import TemperatureFilter
from ..core.temperature_models import TEMPERATURE_MODELS, TemperatureOptions

# Best effort, depth 50 on both sides: measured 0 % loss to 3 kHz here (PERF_NOTES); still matches
# drivers publishing with sensor-data QoS.
STREAM_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
SERVICE_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
MIRROR_PREFIX = "calibration."
GATE_PARAMETERS = ("min_poses", "max_residual_rms_mg", "max_bias_sigma_mg", "max_bias_mps2", "scale_min", "scale_max")


def _describe(text: str, read_only: bool = False) -> ParameterDescriptor:
    return ParameterDescriptor(description=text, read_only=read_only)


class CalibrationNode(Node):
    def __init__(self, **kwargs):
        super().__init__("accel_calibration", **kwargs)
        self._declare_parameters()
        p = self._params = {name: self.get_parameter(name).value for name in self._parameter_names}
        self._calibration_path = Path(os.path.expanduser(p["calibration_file"]))
        self._detector = StaticDetector(
            window_s=p["static.window_s"],
            min_hold_s=p["static.min_hold_s"],
            accel_var_threshold=p["static.accel_var_threshold"] or None,
            gyro_var_threshold=p["static.gyro_var_threshold"] or None,
            k_sigma=p["static.k_sigma"],
        )
        self._gates = self._gates_from(p)
        self._online = OnlineCalibrator(
            model=p["model"],
            gravity=p["gravity"],
            gates=self._gates,
            store=PoseStore(merge_angle_deg=p["merge_angle_deg"], capacity=p["max_poses"],
                            temperature_bin_degc=p["temperature.bin_degc"]),
            temperature=TemperatureOptions(model=p["temperature.model"], bias_order=p["temperature.bias_order"],
                                           scale_order=p["temperature.scale_order"],
                                           segment_width_degc=p["temperature.segment_width_degc"],
                                           min_span_degc=p["temperature.min_span_degc"]),
        )
        self._accel_limit = 0.995 * p["accel_range_mps2"]
        self._temperature = TemperatureFilter(timeout_s=p["temperature_timeout_s"])

        # State shared with the worker: replaced whole, never mutated.
        self._calibration: Calibration | None = None
        self._terms: tuple | None = None  # 9 matrix + 3 bias floats of the calibration in force
        self._gyro_bias: tuple | None = None
        self._covariance: tuple | None = None
        self._enabled = True
        self._file_unreadable = False  # a file we could not read is never overwritten
        self._progress = None
        self._status = (DiagnosticStatus.OK, "starting")
        self._counts = collections.Counter()
        self._last_stamp_ns = -1
        self._terms_temperature: float | None = None
        self._pending_poses: queue.SimpleQueue = queue.SimpleQueue()
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="accel_calibration_fit")
        self._mirror_update = threading.local()

        self._load_calibration_at_start()
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._publisher = self.create_publisher(Imu, "imu/data_calibrated", STREAM_QOS)
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.create_subscription(Imu, "imu/data_raw", self._on_imu, STREAM_QOS)
        self.create_subscription(Temperature, "imu/temperature", self._on_temperature, STREAM_QOS)
        # Services keep up to 100 requests (default 10): several tools may call /calibrate at once.
        self.create_service(Trigger, "calibrate", self._srv_calibrate, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, "calibration/get", self._srv_get, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, "calibration/reset", self._srv_reset, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, "calibration/save", self._srv_save, qos_profile=SERVICE_QOS)
        self.create_service(SetBool, "calibration/enable", self._srv_enable, qos_profile=SERVICE_QOS)
        self.create_timer(1.0, self._publish_diagnostics)

    # ------------------------------------------------------------------ parameters
    def _declare_parameters(self):
        specs = [
            ("calibration_file", "~/.ros/accel_calibration.yaml", "calibration YAML loaded at start and written by /calibrate and calibration/save", True),
            ("model", "sphere9", "online error model: sphere9 (bias + lower-triangular M) or six (bias + diagonal)", True),
            ("gravity", STANDARD_GRAVITY, "local gravity magnitude, m/s^2", True),
            ("auto_calibrate", False, "apply (and save) a new fit by itself once it passes the quality gates", False),
            ("min_poses", 12, "poses needed before a fit may be applied", False),
            ("max_residual_rms_mg", 15.0, "quality gate: largest residual rms (mg) of a fit that may be applied", False),
            ("max_bias_sigma_mg", 5.0, "quality gate: largest bias uncertainty (1 sigma, mg) of a fit that may be applied", False),
            ("max_bias_mps2", 2.0, "plausibility gate: largest |bias| per axis, m/s^2", False),
            ("scale_min", 0.9, "plausibility gate: smallest correction gain per axis (row norm of M)", False),
            ("scale_max", 1.1, "plausibility gate: largest correction gain per axis (row norm of M)", False),
            ("merge_angle_deg", 5.0, "a new pose within this angle of a held one is merged into it", True),
            ("max_poses", 100, "pose store capacity; the oldest pose gives way beyond it", True),
            ("accel_range_mps2", 16 * STANDARD_GRAVITY, "sensor full scale; samples at it are counted as saturated and kept out of the fit", True),
            ("temperature_timeout_s", 5.0, "a temperature older than this (header time) is stale and not used", True),
            ("temperature.model", "polynomial", "temperature model learned once the poses span min_span_degc: polynomial, segmented or none", True),
            ("temperature.bias_order", 2, "polynomial model: order of the bias drift (0..3)", True),
            ("temperature.scale_order", 1, "polynomial model: order of the scale drift (0..2)", True),
            ("temperature.segment_width_degc", 10.0, "segmented model: segment width, degC", True),
            ("temperature.min_span_degc", 10.0, "smallest span of pose temperatures to fit a temperature model, degC", True),
            ("temperature.bin_degc", 5.0, "poses at one orientation but temperatures this far apart are kept apart", True),
            ("static.window_s", 0.5, "static detector: sliding window, seconds of header time", True),
            ("static.min_hold_s", 1.0, "static detector: shortest still interval kept as a pose, seconds", True),
            ("static.accel_var_threshold", 0.0, "static detector: accel variance threshold (m/s^2)^2; 0 = k_sigma x measured noise floor", True),
            ("static.gyro_var_threshold", 0.0, "static detector: gyro variance threshold (rad/s)^2; 0 = k_sigma x measured noise floor", True),
            ("static.k_sigma", 6.0, "static detector: threshold as a multiple of the noise-floor variance", True),
        ]
        self._parameter_names = []
        for name, default, text, read_only in specs:
            self.declare_parameter(name, default, _describe(text, read_only))
            self._parameter_names.append(name)
        for name, default, text in [
            ("bias", [0.0, 0.0, 0.0], "bias b of the calibration in force, m/s^2"),
            ("matrix", [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], "matrix M of the calibration in force, row-major"),
            ("residual_rms_mg", 0.0, "residual rms of the calibration in force, mg"),
            ("poses", 0, "poses the calibration in force was fitted to"),
        ]:
            self.declare_parameter(MIRROR_PREFIX + name, default, _describe(text + " (read-only mirror)"))
        self._validate_startup_parameters()

    def _validate_startup_parameters(self):
        p = {name: self.get_parameter(name).value for name in self._parameter_names}
        problems = []
        if p["model"] not in ("six", "sphere9"):
            problems.append(f"model must be six or sphere9, got {p['model']!r}")
        elif p["min_poses"] < parameter_count(p["model"]):
            problems.append(f"min_poses must be at least {parameter_count(p['model'])} for model {p['model']}")
        if p["temperature.model"] not in TEMPERATURE_MODELS:
            problems.append(f"temperature.model must be one of {', '.join(TEMPERATURE_MODELS)}, got {p['temperature.model']!r}")
        if not 9.0 < p["gravity"] < 10.5:
            problems.append(f"gravity must be 9..10.5 m/s^2, got {p['gravity']}")
        if problems:
            raise CalibrationError("; ".join(problems))

    def _on_set_parameters(self, parameters):
        for parameter in parameters:
            if parameter.name.startswith(MIRROR_PREFIX) and not getattr(self._mirror_update, "active", False):
                return SetParametersResult(successful=False, reason=f"{parameter.name} mirrors the calibration in force and is read-only")
            if parameter.name == "min_poses":
                if parameter.type_ != Parameter.Type.INTEGER or parameter.value < parameter_count(self._online.model):
                    return SetParametersResult(successful=False, reason=f"min_poses must be an integer >= {parameter_count(self._online.model)}")
            if parameter.name == "max_residual_rms_mg" and not (parameter.type_ == Parameter.Type.DOUBLE and parameter.value > 0):
                return SetParametersResult(successful=False, reason="max_residual_rms_mg must be a positive number")
        changed = dict(self._params)
        for parameter in parameters:
            if parameter.name in GATE_PARAMETERS + ("auto_calibrate",):
                changed[parameter.name] = parameter.value
        try:
            gates = self._gates_from(changed)
        except (CalibrationError, TypeError) as error:
            return SetParametersResult(successful=False, reason=str(error))
        self._params = changed
        self._gates = gates
        self._online.gates = gates
        return SetParametersResult(successful=True)

    @staticmethod
    def _gates_from(p) -> QualityGates:
        return QualityGates(
            min_poses=p["min_poses"], max_residual_rms_mg=float(p["max_residual_rms_mg"]),
            max_bias_sigma_mg=float(p["max_bias_sigma_mg"]), max_bias_mps2=float(p["max_bias_mps2"]),
            scale_band=(float(p["scale_min"]), float(p["scale_max"])),
        )

    def _mirror(self, calibration: Calibration):
        self._mirror_update.active = True
        try:
            quality = calibration.quality
            self.set_parameters([
                Parameter(MIRROR_PREFIX + "bias", Parameter.Type.DOUBLE_ARRAY, [float(v) for v in calibration.bias]),
                Parameter(MIRROR_PREFIX + "matrix", Parameter.Type.DOUBLE_ARRAY, [float(v) for v in calibration.matrix.ravel()]),
                Parameter(MIRROR_PREFIX + "residual_rms_mg", Parameter.Type.DOUBLE, float(quality.residual_rms_mg) if quality else 0.0),
                Parameter(MIRROR_PREFIX + "poses", Parameter.Type.INTEGER, int(quality.poses) if quality else 0),
            ])
        finally:
            self._mirror_update.active = False

    # ------------------------------------------------------------------ calibration in force
    def _load_calibration_at_start(self):
        path = self._calibration_path
        if not path.exists():
            self.get_logger().info(f"no calibration file at {path}: passing raw acceleration through until calibrated")
            self._status = (DiagnosticStatus.WARN, "uncalibrated: raw passes through")
            return
        try:
            calibration = load_calibration(path)
            implausible = self._gates.plausibility(calibration)
            if implausible is not None:
                raise CalibrationError(f"{path}: implausible for an accelerometer in m/s^2 ({implausible})")
        except CalibrationError as error:
            self._file_unreadable = True
            self.get_logger().error(f"calibration file unusable, left untouched, raw passes through: {error}")
            self._status = (DiagnosticStatus.ERROR, f"calibration file unusable: {error}")
            return
        self._set_calibration(calibration)
        self.get_logger().info(f"loaded calibration from {path} ({calibration.model}, {self._quality_text(calibration)})")
        self._status = (DiagnosticStatus.OK, "calibrated from file")

    @staticmethod
    def _quality_text(calibration: Calibration) -> str:
        q = calibration.quality
        return f"residual {q.residual_rms_mg:.2f} mg rms over {q.poses} poses" if q else "no quality recorded"

    def _set_calibration(self, calibration: Calibration):
        self._calibration = calibration
        self._terms = calibration.terms_at(self._temperature.value)
        self._terms_temperature = self._temperature.value
        gyro_bias = calibration.gyro_bias_radps
        if gyro_bias is not None:
            self._gyro_bias = tuple(float(v) for v in gyro_bias)
        self._update_covariance()
        self._mirror(calibration)

    def _update_covariance(self):
        """REP-145 linear_acceleration_covariance: measured noise (through M) plus the calibration's own
        uncertainty at |a| = g. Computed when either changes, never per message."""
        calibration = self._calibration
        noise = self._detector.noise_floor_accel_var
        if calibration is None and noise is None:
            self._covariance = None  # keep the driver's covariance
            return
        matrix = calibration.matrix if calibration is not None else np.eye(3)
        cov = np.zeros((3, 3))
        if noise is not None:
            cov += matrix @ np.diag(np.broadcast_to(noise, 3)) @ matrix.T
        if calibration is not None and calibration.bias_sigma is not None and calibration.matrix_sigma is not None:
            g = calibration.gravity
            cov += np.diag((matrix**2) @ calibration.bias_sigma**2 + (calibration.matrix_sigma**2).sum(axis=1) * g * g / 3)
        self._covariance = tuple(float(v) for v in cov.ravel())

    # ------------------------------------------------------------------ stream (hot path)
    def _on_temperature(self, msg: Temperature):
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if not self._temperature.update(stamp_ns, msg.temperature):
            self._counts["temperature_bad"] += 1
            return
        filtered = self._temperature.value
        calibration = self._calibration
        if calibration is not None and calibration.temperature is not None:
            # Re-derive the plain-float correction only when the temperature has moved (10 Hz at most),
            # so the per-message path stays a 3x3 multiply.
            last = self._terms_temperature
            if last is None or abs(filtered - last) >= 0.05:
                self._terms = calibration.terms_at(filtered)
                self._terms_temperature = filtered
                if calibration.temperature_clamped(filtered):
                    self._counts["temperature_clamped"] += 1

    def _on_imu(self, msg: Imu):
        stamp = msg.header.stamp
        t_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        a = msg.linear_acceleration
        ax, ay, az = a.x, a.y, a.z
        w = msg.angular_velocity
        if not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az)):
            self._counts["non_finite"] += 1
            self._publisher.publish(msg)  # passed on untouched: the stack sees what the driver sent
            return
        limit = self._accel_limit
        if t_ns <= self._last_stamp_ns:
            self._counts["stamp_backwards"] += 1
        elif abs(ax) >= limit or abs(ay) >= limit or abs(az) >= limit:
            self._counts["saturated"] += 1
            self._last_stamp_ns = t_ns
        else:
            self._last_stamp_ns = t_ns
            temperature = self._temperature.at(t_ns)
            if temperature is None and self._temperature.value is not None:
                self._counts["temperature_stale"] += 1
            pose = self._detector.update(t_ns, ax, ay, az, w.x, w.y, w.z, temperature)
            if pose is not None:
                self._pending_poses.put(pose)
                self._worker.submit(self._absorb_poses)
        terms = self._terms
        if terms is not None and self._enabled:
            m00, m01, m02, m10, m11, m12, m20, m21, m22, b0, b1, b2 = terms
            x, y, z = ax - b0, ay - b1, az - b2
            a.x = m00 * x + m01 * y + m02 * z
            a.y = m10 * x + m11 * y + m12 * z
            a.z = m20 * x + m21 * y + m22 * z
            gyro_bias = self._gyro_bias
            if gyro_bias is not None:
                w.x -= gyro_bias[0]
                w.y -= gyro_bias[1]
                w.z -= gyro_bias[2]
            covariance = self._covariance
            if covariance is not None:
                msg.linear_acceleration_covariance = covariance
        self._publisher.publish(msg)

    # ------------------------------------------------------------------ worker thread
    def _drain(self) -> list:
        poses = []
        while True:
            try:
                poses.append(self._pending_poses.get_nowait())
            except queue.Empty:
                return poses

    def _absorb_poses(self):
        """Worker: take new poses into the store and refit (warm-started)."""
        poses = self._drain()
        if not poses:
            return
        log = self.get_logger()
        for pose in poses:
            event = self._online.add_pose(pose)
            face = _face_of(pose.accel_mps2)
            if event.merged:
                log.info(f"pose {event.index + 1} refined ({face}, {pose.duration_s:.1f} s still)")
            else:
                log.info(f"pose {event.index + 1} accepted ({face}, {pose.duration_s:.1f} s still)")
        self._update_covariance()
        result = self._online.refit()
        progress = self._online.progress(self._calibration)
        self._progress = progress
        if result is not None and result.success:
            log.info(
                f"{progress.poses} poses, fit residual {result.calibration.quality.residual_rms_mg:.2f} mg rms, "
                f"bias sigma {progress.max_bias_sigma_mg:.2f} mg: {progress.advice}"
            )
        else:
            log.info(f"{progress.poses} poses held: {progress.advice}")
        if self._params["auto_calibrate"] and result is not None and self._gates.check(result) is None:
            applied, message = self._apply_and_save(result)
            log.info(("auto-calibrated: " if applied else "auto-calibration not applied: ") + message)

    def _apply_and_save(self, result) -> tuple[bool, str]:
        """Save first, then put in force: a calibration that could not be saved is not applied, so
        what runs is always what the file says."""
        calibration = result.calibration
        gyro_bias = self._online.gyro_bias_radps()
        if gyro_bias is not None:
            calibration = calibration.replace(gyro_bias_radps=gyro_bias)
        if self._file_unreadable:
            return False, (
                f"{self._calibration_path} holds a file this node could not read (foreign or corrupt); "
                "it is left untouched: move it away or set calibration_file"
            )
        try:
            save_calibration(calibration, self._calibration_path)
        except CalibrationError as error:
            self._status = (DiagnosticStatus.ERROR, f"save failed: {error}")
            return False, f"not applied, previous calibration kept in force: {error}"
        self._set_calibration(calibration)
        self._status = (DiagnosticStatus.OK, "calibrated")
        return True, f"saved to {self._calibration_path}"

    def _calibrate_job(self, holding) -> tuple[bool, str]:
        for pose in self._drain():
            self._online.add_pose(pose)
        result, reason = self._online.calibrate(() if holding is None else (holding,))
        self._progress = self._online.progress(self._calibration)
        if reason is not None:
            return False, f"not calibrated ({reason}); previous calibration kept in force"
        applied, message = self._apply_and_save(result)
        if not applied:
            return False, message
        return True, _summary_yaml(result, message)

    def _reset_job(self) -> int:
        self._drain()
        dropped = len(self._online.store)
        self._online.store.clear()
        self._online.last_fit = None
        self._progress = self._online.progress(self._calibration)
        return dropped

    # ------------------------------------------------------------------ services
    def _srv_calibrate(self, request, response):
        # The pose being held right now counts too (taken here, on the thread that owns the detector).
        holding = self._detector.peek()
        response.success, response.message = self._worker.submit(self._calibrate_job, holding).result()
        (self.get_logger().info if response.success else self.get_logger().warning)(
            "/calibrate: " + response.message.splitlines()[0]
        )
        return response

    def _srv_get(self, request, response):
        calibration = self._calibration
        if calibration is None:
            response.success, response.message = False, "no calibration in force: raw acceleration passes through"
        else:
            response.success, response.message = True, calibration_to_yaml(calibration)
        return response

    def _srv_reset(self, request, response):
        dropped = self._worker.submit(self._reset_job).result()
        response.success, response.message = True, f"dropped {dropped} poses; the calibration in force is unchanged"
        self.get_logger().info("calibration/reset: " + response.message)
        return response

    def _srv_save(self, request, response):
        calibration = self._calibration
        if calibration is None:
            response.success, response.message = False, "no calibration in force to save"
        elif self._file_unreadable:
            response.success, response.message = False, f"{self._calibration_path} holds a file this node could not read; left untouched"
        else:
            try:
                save_calibration(calibration, self._calibration_path)
                response.success, response.message = True, f"saved to {self._calibration_path}"
            except CalibrationError as error:
                response.success, response.message = False, str(error)
        return response

    def _srv_enable(self, request, response):
        self._enabled = bool(request.data)
        response.success = True
        response.message = "correction on" if self._enabled else "correction off: raw passes through"
        self.get_logger().info("calibration/enable: " + response.message)
        return response

    # ------------------------------------------------------------------ diagnostics
    def _publish_diagnostics(self):
        progress = self._progress or self._online.progress(self._calibration)
        level, message = self._status
        counts = dict(self._counts)
        bad = {k: v for k, v in counts.items() if v}
        if bad and level == DiagnosticStatus.OK:
            level = DiagnosticStatus.WARN
        values = {
            "poses": str(progress.poses),
            "poses_needed": str(progress.min_poses),
            "missing_directions": ", ".join(progress.missing) or "none",
            "advice": progress.advice,
            "fit_residual_rms_mg": "" if progress.residual_rms_mg is None else f"{progress.residual_rms_mg:.3f}",
            "fit_bias_sigma_max_mg": "" if progress.max_bias_sigma_mg is None else f"{progress.max_bias_sigma_mg:.3f}",
            "detector_state": str(self._detector.state),
            "correction": "on" if self._enabled and self._terms is not None else "off",
            "calibration_file": str(self._calibration_path),
            "temperature_degc": "" if self._temperature.value is None else f"{self._temperature.value:.2f}",
        }
        span = progress.temperature_span_degc
        values["temperature_span_degc"] = "" if span is None else f"{span[0]:.1f}..{span[1]:.1f} ({span[1] - span[0]:.1f})"
        values["temperature_model"] = progress.temperature_status
        for key in ("non_finite", "saturated", "stamp_backwards", "temperature_stale", "temperature_bad", "temperature_clamped"):
            values[key] = str(counts.get(key, 0))
        if self._calibration is not None and self._calibration.quality is not None:
            values["calibration_residual_rms_mg"] = f"{self._calibration.quality.residual_rms_mg:.3f}"
        status = DiagnosticStatus(
            level=level,
            name=f"accel_calibration: {self.get_fully_qualified_name()}",
            message=f"{message}; {progress.advice}",
            hardware_id=self._calibration.sensor_id if self._calibration else "",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(array)

    def destroy_node(self):
        self._worker.shutdown(wait=True, cancel_futures=True)
        return super().destroy_node()


def _face_of(accel) -> str:
    axis = int(np.argmax(np.abs(accel)))
    return f"{'xyz'[axis]} {'up' if accel[axis] > 0 else 'down'}"


def _summary_yaml(result, saved_message: str) -> str:
    c = result.calibration
    lines = [
        f"model: {c.model}",
        f"poses: {result.poses}",
        f"residual_rms_mg: {c.quality.residual_rms_mg:.3f}",
        f"residual_max_mg: {c.quality.residual_max_mg:.3f}",
        "bias_mps2: [" + ", ".join(f"{v:.6f}" for v in c.bias) + "]",
        "bias_sigma_mps2: [" + ", ".join(f"{v:.2e}" for v in result.sigma.bias) + "]",
        "matrix: [" + ", ".join("[" + ", ".join(f"{v:.7f}" for v in row) + "]" for row in c.matrix) + "]",
        f"saved: {saved_message}",
    ]
    if c.temperature is not None:
        t = c.temperature
        lines.insert(-1, f"temperature_model: {{kind: {t.kind}, reference_degc: {t.reference_degc:.2f}, "
                         f"range_degc: [{t.range_degc[0]:.2f}, {t.range_degc[1]:.2f}]}}")
    return "\n".join(lines)


def spin_node(node: Node) -> None:
    """EventsExecutor costs ~2.4x less CPU per message than the SingleThreadedExecutor here; its
    spin() without a timeout busy-loops in the PyPI wheel, so spin in slices (PERF_NOTES)."""
    from rclpy.experimental import EventsExecutor

    executor = EventsExecutor()
    executor.add_node(node)
    never = rclpy.task.Future()
    try:
        while rclpy.ok():
            executor.spin_until_future_complete(never, timeout_sec=0.5)
    finally:
        executor.remove_node(node)


def main(args=None) -> int:
    rclpy.init(args=args)
    node = None
    try:
        node = CalibrationNode()
        spin_node(node)
    except CalibrationError as error:
        print(f"calibration_node: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        pass
    except rclpy.executors.ExternalShutdownException:
        pass
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
