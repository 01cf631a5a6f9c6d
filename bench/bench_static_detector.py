"""Per-sample cost of StaticDetector.update (the node calls it per message), against a bare sliding-window
mean/variance over a deque (the cheapest O(1) detector core), measured in the same run.

Then the batch detector (StaticDetector.process, CalibrationSession.add_recording's path) on the imu_tk
Xsens recording, against the frozen copy of it from before the issue-13 speed work
(bench/_batch_detector_before.py), same data, same run, interleaved, best of many. Target: >= 2x.
"""
import gzip
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np

from accel_calibration.core.static_detector import StaticDetector
from accel_calibration.core.static_detector_batch import detect_batch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _batch_detector_before  # noqa: E402  (the frozen peer, beside this file)

IMU_TK = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imu_tk"


def bench_batch() -> None:
    if not IMU_TK.exists():
        print(f"bench_static_detector: {IMU_TK} not found (../shared beside the clone); batch part skipped")
        return
    # As test/core/test_static_detector.py loads it: Xsens MTi, 100 Hz, raw counts.
    accel = np.loadtxt(gzip.open(IMU_TK / "xsens_acc.txt.gz"))
    gyro = np.loadtxt(gzip.open(IMU_TK / "xsens_gyro.txt.gz"))
    t, a, g = (accel[:, 0] * 1e9).astype(np.int64), accel[:, 1:], gyro[:, 1:]
    new_poses = detect_batch(StaticDetector(), t, a, g)[0]
    before_poses = _batch_detector_before.detect_batch(StaticDetector(), t, a, g)[0]
    same = len(new_poses) == len(before_poses) and all(
        np.array_equal(p.accel_mps2, q.accel_mps2) and p.start_ns == q.start_ns and p.end_ns == q.end_ns
        for p, q in zip(new_poses, before_poses))
    new = before = float("inf")
    for _ in range(40):  # interleaved, best of: the machine is shared and noisy
        start = time.perf_counter()
        _batch_detector_before.detect_batch(StaticDetector(), t, a, g)
        before = min(before, time.perf_counter() - start)
        start = time.perf_counter()
        detect_batch(StaticDetector(), t, a, g)
        new = min(new, time.perf_counter() - start)
    print(f"batch detector on imu_tk Xsens ({len(t)} samples, {len(new_poses)} poses, "
          f"{'same poses' if same else 'POSES DIFFER'} as before): {new * 1e3:.1f} ms, before {before * 1e3:.1f} ms; "
          f"{before / new:.2f}x faster (target >= 2x)")


def main() -> int:
    rng = np.random.default_rng(0)
    n = 200_000
    t = (np.arange(n) * 1e6).astype(np.int64).tolist()  # 1 kHz
    accel = (np.array([0.0, 0.0, 9.8]) + rng.normal(0, 0.03, (n, 3))).tolist()
    gyro = rng.normal(0, 0.002, (n, 3)).tolist()

    detector = StaticDetector()
    update = detector.update
    start = time.perf_counter()
    for i in range(n):
        ax, ay, az = accel[i]
        gx, gy, gz = gyro[i]
        update(t[i], ax, ay, az, gx, gy, gz, 25.0)
    ours = (time.perf_counter() - start) / n * 1e6

    window, s1, s2 = deque(), 0.0, 0.0
    start = time.perf_counter()
    for i in range(n):
        x = accel[i][2]
        window.append((t[i], x))
        s1 += x
        s2 += x * x
        while window[0][0] <= t[i] - 500_000_000:
            _, old = window.popleft()
            s1 -= old
            s2 -= old * old
        _ = s2 / len(window) - (s1 / len(window)) ** 2
    bare = (time.perf_counter() - start) / n * 1e6
    print(f"StaticDetector.update: {ours:.2f} us/sample (accel + gyro + temperature, 1 kHz stream); "
          f"bare one-channel deque variance: {bare:.2f} us/sample; ratio {ours / bare:.1f}x")
    print(f"at 2 kHz that is {ours * 2000 / 1e4:.2f} % of a core")
    bench_batch()
    return 0


if __name__ == "__main__":
    sys.exit(main())
