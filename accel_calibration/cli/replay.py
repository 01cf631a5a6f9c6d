"""accel-calib replay: recalibrate from recordings (rosbag2, PX4 ULog, ArduPilot DataFlash, CSV stream),
the same session as the node, and write what was asked: the calibration, the pose table, a corrected
copy, a report figure. Several recordings: one output of each per recording in the directories given,
a table comparing them, and `--jobs N` runs them on a local Dask cluster (cli/dask_cluster.py)."""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import AccelCalibrationError, CalibrationError
from ..core.units import MG
from .dask_cluster import map_on_local_cluster
from .options import PROG, add_reader_options, add_settings_options, reader_fields, replay_settings
from .report import render_report

if TYPE_CHECKING:
    from ..bag.replay import ReplayResult, ReplaySettings
    from ..core.calibration import Calibration
    from ..core.prior import Prior
    from ..core.settings import Settings

# What replay_one gives: (summary text, calibration, error), each None where there is none.
Outcome = tuple["str | None", "Calibration | None", "str | None"]


@dataclass(frozen=True)
class ReplayJob:
    """One recording to replay and where each of its outputs goes (None: not asked)."""

    bag: str
    settings: ReplaySettings
    output: str | None  # --output: the calibration file
    corrected: str | None  # --corrected: the corrected copy
    report: str | None  # --report: the figure
    progress: bool  # a progress bar (one recording only: bars of parallel jobs would interleave)
    poses_out: str | None = None  # --poses-out: the pose table

    def outputs(self, corrected_flag: str = "--corrected") -> list[tuple[str, str | None]]:
        """(option, path) of each output, as the output checks take them."""
        return [("--output", self.output), (corrected_flag, self.corrected), ("--report", self.report),
                ("--poses-out", self.poses_out)]


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "replay", help="recalibrate from recordings: rosbag2 (directory, .mcap or .db3 file), PX4 ULog, ArduPilot "
                       "DataFlash .bin, CSV stream")
    parser.add_argument("bags", nargs="+", metavar="RECORDING",
                        help="a rosbag2 directory, a .mcap or .db3 file, a PX4 .ulg log, or a CSV of raw samples "
                             "(header: t or t_ns, ax,ay,az [,gx,gy,gz] [,temperature])")
    add_reader_options(parser)
    parser.add_argument("--all-imus", action="store_true",
                        help="ULog, DataFlash: calibrate every IMU of the log, one file each in --output DIR "
                             "(imu<N>_dev<ID>.yaml), and give the rotation between them")
    parser.add_argument("--poses-out", default=None, metavar="POSES.csv",
                        help="write the still intervals found as a CSV pose table (also when the fit is refused; "
                             "readable by 'fit' and 'report --poses'; several recordings: a directory)")
    parser.add_argument("--output", "-o", default=None,
                        help="calibration YAML to write (several bags: a directory, one <bag>.yaml each)")
    parser.add_argument("--corrected", "--corrected-bag", dest="corrected_bag", default=None, metavar="OUT",
                        help="write a corrected copy in the recording's own format: a bag (directory or "
                             "file) with the IMU accelerations corrected, a CSV with ax,ay,az corrected; a ULog "
                             "gets a CSV of corrected samples (t_ns,ax,ay,az,gx,gy,gz,temperature) "
                             "(several recordings: a directory)")
    parser.add_argument("--report", default=None,
                        help="also write a report figure (PNG; several bags: a directory)")
    parser.add_argument("--prior", metavar="CAL.yaml", default=None,
                        help="recalibrate with this calibration (with its uncertainty) as the prior: what the "
                             "poses observe is fitted, the rest stays at the prior (poses near level suffice; the "
                             "pose count is then no gate); the file written says which came from where")
    add_settings_options(parser, detector=True)
    parser.add_argument("--warmup", action="store_true",
                        help="the recordings are warm-ups (still while the temperature changes): fit the "
                             "accelerometer's and gyro's bias against temperature, pooled into one curve, on top "
                             "of --prior, the poses' fit or the log's calibration in force, and write it with -o")
    parser.add_argument("--jobs", "-j", type=int, default=1,
                        help="bags processed in parallel, on a local Dask cluster of N worker processes")

    return parser


