"""The history of flight evidence: a row per vehicle, IMU and flight log (what its still moments on the
ground say of the calibration in force, bag/flight_evidence.py), in the calibration history's database
beside the calibrations (table `flight_evidence`, keyed as the calibrations' row of the same IMU and log,
so a rerun updates the same rows). Per IMU, the series since its calibration in force last changed is
judged by core/evidence_trend.py."""
from __future__ import annotations

import datetime as _dt
import json
import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from ..core.change_rule import ChangeRule
from ..core.evidence_trend import Trend, trend
from ..core.text import printable_text
from ..core.units import AXES, MG

EVIDENCE_STATUSES = ("evidence", "none", "failed")
_TEXT_LIMITS = {"vehicle": 200, "sensor": 200, "status": 16, "device": 40, "verdict": 16, "written_at": 40}
IN_FLIGHT_COLUMNS = ("estimator", "agreement")  # added to flight_evidence later: an older table lacks them
WALL_CLOCK_NS = 946_684_800 * 10**9  # 2000-01-01: a start before it counts from boot (a log's own clock)


@dataclass(frozen=True)
class EvidenceRecord:
    recording_id: str  # the row key: the calibrations' key of the same IMU and log
    path: str
    vehicle: str
    sensor: str  # as the calibrations' row names it (`history --sensor`)
    status: str  # evidence | none (the log gives none: `reason`) | failed (the log could not be read)
    imu: int | None = None  # the IMU's instance in its log (said "IMU n+1")
    device: str = ""  # its device ID as the log names it
    reason: str | None = None
    start_ns: int | None = None
    poses: int | None = None
    verdict: str | None = None  # check's on this flight alone: holds | moved | cannot tell
    in_force: str | None = None  # the calibration in force, as read from the log (parameters and values)
    z_mps2: float | None = None  # what the poses see of z at 1 g (bias z or scale z), m/s^2
    z_sigma_mps2: float | None = None
    changes: str | None = None  # JSON {name: [change, sigma]}: everything the poses observe
    temperature_degc: float | None = None
    written_at: str | None = None
    # In flight, as JSON (io/flight_history reads them; {"reason": ...} where the log gave none): the filter's
    # settled bias {source, samples, accel, accel_sigma (m/s^2), gyro, gyro_sigma (rad/s)} and the agreement
    # with the siblings {against, siblings, seconds, accel, accel_sigma, gyro, gyro_sigma}. Columns added
    # after the table was first written: a history written before reads them as NULL.
    estimator: str | None = None
    agreement: str | None = None

    @property
    def flight(self) -> str:
        """The flight as a reader knows it: its UTC start where the log has a clock time, else its file."""
        if self.start_ns is not None and self.start_ns >= WALL_CLOCK_NS:
            start = _dt.datetime.fromtimestamp(self.start_ns / 1e9, _dt.UTC)
            return start.strftime("%Y-%m-%dT%H:%M")
        return Path(self.path).name

    @property
    def order(self) -> tuple[bool, int, str]:
        """Flights in time order where the logs have a clock time, else by path (autopilots name logs in
        sequence; a ULog's stamps count from boot)."""
        wall = self.start_ns is not None and self.start_ns >= WALL_CLOCK_NS
        return (not wall, self.start_ns if wall and self.start_ns is not None else 0, self.path)

    @property
    def who(self) -> str:
        imu = "IMU" if self.imu is None else f"IMU {self.imu + 1}"
        return f"{imu} (device {self.device})" if self.device else f"{imu} ({self.sensor or '-'})"


def evidence_table(metadata: Any) -> Any:
    from sqlalchemy import BigInteger, Column, Float, Integer, String, Table, Text

    kinds: dict[str, Any] = {"recording_id": String(64), "path": Text, "vehicle": String(200), "sensor": String(200),
                             "status": String(16), "imu": Integer, "device": String(40), "reason": Text,
                             "start_ns": BigInteger, "poses": Integer, "verdict": String(16), "in_force": Text,
                             "z_mps2": Float, "z_sigma_mps2": Float, "changes": Text, "temperature_degc": Float,
                             "written_at": String(40), "estimator": Text, "agreement": Text}
    required = {"path", "vehicle", "sensor", "status"}
    return Table("flight_evidence", metadata,
                 *[Column(f.name, kinds[f.name], primary_key=f.name == "recording_id",
                          nullable=f.name != "recording_id" and f.name not in required)
                   for f in fields(EvidenceRecord)])


