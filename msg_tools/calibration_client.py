"""A client of calibration_node over real rclpy: publishes imu/data_raw + imu/temperature, collects
imu/data_calibrated and /diagnostics, calls the services. Spins in a background thread so it can
collect while the caller publishes. Used by the tests and `make demo`; waits on what it needs."""
from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.experimental import EventsExecutor
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import SetBool, Trigger

if TYPE_CHECKING:
    from .synthetic_imu import SyntheticSamples

STREAM_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
# The node publishes imu/data_calibrated RELIABLE: collecting reliably loses nothing on a busy machine.
COLLECT_QOS = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
CHUNK = 25  # messages in flight at most: half the node's input depth (50), so best effort drops none


class CalibrationClient:
    def __init__(self, name: str = "calibration_client", namespace: str = "") -> None:
        self.node = rclpy.create_node(name, namespace=namespace)
        self.imu_pub = self.node.create_publisher(Imu, "imu/data_raw", STREAM_QOS)
        self.temperature_pub = self.node.create_publisher(Temperature, "imu/temperature", STREAM_QOS)
        self.corrected: list[Imu] = []
        self.diagnostics: list[dict[str, Any]] = []  # one per status of ours: level, message and its values
        self.node.create_subscription(Imu, "imu/data_calibrated", self.corrected.append, COLLECT_QOS)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, 10)
        self.clients = {
            name: self.node.create_client(Trigger, name)
            for name in ("calibrate", "calibration/get", "calibration/reset", "calibration/save")
        }
        self.clients["calibration/enable"] = self.node.create_client(SetBool, "calibration/enable")
        # Spin in the background so the stream is collected while this thread publishes. The EventsExecutor
        # (as the node's) takes 2.5x less CPU per message than the SingleThreadedExecutor: playback is
        # closed-loop, so the client's cost is on every test's path. Entities created on `node` later (a
        # test's own clients and subscriptions) are taken up as they are made.
        self.executor = EventsExecutor()
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._running = True
        self._thread.start()

    def _spin(self) -> None:
        # In slices, as the node does (ros/process.py): spin() without a timeout busy-loops in the PyPI
        # wheel, and a slice lets the loop see `_running` within 0.05 s.
        never = Future()
        while self._running:
            self.executor.spin_until_future_complete(never, timeout_sec=0.05)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.name.startswith("accel_calibration"):
                self.diagnostics.append({"level": status.level, "message": status.message,
                                         **{kv.key: kv.value for kv in status.values}})

    def spin_until(self, predicate: Callable[[], object], timeout: float = 20.0, poll_s: float = 0.02) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if predicate():
                return True
            time.sleep(poll_s)
        return bool(predicate())

    def wait_ready(self, timeout: float = 20.0) -> None:
        """The node answers services and echoes the stream. Matching alone is not proof: DDS remembers a
        node that just exited until its lease ends, so a restarted node is only up once a live answer
        and a probe message have come back. Probes carry stamps near 0, before any real session."""
        for name, client in self.clients.items():
            assert client.wait_for_service(timeout_sec=timeout), f"service {name} not available"
        # A request sent while the client is matched only to a server that just exited (DDS keeps it until
        # its lease ends) is lost: ask again until the live node answers.
        deadline = time.monotonic() + timeout
        while True:
            future = self.clients["calibration/get"].call_async(Trigger.Request())
            if self.spin_until(future.done, 1.0):
                break
            assert time.monotonic() < deadline, "calibration/get did not answer"
        deadline = time.monotonic() + timeout
        probe = 0
        while time.monotonic() < deadline:
            probe += 1
            msg = Imu()
            msg.header.stamp.nanosec = probe
            msg.header.frame_id = "imu_link"  # the frame the tests play in: no frame change seen
            msg.linear_acceleration.z = 9.8
            self.imu_pub.publish(msg)
            if self.spin_until(lambda: any(m.header.stamp.sec == 0 for m in self.corrected), 0.1):
                break
        else:
            raise AssertionError("no echo on imu/data_calibrated")
        self.spin_until(lambda: False, 0.2)  # late probe echoes
        self.corrected.clear()

    def call(self, name: str, data: bool | None = None, timeout: float = 20.0) -> Any:
        client = self.clients[name]
        request = SetBool.Request(data=data) if name == "calibration/enable" else Trigger.Request()
        future = client.call_async(request)
        assert self.spin_until(future.done, timeout), f"{name} did not answer"
        return future.result()

    def play(self, samples: SyntheticSamples, *, start_ns: int, indices: Sequence[int] | None = None,
             temperature: bool = True, frame_id: str = "imu_link",
             temperature_period_s: float = 0.1, chunk: int = CHUNK, timeout: float = 20.0) -> int:
        """Closed-loop playback: publish `chunk` messages, wait until the node has echoed them on
        imu/data_calibrated, then the next chunk. Every message reaches the node however busy the
        machine is (its best-effort input queue never overflows), and nothing waits a fixed time.
        Header stamps are start_ns + the sample's stream time. Returns messages sent."""
        from .conversions import make_imu, make_temperature

        t = samples.t_ns
        order = list(range(len(t))) if indices is None else list(indices)
        accel, gyro, temps = samples.accel_raw.tolist(), samples.gyro_raw.tolist(), samples.temperature_degc.tolist()
        period_ns = int(temperature_period_s * 1e9)
        next_temperature_ns = None
        base = len(self.corrected)
        for start in range(0, len(order), chunk):
            block = order[start:start + chunk]
            for i in block:
                stamp = start_ns + int(t[i])
                if temperature and (next_temperature_ns is None or t[i] >= next_temperature_ns):
                    self.temperature_pub.publish(make_temperature(stamp, temps[i], frame_id))
                    next_temperature_ns = t[i] + period_ns
                self.imu_pub.publish(make_imu(stamp, accel[i], gyro[i], frame_id))
            expected = base + start + len(block)
            if not self.spin_until(self._echoed(expected), timeout, poll_s=0.0005):
                raise AssertionError(f"node echoed {len(self.corrected) - base} of {start + len(block)} messages "
                                     f"within {timeout:g} s")
        return len(order)

    def _echoed(self, count: int) -> Callable[[], bool]:
        """Whether `count` corrected messages have come back."""
        return lambda: len(self.corrected) >= count

    def settle(self, count: int, timeout: float = 10.0) -> bool:
        """Wait until `count` corrected messages have arrived (or the timeout)."""
        return self.spin_until(lambda: len(self.corrected) >= count, timeout)

    def destroy(self) -> None:
        self._running = False
        self._thread.join()
        # shutdown() removes the node and takes its callbacks off its entities while they still exist.
        self.executor.shutdown()
        self.node.destroy_node()