def replay_one(job: ReplayJob) -> Outcome:
    """Replay one recording and write what was asked; returns (summary text, calibration or None, error or None).
    The pose table (`poses_out`) is written whether or not the fit passed: it shows what was found.
    All the work (the replay, the calibration's file text, the corrected copy written aside, the report
    rendered) comes before the first output is written, so a failure leaves every output as it was."""
    from ..bag.corrected_copy import stage_corrected_copy
    from ..bag.replay import replay_bag
    from ..io.calibration_file import checked_calibration_text, write_text_atomically
    from ..io.output_paths import write_bytes_atomically
    from ..io.poses_out import poses_table_text

    bag, settings, output, corrected_bag, report, poses_out = (job.bag, job.settings, job.output, job.corrected,
                                                               job.report, job.poses_out)
    try:
        replay = replay_bag(bag, settings, progress=job.progress)
        poses_text = poses_table_text(replay.poses, replay.pose_status) if poses_out else ""
        if replay.calibration is None and poses_out:
            write_text_atomically(poses_out, poses_text)
    except AccelCalibrationError as error:
        return None, None, str(error)
    notes = flight_and_autopilot_lines(replay)
    if replay.calibration is None:
        return ("\n".join(notes) or None), None, f"{bag}: {replay.problem}" + (
            f" (poses written to {poses_out})" if poses_out else "")
    calibration = replay.calibration
    assert replay.result is not None, "a calibration comes with its fit"
    source = replay.source
    lines = [f"{bag}: {source.messages} {source.recording.unit} on {source.imu_topic} over {source.duration_s:.1f} s, "
             f"{len(replay.poses)} static poses, {replay.elapsed_s:.2f} s",
             replay.result.summary(), *gyro_lines(replay),
             *([calibration.noise.describe()] if calibration.noise is not None else []), *notes]
    from ..core.stream.screening import Counters

    informational = Counters.INFORMATIONAL  # counts of what was read, not of what was skipped
    bad = {k: v for k, v in replay.counts.items() if v and k not in informational}
    if bad:
        lines.append("skipped: " + ", ".join(f"{k} {v}" for k, v in bad.items()))
    copy = None
    try:
        calibration_text = checked_calibration_text(calibration, output, replay.result.parameter_sources,
                                                    settings.prior_path) if output else ""
        if corrected_bag:
            copy = stage_corrected_copy(replay, calibration, corrected_bag)
        figure = (render_report(calibration, [p.accel_mps2 for p in replay.poses],
                                 [p.temperature_degc for p in replay.poses], title=Path(bag).name, gyro=replay.gyro)
                  if report else b"")
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


def replay_prior(path: str, session: Settings) -> Prior:
    """--prior's calibration, checked against the session's model and gravity before any work: one line if not."""
    from ..core.prior import Prior, prior_terms
    from ..io.calibration_file import load_calibration

    prior = Prior(load_calibration(path))
    try:
        prior_terms(prior, session.model, session.gravity)
    except CalibrationError as error:
        raise CalibrationError(f"--prior {path}: {error}") from None
    return prior


def check_corrected_targets(jobs: Sequence[ReplayJob]) -> None:
    """Before any work: a corrected copy of a bag directory is a new directory, and no corrected copy
    is written over a directory."""
    for job in jobs:
        bag, destination = job.bag, job.corrected
        if destination is None or not os.path.lexists(destination):
            continue
        if os.path.isdir(bag) or os.path.isdir(destination):
            raise CalibrationError(f"--corrected {destination}: already exists "
                                   + ("(a corrected bag is a new directory)" if os.path.isdir(bag)
                                      else "and is a directory; give a file name"))


def flight_and_autopilot_lines(replay: ReplayResult) -> list[str]:
    """What replay says of the flight state it kept out, and of the autopilot's calibration logged with it."""
    lines = []
    if replay.calibration is not None and replay.calibration.fitted_to:
        lines.append(f"fitted to {replay.calibration.fitted_to}")
    if replay.flight_state is not None:
        lines.append(replay.flight_state.report_line())
    if replay.autopilot is not None:
        lines.append(replay.autopilot.calibration.describe())
        if replay.autopilot.difference_mg is not None:
            lines.append(f"ours differs from the autopilot's by up to {replay.autopilot.difference_mg:.1f} mg at 1 g "
                         "(worst orientation)")
    return lines


