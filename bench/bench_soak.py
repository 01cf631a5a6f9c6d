"""Soak: an hour of simulated 1 kHz IMU stream through calibration_node, played faster than real time
(separate publisher, node, subscriber processes). Reports messages lost, the node's peak RSS and its
growth, and p99 latency per simulated minute (first vs last ten minutes: no drift).

BENCH_SOAK_SIM_S (default 3600) and BENCH_SOAK_SPEED (default 3) set the simulated length and speed.
"""
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
SIM_S = float(os.environ.get("BENCH_SOAK_SIM_S", "3600"))
SPEED = float(os.environ.get("BENCH_SOAK_SPEED", "3"))


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> int:
    env = dict(os.environ, ROS_DOMAIN_ID=str(30 + os.getpid() % 60), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "soak.json"
        node = subprocess.Popen([sys.executable, "-m", "accel_calibration.ros.node", "--ros-args",
                                 "-p", f"calibration_file:={tmp}/cal.yaml", "-p", "auto_calibrate:=true",
                                 "--log-level", "warn"], env=env)
        subscriber = subprocess.Popen([sys.executable, HERE / "soak_peers.py", "subscribe", out], env=env)
        publisher = subprocess.Popen([sys.executable, HERE / "soak_peers.py", "publish", str(SIM_S), str(SPEED)],
                                     env=env, stdout=subprocess.PIPE, text=True)
        rss = []
        while publisher.poll() is None:
            rss.append((time.monotonic(), rss_mb(node.pid)))
            time.sleep(2.0)
        published = json.loads(publisher.stdout.read().strip().splitlines()[-1])["published"]
        subscriber.wait(timeout=120)
        rss.append((time.monotonic(), rss_mb(node.pid)))
        node.send_signal(signal.SIGINT)
        node.wait(timeout=30)
        minutes = json.loads(out.read_text())
    received = sum(m["received"] for m in minutes.values())
    p99 = [m["p99_ms"] for _, m in sorted(minutes.items(), key=lambda kv: int(kv[0]))]
    values = np.array([r for _, r in rss])
    tenth = max(1, len(values) // 10)
    window = max(1, min(10, len(p99) // 3))
    print(f"soak: {SIM_S / 60:.0f} min of 1 kHz stream at {SPEED:g}x real time, {published} messages published, "
          f"{received} delivered corrected, lost {100 * (1 - received / published):.3f} %")
    print(f"node RSS: peak {values.max():.1f} MB; first tenth {values[:tenth].mean():.1f} MB, last tenth "
          f"{values[-tenth:].mean():.1f} MB (bounded: pose store {100} poses, fixed windows)")
    print(f"p99 latency per simulated minute: first {window} min {np.median(p99[:window]):.2f} ms, "
          f"last {window} min {np.median(p99[-window:]):.2f} ms, worst minute {max(p99):.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
