"""A damaged DataFlash log is one line, a nonzero exit and nothing written: stamps a nanosecond clock
cannot hold, FMT records that lie about their lengths (pymavlink's C indexer prints to the process's
stderr, below Python), a file of garbage after the header; `compare` reads such a log's parameters alike."""
from __future__ import annotations

import numpy as np
import pytest

from accel_calibration.cli.main import main
from msg_tools.dataflash_writer import FORMATS_4X, imu_records, parameter_records, write_dataflash

from helpers.autopilot_logs import ardupilot_parameters, logged, simulate

SHORT = 400  # records of each kind: enough to show the defect, quick to read


def short_log(path, board, stamps_us=None, extra=()):
    accel, gyro = logged(board.imus[0])
    t_us = board.t_us[:SHORT] if stamps_us is None else stamps_us
    records = parameter_records(int(t_us[0]), ardupilot_parameters(board))
    write_dataflash(path, FORMATS_4X, [*records, *extra, *imu_records(t_us, accel[:SHORT], gyro[:SHORT],
                                                                      board.temperature[:SHORT])])


def assert_one_line(capfd, argv, output, *words):
    assert main(argv) == 1
    captured = capfd.readouterr()
    assert captured.err.count("\n") == 1 and captured.err.startswith("accel-calib: error: "), captured.err[:300]
    for word in words:
        assert word in captured.err
    assert output is None or not output.exists()


@pytest.fixture(scope="module")
def board():
    return simulate(31)


def test_imu_stamps_beyond_a_nanosecond_clock_are_refused(board, tmp_path, capfd):
    log = tmp_path / "far.bin"
    short_log(log, board, stamps_us=2**62 + board.t_us[:SHORT])
    out = tmp_path / "cal.yaml"
    assert_one_line(capfd, ["replay", str(log), "--poses-out", str(tmp_path / "p.csv"), "-o", str(out)], out,
                    "TimeUS", "beyond")
    assert not (tmp_path / "p.csv").exists()


def test_one_arm_record_beyond_a_nanosecond_clock_is_refused(board, tmp_path, capfd):
    log = tmp_path / "arm.bin"
    short_log(log, board, extra=[("ARM", (2**62, 1, 0, 0, 0))])
    out = tmp_path / "cal.yaml"
    assert_one_line(capfd, ["replay", str(log), "-o", str(out)], out, "ARM", "beyond")


def lying(board, path, name: bytes, delta: int) -> None:
    """The log with the FMT record of `name` saying a length `delta` bytes off its format's."""
    short_log(path, board)
    data = bytearray(path.read_bytes())
    at = data.find(b"\xa3\x95\x80" + bytes([FORMATS_4X_IDS[name]]))
    data[at + 4] = (data[at + 4] + delta) % 256
    path.write_bytes(bytes(data))


FORMATS_4X_IDS = {name.encode(): 0x81 + i for i, name in enumerate(FORMATS_4X)}


@pytest.mark.parametrize(("name", "delta"), [(b"IMU", -7), (b"IMU", 20), (b"PARM", -7), (b"PARM", 1)])
def test_fmt_records_that_lie_about_lengths_are_one_line(board, tmp_path, capfd, name, delta):
    log = tmp_path / "lying.bin"
    lying(board, log, name, delta)
    out = tmp_path / "cal.yaml"
    assert_one_line(capfd, ["replay", str(log), "-o", str(out)], out, "damaged DataFlash log")


def test_garbage_after_the_header_is_one_line_for_replay_and_compare(tmp_path, capfd):
    log = tmp_path / "garbage.bin"
    rng = np.random.default_rng(5)
    log.write_bytes(b"\xa3\x95\x80" + rng.integers(0, 256, 2 << 20, dtype=np.uint8).tobytes())
    out = tmp_path / "cal.yaml"
    assert_one_line(capfd, ["replay", str(log), "-o", str(out)], out)
    calibration = tmp_path / "ours.yaml"
    from accel_calibration.core.calibration import Calibration
    from accel_calibration.io.calibration_file import save_calibration

    save_calibration(Calibration.identity(), calibration)
    assert_one_line(capfd, ["compare", str(calibration), str(log)], None)
