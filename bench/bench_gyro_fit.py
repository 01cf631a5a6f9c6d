"""The gyro fit of the imu_tk Xsens session (issue 23): its time, and imu_tk's method on the same motions.

Poses come from our session's detector on the Xsens MTi recording (counts read with imu_tk's nominal
offset 32768, 4060 counts/g and 6258 counts per rad/s), the accelerometer from fit(); then
fit_gyro on the 38 motions between the 39 poses. Printed: the fit's time (best and median of
interleaved runs, wall and CPU: the machine is shared), and the motion residual |R^T u_i - u_{i+1}| of
  - ours (bias interpolated between the poses' gyro means, residuals weighted by the noise model),
  - imu_tk's method ported to numpy/scipy: the gyro bias from the initial still interval (pose 1), RK4 of
    the quaternion with the rate linear between samples (integrateGyroInterval), unweighted residuals,
    gyro samples from the first at or after the end of pose i to the last before the start of pose
    i + 1, solved with least_squares (imu_tk uses Ceres; same cost).
Target: the fit in under 0.1 s here. imu_tk's own C++/Ceres solve takes about 0.5 s (issue 23).
"""
import gzip
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from accel_calibration import fit
from accel_calibration.core.gyro_fit import fit_gyro, motions_between
from accel_calibration.core.session import CalibrationSession
from accel_calibration.core.settings import Settings

IMU_TK = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "imu_tk"
G = 9.81744


def xsens():
    acc = np.loadtxt(gzip.open(IMU_TK / "xsens_acc.txt.gz"))
    gyr = np.loadtxt(gzip.open(IMU_TK / "xsens_gyro.txt.gz"))
    stamps = (acc[:, 0] * 1e9).astype(np.int64)
    accel = (acc[:, 1:] - 32768) / 4060 * G
    gyro = (gyr[:, 1:] - 32768) / 6258.0
    poses = CalibrationSession(Settings(gravity=G)).add_recording(stamps, accel, gyro)
    return stamps, gyro, poses, fit(poses, gravity=G).calibration


def timed(function, rounds=15):
    wall, cpu = [], []
    for _ in range(rounds):
        w, c = time.perf_counter(), time.process_time()
        function()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return min(wall), statistics.median(wall), min(cpu)


class ImuTkMethod:
    """imu_tk's MultiPosGyroResidual on the same poses and gravity directions, vectorised over the motions."""

    def __init__(self, stamps, gyro, poses, directions):
        bias = gyro[(stamps >= poses[0].start_ns) & (stamps <= poses[0].end_ns)].mean(axis=0)
        pieces = []
        for before, after in zip(poses[:-1], poses[1:]):
            inside = np.flatnonzero((stamps >= before.end_ns) & (stamps < after.start_ns))
            pieces.append((stamps[inside] * 1e-9, gyro[inside] - bias))
        longest = max(len(t) for t, _ in pieces)
        self.rates = np.zeros((len(pieces), longest, 3))
        self.dt = np.zeros((len(pieces), longest - 1))  # 0 past a motion's end: RK4 then leaves q alone
        for k, (t, w) in enumerate(pieces):
            self.rates[k, :len(t)] = w
            self.dt[k, :len(t) - 1] = np.diff(t)
        self.start, self.end = directions[:-1], directions[1:]
        self.bias = bias

    @staticmethod
    def _omega(w):
        """0.5 * imu_tk's computeOmegaSkew(w), (K, 4, 4)."""
        x, y, z = w[:, 0], w[:, 1], w[:, 2]
        zero = np.zeros_like(x)
        return 0.5 * np.stack([np.stack([zero, -x, -y, -z], -1), np.stack([x, zero, z, -y], -1),
                               np.stack([y, -z, zero, x], -1), np.stack([z, y, -x, zero], -1)], -2)

    def rotations(self, matrix):
        rates = self.rates @ matrix.T
        q = np.zeros((len(rates), 4))
        q[:, 0] = 1.0
        for j in range(rates.shape[1] - 1):
            dt = self.dt[:, j:j + 1]
            w0, w1 = rates[:, j], rates[:, j + 1]
            a, b, c = self._omega(w0), self._omega(0.5 * (w0 + w1)), self._omega(w1)
            k1 = np.einsum("kab,kb->ka", a, q)
            k2 = np.einsum("kab,kb->ka", b, q + 0.5 * dt * k1)
            k3 = np.einsum("kab,kb->ka", b, q + 0.5 * dt * k2)
            k4 = np.einsum("kab,kb->ka", c, q + dt * k3)
            q = q + dt * (k1 + 2 * k2 + 2 * k3 + k4) / 6
            q /= np.linalg.norm(q, axis=1, keepdims=True)
        w, x, y, z = q.T
        return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                         np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                         np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)

    def residuals(self, parameters):
        moved = np.einsum("kba,kb->ka", self.rotations(parameters.reshape(3, 3)), self.start)
        return (moved - self.end).ravel()

    def fit(self):
        return least_squares(self.residuals, np.eye(3).ravel(), x_scale="jac").x.reshape(3, 3)


