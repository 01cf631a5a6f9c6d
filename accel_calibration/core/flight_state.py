"""When a vehicle was armed or airborne, from the state a recording carries (a log's arming and landing
topics, a bag's /mavros/state, an autopilot's ARM events), and which samples that leaves for calibration.

A state reading holds from its stamp until the next reading of the same source; the first reading also
holds back to the start of the recording (a log that begins armed was armed before its first status
message). Spans of several sources are joined: armed or airborne is flying. Nothing within `margin`
before a span or after it is collected (motors spin up before lift-off, run down after disarm); the
session drops a still interval in progress when collection pauses, so nothing of a flight is a pose.
Stamps in ns on the IMU samples' clock. Pure numpy.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import CalibrationError

EARLIEST = int(np.iinfo(np.int64).min)  # a span that began before the recording did
LATEST = int(np.iinfo(np.int64).max)  # a span still open when the recording ended
GROUND_BORDER_S = 1.0  # of a flight kept beside the ground by a read for the still moments (ground_kept)


def _no_spans() -> np.ndarray:
    return np.zeros((0, 2), dtype=np.int64)


@dataclass(frozen=True)
class FlightState:
    """The spans a recording says the vehicle was armed or airborne, and where that was read.

    `spans_ns`: (K, 2) int64 [start, end], sorted and disjoint; EARLIEST/LATEST for a span open at either
    end. `sources`: what was read, e.g. ("PX4 vehicle_status", "vehicle_land_detected"), in the words of
    the one-line report. No source found: `sources` is empty (replay warns in one line)."""

    spans_ns: np.ndarray = field(default_factory=_no_spans)
    sources: tuple[str, ...] = ()

    @property
    def found(self) -> bool:
        return bool(self.sources)

    def collecting(self, t_ns: np.ndarray, margin_s: float) -> np.ndarray:
        """One bool per sample stamp: False where the vehicle was armed or airborne or within `margin_s`."""
        return collecting_mask(t_ns, self.spans_ns, margin_s)

    def left_out_s(self, first_ns: int, last_ns: int, margin_s: float) -> float:
        """Seconds of [first_ns, last_ns] (the recording's span) that are flight or its margin."""
        return left_out_s(first_ns, last_ns, self.spans_ns, margin_s)

    def ground_kept(self, t_ns: np.ndarray, margin_s: float, border_s: float = GROUND_BORDER_S) -> np.ndarray:
        """One bool per stamp: what a read for the still moments on the ground keeps of a long log. Every
        sample `collecting` takes, and `border_s` of each flight (margin included) next to them: the session
        then sees each flight begin and end as it would in the whole log, and a gyro interpolated at the
        accelerometer's stamps has its neighbours. The rest of a flight can never be a pose."""
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        spans = widened(self.spans_ns, margin_s)
        border = int(round(float(border_s) * 1e9))
        starts = np.where(spans[:, 0] == EARLIEST, EARLIEST, spans[:, 0] + border)
        ends = np.where(spans[:, 1] == LATEST, LATEST, spans[:, 1] - border)
        inner = np.column_stack([starts, ends])[starts <= ends]
        if not len(inner) or not len(t):
            return np.ones(len(t), dtype=bool)
        at = np.searchsorted(inner[:, 0], t, side="right") - 1
        inside: np.ndarray = (at >= 0) & (t <= inner[np.maximum(at, 0), 1])
        return ~inside


def spans_from_states(stamps_ns: np.ndarray, flying: np.ndarray, initial: bool | None = None) -> np.ndarray:
    """The spans (K, 2) a series of state readings says were flying: each reading holds until the next
    (stamps sorted first, stable), the last until LATEST. Before the first reading the state is `initial`;
    None: the first reading's own (a status logged now and then; events, ARMED then DISARMED, pass False)."""
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    states = np.asarray(flying, dtype=bool).reshape(-1)
    if len(stamps) != len(states):
        raise CalibrationError(f"flight state: {len(stamps)} stamps but {len(states)} states")
    if not len(stamps):
        return _no_spans()
    order = np.argsort(stamps, kind="stable")
    stamps, states = stamps[order], states[order]
    if initial is not None:  # the state before the first reading, as a reading at EARLIEST
        stamps = np.concatenate([[EARLIEST], stamps]).astype(np.int64)
        states = np.concatenate([[bool(initial)], states])
    previous = np.concatenate([[False], states[:-1]])
    following = np.concatenate([states[1:], [False]])
    starts = stamps[states & ~previous]
    ends = np.concatenate([stamps[1:], [LATEST]])[states & ~following]  # the stamp of the reading that ends it
    if states[0]:
        starts = starts.copy()
        starts[0] = EARLIEST
    return np.column_stack([starts, ends]).astype(np.int64)


def union_spans(*spans: np.ndarray) -> np.ndarray:
    """Several sources' spans as one sorted, disjoint set (touching or overlapping spans joined)."""
    joined = np.concatenate([np.asarray(s, dtype=np.int64).reshape(-1, 2) for s in spans] or [_no_spans()])
    if not len(joined):
        return _no_spans()
    joined = joined[np.lexsort((joined[:, 1], joined[:, 0]))]
    ends_so_far = np.maximum.accumulate(joined[:, 1])
    # A span starts a new group when it begins after every earlier span has ended.
    new = np.concatenate([[True], joined[1:, 0] > ends_so_far[:-1]])
    group = np.cumsum(new) - 1
    starts = joined[new, 0]
    ends = np.full(int(group[-1]) + 1, EARLIEST, dtype=np.int64)
    np.maximum.at(ends, group, joined[:, 1])
    return np.column_stack([starts, ends])


def _margin_ns(margin_s: float) -> int:
    margin = float(margin_s)
    if not np.isfinite(margin) or margin < 0 or margin > 1e6:
        raise CalibrationError(f"--armed-margin-s must be a number of seconds from 0 to 1e6, got {margin_s!r}")
    return int(round(margin * 1e9))


def widened(spans_ns: np.ndarray, margin_s: float) -> np.ndarray:
    """The spans grown by the margin on both sides (saturating at EARLIEST/LATEST), joined."""
    margin = _margin_ns(margin_s)
    spans = np.asarray(spans_ns, dtype=np.int64).reshape(-1, 2)
    starts, ends = spans[:, 0], spans[:, 1]
    starts = np.where(starts < EARLIEST + margin, EARLIEST, starts - margin)
    ends = np.where(ends > LATEST - margin, LATEST, ends + margin)
    return union_spans(np.column_stack([starts, ends]))


def collecting_mask(t_ns: np.ndarray, spans_ns: np.ndarray, margin_s: float) -> np.ndarray:
    """One bool per stamp: False within `margin_s` of a flying span (ends included), True elsewhere."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    spans = widened(spans_ns, margin_s)
    if not len(spans) or not len(t):
        return np.ones(len(t), dtype=bool)
    at = np.searchsorted(spans[:, 0], t, side="right") - 1
    inside: np.ndarray = (at >= 0) & (t <= spans[np.maximum(at, 0), 1])
    return ~inside


def left_out_s(first_ns: int, last_ns: int, spans_ns: np.ndarray, margin_s: float) -> float:
    """Seconds of [first_ns, last_ns] covered by the flying spans grown by the margin."""
    spans = widened(spans_ns, margin_s)
    if not len(spans) or last_ns < first_ns:
        return 0.0
    starts = np.maximum(spans[:, 0], first_ns).astype(float)
    ends = np.minimum(spans[:, 1], last_ns).astype(float)
    return float(np.sum(np.clip(ends - starts, 0.0, None))) / 1e9


def combined(states: list[FlightState]) -> FlightState:
    """Several sources as one flight state (armed or airborne in any is flying)."""
    found = [s for s in states if s.found]
    return FlightState(union_spans(*(s.spans_ns for s in found)), tuple(name for s in found for name in s.sources))


def report_line(state: FlightState, first_ns: int | None, last_ns: int | None, margin_s: float) -> str:
    """What replay says of it, one line: how much was left out and from which sources, or that none was found."""
    if not state.found:
        return ("no flight state in this recording (no arming or landing topic or record): every sample was "
                "taken as on the ground; a bag's can be named with --armed-topic; --ignore-flight-state silences this")
    seconds = 0.0 if first_ns is None or last_ns is None else state.left_out_s(first_ns, last_ns, margin_s)
    return f"left out {seconds:.1f} s armed or airborne ({', '.join(state.sources)})"
