"""accel-calib: fit and apply calibrations from the command line.

The body is `main(argv) -> exit code` so tests call it directly. Expected failures (bad input,
a fit that cannot be done) print one line on stderr and exit non-zero; an existing output file is
only ever replaced whole, by an atomic rename, after everything succeeded.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

import numpy as np

from ..bag.bag_io import missing_module
from ..core.calibration import MG, STANDARD_GRAVITY
from ..core.errors import AccelCalibrationError, CalibrationError
from ..core.models import DIVIDING_HEAD, MODELS, REFERENCE_MODELS
from ..core.temperature_models import TEMPERATURE_MODELS

# The fit, settings, YAML files and tables are imported by the commands that use them: `--help` and
# a start-up cost at most twice numpy's own import (bench/bench_startup.py).
from . import compare as compare_command
from . import dividing_head as dividing_head_command
from . import export as export_command
from . import fleet as fleet_command
from . import history as history_command
from . import noise as noise_command
from .flight_options import add_flight_state_options, flight_state_settings

PROG = "accel-calib"
UNIT_SCALE = {"mps2": 1.0, "g": STANDARD_GRAVITY}  # a reading of 1 g is 9.80665 m/s^2 by definition


class _OneLineParser(argparse.ArgumentParser):
    def error(self, message):
        raise CalibrationError(f"{message} (see '{self.prog} --help')")


def _parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(prog=PROG, description="Calibrate MEMS accelerometers: a_true = M (a_raw - b), SI units.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_OneLineParser)

    fit_cmd = commands.add_parser("fit", help="fit a calibration to a CSV table of static pose means")
    fit_cmd.add_argument("poses", help="CSV with header ax,ay,az [,temperature] [,ref_x,ref_y,ref_z] [,sigma_mg] "
                                       "(dividing-head: alpha_deg,beta_deg or pos k-j)")
    fit_cmd.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of ax,ay,az (default mps2)")
    fit_cmd.add_argument("--model", choices=MODELS + (DIVIDING_HEAD,), default="sphere9",
                         help="error model (default sphere9)")
    fit_cmd.add_argument("--gravity", type=float, default=STANDARD_GRAVITY,
                         help="local gravity, m/s^2 (default 9.80665)")
    fit_cmd.add_argument("--frame-id", default="", help="sensor frame id stored in the file")
    fit_cmd.add_argument("--temperature-model", choices=TEMPERATURE_MODELS, default="none",
                         help="temperature drift model, needs a temperature column (default none)")
    fit_cmd.add_argument("--bias-order", type=int, default=2,
                         help="polynomial: order of the bias drift, 0..3 (default 2)")
    fit_cmd.add_argument("--scale-order", type=int, default=1,
                         help="polynomial: order of the scale drift, 0..2 (default 1)")
    fit_cmd.add_argument("--segment-width", type=float, default=10.0,
                         help="segmented: segment width, degC (default 10)")
    fit_cmd.add_argument("--segment-blend", action=argparse.BooleanOptionalAction, default=True,
                         help="segmented: interpolate between the temperatures segments were learned at "
                              "(default); --no-segment-blend: the seed paper's pick of the segment holding it")
    fit_cmd.add_argument("--reference-temperature", type=float, default=None,
                         help="T_ref, degC (default: the poses' median temperature)")
    fit_cmd.add_argument("--min-span", type=float, default=10.0, help="smallest temperature span to fit a model, degC")
    fit_cmd.add_argument("--output", "-o", required=True, help="calibration YAML to write")

    replay_cmd = commands.add_parser(
        "replay", help="recalibrate from recordings: rosbag2 (directory, .mcap or .db3 file), PX4 ULog, ArduPilot "
                       "DataFlash .bin, CSV stream")
    replay_cmd.add_argument("bags", nargs="+", metavar="RECORDING",
                            help="a rosbag2 directory, a .mcap or .db3 file, a PX4 .ulg log, or a CSV of raw samples "
                                 "(header: t or t_ns, ax,ay,az [,gx,gy,gz] [,temperature])")
    replay_cmd.add_argument("--format", choices=("rosbag2", "mcap", "sqlite3", "ulog", "dataflash", "csv"),
                            default=None,
                            help="the recordings' format (default: found from the path and content)")
    replay_cmd.add_argument("--instance", type=int, default=None, metavar="N",
                            help="ULog: read sensor_accel/sensor_gyro instance N and its temperature "
                                 "(default: sensor_combined); DataFlash: IMU instance N (default 0)")
    replay_cmd.add_argument("--time-unit", choices=("s", "ms", "us", "ns"), default=None,
                            help="CSV: unit of the time column (default: s for t, ns for t_ns)")
    replay_cmd.add_argument("--units", choices=("mps2", "g", "counts"), default=None,
                            help="CSV: units of ax,ay,az (default mps2; gx,gy,gz are rad/s)")
    replay_cmd.add_argument("--counts-per-g", type=float, default=None, metavar="COUNTS",
                            help="CSV with --units counts: the sensor's counts per g (e.g. 16384: MPU-6050 at +-2 g)")
    replay_cmd.add_argument("--poses-out", default=None, metavar="POSES.csv",
                            help="write the still intervals found as a CSV pose table (also when the fit is refused; "
                                 "readable by 'fit' and 'report --poses'; several recordings: a directory)")
    replay_cmd.add_argument("--imu-topic", default=None, help="sensor_msgs/Imu topic (default: the only one)")
    replay_cmd.add_argument("--temperature-topic", default=None,
                            help="sensor_msgs/Temperature topic (default: the only one)")
    replay_cmd.add_argument("--output", "-o", default=None,
                            help="calibration YAML to write (several bags: a directory, one <bag>.yaml each)")
    replay_cmd.add_argument("--corrected", "--corrected-bag", dest="corrected_bag", default=None, metavar="OUT",
                            help="write a corrected copy in the recording's own format: a bag (directory or "
                                 "file) with the IMU accelerations corrected, a CSV with ax,ay,az corrected; a ULog "
                                 "gets a CSV of corrected samples (t_ns,ax,ay,az,gx,gy,gz,temperature) "
                                 "(several recordings: a directory)")
    replay_cmd.add_argument("--report", default=None,
                            help="also write a report figure (PNG; several bags: a directory)")
    replay_cmd.add_argument("--params-file", default=None,
                            help="ROS 2 parameters YAML (config/accel_calibration.yaml): the node's settings")
    replay_cmd.add_argument("--node", default=None, metavar="/NAMESPACE/NAME",
                            help="the node whose --params-file blocks apply, as rcl matches them "
                                 "(default /accel_calibration)")
    replay_cmd.add_argument("--param", "-p", action="append", default=[], metavar="NAME:=VALUE",
                            help="one setting as the node takes it, e.g. -p static.window_s:=0.3 (repeatable)")
    replay_cmd.add_argument("--model", choices=("six", "sphere9"), default=None, help="same as -p model:=...")
    replay_cmd.add_argument("--temperature-model", choices=TEMPERATURE_MODELS, default=None,
                            help="same as -p temperature.model:=...")
    replay_cmd.add_argument("--min-span", type=float, default=None, help="same as -p temperature.min_span_degc:=...")
    replay_cmd.add_argument("--gravity", type=float, default=None, help="same as -p gravity:=...")
    replay_cmd.add_argument("--min-poses", type=int, default=None, help="same as -p min_poses:=...")
    replay_cmd.add_argument("--window", type=float, default=None, help="detector window, s (-p static.window_s:=...)")
    replay_cmd.add_argument("--min-hold", type=float, default=None,
                            help="shortest still interval, s (-p static.min_hold_s:=...)")
    replay_cmd.add_argument("--k-sigma", type=float, default=None,
                            help="detector threshold over the noise floor (-p static.k_sigma:=...)")
    add_flight_state_options(replay_cmd)
    replay_cmd.add_argument("--jobs", "-j", type=int, default=1,
                            help="bags processed in parallel, on a local Dask cluster of N worker processes")

    report_cmd = commands.add_parser("report", help="a figure of a calibration against its poses")
    report_cmd.add_argument("calibration", nargs="?", help="calibration YAML (not with --history)")
    source = report_cmd.add_mutually_exclusive_group(required=True)
    source.add_argument("--bag", help="rosbag2 whose static poses to show")
    source.add_argument("--poses", help="CSV of pose means (ax,ay,az[,temperature])")
    source.add_argument("--history", help="calibration history (accel-calib fleet): one panel per sensor")
    history_command.add_drift_options(report_cmd)
    report_cmd.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of the poses CSV")
    report_cmd.add_argument("--output", "-o", required=True, help="PNG to write")

    apply_cmd = commands.add_parser("apply", help="correct the ax,ay,az columns of a CSV file")
    apply_cmd.add_argument("--calibration", "-c", required=True, help="calibration YAML")
    apply_cmd.add_argument("--units", choices=sorted(UNIT_SCALE), default="mps2", help="units of ax,ay,az in and out")
    apply_cmd.add_argument("input", help="CSV with ax,ay,az (other columns copied unchanged)")
    apply_cmd.add_argument("output", help="CSV to write")
    fleet_command.add_parser(commands)
    history_command.add_parser(commands)
    export_command.add_parser(commands)
    compare_command.add_parser(commands)
    noise_command.add_parser(commands)
    return parser


def _check_finite(args) -> None:
    """argparse's float() takes 'nan', 'inf' and '1e999': no number option may be one."""
    for name, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise CalibrationError(f"--{name.replace('_', '-')} must be a finite number, got {value}")


