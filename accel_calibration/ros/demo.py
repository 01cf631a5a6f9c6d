"""`make demo`: the main job on an embedded default.

calibration_node runs in its own process; this process plays a badly calibrated MPU-6050-class
sensor turned through 16 poses (4x faster than real time; header stamps carry the session's time),
shows the node's progress as poses are found, calls /calibrate, then turns the sensor to fresh
orientations and prints the errors before and after, in mg.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..core.units import MG

SPEED = 4.0


def main() -> int:
    # Our own DDS domain on this machine only, so the demo never talks to a live vehicle's graph.
    os.environ.setdefault("ROS_DOMAIN_ID", str(60 + os.getpid() % 40))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy

    from msg_tools.calibration_client import CalibrationClient
    from msg_tools.node_process import NodeProcess
    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    rng = np.random.default_rng(2026)
    errors = SensorErrors.mpu6050_like(rng)
    imu = SyntheticImu(errors, spread_orientations(16, rng), dwell_s=3.0, move_s=1.5, rate_hz=200.0, seed=1)
    print(f"sensor: MPU-6050-class, bias {np.round(errors.bias_mps2, 3)} m/s^2, "
          f"scale {np.round(np.diag(errors.matrix), 3)}, "
          f"noise {errors.noise_mps2 / MG:.0f} mg")
    with tempfile.TemporaryDirectory() as tmp:
        cal_file = Path(tmp) / "accel_calibration.yaml"
        node = NodeProcess(cal_file)
        rclpy.init()
        client = CalibrationClient("demo")
        try:
            client.wait_ready()
            print(f"node up; playing {len(imu.rotations)} poses ({imu.duration_s:.0f} s of session at {SPEED:g}x)...")
            print("  to watch the poses: RViz (fixed frame imu_link) or Foxglove (3D panel), add the topic "
                  "calibration/markers (visualization_msgs/MarkerArray): a point per pose, an arrow where to turn")
            shown = [0]

            def show_progress() -> None:
                if client.diagnostics and len(client.diagnostics) > shown[0]:
                    shown[0] = len(client.diagnostics)
                    d = client.diagnostics[-1]
                    print(f"  poses {d['poses']}/{d['poses_needed']}  fit {d['fit_residual_rms_mg'] or '-'} mg rms  "
                          f"-> {d['advice']}")

            samples = imu.samples()
            start_ns = time.time_ns()
            chunk = int(imu.rate_hz * 2)
            for first in range(0, len(samples.t_ns), chunk):
                client.play(samples, start_ns=start_ns,
                     indices=range(first, min(first + chunk, len(samples.t_ns))))
                show_progress()
            client.spin_until(
                lambda: client.diagnostics and client.diagnostics[-1]["advice"] == "ready: call /calibrate", 5)
            show_progress()

            answer = client.call("calibrate")
            print("/calibrate ->", "success" if answer.success else "failed")
            print("  " + answer.message.replace("\n", "\n  "))
            if not answer.success:
                return 1

            fresh = SyntheticImu(errors, [Rotation.random(random_state=rng) for _ in range(5)],
                                 dwell_s=1.5, move_s=0.8, rate_hz=200.0, seed=7)
            fresh_samples = fresh.samples()
            fresh_start = start_ns + int((imu.duration_s + 10) * 1e9)
            client.corrected.clear()
            sent = client.play(temperature=False, samples=fresh_samples, start_ns=fresh_start)
            client.settle(int(0.99 * sent))
            received = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec: m for m in client.corrected}
            before, after = [], []
            for _start, end, truth in fresh.static_intervals():
                index = [i for i, t in enumerate(fresh_samples.t_ns) if end - 1e9 <= t < end]
                raw = fresh_samples.accel_raw[index].mean(axis=0)
                corrected = np.mean([[received[k].linear_acceleration.x, received[k].linear_acceleration.y,
                                      received[k].linear_acceleration.z]
                                     for k in (fresh_start + int(fresh_samples.t_ns[i]) for i in index)
                                     if k in received], axis=0)
                before.append(np.linalg.norm(raw - truth) / MG)
                after.append(np.linalg.norm(corrected - truth) / MG)
            print(f"error at {len(before)} fresh orientations (1 s averages): before {np.mean(before):.1f} mg mean / "
                  f"{np.max(before):.1f} mg max; after {np.mean(after):.2f} mg mean / {np.max(after):.2f} mg max")
            return 0
        finally:
            client.destroy()
            rclpy.shutdown()
            node.stop()
            print("node log (last lines):")
            print("  " + "\n  ".join(node.log().strip().splitlines()[-4:]))


if __name__ == "__main__":
    sys.exit(main())
