"""One evaluation of the gyro fit's rotations and derivatives (rotation_integration.IntervalSet.
rotations_and_derivatives) over 45 motions of 2 s at 1 kHz (~90k intervals, a 166 s session's motions),
against the same evaluation with frames x Jacobians as the former stacked 3 x 3 matmul, their transposes
included (the peer, in the same run; the (N, 3, 3) entry writes it also had are not counted): process CPU
time, one BLAS thread (as the CLI sets it), the two in turn, every run printed."""
from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from accel_calibration.core import rotation_integration as ri  # noqa: E402

RUNS, REPEAT = 7, 5


def _stacked(f: np.ndarray, j: np.ndarray) -> np.ndarray:
    """The former way: (N, 3, 3) stacks of frames and Jacobians, one stacked matmul."""
    frames = np.ascontiguousarray(f.T).reshape(-1, 3, 3)
    jacobians = np.ascontiguousarray(j.T).reshape(-1, 3, 3)
    return (frames @ jacobians).reshape(-1, 9).T


def main() -> int:
    rng = np.random.default_rng(1)
    stamps, rates, shares, start = [], [], [], 0
    for _ in range(45):
        t = start + np.arange(2000, dtype=np.int64) * 1_000_000
        start = int(t[-1]) + 10**9
        stamps.append(t)
        rates.append(0.5 * rng.standard_normal((2000, 3)))
        shares.append(np.linspace(0.0, 1.0, 2000))
    intervals = ri.IntervalSet(stamps, rates, shares)
    matrix, bias = np.eye(3) + 0.01 * rng.standard_normal((3, 3)), np.array([1e-3, 2e-3, -1e-3])
    ours = ri._frames_times_jacobians
    ratios = []
    print(f"{len(intervals.dt_s)} intervals, {REPEAT} evaluations per figure, process CPU time, {RUNS} runs:")
    for run in range(RUNS):
        figures = {}
        for name in (("ours", "former") if run % 2 == 0 else ("former", "ours")):
            ri._frames_times_jacobians = ours if name == "ours" else _stacked  # type: ignore[assignment]
            started = time.process_time()
            for _ in range(REPEAT):
                intervals.rotations_and_derivatives(matrix, bias, with_bias=True)
            figures[name] = (time.process_time() - started) / REPEAT
        ri._frames_times_jacobians = ours  # type: ignore[assignment]
        ratios.append(figures["former"] / figures["ours"])
        print(f"  run {run + 1}: ours {figures['ours'] * 1e3:.1f} ms, stacked matmul "
              f"{figures['former'] * 1e3:.1f} ms: {ratios[-1]:.2f}x")
    print(f"  median {statistics.median(ratios):.2f}x (min {min(ratios):.2f}, max {max(ratios):.2f}); "
          f"load {Path('/proc/loadavg').read_text()[:14]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
