"""calibration_node under faults, with real processes and real filesystems: a full disk and a read-only
directory under the calibration file, many /calibrate calls at once, a publisher that dies and comes
back, signals during saves. The calibration in force and its file are never lost."""
from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros
from std_srvs.srv import Trigger

from accel_calibration import Calibration, load_calibration, save_calibration
from msg_tools.node_process import NodeProcess
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

from helpers.ci import under_ci

START_NS = 1_700_000_000 * 10**9
IN_FORCE = Calibration(bias=[0.1, -0.2, 0.3], matrix=[[1.01, 0, 0], [0.01, 0.99, 0], [0.0, 0.02, 1.02]])


def good_session(seed=41):
    errors = SensorErrors.mpu6050_like(np.random.default_rng(seed), noise_mps2=0.02)
    rng = np.random.default_rng(seed + 1)
    return SyntheticImu(errors, spread_orientations(16, rng), dwell_s=2.5, move_s=1.0, rate_hz=200.0, seed=seed)


@contextlib.contextmanager
def unwritable(directory, kind):
    """A real full disk (a 64 KiB tmpfs, filled) or a real read-only directory (chattr +i, which holds
    for root too), with the calibration file already in it."""
    root = os.geteuid() == 0
    if kind == "full disk":
        if not root:
            if under_ci():
                pytest.fail("CI must run as root to mount a small full tmpfs")
            pytest.skip("mounting a small full tmpfs needs root (CI runs as root)")
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(directory)], check=True)
        try:
            save_calibration(IN_FORCE, directory / "cal.yaml")
            filler = open(directory / "filler", "wb", buffering=0)
            with contextlib.suppress(OSError):
                while True:
                    filler.write(b"\0" * 4096)
            filler.close()
            yield
        finally:
            subprocess.run(["umount", str(directory)], check=False)
    else:
        save_calibration(IN_FORCE, directory / "cal.yaml")
        if root:  # permissions do not stop root; the immutable flag does
            subprocess.run(["chattr", "+i", str(directory)], check=True)
        else:
            directory.chmod(0o500)
        try:
            yield
        finally:
            if root:
                subprocess.run(["chattr", "-i", str(directory)], check=False)
            else:
                directory.chmod(0o700)


@pytest.mark.parametrize("kind", ["full disk", "read-only directory"])
def test_a_failed_save_keeps_the_calibration_in_force_and_its_file_whole(tmp_path, tester, kind):
    directory = tmp_path / "cal"
    directory.mkdir()
    with unwritable(directory, kind):
        cal_file = directory / "cal.yaml"
        before = cal_file.read_bytes()
        node = NodeProcess(cal_file, log_path=tmp_path / "node.log")
        try:
            tester.wait_ready()
            tester.play(good_session().samples(), start_ns=START_NS)
            answer = tester.call("calibrate")
            assert not answer.success
            assert answer.message.startswith("not applied: cannot write")
            assert answer.message.endswith("previous calibration kept in force")
            expected = ("No space left",) if kind == "full disk" else ("not permitted", "Permission denied")
            assert any(text in answer.message for text in expected), answer.message
            assert load_calibration(cal_file) == IN_FORCE and cal_file.read_bytes() == before
            got = tester.call("calibration/get")
            assert got.success and "0.1" in got.message.split("bias:")[1].splitlines()[0]
            saved = tester.call("calibration/save")
            assert not saved.success and "cannot write" in saved.message
            assert tester.spin_until(lambda: tester.diagnostics and tester.diagnostics[-1]["level"] == b"\x02", 5)
            assert "save failed" in tester.diagnostics[-1]["message"]
            assert sorted(p.name for p in directory.iterdir() if p.name != "filler") == ["cal.yaml"]
        finally:
            assert node.stop() == 0, node.log()


def test_many_calibrate_calls_at_once(tmp_path, tester):
    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file)
    try:
        tester.wait_ready()
        tester.play(good_session(seed=43).samples(), start_ns=START_NS)
        # Four clients (tools, people) with 6 calls each in flight together, gets in between.
        clients = [tester.node.create_client(Trigger, "calibrate") for _ in range(4)]
        for client in clients:
            assert client.wait_for_service(timeout_sec=10)
        futures = [client.call_async(Trigger.Request()) for client in clients for _ in range(3)]
        gets = [tester.clients["calibration/get"].call_async(Trigger.Request()) for _ in range(4)]
        futures += [client.call_async(Trigger.Request()) for client in clients for _ in range(3)]
        assert tester.spin_until(lambda: all(f.done() for f in futures + gets), 30)
        calibrate_answers = [f.result() for f in futures]
        assert all(a.success for a in calibrate_answers)
        assert len({a.message.split("saved:")[0] for a in calibrate_answers}) == 1  # the same fit each time
        assert load_calibration(cal_file).quality.poses >= 12
        assert node.process.poll() is None
    finally:
        assert node.stop() == 0, node.log()


def test_the_publisher_dies_and_comes_back(tmp_path, tester):
    cal_file = tmp_path / "cal.yaml"
    node = NodeProcess(cal_file)
    publisher_args = [sys.executable, "-m", "msg_tools.synthetic_publisher", "--poses", "16", "--dwell", "2.5",
                      "--move", "1.0", "--speed", "8", "--seed", "5"]
    try:
        tester.wait_ready()
        first = subprocess.Popen(publisher_args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        assert tester.spin_until(lambda: tester.diagnostics and int(tester.diagnostics[-1]["poses"]) >= 4, 30)
        first.kill()  # mid-session, no goodbye
        first.wait()
        assert node.process.poll() is None
        second = subprocess.Popen(publisher_args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        assert second.wait(timeout=60) == 0
        assert tester.spin_until(lambda: int(tester.diagnostics[-1]["poses"]) >= 12, 10)
        answer = tester.call("calibrate")
        assert answer.success, answer.message
    finally:
        assert node.stop() == 0, node.log()


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_signals_during_saves_leave_a_whole_file(tmp_path, tester, sig):
    cal_file = tmp_path / "cal.yaml"
    save_calibration(IN_FORCE, cal_file)
    for attempt in range(4):
        node = NodeProcess(cal_file, log_path=tmp_path / f"node{attempt}.log")
        tester.wait_ready()
        futures = [tester.clients["calibration/save"].call_async(Trigger.Request()) for _ in range(20)]
        time.sleep(0.002 * attempt)
        node.process.send_signal(sig)
        assert node.process.wait(timeout=20) == 0, node.log()
        node.stop()
        assert load_calibration(cal_file) == IN_FORCE  # whole, and still the one in force
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".cal.yaml")] == []
        del futures
