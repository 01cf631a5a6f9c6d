"""accel-calib history: per sensor, bias and scale over time with their sigma, and the changes the
sigmas do not explain (or that no healthy sensor makes). `accel-calib report --history` draws the
same as a figure (`report_history`)."""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.units import MG
from .fleet import DEFAULT_HISTORY

if TYPE_CHECKING:  # imported where used: the CLI's start-up does not pay for the history module
    from ..io.flight_history import EvidenceRecord, ImuSeries
    from ..io.history import DriftFlag, DriftRule, HistoryRecord

DRIFT_EXIT_CODE = 3  # drift flagged (1 stays "could not run")


def add_drift_options(parser: argparse.ArgumentParser) -> None:
    """The history selection and the drift rule, shared by `history` and `report --history`."""
    parser.add_argument("--vehicle", default=None, help="only this vehicle")
    parser.add_argument("--sensor", default=None, help="only this sensor (its frame_id, else its IMU topic)")
    add_change_rule_options(parser)


def add_change_rule_options(parser: argparse.ArgumentParser) -> None:
    """The change rule's thresholds (core/change_rule.py), shared by `history`, `report --history` and `check`."""
    from ..core.change_rule import ChangeRule

    defaults = ChangeRule()
    parser.add_argument("--drift-k-sigma", "--k-sigma", dest="drift_k_sigma", type=float, default=defaults.k_sigma,
                        help="flag a change larger than K times the combined sigma of the two calibrations, "
                             f"|delta| > K sqrt(s1^2 + s2^2) (default {defaults.k_sigma:g})")
    parser.add_argument("--max-bias-change", type=float, default=defaults.max_bias_change_mg, metavar="MG",
                        help="flag a bias change beyond this whatever the sigmas, mg "
                             f"(default {defaults.max_bias_change_mg:g})")
    parser.add_argument("--max-scale-change", type=float, default=defaults.max_scale_change,
                        help="flag a scale change beyond this whatever the sigmas, fraction "
                             f"(default {defaults.max_scale_change:g})")


def add_parser(commands: argparse._SubParsersAction[argparse.ArgumentParser]) -> argparse.ArgumentParser:
    parser = commands.add_parser(
        "history", help="bias and scale of each sensor over time, and where they moved",
        description="Per sensor, the calibrations of the history database in time order (bias and scale with "
                    "their 1-sigma) and the changes between consecutive ones that exceed what the sigmas "
                    "explain or a plausibility bound. Exit code 0 when nothing moved, "
                    f"{DRIFT_EXIT_CODE} when a change was flagged, 1 on an error.")
    parser.add_argument("--history", default=DEFAULT_HISTORY,
                        help=f"history database: SQLite file (default {DEFAULT_HISTORY}) or SQLAlchemy URL")
    add_drift_options(parser)
    return parser


def _rule(args: argparse.Namespace) -> DriftRule:
    from ..io.history import DriftRule

    return DriftRule(k_sigma=args.drift_k_sigma, max_bias_change_mg=args.max_bias_change,
                     max_scale_change=args.max_scale_change)


def _records(args: argparse.Namespace) -> tuple[list[HistoryRecord], list[EvidenceRecord]]:
    from ..core.errors import CalibrationError
    from ..io.history import masked_url

    name = masked_url(args.history)
    if "://" not in args.history and not Path(args.history).expanduser().is_file():
        raise CalibrationError(f"{name}: no such history (write one with 'accel-calib fleet')")
    from ..io.history import open_history

    with open_history(args.history, read_only=True) as history:  # only read: nothing created or switched
        records = history.records(vehicle=args.vehicle, sensor=args.sensor)
        unreadable = history.unreadable
        evidence = history.evidence(vehicle=args.vehicle, sensor=args.sensor)
        unreadable_evidence = history.unreadable_evidence
    for what, rows in (("", unreadable), ("flight evidence ", unreadable_evidence)):
        if rows:
            print(f"accel-calib: warning: {name}: {len(rows)} {what}row{'s' if len(rows) != 1 else ''} "
                  f"not as accel_calibration writes them, left out (first: {rows[0]})", file=sys.stderr)
    if not records and not evidence:
        which = " ".join(f"{k} {v}" for k, v in (("vehicle", args.vehicle), ("sensor", args.sensor)) if v)
        raise CalibrationError(f"{name}: no recordings{' of ' + which if which else ''}")
    return records, evidence


def _date(record: HistoryRecord) -> str:
    return record.start.strftime("%Y-%m-%d %H:%M") if record.start is not None else "-"


def _pm(values: Sequence[float] | None, sigmas: Sequence[float] | None, scale: float, digits: int, width: int) -> str:
    assert values is not None, "sensor_series keeps only calibrated rows, which have a bias and a matrix"
    out = []
    for i, v in enumerate(values):
        s = "" if sigmas is None else f"±{sigmas[i] * scale:.{digits}f}"
        out.append(f"{v * scale:+.{digits}f}{s}".rjust(width))
    return " ".join(out)


