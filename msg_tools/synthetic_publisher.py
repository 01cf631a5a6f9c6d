"""Plays a SyntheticImu on imu/data_raw (+ imu/temperature at ~10 Hz), paced by the wall clock.

Header stamps follow the simulated stream (start + sample time), so `--speed 10` plays ten times
faster than real time while every time window downstream (which follows header stamps) sees the
session as recorded. Used by the tests and `make demo`; `python -m msg_tools.synthetic_publisher`.
"""
from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rclpy
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature

from .conversions import make_imu, make_temperature
from .synthetic_imu import SensorErrors, SyntheticImu, SyntheticSamples, spread_orientations

if TYPE_CHECKING:
    from rclpy.node import Node
    from rclpy.publisher import Publisher

STREAM_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)


def wait_for_subscriber(node: Node, publisher: Publisher, timeout_s: float = 20.0) -> bool:
    """Discovery takes 0.1-3 s: wait until someone listens instead of sleeping a fixed time."""
    deadline = time.monotonic() + timeout_s
    while publisher.get_subscription_count() == 0:
        if time.monotonic() > deadline:
            return False
        rclpy.spin_once(node, timeout_sec=0.05)
    return True


def play(
    imu_publisher: Publisher,
    temperature_publisher: Publisher | None,
    samples: SyntheticSamples,
    *,
    start_ns: int,
    speed: float = 1.0,
    temperature_period_s: float = 0.1,
    frame_id: str = "imu_link",
    indices: Sequence[int] | np.ndarray | None = None,
) -> int:
    """Publish `samples` (or the given indices) paced at `speed` x real time; returns messages sent."""
    t = samples.t_ns
    order = np.arange(len(t)) if indices is None else np.asarray(indices)
    if len(order) == 0:
        return 0
    t0 = int(t[order[0]])
    wall0 = time.perf_counter()
    next_temperature_ns = t0
    period_ns = int(temperature_period_s * 1e9)
    accel, gyro, temps = samples.accel_raw.tolist(), samples.gyro_raw.tolist(), samples.temperature_degc.tolist()
    for i in order.tolist():
        due = (t[i] - t0) / 1e9 / speed
        delay = due - (time.perf_counter() - wall0)
        if delay > 0.002:
            time.sleep(delay)
        stamp = start_ns + int(t[i])
        if temperature_publisher is not None and t[i] >= next_temperature_ns:
            temperature_publisher.publish(make_temperature(stamp, temps[i], frame_id))
            next_temperature_ns = t[i] + period_ns
        imu_publisher.publish(make_imu(stamp, accel[i], gyro[i], frame_id))
    return len(order)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="synthetic_publisher", description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=200.0, help="IMU rate, Hz")
    parser.add_argument("--poses", type=int, default=16, help="number of static poses")
    parser.add_argument("--dwell", type=float, default=3.0, help="seconds still at each pose")
    parser.add_argument("--move", type=float, default=1.5, help="seconds per turn between poses")
    parser.add_argument("--speed", type=float, default=1.0, help="play this many times faster than real time")
    parser.add_argument("--seed", type=int, default=0)
    args, ros_args = parser.parse_known_args(argv)
    rng = np.random.default_rng(args.seed)
    imu = SyntheticImu(SensorErrors.mpu6050_like(rng), spread_orientations(args.poses, rng),
                       dwell_s=args.dwell, move_s=args.move, rate_hz=args.rate, seed=args.seed)
    rclpy.init(args=ros_args)
    node = rclpy.create_node("synthetic_imu")
    try:
        imu_publisher = node.create_publisher(Imu, "imu/data_raw", STREAM_QOS)
        temperature_publisher = node.create_publisher(Temperature, "imu/temperature", STREAM_QOS)
        if not wait_for_subscriber(node, imu_publisher):
            print("synthetic_publisher: no subscriber on imu/data_raw after 20 s", file=sys.stderr)
            return 1
        sent = play(imu_publisher, temperature_publisher, imu.samples(),
                    start_ns=node.get_clock().now().nanoseconds, speed=args.speed)
        node.get_logger().info(f"played {sent} samples ({imu.duration_s:.1f} s of stream)")
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()


if __name__ == "__main__":
    sys.exit(main())