def evidence_rows(records: Iterable[EvidenceRecord]) -> list[dict[str, Any]]:
    """Rows to write, in key order (writers lock rows in the same order), NaN stored as NULL."""
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    rows = []
    for record in records:
        row = asdict(record)
        row["written_at"] = row["written_at"] or now
        for name in IN_FLIGHT_COLUMNS:  # NaN inside the JSON as null, as NaN columns are NULL
            if row[name] is not None:
                row[name] = json.dumps(_finite(json.loads(row[name])))
        for name, value in row.items():
            if isinstance(value, float) and not math.isfinite(value):
                row[name] = None
            elif isinstance(value, str):  # the same text on every backend: no NUL, within the column
                row[name] = printable_text(value)[:_TEXT_LIMITS.get(name, len(value) + 1)]
        rows.append(row)
    return rows  # History._write_rows puts them in key order


def _finite(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return None if isinstance(value, float) and not math.isfinite(value) else value


_EVIDENCE_KINDS = {f.name: str(f.type) for f in fields(EvidenceRecord)}
_JSON_OBJECTS = ("changes", "estimator", "agreement")


def evidence_from_row(values: dict[str, Any]) -> EvidenceRecord:
    """A row as an EvidenceRecord, each value checked against its field's type: a row another program wrote
    off the schema (text where a number belongs, a JSON column that is no object) raises ValueError, one line."""
    row: dict[str, Any] = {}
    for name, value in values.items():
        kind = _EVIDENCE_KINDS.get(name)
        if kind is None or value is None:
            row[name] = value
            continue
        if "int" in kind and (isinstance(value, bool) or not isinstance(value, int)):
            raise ValueError(f"{name} is not an integer: {str(value)[:30]!r}")
        if "float" in kind:
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"{name} is not a number: {str(value)[:30]!r}")
            value = float(value)
        if kind.startswith("str") and not isinstance(value, str):
            value = str(value)
        if name in _JSON_OBJECTS:
            try:
                parsed = json.loads(value)
            except ValueError:
                raise ValueError(f"{name} is not JSON: {value[:30]!r}") from None
            if not isinstance(parsed, dict):
                raise ValueError(f"{name} is not a JSON object: {value[:30]!r}")
        row[name] = value
    for name in ("path", "vehicle", "sensor", "status"):
        if row.get(name) is None:
            raise ValueError(f"{name} is missing")
    return EvidenceRecord(**{k: v for k, v in row.items() if k in _EVIDENCE_KINDS})


def evidence_record(evidence: Any, recording_id: str, path: str, vehicle: str, sensor: str, imu: int | None,
                    start_ns: int | None) -> EvidenceRecord:
    """A row of one IMU's evidence (bag/flight_evidence.FlightEvidence)."""
    z = evidence.z
    return EvidenceRecord(
        recording_id=recording_id, path=path, vehicle=vehicle, sensor=sensor,
        status="evidence" if evidence.changes else "none", imu=imu, device=evidence.device, reason=evidence.reason,
        start_ns=start_ns, poses=evidence.poses, verdict=evidence.verdict, in_force=evidence.in_force or None,
        z_mps2=None if z is None else z[0], z_sigma_mps2=None if z is None else z[1],
        changes=json.dumps({name: [value, sigma] for name, value, sigma in evidence.changes}),
        temperature_degc=evidence.temperature_degc,
        estimator=None if evidence.estimator is None else json.dumps(evidence.estimator),
        agreement=None if evidence.agreement is None else json.dumps(evidence.agreement))


