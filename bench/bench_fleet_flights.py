"""A fleet's ordinary flight logs through `accel-calib fleet` on Dask, and one worker's memory on a long log.

1. Scaling: BENCH_FLIGHTS logs (default 1000; PX4 ULog and ArduPilot DataFlash alternating, each two IMUs,
   40 s at 100 Hz: still on the ground, armed, a flight of turns and vibration, landed, still), through the
   command as a user runs it (`fleet DIR --workers N`: the local cluster started and stopped by the command,
   its start-up inside the clock), on 1 worker and on 2. Prints logs per second against the worker count,
   the ratio (target: 2 workers >= 1.7x one), and each worker process's peak resident memory (VmHWM, read
   from /proc while the command runs, of every process below this one that is not this one's fork server).
   The history must hold a calibration row and an evidence row per IMU of every log.
   The logs: BENCH_FLIGHTS_DISTINCT (16) simulated flights (test/helpers/flight_logs.py), each written to
   many paths with the calibration in force nudged by a micro-g per copy, so that every log is a recording
   of its own (the history keys rows by content: hard links would collapse into 16 rows).
2. Memory: the flight-evidence path (`calibrate_recording`, what a worker runs per log) on a 1-hour, 1 kHz,
   three-IMU log, ULog and DataFlash, each in a fresh process: its peak RSS against the 500 MB target; then
   on logs of the same length on the ground but for 20 s of flight (their ground streamed, not kept).
   BENCH_FLIGHTS_MEMORY_S (default 3600) sets the logs' length (each hour's two logs, 1.2 GB and 0.6 GB, take
   about 2 minutes to write and up to 2 minutes each to read); BENCH_FLIGHTS_SKIP_MEMORY=1 skips part 2,
   BENCH_FLIGHTS_SKIP_SCALING=1 part 1.
"""
from __future__ import annotations

import contextlib
import io
import os
import shutil
import sqlite3
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "test")]

from accel_calibration.cli.main import main as accel_calib  # noqa: E402

from helpers.flight_logs import (  # noqa: E402 - test/helpers holds the writers of logs with known truth
    InForce,
    fly,
    sensors,
    true_in_force,
    write_dataflash_flight,
    write_ulog_flight,
)

FLIGHTS = int(os.environ.get("BENCH_FLIGHTS", "1000"))
DISTINCT = int(os.environ.get("BENCH_FLIGHTS_DISTINCT", "16"))
MEMORY_S = float(os.environ.get("BENCH_FLIGHTS_MEMORY_S", "3600"))
MEMORY_TARGET_MB = 500.0
MICRO_G = 9.80665e-6


def write_fleet(root: Path) -> int:
    """FLIGHTS logs under root/uavNN/, DISTINCT flights each written to many paths, every file distinct."""
    flights = []
    for k in range(DISTINCT):
        truths = sensors(100 + k)
        flights.append((fly(truths, 200 + k), [true_in_force(t) for t in truths]))
    for i in range(FLIGHTS):
        flight, in_force = flights[i % DISTINCT]
        nudged = [InForce(c.offset + [0.0, 0.0, i * MICRO_G], c.scale) for c in in_force]
        folder = root / f"uav{i % 25:02d}"
        folder.mkdir(parents=True, exist_ok=True)
        if i % 2:
            write_dataflash_flight(folder / f"{i:08d}.bin", flight, nudged)
        else:
            write_ulog_flight(folder / f"log_{i:04d}.ulg", flight, nudged)
    return FLIGHTS


def _peak_kb(pid: int) -> int:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0
    return next((int(line.split()[1]) for line in text.splitlines() if line.startswith("VmHWM:")), 0)


@contextlib.contextmanager
def worker_peaks():
    """{pid: peak RSS kB} of Dask's worker processes while the block runs, polled every 0.2 s: the processes
    below this one's children (a worker is forked by the fork server, this process's child)."""
    import psutil

    peaks: dict[int, int] = {}
    done = threading.Event()

    def poll() -> None:
        me = psutil.Process()
        while not done.wait(0.2):
            for child in me.children(recursive=True):
                with contextlib.suppress(psutil.Error):
                    if child.ppid() != me.pid:
                        peaks[child.pid] = max(peaks.get(child.pid, 0), _peak_kb(child.pid))

    thread = threading.Thread(target=poll, daemon=True)
    thread.start()
    try:
        yield peaks
    finally:
        done.set()
        thread.join()


def run_fleet(root: Path, db: Path, workers: int) -> tuple[float, float, int, str, list[float]]:
    """Seconds, this process's CPU seconds (the command's own share: the client, the history's writes), the
    exit code, what it printed, the workers' peak RSS (MB)."""
    import resource

    out = io.StringIO()
    with worker_peaks() as peaks:
        cpu = resource.getrusage(resource.RUSAGE_SELF)
        began = time.perf_counter()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            code = accel_calib(["fleet", str(root), *[str(p) for p in sorted(root.rglob("*.bin"))],
                                "--workers", str(workers), "--history", str(db)])
        took = time.perf_counter() - began
        after = resource.getrusage(resource.RUSAGE_SELF)
    workers_mb = sorted((kb / 1024 for kb in peaks.values() if kb > 0), reverse=True)
    client_s = after.ru_utime + after.ru_stime - cpu.ru_utime - cpu.ru_stime
    return took, client_s, code, out.getvalue(), workers_mb


