"""What a person sees when `accel-calib` refuses something: one line, `accel-calib: error: ...`, and never a
traceback. One copy of each check, used by the tests of every layer."""
from __future__ import annotations

import contextlib
import io

from accel_calibration.cli.main import main

ERROR_PREFIX = "accel-calib: error: "


def run_main(args) -> tuple[int, str]:
    """main() in-process: (exit code, stderr), stdout discarded. Any exception escaping main is a traceback:
    the test fails."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main([str(a) for a in args])
    return code, err.getvalue()


def assert_one_error_line(code: int, err: str, *needles: str) -> str:
    """Exit code 1 and exactly one line on stderr, `accel-calib: error: ...`, holding every needle; no
    traceback. Returns stderr."""
    assert code == 1, err
    assert err.count("\n") == 1 and err.startswith(ERROR_PREFIX) and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def assert_at_most_one_line(code: int, err: str) -> None:
    """A success or a refusal (exit code 0, 1 or 2) in at most one line, never a traceback: what any input,
    however hostile, may give."""
    assert code in (0, 1, 2), err
    assert err.count("\n") <= 1 and "Traceback" not in err, err


def refused(capsys, args, *needles: str) -> str:
    """main(args) in-process refuses in one error line holding every needle (stderr read from capsys).
    Returns stderr."""
    code = main([str(a) for a in args])
    return assert_one_error_line(code, capsys.readouterr().err, *needles)


def one_error_line(capsys) -> str:
    """The one error line on stderr so far (read from capsys), without its newline; no traceback."""
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(ERROR_PREFIX) and "Traceback" not in err, err
    return err.rstrip("\n")
