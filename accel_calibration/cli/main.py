"""accel-calib: fit and apply calibrations from the command line.

The body is `main(argv) -> exit code` so tests call it directly. Expected failures (bad input,
a fit that cannot be done) print one line on stderr and exit non-zero; an existing output file is
only ever replaced whole, by an atomic rename, after everything succeeded.
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from typing import NoReturn, TextIO

from ..core.errors import AccelCalibrationError, CalibrationError, DeprecatedInputWarning

# One module per command (add_parser, run). The fit, settings, YAML files, tables and Dask are imported
# by the commands that use them: `--help` and a start-up cost at most twice numpy's own import
# (bench/bench_startup.py).
from . import apply as apply_command
from . import check as check_command
from . import compare as compare_command
from . import export as export_command
from . import fit as fit_command
from . import fleet as fleet_command
from . import history as history_command
from . import noise as noise_command
from . import replay as replay_command
from . import report as report_command
from .options import PROG

COMMANDS = {"fit": fit_command, "replay": replay_command, "report": report_command, "apply": apply_command,
            "fleet": fleet_command, "history": history_command, "export": export_command,
            "compare": compare_command, "noise": noise_command, "check": check_command}


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise CalibrationError(f"{message} (see '{self.prog} --help')")


def _parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog=PROG, description="Calibrate MEMS accelerometers: a_true = M (a_raw - b), SI units.")
    parser.add_argument("--version", action="version", version=f"{PROG} {_version()}")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)
    for command in COMMANDS.values():
        command.add_parser(commands)
    return parser


def _version() -> str:
    """The installed distribution's version (setup.py's), or "unknown" for a source tree never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("accel_calibration")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _check_finite(args: argparse.Namespace) -> None:
    """argparse's float() takes 'nan', 'inf' and '1e999': no number option may be one."""
    for name, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CalibrationError(f"--{name.replace('_', '-')} must be a finite number, got {value}")


class _WatchedStdout:
    """sys.stdout as the commands see it, noting the first write to it that failed: a failure there (the reader
    of a pipe gone, a full device) is told from a failure of the command's own files by where it happened."""

    def __init__(self, stream: object) -> None:
        self.stream = stream
        self.failure: OSError | None = None

    def write(self, text: str) -> int:
        try:
            written: int = self.stream.write(text)  # type: ignore[attr-defined]
        except OSError as error:
            self.failure = self.failure or error
            raise
        return written

    def flush(self) -> None:
        try:
            self.stream.flush()  # type: ignore[attr-defined]
        except OSError as error:
            self.failure = self.failure or error
            raise

    def __getattr__(self, name: str) -> object:
        return getattr(self.stream, name)


def _stdout_lost(failure: OSError, stream: object) -> int:
    """Python's recipe for a broken pipe: what is still buffered goes to devnull (no second error at exit), exit 1;
    quietly for a reader that has gone (as `| head` expects), in one line for anything else (a full device)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, stream.fileno())  # type: ignore[attr-defined]
        os.close(devnull)
    except (OSError, AttributeError, ValueError):
        pass  # not a file descriptor (a test's capture): nothing to flush at exit
    if not isinstance(failure, BrokenPipeError):
        try:
            print(f"{PROG}: error: cannot write the standard output: {failure.strerror or failure}", file=sys.stderr)
        except OSError:
            pass
    return 1


def main(argv: Sequence[str] | None = None) -> int:
    """The command's exit code; its output lost (stdout closed, full, a pipe whose reader left) is exit 1 in at
    most one line, never a traceback."""
    original = sys.stdout
    watched = None if original is None else _WatchedStdout(original)
    if watched is not None:
        sys.stdout = watched
    leaving: SystemExit | None = None
    try:
        try:
            with _older_forms_said_in_one_line():
                status = _main(argv)
        except SystemExit as exit_:  # --help: argparse itself ignores a failed write, then exits
            leaving, status = exit_, 0
        if watched is not None:
            watched.flush()
    except OSError:
        if watched is None or watched.failure is None:
            raise
    finally:
        sys.stdout = original
    if watched is not None and watched.failure is not None:
        return _stdout_lost(watched.failure, original)
    if leaving is not None:
        raise leaving
    return status


@contextlib.contextmanager
def _older_forms_said_in_one_line() -> Iterator[None]:
    """An input read in a form an older version wrote (DeprecatedInputWarning) is one line on stderr, each
    time; any other warning as Python shows it."""
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: TextIO | None = None, line: str | None = None) -> None:
            if issubclass(category, DeprecatedInputWarning):
                print(f"{PROG}: warning: {message}", file=sys.stderr)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.simplefilter("always", DeprecatedInputWarning)
        warnings.showwarning = show
        yield


def _main(argv: Sequence[str] | None) -> int:
    try:
        args = _parser().parse_args(argv)
        _check_finite(args)
        status: int = COMMANDS[args.command].run(args)
        return status
    except AccelCalibrationError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 1
    except ModuleNotFoundError as error:  # an install without a third-party module: say what to install
        from ..bag.bag_io import missing_module  # only here: bag_io is not needed to start

        if (missing := missing_module(error)) is None:
            raise
        print(f"{PROG}: error: {missing}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
