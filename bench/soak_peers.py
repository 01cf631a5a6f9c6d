"""Processes for bench_soak.py.

publish SIM_S SPEED   one 60 s cycle of a synthetic session at 1 kHz, repeated with advancing header
                      stamps for SIM_S seconds of stream, played SPEED x faster than real time; the
                      monotonic send time rides in orientation.x (the node passes it through)
subscribe OUT.json    per simulated minute: messages received and p99 latency (ms)
"""
import json
import sys
import time

import numpy as np
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature

from msg_tools.conversions import make_imu, make_temperature
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
START_NS = 1_700_000_000 * 10**9


def publish(sim_s: float, speed: float) -> None:
    rclpy.init()
    node = rclpy.create_node("soak_publisher")
    imu_pub = node.create_publisher(Imu, "imu/data_raw", QOS)
    temperature_pub = node.create_publisher(Temperature, "imu/temperature", QOS)
    while imu_pub.get_subscription_count() == 0:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)
    rng = np.random.default_rng(0)
    cycle = SyntheticImu(SensorErrors.mpu6050_like(rng), spread_orientations(18, rng), dwell_s=2.0, move_s=1.3,
                         rate_hz=1000.0, seed=0).samples()
    cycle_ns = int(cycle.t_ns[-1]) + 1_000_000
    accel, gyro = cycle.accel_raw.tolist(), cycle.gyro_raw.tolist()
    msg = make_imu(START_NS, accel[0], gyro[0])
    total = int(sim_s * 1000)
    wall0 = time.perf_counter()
    sent = 0
    for k in range(total):
        i = k % len(accel)
        t = START_NS + (k // len(accel)) * cycle_ns + int(cycle.t_ns[i])
        due = (k / 1000.0) / speed
        if due - (time.perf_counter() - wall0) > 0.002:
            time.sleep(due - (time.perf_counter() - wall0))
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 1_000_000_000)
        a, w = msg.linear_acceleration, msg.angular_velocity
        a.x, a.y, a.z = accel[i]
        w.x, w.y, w.z = gyro[i]
        msg.orientation.x = float(time.monotonic_ns())
        imu_pub.publish(msg)
        sent += 1
        if k % 100 == 0:
            temperature_pub.publish(make_temperature(t, 25.0 + 10.0 * np.sin(k / total * np.pi)))
    print(json.dumps({"published": sent, "wall_s": time.perf_counter() - wall0}), flush=True)
    time.sleep(1.0)
    node.destroy_node()
    rclpy.shutdown()


def subscribe(out: str) -> None:
    rclpy.init()
    node = rclpy.create_node("soak_subscriber")
    minutes: dict[int, list] = {}

    def on_imu(msg):
        minute = (msg.header.stamp.sec - START_NS // 10**9) // 60
        minutes.setdefault(minute, []).append(time.monotonic_ns() - msg.orientation.x)

    node.create_subscription(Imu, "imu/data_calibrated", on_imu, QOS)
    last_count, idle_since = -1, time.monotonic()
    while True:
        rclpy.spin_once(node, timeout_sec=0.1)
        count = sum(len(v) for v in minutes.values())
        if count != last_count:
            last_count, idle_since = count, time.monotonic()
        elif count > 0 and time.monotonic() - idle_since > 5.0:
            break
    summary = {str(m): {"received": len(v), "p99_ms": float(np.percentile(np.array(v) / 1e6, 99))}
               for m, v in sorted(minutes.items())}
    with open(out, "w") as f:
        json.dump(summary, f)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    if sys.argv[1] == "publish":
        publish(float(sys.argv[2]), float(sys.argv[3]))
    else:
        subscribe(sys.argv[2])
