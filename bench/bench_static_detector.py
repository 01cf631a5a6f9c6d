"""The batch detector (detect_batch: the one sample path, node and replay alike) on the imu_tk Xsens
recording, against a peer measured in the same run on the same arrays, interleaved, best of many.

The peer is the plainest still-window detector numpy allows, written here: the recording cut into
fixed windows of the detector's length by sample count, each window's variance (sum of the axes, accel
and gyro), a fixed threshold (the quietest accel window x k_sigma, the quietest gyro window x
gyro_k_sigma), and runs of still windows at least min_hold_s long kept as poses (their mean). It has
none of the detector's screening, learned noise floor, warm-up, trims, gap and length cuts, so the
ratio is what those rules cost over a bare variance test; the raw read of the arrays (one pass summing
them) is printed as the floor under both.
(The per-message detector is gone: the node's cost per message is bench/bench_node_stream.py's.)
"""
import gzip
import sys
import time
from pathlib import Path

import numpy as np

from accel_calibration.core.stream.detector import StaticDetector
from accel_calibration.core.stream.detector_batch import detect_batch

IMU_TK = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imu_tk"


def plain_variance_poses(t: np.ndarray, a: np.ndarray, g: np.ndarray) -> list[np.ndarray]:
    """The peer: the mean acceleration of each run of still fixed windows (see the module's docstring)."""
    c = StaticDetector().config
    period_ns = float(np.median(np.diff(t)))
    per_window = max(2, round(c.window_ns / period_ns))
    windows = len(t) // per_window
    a_windows = a[:windows * per_window].reshape(windows, per_window, 3)
    g_windows = g[:windows * per_window].reshape(windows, per_window, 3)
    a_var = a_windows.var(axis=1).sum(axis=1)
    g_var = g_windows.var(axis=1).sum(axis=1)
    still = (a_var <= a_var.min() * c.k_sigma) & (g_var <= g_var.min() * c.gyro_k_sigma)
    min_windows = max(1, int(np.ceil(c.min_hold_s * 1e9 / (per_window * period_ns))))
    edges = np.flatnonzero(np.diff(np.concatenate(([0], still.astype(np.int8), [0]))))
    return [a_windows[start:end].reshape(-1, 3).mean(axis=0)
            for start, end in zip(edges[::2], edges[1::2]) if end - start >= min_windows]


def detector_poses(t: np.ndarray, a: np.ndarray, g: np.ndarray) -> list:
    detector = StaticDetector()
    return detect_batch(detector.config, detector.state, t, a, g)[0]


def raw_read(t: np.ndarray, a: np.ndarray, g: np.ndarray) -> float:
    return float(t.sum() + a.sum() + g.sum())


def best_of(function, *arrays, rounds: int = 40) -> float:
    best = float("inf")
    for _ in range(rounds):
        start = time.perf_counter()
        function(*arrays)
        best = min(best, time.perf_counter() - start)
    return best


def bench_batch() -> None:
    if not IMU_TK.exists():
        print(f"bench_static_detector: {IMU_TK} not found (../shared beside the clone); batch part skipped")
        return
    # As test/core/test_static_detector.py loads it: Xsens MTi, 100 Hz, raw counts.
    accel = np.loadtxt(gzip.open(IMU_TK / "xsens_acc.txt.gz"))
    gyro = np.loadtxt(gzip.open(IMU_TK / "xsens_gyro.txt.gz"))
    t, a, g = (accel[:, 0] * 1e9).astype(np.int64), accel[:, 1:], gyro[:, 1:]
    found, plain = detector_poses(t, a, g), plain_variance_poses(t, a, g)
    ours = peer = read = float("inf")
    for _ in range(10):  # interleaved, best of: the machine is shared and noisy
        ours = min(ours, best_of(detector_poses, t, a, g, rounds=4))
        peer = min(peer, best_of(plain_variance_poses, t, a, g, rounds=4))
        read = min(read, best_of(raw_read, t, a, g, rounds=4))
    print(f"batch detector on imu_tk Xsens ({len(t)} samples): {ours * 1e3:.1f} ms, {len(found)} poses; "
          f"plain per-window variance peer {peer * 1e3:.1f} ms, {len(plain)} poses "
          f"(the detector costs {ours / peer:.1f}x the peer); raw read of the arrays {read * 1e3:.2f} ms")


def main() -> int:
    bench_batch()
    return 0


if __name__ == "__main__":
    sys.exit(main())
