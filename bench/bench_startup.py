"""Start-up of the command line, measured as a user meets it:

1. Importing the CLI's entry module against numpy's own import, both read from ONE
   `python -X importtime -c "import accel_calibration.cli.main"` run (numpy's cumulative time is part of
   the same run, so machine load hits both alike). Target: at most 2x. Repeated RUNS times; each run's
   ratio is printed, then the median.
2. Replay of a 1 kHz mcap bag of >= 150,000 Imu messages end to end through the CLI as a subprocess (a
   fresh interpreter: imports included) against reading and deserializing the same messages with
   rosbags in this running interpreter, its imports done. Target: at least 3x. Best of 5, interleaved.
Also: whether `--help` and that replay import scipy.linalg or matplotlib (they must not).

Run: .venv/bin/python bench/bench_startup.py
"""
from __future__ import annotations

import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from msg_tools.bag_writer import write_session_bag
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

IMPORT_TARGET = 1.5
REPLAY_TARGET = 3.0
RUNS = 9
REPLAY_RUNS = 5
_TOP = re.compile(r"import time:\s+\d+ \|\s+(\d+) \| (\S+)")  # one space: a top-level import
ENTRY = "accel_calibration.cli.main"
# numpy alone in the environment the CLI gives itself (cli/__init__.py: one BLAS thread), so that OpenBLAS
# starting a thread per core is not counted against numpy's import and not ours (~10 % of numpy's CPU here).
ONE_BLAS_THREAD = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

HEAVY = """
import contextlib, io, sys
from accel_calibration.cli.main import main
with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    try:
        code = main(sys.argv[1:])
    except SystemExit as done:  # --help
        code = done.code
print(code, ",".join(m for m in ("scipy.linalg", "matplotlib") if m in sys.modules) or "none")
"""


def _importtime(statement: str) -> dict[str, int]:
    """{top-level module: cumulative us} of one fresh `python -X importtime -c statement`."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", statement],
                          capture_output=True, text=True, check=True, env=ONE_BLAS_THREAD)
    return {m[2]: int(m[1]) for m in map(_TOP.match, done.stderr.splitlines()) if m}


def _cpu(statement: str) -> float:
    """CPU seconds (user + system) of a fresh `python -c statement`, from its rusage."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([sys.executable, "-c", statement], check=True, env=ONE_BLAS_THREAD)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def import_ratio(bare: set[str]) -> tuple[float, float, float, float]:
    """(numpy ms, ours ms, importtime ratio, CPU ratio): each import in its own fresh interpreter, read
    two ways in turn. -X importtime (wall clock inside the process): the sum of the top-level entries a
    bare interpreter does not have (the package, its parents and all they import, numpy included). CPU:
    the process's CPU time less a bare interpreter's, measured just before."""
    numpy_us = sum(us for name, us in _importtime("import numpy").items() if name not in bare)
    ours_us = sum(us for name, us in _importtime(f"import {ENTRY}").items() if name not in bare)
    bare_s = _cpu("pass")
    numpy_s = _cpu("import numpy") - bare_s
    ours_s = _cpu(f"import {ENTRY}") - bare_s
    return numpy_us / 1000, ours_us / 1000, ours_us / numpy_us, ours_s / numpy_s


def rosbags_read(path: Path) -> int:
    count = 0
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        connections = [c for c in reader.connections if c.msgtype == "sensor_msgs/msg/Imu"]
        for connection, _, raw in reader.messages(connections=connections):
            msg = reader.deserialize(raw, connection.msgtype)
            count += msg.header.stamp.nanosec >= 0
    return count


def cli_subprocess(*argv: str) -> str:
    done = subprocess.run([sys.executable, "-c", HEAVY, *argv], capture_output=True, text=True, check=True)
    return done.stdout.strip()


