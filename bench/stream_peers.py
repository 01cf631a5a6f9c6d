"""Processes for bench_node_stream.py: a paced Imu publisher, a bare relay, and a counting subscriber.

publish RATE SECONDS        a sensor turned between still poses (1.5 s still, 0.5 s turning: the node finds a
                            pose and refits every 2 s), each Imu stamped with the wall clock at publish
                            (latency = receive - stamp)
relay                       imu/data_raw -> imu/data_calibrated unchanged, rclpy.spin (SingleThreadedExecutor)
relay-events                the same on rclpy's EventsExecutor, spun in slices as the node spins (~2.4x less CPU
                            per message: the cheapest bare relay rclpy offers)
subscribe SECONDS OUT.json  counts imu/data_calibrated, writes delivered count and latencies (EventsExecutor, so
                            the measuring process takes as little of the 2 cores as it can)
"""
import json
import sys
import time

import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
# The measuring subscriber must not be where messages are lost: a deep queue (the relay and the node
# keep their own input depths).
MEASURE_QOS = QoSProfile(depth=2000, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)


def wait_for_subscribers(node, publisher, count=1, timeout=30.0):
    deadline = time.monotonic() + timeout
    while publisher.get_subscription_count() < count and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)


def turned_sensor(rate_hz: float) -> tuple[list, list]:
    """A sensor with MPU-6050-like errors held still in 12 orientations in turn, as plain floats."""
    import numpy as np

    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    errors = SensorErrors.mpu6050_like(np.random.default_rng(7), noise_mps2=0.02)
    samples = SyntheticImu(errors, spread_orientations(12, np.random.default_rng(8)), dwell_s=1.5, move_s=0.5,
                           rate_hz=rate_hz, seed=7).samples()
    return samples.accel_raw.tolist(), samples.gyro_raw.tolist()


def publish(rate_hz: float, seconds: float) -> None:
    rclpy.init()
    node = rclpy.create_node("bench_publisher")
    pub = node.create_publisher(Imu, "imu/data_raw", QOS)
    wait_for_subscribers(node, pub)
    time.sleep(0.5)  # the relay's own publisher to the subscriber matches too; both sides have discovered
    msg = Imu()
    msg.header.frame_id = "imu_link"
    msg.orientation_covariance[0] = -1.0
    accel, gyro = turned_sensor(rate_hz)
    period = 1.0 / rate_hz
    total = int(rate_hz * seconds)
    start = time.perf_counter()
    for i in range(total):
        target = start + i * period
        wait = target - time.perf_counter()
        if wait > 0:  # sleeping, not spinning: a spinning publisher would take a whole core from the measured
            time.sleep(wait)
        t = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
        a, w, k = msg.linear_acceleration, msg.angular_velocity, i % len(accel)
        a.x, a.y, a.z = accel[k]
        w.x, w.y, w.z = gyro[k]
        pub.publish(msg)
    print(json.dumps({"published": total}))
    time.sleep(0.5)
    node.destroy_node()
    rclpy.shutdown()


def spin_events(node, done) -> None:
    """EventsExecutor's spin() without a timeout busy-loops in the PyPI wheel: spin in slices (PERF_NOTES)."""
    from rclpy.experimental import EventsExecutor

    executor = EventsExecutor()
    executor.add_node(node)
    never = rclpy.task.Future()
    while rclpy.ok() and not done():
        executor.spin_until_future_complete(never, timeout_sec=0.1)


def relay(events: bool, raw: bool = False) -> None:
    """`raw`: the messages as their serialised bytes, never built as Python messages (rclpy's conversion
    is most of a relay's CPU per message): the floor of any rclpy relay's cost."""
    rclpy.init()
    node = rclpy.create_node("bench_relay")
    pub = node.create_publisher(Imu, "imu/data_calibrated", QOS)
    node.create_subscription(Imu, "imu/data_raw", pub.publish, QOS, raw=raw)
    try:
        if events:
            spin_events(node, lambda: False)
        else:
            rclpy.spin(node)
    except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        pass


def subscribe(seconds: float, out: str) -> None:
    rclpy.init()
    node = rclpy.create_node("bench_subscriber")
    latencies = []
    last = [0.0]

    def on_imu(msg):
        latencies.append(time.time_ns() - (msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec))
        last[0] = time.monotonic()

    node.create_subscription(Imu, "imu/data_calibrated", on_imu, MEASURE_QOS)
    # Until the stream has ended (3 s without a message after the first), or `seconds` at most: a
    # publisher slow to start on a busy machine is not counted as loss.
    deadline = time.monotonic() + seconds
    spin_events(node, lambda: time.monotonic() > deadline or bool(latencies and time.monotonic() - last[0] > 3.0))
    with open(out, "w") as f:
        json.dump({"delivered": len(latencies), "latency_ns": latencies}, f)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    command = sys.argv[1]
    if command == "publish":
        publish(float(sys.argv[2]), float(sys.argv[3]))
    elif command in ("relay", "relay-events", "relay-raw"):
        relay(events=command != "relay", raw=command == "relay-raw")
    elif command == "subscribe":
        subscribe(float(sys.argv[2]), sys.argv[3])
