"""accel-calib: fit and apply calibrations from the command line.

The body is `main(argv) -> exit code` so tests call it directly. Expected failures (bad input,
a fit that cannot be done) print one line on stderr and exit non-zero; an existing output file is
only ever replaced whole, by an atomic rename, after everything succeeded.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from .calibration import STANDARD_GRAVITY
from .calibration_file import load_calibration, write_text_atomically
from .errors import CalibrationError
from .fit import fit
from .models import MODELS, REFERENCE_MODELS
from .pose_table import read_table, table_with_accel
from .temperature_models import TEMPERATURE_MODELS, TemperatureOptions

PROG = "accel-calib"
UNIT_SCALE = {"mps2": 1.0, "g": STANDARD_GRAVITY}  # a reading of 1 g is 9.80665 m/s^2 by definition


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message):
        raise CalibrationError(f"{message} (see '{self.prog} --help')")


def _parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog=PROG, description="Calibrate MEMS accelerometers: a_true = M (a_raw - b), SI units.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)

    fit_cmd = commands.add_parser("fit", help="fit a calibration to a CSV table of static pose means")
    fit_cmd.add_argument("poses", help="CSV with header ax,ay,az [,temperature] [,ref_x,ref_y,ref_z]")
    fit_cmd.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of ax,ay,az (default mps2)")
    fit_cmd.add_argument("--model", choices=MODELS, default="sphere9", help="error model (default sphere9)")
    fit_cmd.add_argument("--gravity", type=float, default=STANDARD_GRAVITY, help="local gravity, m/s^2 (default 9.80665)")
    fit_cmd.add_argument("--frame-id", default="", help="sensor frame id stored in the file")
    fit_cmd.add_argument("--temperature-model", choices=TEMPERATURE_MODELS, default="none",
                         help="temperature drift model, needs a temperature column (default none)")
    fit_cmd.add_argument("--bias-order", type=int, default=2, help="polynomial: order of the bias drift, 0..3 (default 2)")
    fit_cmd.add_argument("--scale-order", type=int, default=1, help="polynomial: order of the scale drift, 0..2 (default 1)")
    fit_cmd.add_argument("--segment-width", type=float, default=10.0, help="segmented: segment width, degC (default 10)")
    fit_cmd.add_argument("--reference-temperature", type=float, default=None,
                         help="T_ref, degC (default: the poses' median temperature)")
    fit_cmd.add_argument("--min-span", type=float, default=10.0, help="smallest temperature span to fit a model, degC")
    fit_cmd.add_argument("--output", "-o", required=True, help="calibration YAML to write")

    apply_cmd = commands.add_parser("apply", help="correct the ax,ay,az columns of a CSV file")
    apply_cmd.add_argument("--calibration", "-c", required=True, help="calibration YAML")
    apply_cmd.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of ax,ay,az in and out")
    apply_cmd.add_argument("input", help="CSV with ax,ay,az (other columns copied unchanged)")
    apply_cmd.add_argument("output", help="CSV to write")
    return parser


def _fit(args) -> int:
    if not (args.gravity > 0 and args.gravity < 1e3):
        raise CalibrationError(f"--gravity must be a positive number of m/s^2, got {args.gravity}")
    table = read_table(args.poses)
    if args.model in REFERENCE_MODELS and table.reference is None:
        raise CalibrationError(f"{args.poses}: model {args.model} needs columns ref_x,ref_y,ref_z")
    accel = table.accel * UNIT_SCALE[args.units]
    options = None
    if args.temperature_model != "none":
        if table.temperature_degc is None:
            raise CalibrationError(f"{args.poses}: --temperature-model {args.temperature_model} needs a temperature column")
        options = TemperatureOptions(model=args.temperature_model, bias_order=args.bias_order, scale_order=args.scale_order,
                                     segment_width_degc=args.segment_width, min_span_degc=args.min_span,
                                     reference_degc=args.reference_temperature)
    result = fit(
        accel,
        model=args.model,
        gravity=args.gravity,
        temperature_degc=table.temperature_degc,
        reference=table.reference if args.model in REFERENCE_MODELS else None,
        frame_id=args.frame_id,
        temperature_model=args.temperature_model,
        temperature_options=options,
    )
    if not result.success:
        raise CalibrationError(f"fit failed: {result.message}")
    result.calibration.save(args.output)
    print(result.summary())
    print(f"written {args.output}")
    return 0


def _apply(args) -> int:
    calibration = load_calibration(args.calibration)
    table = read_table(args.input)
    scale = UNIT_SCALE[args.units]
    if calibration.temperature is not None and table.temperature_degc is None:
        raise CalibrationError(f"{args.input}: the calibration has a temperature model; add a temperature column")
    corrected = calibration.apply(table.accel * scale, temperature=table.temperature_degc) / scale
    write_text_atomically(args.output, table_with_accel(table, corrected))
    print(f"corrected {len(corrected)} rows -> {args.output}")
    clamped = int(np.count_nonzero(calibration.temperature_clamped(table.temperature_degc)))
    if clamped:
        lo, hi = calibration.temperature.range_degc
        print(f"{clamped} row{'s' if clamped > 1 else ''} outside the calibrated temperature range "
              f"{lo:.1f}..{hi:.1f} degC: clamped to its edge")
    return 0


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
        return {"fit": _fit, "apply": _apply}[args.command](args)
    except CalibrationError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
