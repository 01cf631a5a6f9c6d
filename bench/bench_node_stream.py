"""calibration_node against a bare rclpy relay, same machine, same run: delivery, p99 latency, CPU per
message. Separate publisher, relay/node and subscriber processes, as in the field. The publisher turns a
sensor between still poses (1.5 s still, 0.5 s turning), so the node's work finds a pose and refits every
2 s while the stream is measured. The node's CPU is its whole process tree (the worker process included).

Targets, at 1, 2 and 4 kHz, in every run, each against the relay measured just before it: the node's p99
latency within the relay's p99 + 0.5 ms; delivered >= 99.9 % at 1 and 2 kHz; CPU per message <= 1.3x the
relay's. BENCH_RUNS (10) runs per rate, BENCH_RATES="1000,2000" to choose the rates, BENCH_SECONDS (10)
of stream per run. BENCH_RELAY: `events` (default: a relay of typed messages on rclpy's EventsExecutor, the node's own
executor: what a bare rclpy relay costs as written), `raw` (the same relay over serialised bytes, never building
a Python message, as the node's Imu path does: the floor of any rclpy relay) or `single` (`rclpy.spin`, the
SingleThreadedExecutor).

The measuring processes take their share of the 2 cores too, so the subscriber spins an EventsExecutor, and the
stream starts only once the measured process tree is idle (its imports, and the node's worker's, done).
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
PY = sys.executable
SECONDS = float(os.environ.get("BENCH_SECONDS", "10"))


def _stat(pid: int) -> list[str]:
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def cpu_seconds(pid: int) -> float:
    """CPU time of `pid` and every process below it (utime + stime)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                parents[int(entry.name)] = int(_stat(int(entry.name))[1])
            except (OSError, IndexError):
                pass
    tree, grew = {pid}, True
    while grew:
        below = {child for child, parent in parents.items() if parent in tree} - tree
        tree |= below
        grew = bool(below)
    total = 0
    for member in tree:
        try:
            fields = _stat(member)
        except OSError:
            continue
        total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


def wait_idle(pid: int, timeout: float = 60.0) -> None:
    """Until `pid`'s tree has spent < 20 ms of CPU in 0.5 s: started, imports done, waiting for messages."""
    deadline = time.monotonic() + timeout
    before = cpu_seconds(pid)
    while time.monotonic() < deadline:
        time.sleep(0.5)
        now = cpu_seconds(pid)
        if now - before < 0.02:
            return
        before = now
    raise RuntimeError(f"process {pid} still busy after {timeout:.0f} s")


def run(kind: str, rate: float, workdir: Path, domain: int) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    if kind == "relay":
        relays = {"events": "relay-events", "single": "relay", "raw": "relay-raw"}
        peer = relays[os.environ.get("BENCH_RELAY", "events")]
        target = subprocess.Popen([PY, HERE / "stream_peers.py", peer], env=env)
    else:
        cal = workdir / "cal.yaml"
        cal.write_text(
            "accel_calibration:\n  model: sphere9\n  gravity: 9.80665\n  bias: [0.1, -0.2, 0.3]\n"
            "  matrix: [[1.01, 0, 0], [0.01, 0.99, 0], [0.002, -0.003, 1.02]]\n"
        )
        target = subprocess.Popen(
            [PY, "-m", "accel_calibration.ros.node", "--ros-args", "-p", f"calibration_file:={cal}",
             "--log-level", "warn"], env=env)
    out = workdir / f"{kind}_{rate}.json"
    subscriber = subprocess.Popen([PY, HERE / "stream_peers.py", "subscribe", str(SECONDS + 90), out], env=env)
    wait_idle(target.pid)
    wait_idle(subscriber.pid)
    cpu0 = cpu_seconds(target.pid)
    publisher = subprocess.run([PY, HERE / "stream_peers.py", "publish", str(rate), str(SECONDS)], env=env,
                               capture_output=True, text=True, check=True)
    cpu1 = cpu_seconds(target.pid)
    published = json.loads(publisher.stdout.strip().splitlines()[-1])["published"]
    subscriber.wait(timeout=120)
    target.send_signal(signal.SIGINT)
    target.wait(timeout=20)
    data = json.loads(out.read_text())
    latency = np.array(data["latency_ns"]) / 1e6
    return {
        "delivered": data["delivered"] / published,
        "p99_ms": float(np.percentile(latency, 99)) if len(latency) else float("nan"),
        "cpu_us_per_msg": (cpu1 - cpu0) / published * 1e6,
        "cpu_share": (cpu1 - cpu0) / SECONDS,
    }


def main() -> int:
    domain = 40 + os.getpid() % 50
    rates = [float(r) for r in os.environ.get("BENCH_RATES", "1000,2000,4000").split(",")]
    runs = int(os.environ.get("BENCH_RUNS", "10"))
    met = {rate: 0 for rate in rates}
    with tempfile.TemporaryDirectory() as tmp:
        for run_index in range(runs):
            for rate in rates:
                relay = run("relay", rate, Path(tmp), domain)
                node = run("node", rate, Path(tmp), domain)
                budget = relay["p99_ms"] + 0.5
                cpu_ratio = node["cpu_us_per_msg"] / relay["cpu_us_per_msg"]
                verdicts = [node["delivered"] >= 0.999 or rate > 2000, cpu_ratio <= 1.3, node["p99_ms"] <= budget]
                met[rate] += all(verdicts)
                missed = [name for name, ok in zip(("delivered", "cpu", "p99"), verdicts) if not ok]
                print(f"run {run_index + 1:2d} {rate / 1000:g} kHz | relay: delivered {100 * relay['delivered']:6.2f} %"
                      f" p99 {relay['p99_ms']:5.2f} ms CPU {relay['cpu_us_per_msg']:5.1f} us/msg | node: delivered "
                      f"{100 * node['delivered']:6.2f} % p99 {node['p99_ms']:5.2f} ms (budget {budget:5.2f}) CPU "
                      f"{node['cpu_us_per_msg']:5.1f} us/msg ({cpu_ratio:.2f}x) | "
                      f"{'MISSED ' + ','.join(missed) if missed else 'ok'}"
                      f" | load {os.getloadavg()[0]:.1f}", flush=True)
    for rate in rates:
        print(f"{rate / 1000:g} kHz: {met[rate]} of {runs} runs meet every target")
    return 0


if __name__ == "__main__":
    sys.exit(main())
