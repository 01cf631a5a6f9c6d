"""accel-calib apply: correct the ax,ay,az columns of a CSV table with a calibration file."""
from __future__ import annotations

import argparse

import numpy as np

from ..core.errors import CalibrationError
from .options import UNIT_SCALE, calibration_in_force


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser("apply", help="correct the ax,ay,az columns of a CSV file")
    parser.add_argument("--calibration", "-c", required=True, help="calibration YAML")
    parser.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of ax,ay,az in and out")
    parser.add_argument("input", help="CSV with ax,ay,az (other columns copied unchanged)")
    parser.add_argument("output", help="CSV to write")
    return parser


def run(args: argparse.Namespace) -> int:
    from ..core.correction import correct_rows
    from ..io.calibration_file import write_text_atomically
    from ..io.output_paths import check_outputs
    from ..io.pose_table import read_table, table_with_accel

    check_outputs([("output", args.output)], [args.calibration, args.input])
    calibration = calibration_in_force(args.calibration)
    table = read_table(args.input)
    scale = UNIT_SCALE[args.units]
    if calibration.temperature is not None and table.temperature_degc is None:
        raise CalibrationError(f"{args.input}: the calibration has a temperature model; add a temperature column")
    corrected = correct_rows(calibration, table.accel * scale, table.temperature_degc) / scale
    write_text_atomically(args.output, table_with_accel(table, corrected))
    print(f"corrected {len(corrected)} rows -> {args.output}")
    clamped = int(np.count_nonzero(calibration.temperature_clamped(table.temperature_degc)))
    if clamped:
        lo, hi = calibration.temperature.range_degc
        print(f"{clamped} row{'s' if clamped > 1 else ''} outside the calibrated temperature range "
              f"{lo:.1f}..{hi:.1f} degC: clamped to its edge")
    return 0