def _in_force(path) -> object:
    """A calibration file fit to be put in force (what the node checks at start-up): loaded safely and
    plausible under the default gates, else one line naming the problem."""
    from ..core.plausibility import plausibility_problem
    from ..core.settings import Settings
    from ..io.calibration_file import load_calibration

    calibration = load_calibration(path)
    defaults = Settings()
    problem = plausibility_problem(calibration, max_bias_mps2=defaults.max_bias_mps2,
                                   scale_band=(defaults.scale_min, defaults.scale_max))
    if problem is not None:
        raise CalibrationError(f"{path}: implausible, not used ({problem})")
    return calibration


def _render_report(calibration, accel, temperatures, title: str) -> bytes:
    """The report figure's PNG bytes, rendered aside (written later like every output)."""
    import tempfile

    from ..io.report import write_report

    with tempfile.TemporaryDirectory(prefix="accel-calib-report-") as scratch:
        rendered = Path(scratch) / "report.png"
        write_report(calibration, accel, temperatures, rendered, title=title)
        return rendered.read_bytes()


def _write_report(calibration, accel, temperatures, output, title: str) -> None:
    """The report figure, rendered aside and then written like every output (whole, through symlinks,
    keeping the old file's mode)."""
    from ..io.output_paths import write_bytes_atomically

    write_bytes_atomically(output, _render_report(calibration, accel, temperatures, title))


