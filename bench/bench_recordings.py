"""Recordings other than bags, 1 M IMU samples each, against a peer measured in the same run:

- CSV stream (t,ax,ay,az,gx,gy,gz,temperature, as a logger writes it), end to end to the calibration,
  against numpy.genfromtxt merely loading the same file. Target: >= 3x faster.
- PX4 ULog shaped like the real `sample.ulg` (its 14 other topics at their logged rates, tiled in time;
  sensor_combined replaced by the session), end to end, against pyulog merely loading it. Target: within
  1.3x. Also shown: pyulog loading only the topics the reader asks for (the floor for any pyulog reader).

Each figure is the best of two runs; the session's share is printed, as it is the same whatever the format.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from pyulog import ULog

from accel_calibration.bag.recording import open_recording
from accel_calibration.bag.replay import ReplaySettings, replay_bag, replay_recording
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations
from msg_tools.ulog_writer import write_ulog

N = 1_000_000
RATE_HZ = 250.0  # PX4's sensor_combined rate; a logger's CSV alike
REAL_ULOG = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "px4_ulog" / "sample.ulg"


def best_of(fn, repeat=2) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - start)
    return min(times), out


def session_samples():
    rng = np.random.default_rng(0)
    errors = SensorErrors.mpu6050_like(rng)
    poses = 200
    dwell = 12.0
    move = (N / RATE_HZ - poses * dwell) / (poses - 1)
    samples = SyntheticImu(errors, spread_orientations(poses, rng), dwell_s=dwell, move_s=move, rate_hz=RATE_HZ,
                           temperature_degc=lambda t: 20.0 + 25.0 * t / (N / RATE_HZ), seed=0).samples()
    return samples


def write_csv(path: Path, samples) -> None:
    data = np.column_stack([(samples.t_ns + 10**9) / 1e9, samples.accel_raw, samples.gyro_raw,
                            np.round(samples.temperature_degc, 2)])
    with open(path, "w") as stream:
        stream.write("t,ax,ay,az,gx,gy,gz,temperature\n")
        np.savetxt(stream, data, fmt="%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.2f")


def _as_records(dataset) -> np.ndarray:
    names = [f.field_name for f in dataset.field_data]
    dtype = [(n, dataset.data[n].dtype.newbyteorder("<")) for n in names]
    out = np.empty(len(dataset.data["timestamp"]), dtype=dtype)
    for name in names:
        out[name] = dataset.data[name]
    return out


def write_realistic_ulog(path: Path, samples) -> int:
    """sample.ulg's topics at their own rates, repeated until its sensor_combined holds the session."""
    real = ULog(str(REAL_ULOG))
    span_us = real.last_timestamp - real.start_timestamp
    repeats = int(np.ceil(N / RATE_HZ * 1e6 / span_us))
    t_us = real.start_timestamp + samples.t_ns // 1000
    topics = []
    for dataset in real.data_list:
        records = _as_records(dataset)
        if dataset.name == "sensor_combined":
            combined = np.zeros(len(t_us), dtype=records.dtype)
            combined["timestamp"] = t_us
            for i in range(3):
                combined[f"gyro_rad[{i}]"] = samples.gyro_raw[:, i]
                combined[f"accelerometer_m_s2[{i}]"] = samples.accel_raw[:, i]
            topics.append((dataset.name, dataset.multi_id, combined))
            continue
        tiled = np.concatenate([records] * repeats)
        tiled["timestamp"] = (np.concatenate([records["timestamp"] + k * span_us for k in range(repeats)]))
        topics.append((dataset.name, dataset.multi_id, tiled[tiled["timestamp"] <= t_us[-1]]))
    return write_ulog(path, topics, start_us=real.start_timestamp)


def end_to_end(path, **options):
    result = replay_bag(path, ReplaySettings(**options))
    assert result.calibration is not None, result.problem
    return result


def session_only(path, **options) -> float:
    recording = open_recording(path, **options)
    start = time.perf_counter()
    replay_recording(recording, ReplaySettings())
    return time.perf_counter() - start


def main() -> int:
    if not REAL_ULOG.exists():
        print(f"bench_recordings: {REAL_ULOG} not found (../shared beside the clone); skipped")
        return 0
    samples = session_samples()
    assert abs(len(samples.t_ns) - N) <= 1, len(samples.t_ns)
    with tempfile.TemporaryDirectory() as tmp:
        csv_path = Path(tmp) / "session.csv"
        write_csv(csv_path, samples)
        peer, _ = best_of(lambda: np.genfromtxt(csv_path, delimiter=",", names=True))
        read, _ = best_of(lambda: open_recording(csv_path))
        ours, result = best_of(lambda: end_to_end(csv_path))
        session_s = session_only(csv_path)
        print(f"CSV  {N} samples ({csv_path.stat().st_size / 1e6:.0f} MB): numpy.genfromtxt load {peer:.2f} s; "
              f"our read {read:.2f} s ({peer / read:.1f}x faster); replay end to end {ours:.2f} s (session "
              f"{session_s:.2f} s of it, {len(result.poses)} poses, "
              f"fit {result.calibration.quality.residual_rms_mg:.2f} mg): {peer / ours:.2f}x faster (target >= 3x)")

        ulog_path = Path(tmp) / "flight.ulg"
        messages = write_realistic_ulog(ulog_path, samples)
        peer, _ = best_of(lambda: ULog(str(ulog_path)))
        floor, _ = best_of(lambda: ULog(str(ulog_path), ["sensor_combined", "sensor_accel", "sensor_selection"]))
        read, _ = best_of(lambda: open_recording(ulog_path))
        ours, result = best_of(lambda: end_to_end(ulog_path))
        session_s = session_only(ulog_path)
        print(f"ULog {N} sensor_combined samples in {messages} messages ({ulog_path.stat().st_size / 1e6:.0f} MB): "
              f"pyulog load {peer:.2f} s (only the reader's topics {floor:.2f} s); our read {read:.2f} s; "
              f"replay end to end {ours:.2f} s (session {session_s:.2f} s of it, {len(result.poses)} poses): "
              f"{ours / peer:.2f}x pyulog's load (target <= 1.3x), {ours / floor:.2f}x its filtered load")
    return 0


if __name__ == "__main__":
    sys.exit(main())
