"""Real-process harness for calibration_node tests: the node in its own process, a tester node in this
one (publisher of the synthetic session, subscriber of the corrected stream and diagnostics, service
clients), all over real rclpy / Fast DDS. Waits on what it needs, never a fixed sleep."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import SetBool, Trigger

STREAM_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)


class NodeProcess:
    """calibration_node as a user runs it (console script), with --ros-args parameters."""

    def __init__(self, calibration_file: Path, *params: str, log_path: Path | None = None):
        args = [str(Path(sys.executable).parent / "calibration_node"), "--ros-args",
                "-p", f"calibration_file:={calibration_file}"]
        for p in params:
            args += ["-p", p]
        self.log_path = log_path or calibration_file.with_suffix(".node.log")
        self._log = open(self.log_path, "w")
        self.process = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT, env=dict(os.environ))

    def log(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()

    def stop(self, timeout: float = 15.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self._log.close()
        return self.process.returncode


class NodeTester:
    def __init__(self, name: str = "tester"):
        self.node = rclpy.create_node(name)
        self.imu_pub = self.node.create_publisher(Imu, "imu/data_raw", QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST))
        self.temperature_pub = self.node.create_publisher(Temperature, "imu/temperature", QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST))
        self.corrected: list[Imu] = []
        self.diagnostics: list = []
        self.node.create_subscription(Imu, "imu/data_calibrated", self.corrected.append, STREAM_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.clients = {
            name: self.node.create_client(Trigger, name)
            for name in ("calibrate", "calibration/get", "calibration/reset", "calibration/save")
        }
        self.clients["calibration/enable"] = self.node.create_client(SetBool, "calibration/enable")
        # Spin in the background so the stream is collected while this thread publishes.
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._running = True
        self._thread.start()

    def _spin(self):
        while self._running:
            self.executor.spin_once(timeout_sec=0.05)

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.name.startswith("accel_calibration"):
                self.diagnostics.append({"level": status.level, "message": status.message,
                                         **{kv.key: kv.value for kv in status.values}})

    def spin_until(self, predicate, timeout: float = 20.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(0.02)
        return predicate()

    def wait_ready(self, timeout: float = 20.0):
        """Services up and both stream directions matched."""
        for name, client in self.clients.items():
            assert client.wait_for_service(timeout_sec=timeout), f"service {name} not available"
        assert self.spin_until(lambda: self.imu_pub.get_subscription_count() > 0
                               and self.node.count_publishers("imu/data_calibrated") > 0, timeout)
        # Our subscription must be matched by the node's publisher too before data flows back.
        assert self.spin_until(lambda: self.node.get_subscriptions_info_by_topic("imu/data_calibrated") != [], timeout)

    def call(self, name: str, data: bool | None = None, timeout: float = 20.0):
        client = self.clients[name]
        request = SetBool.Request(data=data) if name == "calibration/enable" else Trigger.Request()
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"{name} did not answer"
        return future.result()

    def settle(self, count: int, timeout: float = 10.0) -> bool:
        """Wait until `count` corrected messages have arrived (or the timeout)."""
        return self.spin_until(lambda: len(self.corrected) >= count, timeout)

    def destroy(self):
        self._running = False
        self._thread.join()
        self.executor.remove_node(self.node)
        self.node.destroy_node()