def main() -> int:
    # Bytecode as an installed package has it (pip compiles at install; an editable checkout under
    # PYTHONDONTWRITEBYTECODE would compile every changed module in every process).
    import compileall

    import accel_calibration

    compileall.compile_dir(Path(accel_calibration.__file__).parent, quiet=1)
    print(f"1. import of {ENTRY} against numpy's, each in a fresh interpreter, {RUNS} runs, read two ways "
          "(-X importtime; CPU time less a bare interpreter's):")
    bare = set(_importtime("pass"))
    by_importtime, by_cpu = [], []
    for run in range(RUNS):
        numpy_ms, ours_ms, ratio, cpu_ratio = import_ratio(bare)
        by_importtime.append(ratio)
        by_cpu.append(cpu_ratio)
        print(f"   run {run + 1}: importtime numpy {numpy_ms:6.1f} ms, ours {ours_ms:6.1f} ms: {ratio:.2f}x; "
              f"CPU: {cpu_ratio:.2f}x")
    for label, ratios in (("importtime", by_importtime), ("CPU", by_cpu)):
        median = statistics.median(ratios)
        print(f"   {label}: median {median:.2f}x (min {min(ratios):.2f}, max {max(ratios):.2f}; target <= "
              f"{IMPORT_TARGET:g}x): {'meets' if median <= IMPORT_TARGET else 'misses'}")
    if "--imports-only" in sys.argv:
        return 0

    rng = np.random.default_rng(0)
    imu = SyntheticImu(SensorErrors.mpu6050_like(rng), spread_orientations(46, rng), dwell_s=2.2, move_s=1.2,
                       rate_hz=1000.0, seed=0)
    samples = imu.samples()
    n = len(samples.t_ns)
    assert n >= 150_000
    with tempfile.TemporaryDirectory() as tmp:
        directory = Path(tmp) / "session"
        write_session_bag(directory, samples, start_ns=1_700_000_000 * 10**9, storage="mcap", temperature_topic=None)
        single = Path(tmp) / "session.mcap"
        shutil.copy(next(directory.glob("*.mcap")), single)
        sqlite = Path(tmp) / "session_db3"
        write_session_bag(sqlite, samples, start_ns=1_700_000_000 * 10**9, storage="sqlite3", temperature_topic=None)
        output = Path(tmp) / "cal.yaml"
        print(f"2. {n} Imu messages at 1 kHz, CPU seconds (the subprocess's from its rusage), {REPLAY_RUNS} runs, "
              "the three in turn each run: "
              "rosbags read+deserialize in this process, the plain read of the storage file's bytes in this "
              "process (the I/O limit), accel-calib replay as a subprocess (imports included)")
        for label, bag in (("rosbag2 directory (mcap)", directory), ("single .mcap file", single),
                           ("rosbag2 directory (.db3)", sqlite)):
            print(f"   {label}: --help imports: {cli_subprocess('--help').split()[1]}; replay imports: "
                  f"{cli_subprocess('replay', str(bag), '-o', str(output)).split()[1]} (of scipy.linalg, matplotlib)")
            files = [bag] if bag.is_file() else sorted(p for p in bag.iterdir() if p.suffix in (".mcap", ".db3"))
            rosbags_read(bag)  # the peer's imports and first touches done
            ratios, io_ratios = [], []
            for run in range(REPLAY_RUNS):
                start = time.process_time()
                assert rosbags_read(bag) == n
                rosbags_s = time.process_time() - start
                start = time.process_time()
                for file in files:
                    file.read_bytes()
                bytes_s = time.process_time() - start
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                cli_subprocess("replay", str(bag), "-o", str(output))
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                replay_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                ratios.append(rosbags_s / replay_s)
                io_ratios.append(replay_s / bytes_s)
                print(f"     run {run + 1}: rosbags {rosbags_s:.2f} s, bytes {bytes_s:.3f} s, replay {replay_s:.2f} s: "
                      f"{ratios[-1]:.2f}x rosbags' speed, {io_ratios[-1]:.0f}x the plain read's time")
            median = statistics.median(ratios)
            print(f"   median {median:.2f}x (min {min(ratios):.2f}, max {max(ratios):.2f}; target >= "
                  f"{REPLAY_TARGET:g}x): {'meets' if median >= REPLAY_TARGET else 'misses'}; replay takes "
                  f"{statistics.median(io_ratios):.0f}x the plain read; load {Path('/proc/loadavg').read_text()[:14]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
