"""A warm-up calibrated by the autopilots' own tools and by ours, on the same logs: ArduPilot's
`Tools/scripts/tempcal_IMU.py` (../shared/peers/, GPL-3.0: run here as a separate process, nothing of it
copied) beside `accel-calib replay --warmup` then `export --to ardupilot`, each tool's INS_TCALn_* applied
with ArduPilot's formula (TCal::correct_sensor: v -= P(clamp(T) - 35) - P(clamp(CALTEMP) - 35), before the
offsets and scales) to the noise-free raw output of the simulated sensors; and PX4's
`Tools/process_sensor_caldata.py` (its method re-done in `px4_method`, as read with the search tools) beside
`replay --warmup` of a ULog of the same board then `export --to px4`, applied with PX4's formula.

The log: test/helpers/autopilot_logs writes a real DataFlash log of two IMUs sitting still and level for 15
minutes while the board warms 15 -> 45 degC (T = 45 - 30 exp(-t / 200 s): a fast rise, then a slow one),
biases following tanh and exponential curves (helpers/warmup_sessions), MPU-6050-class noise, a stale
calibration in force (INS_ACC*OFFS/SCAL, INS_GYR*OFFS) and the board turned 90 deg in yaw.

Error: each tool's corrected output at rest across the range, its worst departure per axis from its middle
value (half its peak-to-peak: a constant is the offsets' business, which ArduPilot recomputes for the gyro
at boot), worst axis, mg and mrad/s. Run: .venv/bin/python bench/bench_warmup.py [seeds]"""
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.signal import medfilt

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "test")]

from accel_calibration.core.units import MG, STANDARD_GRAVITY  # noqa: E402

from helpers.autopilot_logs import ardupilot_parameters, write_ardupilot_log, write_px4_log  # noqa: E402
from helpers.warmup_sessions import (  # noqa: E402
    ardupilot_applied,
    px4_applied,
    read_params,
    read_px4_params,
    warmup_board,
)

PEER = ROOT.parent / "shared" / "peers" / "ardupilot_tempcal_IMU.py"


def temperature_error(values: np.ndarray) -> float:
    """Half the peak-to-peak per axis, worst axis."""
    return float(np.max(np.ptp(values, axis=0)) / 2)


def px4_method(degc: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, float, tuple[float, float]]:
    """PX4's Tools/process_sensor_caldata.py, its method re-done here (read with the search tools, nothing
    copied): a 31-sample median filter per axis, the samples averaged in 2000 equal temperature bins over the
    range, a cubic per axis through the bins' means in T - TREF, TREF the middle of the range, TMIN/TMAX its
    ends. Returns X0..X3 per axis, TREF, (TMIN, TMAX)."""
    low, high = float(degc.min()), float(degc.max())
    reference = 0.5 * (low + high)
    filtered = np.column_stack([medfilt(values[:, axis], 31) for axis in range(3)])
    index = np.minimum(((degc - low) / ((high - low) / 2000)).astype(int), 1999)
    counts = np.bincount(index, minlength=2000)
    used = counts > 0
    at = np.bincount(index, degc, 2000)[used] / counts[used] - reference
    rows = np.zeros((4, 3))
    for axis in range(3):
        means = np.bincount(index, filtered[:, axis], 2000)[used] / counts[used]
        rows[:, axis] = np.polynomial.polynomial.polyfit(at, means, 3)
    return rows, reference, (low, high)


def px4_thermal_error(rows: np.ndarray, reference: float, clamp: tuple[float, float], values: np.ndarray,
                      degc: np.ndarray) -> float:
    """The output after PX4's thermal offset (X0 + X1 dT + X2 dT^2 + X3 dT^3, dT = clamp(T) - TREF)."""
    dt = np.clip(degc, *clamp)[:, None] - reference
    return temperature_error(values - sum(rows[k] * dt**k for k in range(4)))


