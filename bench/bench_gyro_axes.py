"""A 166 s, 1 kHz hand-turned session through the session's sample path and /calibrate, its gyro right and
read negated (-x, -y, -z): the time of each, and what the gyro check and the gyro fit cost.

Before the axes check the negated gyro ran the gyro fit's 30 iterations and ended "did not converge";
now the check names it and the fit is not run. Measured, not a test (the machine is shared)."""
import sys
import time

import numpy as np

from accel_calibration import fit
from accel_calibration.core.gyro_axes import gyro_axes_problem
from accel_calibration.core.gyro_fit import fit_gyro, motions_between
from accel_calibration.core.session import CalibrationSession
from msg_tools.synthetic_motion import simulate_session


def main() -> int:
    simulated = simulate_session(np.random.default_rng(4), poses=29, rate_hz=1000.0)
    seconds = (simulated.stamps_ns[-1] - simulated.stamps_ns[0]) * 1e-9
    print(f"session: {seconds:.0f} s at 1 kHz, {len(simulated.stamps_ns)} samples")
    for label, sign in (("right gyro", 1.0), ("gyro negated", -1.0)):
        gyro = sign * simulated.gyro_radps
        start = time.perf_counter()
        session = CalibrationSession()
        for pose in session.add_recording(simulated.stamps_ns, simulated.accel_mps2, gyro):
            session.add_pose(pose)
        verdict = session.calibrate()
        elapsed = time.perf_counter() - start
        print(f"{label}: session + /calibrate {elapsed:.2f} s; gyro: {verdict.gyro_refusal or 'applied'}")
        poses = session.store.poses
        accel = fit(poses).calibration
        motions = motions_between(poses, simulated.stamps_ns, gyro)
        directions = accel.apply(np.array([p.accel_mps2 for p in poses]))
        directions /= np.linalg.norm(directions, axis=1)[:, None]
        start = time.perf_counter()
        gyro_axes_problem(poses, motions, directions, np.eye(3))
        check = time.perf_counter() - start
        start = time.perf_counter()
        result = fit_gyro(poses, motions, accel)
        print(f"  axes check {check * 1e3:.0f} ms; fit_gyro (check included) {(time.perf_counter() - start) * 1e3:.0f} "
              f"ms, {result.iterations} iterations: {result.message}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
