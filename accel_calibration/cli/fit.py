"""accel-calib fit: a calibration from a CSV table of static pose means."""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ..core.errors import CalibrationError
from ..core.models import DIVIDING_HEAD, MODELS, REFERENCE_MODELS, SPHERE_MODELS
from ..core.temperature_models import TEMPERATURE_MODELS, TemperatureOptions
from ..core.units import MG, STANDARD_GRAVITY
from .options import UNIT_SCALE, add_local_gravity_options, check_table_units, local_gravity

if TYPE_CHECKING:
    from ..core.prior import Prior


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    defaults = TemperatureOptions()  # the temperature fit's defaults, as the node's settings take them
    parser = commands.add_parser("fit", help="fit a calibration to a CSV table of static pose means")
    parser.add_argument("poses", help="CSV with header ax,ay,az [,temperature] [,ref_x,ref_y,ref_z] [,sigma_mg] "
                                      "(dividing-head: alpha_deg,beta_deg or pos k-j)")
    parser.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of ax,ay,az (default mps2)")
    parser.add_argument("--model", choices=MODELS + (DIVIDING_HEAD,), default="sphere9",
                        help="error model (default sphere9)")
    add_local_gravity_options(parser)
    parser.add_argument("--frame-id", default="", help="sensor frame id stored in the file")
    parser.add_argument("--temperature-model", choices=TEMPERATURE_MODELS, default="none",
                        help="temperature drift model, needs a temperature column (default none)")
    parser.add_argument("--bias-order", type=int, default=defaults.bias_order,
                        help=f"polynomial: order of the bias drift, 0..3 (default {defaults.bias_order})")
    parser.add_argument("--scale-order", type=int, default=defaults.scale_order,
                        help=f"polynomial: order of the scale drift, 0..2 (default {defaults.scale_order})")
    parser.add_argument("--segment-width", type=float, default=defaults.segment_width_degc,
                        help=f"segmented: segment width, degC (default {defaults.segment_width_degc:g})")
    parser.add_argument("--segment-blend", action=argparse.BooleanOptionalAction, default=defaults.segment_blend,
                        help="segmented: interpolate between the temperatures segments were learned at "
                             "(default); --no-segment-blend: the seed paper's pick of the segment holding it")
    parser.add_argument("--reference-temperature", type=float, default=None,
                        help="T_ref, degC (default: the poses' median temperature)")
    parser.add_argument("--min-span", type=float, default=defaults.min_span_degc,
                        help=f"smallest temperature span to fit a model, degC (default {defaults.min_span_degc:g})")
    parser.add_argument("--prior", metavar="CAL.yaml", default=None,
                        help="recalibrate against this calibration (same model, with its uncertainty): what the "
                             "poses observe is fitted, the rest stays at the prior (poses near level suffice)")
    parser.add_argument("--prior-bias-drift", type=float, default=None, metavar="MG",
                        help="how far the bias may have drifted since the prior, 1 sigma in mg, added to its "
                             "sigma (default 10, core.prior.DEFAULT_BIAS_DRIFT_MPS2)")
    parser.add_argument("--output", "-o", required=True, help="calibration YAML to write")

    return parser


def _gravity(args: argparse.Namespace) -> tuple[float, str]:
    """The local g and where it came from: --latitude [--height] (checked as the node checks them), else
    --gravity (any positive number: a table in other units), else the standard 1 g."""
    from ..core.gravity import given_gravity_source

    located = local_gravity(args) if args.latitude_deg is not None or args.height_m is not None else None
    if located is not None:
        return located
    gravity = STANDARD_GRAVITY if args.gravity is None else args.gravity
    if not (gravity > 0 and gravity < 1e3):
        raise CalibrationError(f"--gravity must be a positive number of m/s^2, got {gravity}")
    return gravity, given_gravity_source(gravity)