@dataclass(frozen=True)
class KindTrend:
    """One quantity of the in-flight evidence over flights: the filter's bias ("estimator") or the
    agreement with the siblings ("agreement"), the axis whose series says most."""

    kind: str  # estimator | agreement
    quantity: str  # "accel bias z", "gyro bias x" (estimator); "accel z", "gyro x" (agreement)
    unit: str  # mg | deg/s
    per_unit: float  # SI per unit (MG, one deg/s in rad/s)
    flights: list[str]  # the flights judged, as EvidenceRecord.flight
    values: list[float]  # SI
    sigmas: list[float]
    trend: Trend
    against: str = ""  # agreement: the sibling of the last flight
    siblings: int = 0


@dataclass(frozen=True)
class ImuSeries:
    vehicle: str
    who: str  # "IMU 1 (device 1310988)"
    flights: list[EvidenceRecord]  # every row of this IMU, in flight order
    judged: list[EvidenceRecord]  # the flights with z evidence since the calibration in force last changed
    trend: Trend
    in_flight: tuple[KindTrend, ...] = ()  # per kind of in-flight evidence with values, its telling axis
    in_flight_none: tuple[tuple[str, str], ...] = ()  # (kind, why) for a kind no flight gave a value of

    @property
    def status(self) -> str:
        """moved when any evidence moved; else holds when any holds; else cannot tell."""
        statuses = {self.trend.status, *(k.trend.status for k in self.in_flight)}
        return "moved" if "moved" in statuses else "holds" if "holds" in statuses else "cannot tell"

    def said_in_flight(self) -> list[str]:
        """A line per kind of in-flight evidence, as said() is the ground's."""
        head = f"vehicle {self.vehicle} {self.who}"
        lines = []
        for k in self.in_flight:
            t = k.trend
            label = "the filter's bias" if k.kind == "estimator" else "agreement with its siblings"
            if t.status == "cannot tell" or t.change is None or t.since is None:
                lines.append(f"{head}: {label}: cannot tell: {t.reason}")
                continue
            over = len(k.values) - t.since
            figure = (f"{k.quantity} {t.change / k.per_unit:+.3g} {k.unit} over {over} flight{'s' if over != 1 else ''}"
                      f" ({t.sigmas:.1f} sigma)")
            if t.status == "moved" and k.kind == "agreement":
                whom = "its siblings" if k.siblings > 1 else f"{k.against}, its only sibling (either may have moved)"
                lines.append(f"{head} disagrees with {whom}: {figure}, since flight {k.flights[t.since]}: recalibrate")
            elif t.status == "moved":
                lines.append(f"{head}: the filter keeps learning a bias: {figure}, since flight {k.flights[t.since]}: "
                             "recalibrate")
            else:
                lines.append(f"{head}: {label} holds: {len(k.values)} flights, largest change {figure}; scatter "
                             f"between flights {t.scatter / k.per_unit:.3g} {k.unit}")
        labels = {"estimator": "the filter's bias", "agreement": "agreement with its siblings"}
        lines += [f"{head}: {labels[kind]}: none: {why}" for kind, why in self.in_flight_none]
        return lines

    def said(self) -> str:
        """'vehicle uav07 IMU 1 (device 1310988): bias z or scale z +4.20 mg at 1 g over 30 flights (6.0 sigma),
        since flight 2026-11-02T10:14: recalibrate', or how it holds, or why it cannot tell."""
        t = self.trend
        head = f"vehicle {self.vehicle} {self.who}"
        if t.status == "cannot tell" or t.change is None or t.since is None:
            return f"{head}: cannot tell: {t.reason}"
        over = len(self.judged) - t.since
        figure = (f"bias z or scale z {t.change / MG:+.2f} mg at 1 g over {over} flight{'s' if over != 1 else ''} "
                  f"({t.sigmas:.1f} sigma)")
        if t.status == "moved":
            return f"{head}: {figure}, since flight {self.judged[t.since].flight}: recalibrate"
        return (f"{head}: holds: {len(self.judged)} flights, largest change {figure}; scatter between flights "
                f"{t.scatter / MG:.2f} mg")


def unplaced(records: Iterable[EvidenceRecord]) -> list[EvidenceRecord]:
    """The rows of logs that could not be read far enough to name an IMU."""
    return sorted((r for r in records if not (r.device or r.sensor)), key=lambda r: (r.vehicle, r.order))