def bag_labels(bags: Sequence[str]) -> list[str]:
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


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from ..io.output_paths import check_output_places, check_outputs

    if args.jobs < 1:
        raise CalibrationError(f"--jobs must be at least 1, got {args.jobs}")
    settings = dataclasses.replace(replay_settings(args), **reader_fields(args))
    if args.prior is not None:
        temperature_model = getattr(args, "temperature.model")
        if temperature_model not in (None, "none"):  # the fit with a prior fits b and M alone, as fit says
            raise CalibrationError(f"--prior fits the sphere models without a temperature model, not with "
                                   f"--temperature-model {temperature_model}")
        settings = dataclasses.replace(settings, prior=replay_prior(args.prior, settings.session),
                                       prior_path=args.prior)
    if args.warmup:
        from .warmup import run_warmup

        return run_warmup(args, settings)
    if args.all_imus:
        from .all_imus import run_all_imus

        return run_all_imus(args, settings)
    several = len(args.bags) > 1
    first_seen: dict[str, str] = {}
    for bag in args.bags:
        real = os.path.realpath(bag)
        if real in first_seen:
            raise CalibrationError(f"bag {bag} given twice (also as {first_seen[real]}): give each bag once")
        first_seen[real] = bag
    labels = bag_labels(args.bags) if several else [Path(bag).name for bag in args.bags]

    def target(option: str | None, label: str, suffix: str) -> str | None:
        if option is None:
            return None
        if not several:
            return option
        return str(Path(option) / (label + suffix))

    jobs = [ReplayJob(bag, _prior_device(args, bag, settings), output=target(args.output, label, ".yaml"),
                      corrected=target(args.corrected_bag, label, ""), report=target(args.report, label, ".png"),
                      progress=not several, poses_out=target(args.poses_out, label, ".poses.csv"))
            for bag, label in zip(args.bags, labels)]
    # Before any work: no output may be an input (a bag, a file inside one, the params file) or another output.
    inputs = [*args.bags, args.params_file, args.prior]
    check_outputs([place for job in jobs for place in job.outputs("--corrected-bag")], inputs,
                  directories=("--corrected-bag",))
    if several:  # the directories holding one output per bag
        for flag, option in (("--output", args.output), ("--corrected-bag", args.corrected_bag),
                             ("--report", args.report), ("--poses-out", args.poses_out)):
            if option is not None:
                check_outputs([(flag, option)], inputs, directories=(flag,))
                try:
                    Path(option).mkdir(parents=True, exist_ok=True)
                except OSError as error:
                    raise CalibrationError(f"cannot make output directory {option}: {error.strerror}") from None
    check_output_places([place for job in jobs for place in job.outputs()])
    check_corrected_targets(jobs)
    if args.jobs > 1 and several:  # one way to run many: the fleet's local Dask cluster of --jobs processes
        outcomes = map_on_local_cluster(
            replay_one, [(job,) for job in jobs], workers=args.jobs,  # a lost worker (out of memory): that bag only
            failed=lambda task, reason: (None, None, f"{task[0].bag}: its replay process died ({reason})"))
    else:
        outcomes = [replay_one(job) for job in jobs]
    errors = [error for _, _, error in outcomes if error]
    for summary, _, _ in outcomes:
        if summary:
            print(summary)
    if several:
        print(comparison_table(labels, outcomes))
    for message in errors:
        print(f"{PROG}: error: {message}", file=sys.stderr)
    return 1 if errors else 0


def _prior_device(args: argparse.Namespace, bag: str, settings: ReplaySettings) -> ReplaySettings:
    """An autopilot log read as the IMU --prior is the calibration of (said), or one line when it holds none."""
    from .options import instance_of_device

    if settings.prior is None:
        return settings
    settings, said = instance_of_device(settings.prior.calibration, f"--prior {args.prior}", bag, settings)
    if said is not None:
        print(said)
    return settings


def comparison_table(bags: Sequence[str], outcomes: Sequence[Outcome]) -> str:
    """How the calibration wanders from bag to bag: bias (mg) and scale (diag M) per bag, then the spread."""
    rows = ["", f"{'bag':32s} {'poses':>5s} {'rms mg':>7s} {'b_x mg':>8s} {'b_y mg':>8s} {'b_z mg':>8s} "
                f"{'M_xx':>9s} {'M_yy':>9s} {'M_zz':>9s}"]
    biases, scales = [], []
    for bag, (_, calibration, error) in zip(bags, outcomes):
        name = Path(bag).name[:32]
        if calibration is None:
            rows.append(f"{name:32s} {'-':>5s}  no calibration: {error.rsplit(': ', 1)[-1][:60] if error else ''}")
            continue
        assert calibration.quality is not None, "a fitted calibration has its quality"
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


def gyro_lines(replay: ReplayResult) -> list[str]:
    """What replay says of the gyro: its calibration from the motions, or why it keeps its bias only."""
    gyro, calibration = replay.gyro, replay.calibration
    if calibration is not None and calibration.gyro_bias_radps is None and replay.gyro_refusal:
        return [replay.gyro_refusal]  # the whole gyro part left out (core/plausibility.loadable_part)
    if gyro is None:
        return []
    if calibration is not None and calibration.gyro_matrix is not None:
        return [gyro.summary()]
    return [f"{replay.gyro_refusal or 'gyro: ' + gyro.message} (the gyro keeps its bias only)"]
