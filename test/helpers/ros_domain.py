"""A DDS domain of its own for each process that runs tests.

`make test` runs pytest with pytest-xdist: two workers at once, each starting calibration_node processes
and rclpy nodes of the same names. They must never see each other (test_namesakes.py counts the nodes of
one name; a tester must only ever talk to its own node), nor another session's tests on this machine.
So each worker, or a plain pytest process, claims a domain ID by holding an exclusive lock on
<tmp>/accel_calibration-ros-domains/<id>.lock for its whole life (released by the kernel when it exits,
however it exits) and sets ROS_DOMAIN_ID before anything initialises rclpy; the node processes it starts
inherit it. A domain held by another process is skipped, so two concurrent runs never share one.

The search starts at a point drawn from the run (xdist's run id, shared by its workers, else the pid)
plus the worker's number, so runs and workers spread out and a domain just given back is not the first
one tried. IDs 1-101 only: 0 is ROS's default (a user's own graph), and on Linux domains above 101 put
DDS ports in the ephemeral port range. 1-9, 100 and 101 are tried first: `make demo` and the benchmarks
pick theirs in 10-99 from their pid, without a lock.
"""
from __future__ import annotations

import fcntl
import os
import tempfile
import warnings
from pathlib import Path

PREFERRED = [*range(1, 10), 100, 101]
OTHERS = list(range(10, 100))
LOCK_DIR = Path(tempfile.gettempdir()) / "accel_calibration-ros-domains"
_held: list[int] = []  # the open lock's file descriptor: kept for the life of the process


def _candidates() -> list[int]:
    """Every domain, in the order to try: the preferred ones, then the others, each list rotated to start
    at this run's point plus this worker's number."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    run = os.environ.get("PYTEST_XDIST_TESTRUNUID", "")
    start = (int(run[:8], 16) if run else os.getpid()) + (int(worker[2:]) if worker[2:].isdigit() else 0)
    return [domains[(start + i) % len(domains)] for domains in (PREFERRED, OTHERS) for i in range(len(domains))]


def _try_lock(domain: int) -> int | None:
    try:
        fd = os.open(LOCK_DIR / f"{domain}.lock", os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        return None
    return fd


def claim_ros_domain() -> int:
    """Set ROS_DOMAIN_ID to a domain no other test process on this machine holds, and hold it.

    A plain pytest run where ROS_DOMAIN_ID is already set keeps it (the user chose it). An xdist worker
    always claims its own: the ID it inherited is shared with the other workers."""
    if _held:
        return int(os.environ["ROS_DOMAIN_ID"])
    if "PYTEST_XDIST_WORKER" not in os.environ and "ROS_DOMAIN_ID" in os.environ:
        return int(os.environ["ROS_DOMAIN_ID"])
    candidates = _candidates()
    try:
        LOCK_DIR.mkdir()
        LOCK_DIR.chmod(0o1777)  # any user's tests lock here (mkdir's mode is cut by the umask)
    except OSError:
        pass  # there already, or not creatable: then no lock is had and the warning below says so
    for domain in candidates:
        fd = _try_lock(domain)
        if fd is not None:
            _held.append(fd)
            os.environ["ROS_DOMAIN_ID"] = str(domain)
            return domain
    domain = candidates[0]
    warnings.warn(f"no free DDS domain lock in {LOCK_DIR}: using ROS_DOMAIN_ID={domain} unclaimed", stacklevel=2)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    return domain
