"""accel-calib fit --model dividing-head: a dividing head's table of positions (alpha_deg,beta_deg or pos
k-j, and ax,ay,az) to a calibration file of model dividing-head, and the paper's table of terms."""
from __future__ import annotations

import argparse

import numpy as np

from ..core.dividing_head_fit import fit_dividing_head
from ..core.errors import CalibrationError
from ..io.calibration_file import save_calibration
from ..io.head_table import read_head_table
from .options import check_table_units


def fit_table(args: argparse.Namespace, unit_mps2: float, gravity: float) -> int:
    """The body of `fit` for model dividing-head (cli/fit.py has worked out the local g and checked the outputs);
    unit_mps2: what one unit of the table's ax,ay,az is in m/s^2 (--units)."""
    if args.temperature_model != "none":
        raise CalibrationError("model dividing-head has no temperature model: fit it with --temperature-model none")
    table = read_head_table(args.poses)
    check_table_units(table.accel, unit_mps2, args.units, gravity, args.poses)
    result = fit_dividing_head(np.radians(table.alpha_deg), np.radians(table.beta_deg),
                               table.accel * unit_mps2, gravity=gravity, frame_id=args.frame_id)
    if not result.success or result.calibration is None or result.calibration.dividing_head is None:
        raise CalibrationError(f"fit failed: {result.message}")
    save_calibration(result.calibration, args.output)
    print(result.summary())
    print(result.calibration.dividing_head.describe())
    print(f"written {args.output}")
    return 0
