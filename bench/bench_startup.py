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

import re
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

IMPORT_TARGET = 2.0
REPLAY_TARGET = 3.0
RUNS = 7
_LINE = re.compile(r"import time:\s+\d+ \|\s+(\d+) \| +(\S+)")

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


def import_ratio() -> tuple[float, float, float]:
    """(numpy us, cli.main us, ratio) from one -X importtime run."""
    done = subprocess.run([sys.executable, "-X", "importtime", "-c", "import accel_calibration.cli.main"],
                          capture_output=True, text=True, check=True)
    cumulative = {m[2]: int(m[1]) for m in map(_LINE.match, done.stderr.splitlines()) if m}
    numpy_us, main_us = cumulative["numpy"], cumulative["accel_calibration.cli.main"]
    return numpy_us, main_us, main_us / numpy_us


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
    print(f"1. import of accel_calibration.cli.main against numpy's, {RUNS} runs of python -X importtime:")
    ratios = []
    for _ in range(RUNS):
        numpy_us, main_us, ratio = import_ratio()
        ratios.append(ratio)
        print(f"   numpy {numpy_us / 1000:6.1f} ms, cli.main {main_us / 1000:6.1f} ms: {ratio:.2f}x")
    median = statistics.median(ratios)
    print(f"   median {median:.2f}x, worst {max(ratios):.2f}x (target <= {IMPORT_TARGET:g}x): "
          f"{'meets' if median <= IMPORT_TARGET else 'misses'}")

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
        output = Path(tmp) / "cal.yaml"
        print(f"2. {n} Imu messages at 1 kHz, mcap storage, best of 5 (interleaved):")
        for label, bag in (("rosbag2 directory", directory), ("single .mcap file", single)):
            print(f"   {label}: --help imports: {cli_subprocess('--help').split()[1]}; replay imports: "
                  f"{cli_subprocess('replay', str(bag), '-o', str(output)).split()[1]} (of scipy.linalg, matplotlib)")
            rosbags_read(bag)  # the peer's imports and first touches done
            best = {"rosbags": np.inf, "replay": np.inf}
            for _ in range(5):
                start = time.perf_counter()
                assert rosbags_read(bag) == n
                best["rosbags"] = min(best["rosbags"], time.perf_counter() - start)
                start = time.perf_counter()
                cli_subprocess("replay", str(bag), "-o", str(output))
                best["replay"] = min(best["replay"], time.perf_counter() - start)
            ratio = best["rosbags"] / best["replay"]
            print(f"   rosbags read+deserialize in process {best['rosbags']:.2f} s; accel-calib replay as a "
                  f"subprocess {best['replay']:.2f} s: {ratio:.1f}x (target >= {REPLAY_TARGET:g}x): "
                  f"{'meets' if ratio >= REPLAY_TARGET else 'misses'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