def _fit(args) -> int:
    from ..core.fit import fit
    from ..core.plausibility import PLAUSIBLE_TEMPERATURE_DEGC
    from ..core.temperature_models import TemperatureOptions
    from ..io.calibration_file import save_calibration
    from ..io.output_paths import check_outputs
    from ..io.pose_table import read_table

    if not (args.gravity > 0 and args.gravity < 1e3):
        raise CalibrationError(f"--gravity must be a positive number of m/s^2, got {args.gravity}")
    low, high = PLAUSIBLE_TEMPERATURE_DEGC
    if args.reference_temperature is not None and not low <= args.reference_temperature <= high:
        raise CalibrationError(f"--reference-temperature must be a sensor temperature within {low:g}..{high:g} degC, "
                               f"got {args.reference_temperature:g}")
    check_outputs([("--output", args.output)], [args.poses])
    if args.model == DIVIDING_HEAD:
        return dividing_head_command.fit_table(args, UNIT_SCALE[args.units])
    table = read_table(args.poses)
    if args.model in REFERENCE_MODELS and table.reference is None:
        raise CalibrationError(f"{args.poses}: model {args.model} needs columns ref_x,ref_y,ref_z")
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
        gravity=args.gravity,
        temperature_degc=table.temperature_degc,
        reference=table.reference if args.model in REFERENCE_MODELS else None,
        frame_id=args.frame_id,
        temperature_model=args.temperature_model,
        temperature_options=options,
        pose_sigma_mps2=table.pose_sigma_mps2,
    )
    if not result.success:
        raise CalibrationError(f"fit failed: {result.message}")
    save_calibration(result.calibration, args.output)
    print(result.summary())
    print(f"written {args.output}")
    return 0


