"""accel-calib: fit and apply calibrations from the command line.

The body is `main(argv) -> exit code` so tests call it directly. Expected failures (bad input,
a fit that cannot be done) print one line on stderr and exit non-zero; an existing output file is
only ever replaced whole, by an atomic rename, after everything succeeded.
"""
from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from typing import NoReturn

from ..core.errors import AccelCalibrationError, CalibrationError

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
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)
    for command in COMMANDS.values():
        command.add_parser(commands)
    return parser


def _check_finite(args: argparse.Namespace) -> None:
    """argparse's float() takes 'nan', 'inf' and '1e999': no number option may be one."""
    for name, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CalibrationError(f"--{name.replace('_', '-')} must be a finite number, got {value}")


def main(argv: Sequence[str] | None = None) -> int:
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
