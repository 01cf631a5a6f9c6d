"""The whole gyro fit (gyro_fit.fit_gyro, with the poses' noise model, default options) of a simulated
166 s, 1 kHz hand-turned session: 46 poses, 45 motions of ~2 s, ~91k gyro intervals in them
(msg_tools.synthetic_motion, poses and motions cut as test/helpers/gyro_sessions.py cuts them). Process CPU
time of one fit_gyro call, one BLAS thread (as the CLI sets it), against the 0.2 s target.

The peer, in the same run and in turn with ours: the same fit with rotation_integration as it was at commit
7240174 (its source read from git, so the peer is that code, not a copy of it; its turned-angle sum as that
commit's gyro_fit formed it), i.e. the fit before the evaluation was rewritten. Both fits' results are
compared too (they agree to rounding). Without git or that commit, our figures alone. Every run printed."""
from __future__ import annotations

import os

os.environ["OPENBLAS_NUM_THREADS"] = "1"

import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import types  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "test")]

from accel_calibration import fit  # noqa: E402
from accel_calibration.core import gyro_scoring  # noqa: E402
from accel_calibration.core.gyro_fit import GyroFitResult, fit_gyro  # noqa: E402
from msg_tools.synthetic_motion import simulate_session  # noqa: E402

from helpers.gyro_sessions import poses_and_motions  # noqa: E402

RUNS, TARGET_S, PEER_COMMIT = 9, 0.2, "7240174"
OURS = gyro_scoring.IntervalSet


def peer_interval_set() -> type | None:
    """rotation_integration.IntervalSet as at PEER_COMMIT, or None when git cannot show it."""
    try:
        source = subprocess.run(["git", "-C", str(ROOT), "show", f"{PEER_COMMIT}:accel_calibration/core/"
                                 "rotation_integration.py"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    module = types.ModuleType(f"rotation_integration_{PEER_COMMIT}")
    exec(compile(source, f"{PEER_COMMIT}:rotation_integration.py", "exec"), module.__dict__)

    class Former(module.IntervalSet):
        def turned_rad(self) -> np.ndarray:  # what gyro_fit computed from it at PEER_COMMIT
            return np.sum(np.abs(self.mean_rate) * self.dt_s[:, None], axis=0)

    return Former


def session():
    simulated = simulate_session(np.random.default_rng(3), poses=46, rate_hz=1000.0, hold_s=(1.5, 2.2),
                                 move_s=(1.2, 2.0), first_hold_s=8.5)
    poses, motions = poses_and_motions(simulated)
    return simulated, poses, motions, fit(poses).calibration


def timed(run_fit, interval_set: type) -> tuple[float, GyroFitResult]:
    gyro_scoring.IntervalSet = interval_set  # what motion_intervals builds (the fit's and the axes check's)
    try:
        started = time.process_time()
        result = run_fit()
        return time.process_time() - started, result
    finally:
        gyro_scoring.IntervalSet = OURS


def agreement(ours: GyroFitResult, peer: GyroFitResult) -> str:
    def relative(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.abs(a - b).max() / np.abs(b).max())

    return (f"M_g {relative(ours.matrix, peer.matrix):.1e}, its sigma "
            f"{relative(ours.matrix_sigma, peer.matrix_sigma):.1e}, residuals "
            f"{relative(ours.residuals_mrad, peer.residuals_mrad):.1e} (largest difference, relative)")


def main() -> int:
    simulated, poses, motions, accel = session()

    def run_fit() -> GyroFitResult:
        return fit_gyro(poses, motions, accel, gyro_noise_radps=simulated.gyro_noise_radps)

    former = peer_interval_set()
    names = ["ours"] + ([f"at {PEER_COMMIT}"] if former is not None else [])
    classes = {"ours": OURS, f"at {PEER_COMMIT}": former}
    results = {name: timed(run_fit, classes[name])[1] for name in names}  # warm-up, and the results compared
    duration_s = (simulated.stamps_ns[-1] - simulated.stamps_ns[0]) * 1e-9
    intervals = sum(len(m.stamps_ns) - 1 for m in motions)
    print(f"fit_gyro of a {duration_s:.0f} s, 1 kHz session: {len(poses)} poses, {len(motions)} motions, {intervals} "
          f"intervals in them, {results['ours'].iterations} iterations; process CPU time of one fit, {RUNS} runs; "
          f"load {Path('/proc/loadavg').read_text()[:14]}")
    if former is None:
        print(f"  (git cannot show {PEER_COMMIT}: no peer)")
    else:
        print(f"  ours against the fit at {PEER_COMMIT}: {agreement(results['ours'], results[names[1]])}")
    figures: dict[str, list[float]] = {name: [] for name in names}
    for run in range(RUNS):
        for name in (names if run % 2 == 0 else names[::-1]):
            figures[name].append(timed(run_fit, classes[name])[0])
        ours = figures["ours"][-1]
        verdict = "within" if ours <= TARGET_S else "ABOVE"
        line = f"  run {run + 1}: ours {ours * 1e3:.0f} ms ({verdict} the 0.2 s target)"
        if former is not None:
            peer = figures[names[1]][-1]
            line += f", {names[1]} {peer * 1e3:.0f} ms: {peer / ours:.2f}x"
        print(line)
    median = statistics.median(figures["ours"])
    within = sum(t <= TARGET_S for t in figures["ours"])
    summary = (f"  median ours {median * 1e3:.0f} ms (min {min(figures['ours']) * 1e3:.0f}, max "
               f"{max(figures['ours']) * 1e3:.0f}); {within} of {RUNS} runs within the 0.2 s target")
    if former is not None:
        ratios = [p / o for p, o in zip(figures[names[1]], figures["ours"])]
        summary += (f"; {names[1]} median {statistics.median(figures[names[1]]) * 1e3:.0f} ms, "
                    f"{statistics.median(ratios):.2f}x")
    print(summary + f"; load {Path('/proc/loadavg').read_text()[:14]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