def _apply(args) -> int:
    from ..io.calibration_file import write_text_atomically
    from ..io.output_paths import check_outputs
    from ..io.pose_table import read_table, table_with_accel

    check_outputs([("output", args.output)], [args.calibration, args.input])
    calibration = _in_force(args.calibration)
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


FLAG_PARAMETERS = {"model": "model", "temperature_model": "temperature.model", "min_span": "temperature.min_span_degc",
                   "gravity": "gravity", "min_poses": "min_poses", "window": "static.window_s",
                   "min_hold": "static.min_hold_s", "k_sigma": "static.k_sigma"}


def _replay_settings(args):
    """Settings as the node builds them: defaults, then --params-file, then -p NAME:=VALUE, then flags."""
    from ..bag.replay import ReplaySettings
    from ..core.settings import Settings
    from ..io.calibration_file import safe_yaml_load
    from ..io.params_file import DEFAULT_NODE, params_file_parameters

    if args.jobs < 1:
        raise CalibrationError(f"--jobs must be at least 1, got {args.jobs}")
    values = {}
    if args.params_file:  # the blocks rcl would give the node (io/params_file.py)
        values.update(params_file_parameters(args.params_file, getattr(args, "node", None) or DEFAULT_NODE,
                                             error=CalibrationError))
        values.pop("calibration_file", None)  # the node's file; replay writes --output
        values.pop("output_reliability", None)
    for item in args.param:
        name, sep, text = item.partition(":=")
        if not sep:
            raise CalibrationError(f"-p {item}: write NAME:=VALUE, e.g. -p static.window_s:=0.3")
        values[name.strip()] = safe_yaml_load(text, f"-p {item}: value", error=CalibrationError)
    for flag, name in FLAG_PARAMETERS.items():
        value = getattr(args, flag)
        if value is not None:
            values[name] = value
    return ReplaySettings(session=Settings.from_parameters(values), imu_topic=args.imu_topic,
                          temperature_topic=args.temperature_topic, **flight_state_settings(args))


def _replay_one(bag, settings, output, corrected_bag, report, progress, poses_out=None):
    """Replay one recording and write what was asked; returns (summary text, calibration or None, error or None).
    The pose table (`poses_out`) is written whether or not the fit passed: it shows what was found.
    All the work (the replay, the calibration's file text, the corrected copy written aside, the report
    rendered) comes before the first output is written, so a failure leaves every output as it was."""
    from pathlib import Path

    from ..bag.recording import stage_corrected_copy
    from ..bag.replay import replay_bag
    from ..io.calibration_file import checked_calibration_text, write_text_atomically
    from ..io.output_paths import write_bytes_atomically
    from ..io.poses_out import poses_table_text

    try:
        replay = replay_bag(bag, settings, progress=progress)
        poses_text = poses_table_text(replay.poses, replay.pose_status) if poses_out else None
        if replay.calibration is None and poses_out:
            write_text_atomically(poses_out, poses_text)
    except AccelCalibrationError as error:
        return None, None, str(error)
    notes = _flight_and_autopilot_lines(replay)
    if replay.calibration is None:
        return ("\n".join(notes) or None), None, f"{bag}: {replay.problem}" + (
            f" (poses written to {poses_out})" if poses_out else "")
    calibration = replay.calibration
    unit = replay.recording.unit if replay.recording is not None else "messages"
    lines = [f"{bag}: {replay.messages} {unit} on {replay.imu_topic} over {replay.duration_s:.1f} s, "
             f"{len(replay.poses)} static poses, {replay.elapsed_s:.2f} s",
             replay.result.summary(), *notes]
    bad = {k: v for k, v in replay.counts.items() if v}
    if bad:
        lines.append("skipped: " + ", ".join(f"{k} {v}" for k, v in bad.items()))
    copy = None
    try:
        calibration_text = checked_calibration_text(calibration, output) if output else None
        if corrected_bag:
            copy = stage_corrected_copy(replay, calibration, corrected_bag)
        figure = (_render_report(calibration, [p.accel_mps2 for p in replay.poses],
                                 [p.temperature_degc for p in replay.poses], title=Path(bag).name)
                  if report else None)
        # All the work succeeded: now the outputs, the one that can still be taken by another run first.
        if copy is not None:
            copy.commit()
        if output:
            write_text_atomically(output, calibration_text)
            lines.append(f"written {output}")
        if poses_out:
            write_text_atomically(poses_out, poses_text)
            lines.append(f"poses {poses_out}")
        if copy is not None:
            lines.append(copy.line)
        if report:
            write_bytes_atomically(report, figure)
            lines.append(f"report {report}")
    except AccelCalibrationError as error:
        return None, None, str(error)
    finally:
        if copy is not None:
            copy.discard()
    return "\n".join(lines), calibration, None


