"""The node's worker pass: what the live feed costs per 0.2 s pass, against the same samples read as a
recording (`recording_feed`, parts of PART_ROWS) in the same run. A pass is mostly a fixed cost (some 150 numpy
calls and the Python around them, whatever its rows), and it makes the worker's CPU bursts: 4-5 ms every 0.2 s
at 2 kHz on the 2-core machine.

No target: this prints where the worker's time goes, per pass and per sample, at 1, 2 and 4 kHz, BENCH_RUNS (5)
runs, the two in turn. Both must find the same poses.
"""
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the worker sets it

from stream_peers import turned_sensor  # noqa: E402

from accel_calibration.core.session import CalibrationSession  # noqa: E402
from accel_calibration.core.settings import Settings  # noqa: E402

PASS_S = 0.2  # live/worker_protocol.FEED_PERIOD_S
SECONDS = 48.0  # 24 poses of the turned sensor


def samples(rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    accel, gyro = (np.array(values) for values in turned_sensor(rate_hz))
    n = int(SECONDS * rate_hz)
    index = np.arange(n) % len(accel)
    return np.arange(n, dtype=np.int64) * int(1e9 / rate_hz), accel[index], gyro[index]


def live(t: np.ndarray, accel: np.ndarray, gyro: np.ndarray, rate_hz: float) -> tuple[list[float], int]:
    feed = CalibrationSession(Settings()).live_feed()
    step = int(rate_hz * PASS_S)
    per_pass, poses = [], 0
    for begin in range(0, len(t), step):
        start = time.process_time()
        feed.add_samples(t[begin:begin + step], accel[begin:begin + step], gyro[begin:begin + step])
        poses += len(feed.take_poses())
        per_pass.append(time.process_time() - start)
    return per_pass, poses


def recording(t: np.ndarray, accel: np.ndarray, gyro: np.ndarray) -> tuple[float, int]:
    start = time.process_time()
    feed = CalibrationSession(Settings()).recording_feed(has_temperature=False)
    feed.add_samples(t, accel, gyro)
    poses = len(feed.finish())
    return time.process_time() - start, poses


def main() -> int:
    runs = int(os.environ.get("BENCH_RUNS", "5"))
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for rate in (1000.0, 2000.0, 4000.0):
        t, accel, gyro = samples(rate)
        for run in range(runs):
            per_pass, live_poses = live(t, accel, gyro, rate)
            whole, recording_poses = recording(t, accel, gyro)
            per_pass_ms = np.array(per_pass) * 1e3
            ratio = sum(per_pass) / whole
            print(f"{rate / 1000:g} kHz run {run + 1}: live pass p50 {np.median(per_pass_ms):.2f} ms, p99 "
                  f"{np.percentile(per_pass_ms, 99):.2f} ms, {sum(per_pass) / len(t) * 1e6:.2f} us/sample | "
                  f"recording {whole / len(t) * 1e6:.2f} us/sample | live / recording {ratio:.1f}x | poses "
                  f"{live_poses} and {recording_poses}", flush=True)
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