def run(args: argparse.Namespace) -> int:
    from ..core.fit import fit
    from ..core.plausibility import PLAUSIBLE_TEMPERATURE_DEGC
    from ..core.temperature_models import TemperatureOptions
    from ..io.calibration_file import save_calibration
    from ..io.output_paths import check_outputs
    from ..io.pose_table import read_table

    gravity, gravity_source = _gravity(args)
    low, high = PLAUSIBLE_TEMPERATURE_DEGC
    if args.reference_temperature is not None and not low <= args.reference_temperature <= high:
        raise CalibrationError(f"--reference-temperature must be a sensor temperature within {low:g}..{high:g} degC, "
                               f"got {args.reference_temperature:g}")
    check_outputs([("--output", args.output)], [args.poses, args.prior])
    prior = None if args.prior is None else _prior(args, gravity)
    if args.model == DIVIDING_HEAD:
        from . import dividing_head as dividing_head_command

        return dividing_head_command.fit_table(args, UNIT_SCALE[args.units], gravity)
    table = read_table(args.poses)
    if args.model in REFERENCE_MODELS and table.reference is None:
        raise CalibrationError(f"{args.poses}: model {args.model} needs columns ref_x,ref_y,ref_z")
    check_table_units(table.accel, UNIT_SCALE[args.units], args.units, gravity, args.poses)
    accel = table.accel * UNIT_SCALE[args.units]
    options = None
    if args.temperature_model != "none":
        if table.temperature_degc is None:
            raise CalibrationError(f"{args.poses}: --temperature-model {args.temperature_model} "
                                   "needs a temperature column")
        options = TemperatureOptions(model=args.temperature_model, bias_order=args.bias_order,
                                     scale_order=args.scale_order,
                                     segment_width_degc=args.segment_width, min_span_degc=args.min_span,
                                     reference_degc=args.reference_temperature, segment_blend=args.segment_blend)
    result = fit(
        accel,
        model=args.model,
        gravity=gravity,
        temperature_degc=table.temperature_degc,
        reference=table.reference if args.model in REFERENCE_MODELS else None,
        frame_id=args.frame_id,
        temperature_model=args.temperature_model,
        temperature_options=options,
        pose_sigma_mps2=table.pose_sigma_mps2,
        prior=prior,
    )
    if not result.success or result.calibration is None:
        raise CalibrationError(f"fit failed: {result.message}")
    if prior is not None:
        # With a prior nothing else stops a loose one from standing in for the orientations not reached
        # (the sigma gate) or poses far off the sphere from passing (the residual gate).
        from ..core.gates import QualityGates

        refusal = QualityGates().check_fit(result)
        if refusal is not None:
            raise CalibrationError(f"fit refused with --prior {args.prior} ({refusal})")
    save_calibration(result.calibration.replace(gravity_source=gravity_source), args.output,
                     result.parameter_sources, args.prior)
    print(result.summary())
    print(f"written {args.output}")
    return 0


def _prior(args: argparse.Namespace, gravity: float) -> Prior:
    """--prior's calibration, checked against this fit (model, uncertainty) before any work: one line if not."""
    from ..core.prior import DEFAULT_BIAS_DRIFT_MPS2, Prior, prior_terms
    from ..io.calibration_file import load_calibration

    if args.model not in SPHERE_MODELS or args.temperature_model != "none":
        raise CalibrationError(f"--prior fits the sphere models ({', '.join(SPHERE_MODELS)}) without a "
                               "temperature model")
    drift = DEFAULT_BIAS_DRIFT_MPS2 if args.prior_bias_drift is None else args.prior_bias_drift * MG
    if not (drift >= 0 and drift <= 1000 * MG):
        raise CalibrationError(f"--prior-bias-drift must be a number of mg within 0..1000, got {args.prior_bias_drift}")
    prior = Prior(load_calibration(args.prior), drift)
    try:
        prior_terms(prior, args.model, gravity)
    except CalibrationError as error:
        raise CalibrationError(f"--prior {args.prior}: {error}") from None
    return prior