def _check_corrected_targets(jobs) -> None:
    """Before any work: a corrected copy of a bag directory is a new directory, and no corrected copy
    is written over a directory."""
    for job in jobs:
        bag, destination = job[0], job[3]
        if destination is None or not os.path.lexists(destination):
            continue
        if os.path.isdir(bag) or os.path.isdir(destination):
            raise CalibrationError(f"--corrected {destination}: already exists "
                                   + ("(a corrected bag is a new directory)" if os.path.isdir(bag)
                                      else "and is a directory; give a file name"))


def _flight_and_autopilot_lines(replay) -> list[str]:
    """What replay says of the flight state it kept out, and of the autopilot's calibration logged with it."""
    lines = []
    if replay.flight_state_line:
        lines.append(replay.flight_state_line if replay.flight_state_found else f"warning: {replay.flight_state_line}")
    if replay.autopilot_calibration is not None:
        lines.append(replay.autopilot_calibration.describe())
        if replay.autopilot_difference_mg is not None:
            lines.append(f"ours moves the autopilot's corrected output by up to {replay.autopilot_difference_mg:.1f} "
                         "mg at 1 g (worst orientation): how far ours is from the autopilot's calibration")
    return lines


def _bag_labels(bags) -> list[str]:
    """A distinct name per bag for its outputs and its row: the bag's own name, or, where two bags share
    it (a/flight, b/flight), as many parent directories as tell them apart (a_flight, b_flight)."""
    parts = [Path(os.path.realpath(bag)).parts[::-1] for bag in bags]
    labels = []
    for own in parts:
        depth = 1
        while depth < len(own) and sum(other[:depth] == own[:depth] for other in parts) > 1:
            depth += 1
        labels.append("_".join(part.strip("/") or "root" for part in own[:depth][::-1]))
    return labels


def _replay(args) -> int:
    import dataclasses

    from ..io.output_paths import check_output_places, check_outputs

    settings = dataclasses.replace(_replay_settings(args), format=args.format, instance=args.instance,
                                   time_unit=args.time_unit, units=args.units, counts_per_g=args.counts_per_g)
    several = len(args.bags) > 1
    first_seen: dict[str, str] = {}
    for bag in args.bags:
        real = os.path.realpath(bag)
        if real in first_seen:
            raise CalibrationError(f"bag {bag} given twice (also as {first_seen[real]}): give each bag once")
        first_seen[real] = bag
    labels = _bag_labels(args.bags) if several else [Path(bag).name for bag in args.bags]

    def target(option, label, suffix):
        if option is None:
            return None
        if not several:
            return option
        return str(Path(option) / (label + suffix))

    jobs = [(bag, settings, target(args.output, label, ".yaml"), target(args.corrected_bag, label, ""),
             target(args.report, label, ".png"), not several, target(args.poses_out, label, ".poses.csv"))
            for bag, label in zip(args.bags, labels)]
    # Before any work: no output may be an input (a bag, a file inside one, the params file) or another output.
    inputs = [*args.bags, args.params_file]
    check_outputs([(flag, job[k]) for job in jobs for flag, k in (("--output", 2), ("--corrected-bag", 3),
                                                                    ("--report", 4), ("--poses-out", 6))],
                  inputs, directories=("--corrected-bag",))
    if several:  # the directories holding one output per bag
        for flag, option in (("--output", args.output), ("--corrected-bag", args.corrected_bag),
                             ("--report", args.report), ("--poses-out", args.poses_out)):
            if option is not None:
                check_outputs([(flag, option)], inputs, directories=(flag,))
                try:
                    Path(option).mkdir(parents=True, exist_ok=True)
                except OSError as error:
                    raise CalibrationError(f"cannot make output directory {option}: {error.strerror}") from None
    check_output_places([(flag, job[k]) for job in jobs for flag, k in (("--output", 2), ("--corrected", 3),
                                                                         ("--report", 4), ("--poses-out", 6))])
    _check_corrected_targets(jobs)
    if args.jobs > 1 and several:  # one way to run many: the fleet's local Dask cluster of --jobs processes
        outcomes = fleet_command.map_on_local_cluster(
            _replay_one, jobs, workers=args.jobs,  # a lost worker (out of memory, a signal): that bag only
            failed=lambda job, reason: (None, None, f"{job[0]}: its replay process died ({reason})"))
    else:
        outcomes = [_replay_one(*job) for job in jobs]
    errors = [error for _, _, error in outcomes if error]
    for summary, _, _ in outcomes:
        if summary:
            print(summary)
    if several:
        print(_comparison_table(labels, outcomes))
    for error in errors:
        print(f"{PROG}: error: {error}", file=sys.stderr)
    return 1 if errors else 0


