"""accel-calib report: a figure of a calibration against its poses (from a bag or a pose table), or of
the calibration history (`--history`, cli/history.py)."""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import CalibrationError
from . import history as history_command
from .options import UNIT_SCALE, calibration_in_force

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from ..core.calibration import Calibration
    from ..core.gyro_fit import GyroFitResult


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser("report", help="a figure of a calibration against its poses")
    parser.add_argument("calibration", nargs="?", help="calibration YAML (not with --history)")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--bag", help="rosbag2 whose static poses to show")
    source.add_argument("--poses", help="CSV of pose means (ax,ay,az[,temperature])")
    source.add_argument("--history", help="calibration history (accel-calib fleet): one panel per sensor")
    history_command.add_drift_options(parser)
    parser.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of the poses CSV")
    parser.add_argument("--output", "-o", required=True,
                        help="PNG to write; with --history, a .html name writes the fleet's page of flight evidence")

    return parser


def render_report(calibration: Calibration, accel: npt.ArrayLike, temperatures: Sequence[float | None] | None,
                  title: str, gyro: GyroFitResult | None = None) -> bytes:
    """The report figure's PNG bytes, rendered aside (written later like every output)."""
    import tempfile

    from ..io.report import write_report as draw_report

    with tempfile.TemporaryDirectory(prefix="accel-calib-report-") as scratch:
        rendered = Path(scratch) / "report.png"
        draw_report(calibration, accel, temperatures, rendered, title=title, gyro=gyro)
        return rendered.read_bytes()


def write_report(calibration: Calibration, accel: npt.ArrayLike, temperatures: Sequence[float | None] | None,
                 output: str, title: str, gyro: GyroFitResult | None = None) -> None:
    """The report figure, rendered aside and then written like every output (whole, through symlinks,
    keeping the old file's mode)."""
    from ..io.output_paths import write_bytes_atomically

    write_bytes_atomically(output, render_report(calibration, accel, temperatures, title, gyro))


def run(args: argparse.Namespace) -> int:
    from ..io.output_paths import check_outputs
    from ..io.pose_table import read_table

    if args.history:
        check_outputs([("--output", args.output)], [args.history if "://" not in args.history else None])
        if args.output.lower().endswith((".html", ".htm")):  # the fleet's page of flight evidence
            return history_command.report_page(args)
        return history_command.report_history(args)
    if args.calibration is None:
        raise CalibrationError("report needs a calibration YAML (or --history DB)")
    check_outputs([("--output", args.output)], [args.calibration, args.bag, args.poses])
    calibration = calibration_in_force(args.calibration)
    accel: list[np.ndarray] | np.ndarray
    temps: list[float | None] | None
    if args.bag:
        from ..bag.replay import ReplayError, replay_bag

        try:
            replay = replay_bag(args.bag)
        except ReplayError as error:
            raise CalibrationError(str(error)) from None
        accel = [p.accel_mps2 for p in replay.poses]
        temps = [p.temperature_degc for p in replay.poses]
        gyro = replay.gyro  # the recording's motions, fitted by replay
    else:
        gyro = None
        table = read_table(args.poses)
        accel = table.accel * UNIT_SCALE[args.units]
        temps = None if table.temperature_degc is None else list(table.temperature_degc)
    if len(accel) == 0:
        raise CalibrationError("no poses to show")
    write_report(calibration, accel, temps, args.output, title=str(args.calibration), gyro=gyro)
    print(f"report {args.output}")
    return 0