def scaling(tmp: Path) -> bool:
    root = tmp / "fleet"
    started = time.perf_counter()
    write_fleet(root)
    size_mb = sum(f.stat().st_size for f in root.rglob("*") if f.is_file()) / 1e6
    print(f"fleet: {FLIGHTS} flight logs ({DISTINCT} distinct flights, ULog and DataFlash, 2 IMUs each), "
          f"{size_mb:.0f} MB (written in {time.perf_counter() - started:.1f} s)")
    elapsed = {}
    ok = True
    for workers in (1, 2):
        db = tmp / f"history_{workers}.sqlite"
        took, client_s, code, out, workers_mb = run_fleet(root, db, workers)
        elapsed[workers] = took
        with contextlib.closing(sqlite3.connect(db)) as connection:
            calibrations = connection.execute("SELECT count(*) FROM calibrations").fetchone()[0]
            evidence = connection.execute("SELECT count(*), sum(status = 'evidence') FROM flight_evidence").fetchone()
        print(f"  {workers} worker{'s' if workers > 1 else ' '}: {took:6.1f} s, {FLIGHTS / took:5.2f} logs/s "
              f"({FLIGHTS / took / workers:5.2f} per worker), cluster start-up included; peak RSS per worker "
              f"{', '.join(f'{mb:.0f}' for mb in workers_mb[:workers])} MB; the command's own CPU {client_s:.1f} s; "
              f"history {calibrations} calibration "
              f"rows, {evidence[0]} evidence rows ({evidence[1]} with evidence); exit {code}")
        if calibrations != 2 * FLIGHTS or evidence[0] != 2 * FLIGHTS:
            print(out[-2000:])
            ok = False
    ratio = elapsed[1] / elapsed[2]
    print(f"  2 workers {ratio:.2f}x one (target >= 1.7x): {'OK' if ratio >= 1.7 else 'BELOW TARGET'}; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    return ok and ratio >= 1.7


def write_long_logs(tmp: Path, seconds: float, ground_s: float = 10.0, name: str = "hour") -> list[Path]:
    """A ULog and a DataFlash log of `seconds` at 1 kHz, three IMUs: still `ground_s`, a flight, still `ground_s`."""
    import helpers.flight_logs as logs

    saved = (logs.RATE_HZ, logs.GROUND_S, logs.FLIGHT_S, logs.DEVICES)
    logs.RATE_HZ, logs.GROUND_S, logs.FLIGHT_S = 1000.0, ground_s, seconds - 2 * ground_s
    logs.DEVICES = (1310988, 1442060, 2162700)
    try:
        truths = [*sensors(7), *sensors(8)][:3]  # one per device
        flight = fly(truths, 7)
        in_force = [true_in_force(t) for t in truths]
        paths = [tmp / f"{name}.ulg", tmp / f"{name}.bin"]
        write_ulog_flight(paths[0], flight, in_force)
        write_dataflash_flight(paths[1], flight, in_force)
    finally:
        logs.RATE_HZ, logs.GROUND_S, logs.FLIGHT_S, logs.DEVICES = saved
    return paths


MEASURE = """
import sys, time
from accel_calibration.cli.fleet import calibrate_recording, _peak_rss_mb
before = _peak_rss_mb()
began = time.perf_counter()
outcome = calibrate_recording(sys.argv[1])
took = time.perf_counter() - began
rows = [outcome, *outcome.others]
said = '; '.join(f"{o.evidence.status if o.evidence else '-'} {o.evidence.device if o.evidence else ''}"
                 for o in rows)
print(f"RESULT {_peak_rss_mb():.0f} {before:.0f} {took:.1f} {len(rows)} {said}")
"""


def memory(tmp: Path) -> bool:
    """The flight log (10 s on the ground each side), then the same length nearly all on the ground (20 s of
    flight in the middle: what a pass cannot keep, streamed to each IMU's replay)."""
    ok = True
    for ground_s, name, what in ((10.0, "hour", "flight log"), ((MEMORY_S - 20.0) / 2, "ground", "log on the ground "
                                                                 "but for 20 s of flight")):
        ok = _memory_of(tmp, ground_s, name, what) and ok
        for path in tmp.glob(f"{name}.*"):
            path.unlink()
    return ok


def _memory_of(tmp: Path, ground_s: float, name: str, what: str) -> bool:
    started = time.perf_counter()
    paths = write_long_logs(tmp, MEMORY_S, ground_s, name)
    print(f"memory: a {MEMORY_S / 60:.0f}-minute, 1 kHz, three-IMU {what}, "
          + ", ".join(f"{p.suffix} {p.stat().st_size / 1e6:.0f} MB" for p in paths)
          + f" (written in {time.perf_counter() - started:.0f} s)")
    ok = True
    for path in paths:
        run = subprocess.run([sys.executable, "-c", MEASURE, str(path)], capture_output=True, text=True)
        line = next((line for line in run.stdout.splitlines() if line.startswith("RESULT")), None)
        if line is None:
            print(f"  {path.name}: failed ({run.stderr.strip().splitlines()[-1:] or run.returncode})")
            ok = False
            continue
        _, peak, before, took, rows, said = line.split(" ", 5)
        fits = float(peak) <= MEMORY_TARGET_MB and said.count("evidence") == 3  # a row of evidence per IMU
        ok = ok and fits
        print(f"  {path.suffix}: peak RSS {peak} MB (after imports {before} MB) in {took} s, {rows} IMU rows "
              f"({said}); target <= {MEMORY_TARGET_MB:.0f} MB: {'OK' if fits else 'ABOVE TARGET'}")
    return ok


def run() -> int:
    tmp = Path(tempfile.mkdtemp(prefix="bench_fleet_flights_"))  # under $TMPDIR
    try:
        ok = True
        if os.environ.get("BENCH_FLIGHTS_SKIP_SCALING") != "1":
            ok = scaling(tmp)
            shutil.rmtree(tmp / "fleet")
        if os.environ.get("BENCH_FLIGHTS_SKIP_MEMORY") != "1":
            ok = memory(tmp) and ok
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(run())
