"""A warm-up calibrated by ArduPilot's own tool and by ours, on the same log: ArduPilot's
`Tools/scripts/tempcal_IMU.py` (../shared/peers/, GPL-3.0: run here as a separate process, nothing of it
copied) beside `accel-calib replay --warmup` then `export --to ardupilot`, each tool's INS_TCALn_* applied
with ArduPilot's formula (TCal::correct_sensor: v -= P(clamp(T) - 35) - P(clamp(CALTEMP) - 35), before the
offsets and scales) to the noise-free raw output of the simulated sensors.

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

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "test")]

from accel_calibration.core.units import MG, STANDARD_GRAVITY  # noqa: E402

from helpers.autopilot_logs import ardupilot_parameters, write_ardupilot_log  # noqa: E402
from helpers.warmup_sessions import ardupilot_applied, read_params, warmup_board  # noqa: E402

PEER = ROOT.parent / "shared" / "peers" / "ardupilot_tempcal_IMU.py"


def temperature_error(values: np.ndarray) -> float:
    """Half the peak-to-peak per axis, worst axis."""
    return float(np.max(np.ptp(values, axis=0)) / 2)


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
            rows.append((instance, *errors))
    return rows


def main() -> None:
    seeds = [int(s) for s in sys.argv[1:]] or [40, 41, 42]
    print("IMU  seed   tempcal_IMU.py: accel mg  gyro mrad/s   ours (replay --warmup, export): accel mg  gyro mrad/s")
    worst = np.zeros(4)
    for seed in seeds:
        for instance, *errors in one_seed(seed):
            worst = np.maximum(worst, errors)
            print(f"{instance:3d}  {seed:4d}   {errors[0]:22.2f}  {errors[1]:11.3f}   "
                  f"{errors[2]:39.2f}  {errors[3]:11.3f}")
    print(f"worst        {worst[0]:22.2f}  {worst[1]:11.3f}   {worst[2]:39.2f}  {worst[3]:11.3f}")


if __name__ == "__main__":
    main()