def imu_series(records: Iterable[EvidenceRecord], rule: ChangeRule | None = None) -> list[ImuSeries]:
    """Per vehicle and IMU (its device, else its sensor name), its flights judged."""
    groups: dict[tuple[str, str], list[EvidenceRecord]] = {}
    for record in records:
        if not (record.device or record.sensor):  # a log that could not be read names no IMU: listed only
            continue
        groups.setdefault((record.vehicle, record.device or record.sensor), []).append(record)
    out = []
    for (vehicle, _), rows in sorted(groups.items()):
        rows.sort(key=lambda r: r.order)
        usable = [r for r in rows if r.status == "evidence" and r.z_mps2 is not None and r.z_sigma_mps2 is not None]
        # The series restarts where the calibration in force changed (the vehicle was recalibrated).
        changed = [i for i in range(1, len(usable)) if usable[i].in_force != usable[i - 1].in_force]
        judged = usable[changed[-1]:] if changed else usable
        values = np.array([r.z_mps2 for r in judged], dtype=float)
        sigmas = np.array([r.z_sigma_mps2 for r in judged], dtype=float)
        kinds, none = _in_flight_trends(rows, rule)
        out.append(ImuSeries(vehicle, rows[-1].who, rows, judged, trend(values, sigmas, rule), kinds, none))
    return out


def _since_in_force(rows: list[EvidenceRecord]) -> list[EvidenceRecord]:
    """The rows since the calibration in force last changed (rows that name none stay in)."""
    named = [i for i, r in enumerate(rows) if r.in_force]
    changed = [named[j] for j in range(1, len(named)) if rows[named[j]].in_force != rows[named[j - 1]].in_force]
    return rows[changed[-1]:] if changed else rows


def _said(row: EvidenceRecord, kind: str) -> dict[str, Any]:
    text = getattr(row, kind)
    try:
        said = json.loads(text) if text else {}
    except ValueError:
        return {"reason": "not as accel_calibration writes it"}
    return said if isinstance(said, dict) else {}


def _in_flight_trends(rows: list[EvidenceRecord], rule: ChangeRule | None
                      ) -> tuple[tuple[KindTrend, ...], tuple[tuple[str, str], ...]]:
    """Per kind, the axis whose series says most (moved first, then the most sigmas); or why none."""
    from ..core.evidence_trend import MAX_GYRO_BIAS_CHANGE_RADPS

    kinds, none = [], []
    series = _since_in_force(rows)
    for kind, name in (("estimator", "{part} bias {axis}"), ("agreement", "{part} {axis}")):
        said = [(row, _said(row, kind)) for row in series]
        candidates = []
        for part, unit, per_unit, bound in (("accel", "mg", MG, None),
                                            ("gyro", "deg/s", float(np.radians(1.0)), MAX_GYRO_BIAS_CHANGE_RADPS)):
            for axis, axis_name in enumerate(AXES):
                points = [(row.flight, s[part][axis], s[f"{part}_sigma"][axis], s) for row, s in said
                          if isinstance(s.get(part), list) and isinstance(s.get(f"{part}_sigma"), list)
                          and s[part][axis] is not None and s[f"{part}_sigma"][axis] is not None]
                if not points:
                    continue
                values = np.array([p[1] for p in points], dtype=float)
                sigmas = np.array([p[2] for p in points], dtype=float)
                last = points[-1][3]
                candidates.append(KindTrend(kind, name.format(part=part, axis=axis_name), unit, per_unit,
                                            [p[0] for p in points], list(values), list(sigmas),
                                            trend(values, sigmas, rule, bound), str(last.get("against", "")),
                                            int(last.get("siblings", 0) or 0)))
        if candidates:
            kinds.append(max(candidates, key=lambda k: (k.trend.status == "moved", k.trend.status == "holds",
                                                        k.trend.sigmas)))
            continue
        reasons = [s["reason"] for _, s in said if isinstance(s.get("reason"), str)]
        if reasons:
            none.append((kind, reasons[-1]))
    return tuple(kinds), tuple(none)