def history_text(records: list[HistoryRecord], flags: list[DriftFlag]) -> str:
    from ..io.history import sensor_series

    series = sensor_series(records)
    lines = []
    for (vehicle, sensor), rows in series.items():
        lines.append(f"vehicle {vehicle} {sensor}: {len(rows)} calibration{'s' if len(rows) != 1 else ''}")
        lines.append(f"  {'start (UTC)':16s} {'poses':>5s} {'rms mg':>6s}  "
                     f"{'bias x, y, z (mg ± 1 sigma)':^44s}  {'scale x, y, z (diag M ± 1 sigma)':^62s}  recording")
        for row in rows:
            lines.append(f"  {_date(row):16s} {row.poses or 0:5d} {row.residual_rms_mg or 0:6.2f}  "
                         f"{_pm(row.bias, row.bias_sigma, 1 / MG, 2, 14)}  "
                         f"{_pm(row.scale, row.scale_sigma, 1.0, 6, 20)}  {Path(row.path).name}")
    other = [r for r in records if r.status != "calibrated"]
    if other:
        lines.append(f"not calibrated: {len(other)} recording{'s' if len(other) != 1 else ''}")
        for row in other:
            lines.append(f"  {row.status:8s} {row.vehicle} {row.sensor or '-'} {_date(row)} {row.reason}")
    if flags:
        lines.append(f"{len(flags)} change{'s' if len(flags) != 1 else ''} flagged:")
        lines.extend("  " + flag.message() for flag in flags)
    else:
        lines.append("no change beyond what the sigmas explain")
    return "\n".join(lines)


def evidence_text(series: list[ImuSeries], unread: list[EvidenceRecord]) -> str:
    """Per IMU its flights' evidence judged, one line each, then the flights that gave none and why."""
    lines = ["flight evidence (still on the ground before arming and after landing, against the calibration in "
             "force; level ground sees the z bias and z scale together; in flight, the filter's bias estimates and "
             "the IMUs' agreement):"]
    for imu in series:
        lines += ["  " + line for line in [imu.said(), *imu.said_in_flight()]]
    without = [row for imu in series for row in imu.flights if row.status != "evidence"] + unread
    if without:
        lines.append(f"  flights without evidence: {len(without)}")
        lines += [f"    {row.vehicle} {row.who if row.device or row.sensor else '-'} {row.flight}: {row.reason}"
                  for row in without]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ..io.flight_history import imu_series, unplaced
    from ..io.history import drift_flags

    rule = _rule(args)
    records, evidence = _records(args)
    flags = drift_flags(records, rule)
    if records:
        print(history_text(records, flags))
    if not evidence:
        return DRIFT_EXIT_CODE if flags else 0
    series = imu_series(evidence, rule)
    print(evidence_text(series, unplaced(evidence)))
    statuses = {imu.status for imu in series}
    if flags or "moved" in statuses:
        return DRIFT_EXIT_CODE
    return 1 if "cannot tell" in statuses or not series else 0  # no IMU named: nothing to say it holds


def report_history(args: argparse.Namespace) -> int:
    """`accel-calib report --history DB -o fig.png`: one panel per sensor."""
    from ..io.history import drift_flags, sensor_series
    from ..io.history_figure import write_history_figure

    rule = _rule(args)
    records, _ = _records(args)
    flags = drift_flags(records, rule)
    write_history_figure(records, flags, args.output)
    print(f"history report {args.output} ({len(sensor_series(records))} sensors, {len(flags)} changes flagged)")
    return 0


def report_page(args: argparse.Namespace) -> int:
    """`accel-calib report --history DB --output fleet.html`: the fleet's page (io/fleet_page.py), one file."""
    from ..core.errors import CalibrationError
    from ..io.fleet_page import fleet_page
    from ..io.flight_history import imu_series
    from ..io.history import masked_url
    from ..io.output_paths import write_bytes_atomically

    rule = _rule(args)
    _, evidence = _records(args)
    series = imu_series(evidence, rule)
    if not series:
        raise CalibrationError(f"{masked_url(args.history)}: no flight evidence of any IMU (write it with "
                               "'accel-calib fleet' on flight logs)")
    write_bytes_atomically(args.output, fleet_page(series, masked_url(args.history), rule.k_sigma).encode())
    counts = {status: sum(imu.status == status for imu in series) for status in ("moved", "holds", "cannot tell")}
    print(f"fleet page {args.output} ({len(series)} IMUs: {counts['moved']} moved, {counts['holds']} hold, "
          f"{counts['cannot tell']} cannot tell)")
    return 0