def px4_ours(log: Path, instance: int, folder: Path, raw: np.ndarray, gyro_raw: np.ndarray,
             degc: np.ndarray) -> tuple[float, float]:
    cal, param = folder / f"px4_imu{instance}.yaml", folder / f"px4_imu{instance}.params"
    tool = [sys.executable, "-m", "accel_calibration.cli.main"]
    subprocess.run([*tool, "replay", str(log), "--warmup", "--instance", str(instance), "-o", str(cal)],
                   check=True, capture_output=True, text=True)
    subprocess.run([*tool, "export", str(cal), "--to", "px4", "--instance", str(instance), "--max-loss-mg", "20",
                    "-o", str(param)], check=True, capture_output=True, text=True)
    accel, gyro = px4_applied(read_px4_params(param), instance, raw, gyro_raw, degc)
    return temperature_error(accel) / MG, temperature_error(gyro) * 1e3


def ours(log: Path, instance: int, folder: Path) -> dict[str, float]:
    cal, param = folder / f"imu{instance}.yaml", folder / f"imu{instance}.param"
    tool = [sys.executable, "-m", "accel_calibration.cli.main"]
    subprocess.run([*tool, "replay", str(log), "--warmup", "--instance", str(instance), "-o", str(cal)],
                   check=True, capture_output=True, text=True)
    subprocess.run([*tool, "export", str(cal), "--to", "ardupilot", "--instance", str(instance), "--max-loss-mg",
                    "20", "-o", str(param)], check=True, capture_output=True, text=True)
    return read_params(param)


def one_seed(seed: int) -> list[tuple[int, float, float, float, float]]:
    board, truths = warmup_board(seed)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        log = Path(folder) / "warm.bin"
        write_ardupilot_log(log, board)
        ulog = Path(folder) / "warm.ulg"
        write_px4_log(ulog, board)
        subprocess.run([sys.executable, str(PEER), "--no-graph", "--outfile", str(Path(folder) / "tcal.parm"),
                        str(log)], check=True, capture_output=True, text=True, cwd=folder)
        theirs = read_params(Path(folder) / "tcal.parm")
        vehicle = ardupilot_parameters(board)
        degc = np.linspace(float(board.temperature.min()), float(board.temperature.max()), 300)
        for instance, truth in enumerate(truths):
            still = np.linalg.solve(truth.calibration.matrix, [0.0, 0.0, STANDARD_GRAVITY]) + truth.calibration.bias
            raw = still + truth.accel_drift(degc)
            gyro_raw = truth.calibration.gyro_bias_radps + truth.gyro_drift(degc)
            errors = []
            for params in ({**vehicle, **theirs}, {**vehicle, **ours(log, instance, Path(folder))}):
                accel, gyro = ardupilot_applied(params, instance, raw, gyro_raw, degc)
                errors += [temperature_error(accel) / MG, temperature_error(gyro) * 1e3]
            # PX4: its tool's method on the raw samples it logs (sensor_accel, sensor_gyro), ours from the ULog
            imu = board.imus[instance]
            for values, truth_values, unit in ((imu.raw, raw, MG), (imu.gyro_raw, gyro_raw, 1e-3)):
                fitted, reference, clamp = px4_method(board.temperature, values)
                errors.append(px4_thermal_error(fitted, reference, clamp, truth_values, degc) / unit)
            errors += px4_ours(ulog, instance, Path(folder), raw, gyro_raw, degc)
            rows.append((instance, *errors))
    return rows


def main() -> None:
    seeds = [int(s) for s in sys.argv[1:]] or [40, 41, 42]
    print("error at rest across the range, half peak-to-peak, worst axis: accelerometer mg, gyro mrad/s")
    print("             ArduPilot                           PX4")
    print("IMU  seed    tempcal_IMU.py    ours (export)     process_sensor_caldata  ours (export)")
    worst = np.zeros(8)
    for seed in seeds:
        for instance, *errors in one_seed(seed):
            worst = np.maximum(worst, errors)
            print(f"{instance:3d}  {seed:4d}   " + "   ".join(f"{errors[k]:5.2f} {errors[k + 1]:6.3f}"
                                                      for k in range(0, 8, 2)))
    print("worst        " + "   ".join(f"{worst[k]:5.2f} {worst[k + 1]:6.3f}" for k in range(0, 8, 2)))


if __name__ == "__main__":
    main()
