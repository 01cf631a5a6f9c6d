"""The batch detector (StaticDetector.process: the one sample path, node and replay alike) on the imu_tk
Xsens recording, against the frozen copy of it from before the issue-13 speed work
(bench/_batch_detector_before.py), same data, same run, interleaved, best of many. Target: >= 2x.
(The per-message detector is gone: the node's cost per message is bench/bench_node_stream.py's.)
"""
import gzip
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.core.stream.detector_batch import detect_batch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _batch_detector_before  # noqa: E402  (the frozen peer, beside this file)

IMU_TK = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imu_tk"


def _before(t: np.ndarray, a: np.ndarray, g: np.ndarray) -> list:
    """The frozen peer on a fresh detector's settings, under the private names it read then."""
    c = StaticDetector().config
    floor = SimpleNamespace(quantile=c.noise_quantile, half_life=200_000)
    view = SimpleNamespace(
        _accel_max=c.accel_max, _gyro_max=c.gyro_max, trim_s=c.trim_s, _window_ns=c.window_ns, _gap_ns=c.window_ns,
        _full_ns=c.full_ns, _min_magnitude_squared=c.min_magnitude_squared, _warmup_ns=c.warmup_ns,
        _accel_floor=floor, _gyro_floor=floor, accel_var_threshold=c.accel_var_threshold,
        gyro_var_threshold=c.gyro_var_threshold, k_sigma=c.k_sigma, gyro_k_sigma=c.gyro_k_sigma, _rise_var=c.rise_var,
        _accel_cap=c.accel_cap, _gyro_cap=c.gyro_cap, min_hold_s=c.min_hold_s, max_pose_s=c.max_pose_s)
    return list(_batch_detector_before.detect_batch(view, t, a, g)[0])


def _new(t: np.ndarray, a: np.ndarray, g: np.ndarray) -> list:
    detector = StaticDetector()
    return detect_batch(detector.config, detector.state, t, a, g)[0]


def bench_batch() -> None:
    if not IMU_TK.exists():
        print(f"bench_static_detector: {IMU_TK} not found (../shared beside the clone); batch part skipped")
        return
    # As test/core/test_static_detector.py loads it: Xsens MTi, 100 Hz, raw counts.
    accel = np.loadtxt(gzip.open(IMU_TK / "xsens_acc.txt.gz"))
    gyro = np.loadtxt(gzip.open(IMU_TK / "xsens_gyro.txt.gz"))
    t, a, g = (accel[:, 0] * 1e9).astype(np.int64), accel[:, 1:], gyro[:, 1:]
    new_poses = _new(t, a, g)
    before_poses = _before(t, a, g)
    same = len(new_poses) == len(before_poses) and all(
        np.array_equal(p.accel_mps2, q.accel_mps2) and p.start_ns == q.start_ns and p.end_ns == q.end_ns
        for p, q in zip(new_poses, before_poses))
    new = before = float("inf")
    for _ in range(40):  # interleaved, best of: the machine is shared and noisy
        start = time.perf_counter()
        _before(t, a, g)
        before = min(before, time.perf_counter() - start)
        start = time.perf_counter()
        _new(t, a, g)
        new = min(new, time.perf_counter() - start)
    print(f"batch detector on imu_tk Xsens ({len(t)} samples, {len(new_poses)} poses, "
          f"{'same poses' if same else 'POSES DIFFER'} as before): {new * 1e3:.1f} ms, before {before * 1e3:.1f} ms; "
          f"{before / new:.2f}x faster (target >= 2x)")


def main() -> int:
    bench_batch()
    return 0


if __name__ == "__main__":
    sys.exit(main())