def _comparison_table(bags, outcomes) -> str:
    """How the calibration wanders from bag to bag: bias (mg) and scale (diag M) per bag, then the spread."""
    from pathlib import Path

    rows = ["", f"{'bag':32s} {'poses':>5s} {'rms mg':>7s} {'b_x mg':>8s} {'b_y mg':>8s} {'b_z mg':>8s} "
                f"{'M_xx':>9s} {'M_yy':>9s} {'M_zz':>9s}"]
    biases, scales = [], []
    for bag, (_, calibration, error) in zip(bags, outcomes):
        name = Path(bag).name[:32]
        if calibration is None:
            rows.append(f"{name:32s} {'-':>5s}  no calibration: {error.rsplit(': ', 1)[-1][:60] if error else ''}")
            continue
        b = calibration.bias / MG
        m = np.diag(calibration.matrix)
        biases.append(b)
        scales.append(m)
        rows.append(f"{name:32s} {calibration.quality.poses:5d} {calibration.quality.residual_rms_mg:7.2f} "
                    f"{b[0]:8.2f} {b[1]:8.2f} {b[2]:8.2f} {m[0]:9.6f} {m[1]:9.6f} {m[2]:9.6f}")
    if len(biases) > 1:
        b, m = np.std(biases, axis=0, ddof=1), np.std(scales, axis=0, ddof=1)
        rows.append(f"{'spread (1 sigma across bags)':32s} {'':5s} {'':7s} {b[0]:8.2f} {b[1]:8.2f} {b[2]:8.2f} "
                    f"{m[0]:9.6f} {m[1]:9.6f} {m[2]:9.6f}")
    return "\n".join(rows)


def _report(args) -> int:
    from ..io.output_paths import check_outputs
    from ..io.pose_table import read_table

    if args.history:
        check_outputs([("--output", args.output)], [args.history if "://" not in args.history else None])
        return history_command.report_history(args)
    if args.calibration is None:
        raise CalibrationError("report needs a calibration YAML (or --history DB)")
    check_outputs([("--output", args.output)], [args.calibration, args.bag, args.poses])
    calibration = _in_force(args.calibration)
    if args.bag:
        from ..bag.replay import ReplayError, replay_bag

        try:
            replay = replay_bag(args.bag)
        except ReplayError as error:
            raise CalibrationError(str(error)) from None
        accel = [p.accel_mps2 for p in replay.poses]
        temps = [p.temperature_degc for p in replay.poses]
    else:
        table = read_table(args.poses)
        accel = table.accel * UNIT_SCALE[args.units]
        temps = None if table.temperature_degc is None else list(table.temperature_degc)
    if len(accel) == 0:
        raise CalibrationError("no poses to show")
    _write_report(calibration, accel, temps, args.output, title=str(args.calibration))
    print(f"report {args.output}")
    return 0


def main(argv=None) -> int:
    try:
        args = _parser().parse_args(argv)
        _check_finite(args)
        return {"fit": _fit, "apply": _apply, "replay": _replay, "report": _report,
                "fleet": fleet_command.run, "history": history_command.run,
                "export": export_command.run,
                "compare": compare_command.run,
                "noise": noise_command.run}[args.command](args)
    except AccelCalibrationError as error:
        print(f"{PROG}: error: {error}", file=sys.stderr)
        return 1
    except ModuleNotFoundError as error:  # an install without a third-party module: say what to install
        if (missing := missing_module(error)) is None:
            raise
        print(f"{PROG}: error: {missing}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
