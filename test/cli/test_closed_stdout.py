"""accel-calib with its standard output gone: a reader that has closed the pipe (`| head -c 1`), a full
device (/dev/full), or no stdout at all. Real processes: the failure is at the file descriptor and at the
interpreter's exit. A broken pipe ends quietly with exit 1 (Python's documented recipe); a full device
says so in one line; never a traceback."""
from __future__ import annotations

import os
import subprocess

import numpy as np
import pytest

from accel_calibration.core.calibration import Calibration
from accel_calibration.io.calibration_file import save_calibration
from msg_tools.node_process import installed_command
from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, rotation_with_up, spread_orientations

ACCEL_CALIB = installed_command("accel-calib")


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A CSV recording of 14 poses and the sensor's calibration: `check` and `replay` both print pages."""
    directory = tmp_path_factory.mktemp("stdout")
    rng = np.random.default_rng(4)
    errors = SensorErrors.mpu6050_like(rng, noise_mps2=0.02)
    rotations = [rotation_with_up([0.0, 0.0, 1.0]), *spread_orientations(13, rng)]
    s = SyntheticImu(errors, rotations, dwell_s=2.5, move_s=0.8, rate_hz=100.0, seed=4).samples()
    rows = [f"{t},{','.join(repr(float(v)) for v in a)}" for t, a in zip(s.t_ns, s.accel_raw)]
    recording = directory / "session.csv"
    recording.write_text("t_ns,ax,ay,az\n" + "\n".join(rows) + "\n")
    calibration = directory / "cal.yaml"
    save_calibration(Calibration(bias=errors.bias_mps2, matrix=errors.matrix), str(calibration))
    return directory, recording, calibration


def commands(directory, recording, calibration):
    return {"check": ["check", calibration, recording],
            "replay": ["replay", recording, "-o", directory / "replayed.yaml"],
            "help": ["replay", "--help"]}


def run_with_stdout(args, stdout):
    return subprocess.run([*ACCEL_CALIB, *map(str, args)], stdout=stdout, stderr=subprocess.PIPE, text=True,
                          check=False, timeout=300)


@pytest.mark.parametrize("command", ["check", "replay", "help"])
def test_a_reader_gone_ends_quietly_with_exit_1(inputs, command):
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader has gone before the first byte: every write is EPIPE, not a race
    try:
        run = run_with_stdout(commands(*inputs)[command], write_end)
    finally:
        os.close(write_end)
    assert "Traceback" not in run.stderr and run.stderr.count("\n") <= 1, run.stderr
    assert run.returncode == 1, run.stderr


@pytest.mark.parametrize("command", ["check", "replay", "help"])
def test_a_full_device_is_one_line(inputs, command):
    with open("/dev/full", "w") as full:
        run = run_with_stdout(commands(*inputs)[command], full)
    assert run.returncode == 1, run.stderr
    assert run.stderr.count("\n") == 1 and run.stderr.startswith("accel-calib: error: "), run.stderr
    assert "standard output" in run.stderr and "No space left" in run.stderr, run.stderr


@pytest.mark.parametrize("command", ["check", "replay"])
def test_no_stdout_at_all_still_does_the_work(inputs, command):
    directory, recording, calibration = inputs
    target = directory / "replayed.yaml"
    target.unlink(missing_ok=True)
    run = subprocess.run([*ACCEL_CALIB, *map(str, commands(*inputs)[command])], stderr=subprocess.PIPE,
                         text=True, check=False, timeout=300, preexec_fn=lambda: os.close(1))
    assert "Traceback" not in run.stderr and run.stderr.count("\n") <= 1, run.stderr
    assert run.returncode in (0, 1, 3), run.stderr
    if command == "replay":
        assert run.returncode == 0 and target.exists(), run.stderr