def main() -> int:
    if not IMU_TK.exists():
        print(f"bench_gyro_fit: {IMU_TK} not found (../shared beside the clone); skipped")
        return 0
    stamps, gyro, poses, accel = xsens()
    motions = motions_between(poses, stamps, gyro)
    noise = gyro[stamps <= poses[0].end_ns].std(axis=0)
    samples = sum(len(m.stamps_ns) for m in motions)
    print(f"Xsens session: {len(poses)} poses, {len(motions)} motions, {samples} gyro samples in motions")
    for label, kwargs in (("fit_gyro, equal weights", {}), ("fit_gyro, noise model", {"gyro_noise_radps": noise})):
        result = fit_gyro(poses, motions, accel, **kwargs)
        best, median, cpu = timed(lambda kwargs=kwargs: fit_gyro(poses, motions, accel, **kwargs))
        print(f"{label}: {best * 1e3:.1f} ms best, {median * 1e3:.1f} ms median, {cpu * 1e3:.1f} ms CPU best "
              f"({result.iterations} iterations); residual rms {result.residual_rms_mrad:.2f} mrad, max "
              f"{result.residual_max_mrad:.2f} mrad (nominal scale: {result.residual_rms_before_mrad:.0f} mrad); "
              f"{'OK' if best < 0.1 else 'ABOVE'} the 0.1 s target")
        print("  M_g =", np.array2string(result.matrix, precision=5).replace("\n", ""),
              " scale sigma ppm", np.round(result.scale_sigma_ppm()).tolist(),
              f" misalignment sigma max {result.misalignment_sigma_mrad().max():.2f} mrad")
    directions = accel.apply(np.array([p.accel_mps2 for p in poses]))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    theirs = ImuTkMethod(stamps, gyro, poses, directions)
    start = time.perf_counter()
    matrix = theirs.fit()
    elapsed = time.perf_counter() - start
    residuals = np.linalg.norm(theirs.residuals(matrix.ravel()).reshape(-1, 3), axis=1) * 1e3
    print(f"imu_tk's method (numpy port, {elapsed:.1f} s): residual rms {np.sqrt(np.mean(residuals**2)):.2f} mrad, "
          f"max {residuals.max():.2f} mrad")
    print("  M_g =", np.array2string(matrix, precision=5).replace("\n", ""))
    ours = fit_gyro(poses, motions, accel, gyro_noise_radps=noise)
    ours_their_way = np.linalg.norm(theirs.residuals(ours.matrix.ravel()).reshape(-1, 3), axis=1) * 1e3
    print(f"our M_g with imu_tk's bias and integration: residual rms {np.sqrt(np.mean(ours_their_way**2)):.2f} mrad")
    return 0


if __name__ == "__main__":
    sys.exit(main())
