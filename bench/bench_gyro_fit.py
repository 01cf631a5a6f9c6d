"""The gyro fit of the imu_tk Xsens session: its time.

Poses come from our session's detector on the Xsens MTi recording (counts read with imu_tk's nominal
offset 32768, 4060 counts/g and 6258 counts per rad/s), the accelerometer from fit(); then
fit_gyro on the 38 motions between the 39 poses. Printed: the fit's time (best and median of
interleaved runs, wall and CPU: the machine is shared) and its motion residual |R^T u_i - u_{i+1}|.
Target: the fit in under 0.1 s here. The comparison with imu_tk's own calibration of this recording is a
test (test_gyro_fit.py::test_against_imu_tks_own_calibration_of_the_xsens_recording).
"""
import gzip
import statistics
import sys
import time
from pathlib import Path

import numpy as np

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
    return 0


if __name__ == "__main__":
    sys.exit(main())
