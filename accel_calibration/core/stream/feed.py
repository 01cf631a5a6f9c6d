"""A recording into the session's stream side in parts (replay's reader, or the node's buffer every few
tens of milliseconds): screening, temperature filter and detector over arrays, the poses judged by the
stream side's rule. One sample path for node and replay: live equals replay by construction."""
from __future__ import annotations

import numpy as np

from ..pose import Pose
from .detector import DISCARD, RESTART
from .stream_side import StreamSide


class RecordingFeed:
    """One recording into a stream side in parts of `part_rows` samples: the cut points depend only on the
    sample count, so any reader's chunking gives the same, deterministic poses (and a recording shorter
    than a part is one detector call). A part is processed once the temperature readings of its time have
    come (readings after its last stamp), or when the temperature stream lags by MAX_LAG_PARTS parts.

    Carried between parts: the screen's, temperature filter's and detector's own state, and whether a
    pause or a clock re-synchronisation came after the last sample the detector saw. Poses are checked
    against frozen runs at the end, when every run is known (a run found later may overlap a pose)."""

    PART_ROWS = 1 << 14  # ~16 s at 1 kHz: a part and its temporaries stay in cache (2 workers then scale)
    MAX_LAG_PARTS = 8
    # Live: a part waits this long (stamp span) at most for the temperature readings of its time; a node
    # without a temperature topic then finds its poses this much later.
    LIVE_TEMPERATURE_WAIT_NS = 1_000_000_000

    def __init__(self, stream: StreamSide, has_temperature: bool, live: bool = False, part_rows: int = PART_ROWS):
        self.stream = stream
        self.has_temperature = has_temperature
        self.live = live
        self.part_rows = part_rows
        self._samples: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]] = []
        self._buffered = 0
        self._readings: list[tuple[np.ndarray, np.ndarray]] = []  # as they came
        self._sorted: tuple[np.ndarray, np.ndarray] = (np.zeros(0, np.int64), np.zeros(0))  # not yet taken
        self._latest_reading: int | None = None
        self._paused_since = False  # a paused sample since the detector's last one
        self._restart_since = False  # a clock re-synchronisation since the detector's last one
        self._segment_base = stream.screen.time_base  # the clock of the detector's current segment
        self._found: list[tuple[Pose, int]] = []  # poses with the clock they were measured on
        self.samples = 0

    def add_temperatures(self, stamps_ns: np.ndarray, degc: np.ndarray) -> None:
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
        if len(stamps):
            self._readings.append((stamps, np.asarray(degc, dtype=float).reshape(-1)))
            latest = int(stamps.max())
            self._latest_reading = latest if self._latest_reading is None else max(latest, self._latest_reading)
            self._run(final=False)

    def add_samples(self, t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray,
                    collecting: np.ndarray | None = None) -> None:
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        if not len(t):
            return
        accel = np.asarray(accel_mps2, dtype=float).reshape(-1, 3)
        gyro = np.asarray(gyro_radps, dtype=float).reshape(-1, 3)
        self._samples.append((t, accel, gyro, None if collecting is None else np.asarray(collecting, bool).reshape(-1)))
        self._buffered += len(t)
        self.samples += len(t)
        self._run(final=False)

    def finish(self) -> list[Pose]:
        """The end of the recording: the rest goes through, the interval open at the end ends."""
        self._run(final=True)
        return self._settle(self._found)

    def take_poses(self) -> list[Pose]:
        """Live: the poses ended since the last call (those that are poses: not frozen, plausible gravity)."""
        found, self._found = self._found, []
        return self._settle(found)

    def _settle(self, found: list[tuple[Pose, int]]) -> list[Pose]:
        """The poses found that are poses; the others leave the motion recorder's sequence too."""
        usable = []
        for pose, base in found:
            if self.stream.usable_pose(pose, base) is None:
                self.stream.motions.drop(pose)
            else:
                usable.append(pose)
        return usable

    def drain(self) -> None:
        """Live: everything buffered goes through now, without waiting for later temperature readings
        (/calibrate counts what was held up to the moment it was called)."""
        while self._buffered:
            self._part(*self._take(min(self._buffered, self.part_rows)), final=False)

    def holding(self) -> Pose | None:
        """Live: the still interval in progress as the pose it would end as now (what a person holding a
        pose expects /calibrate to count), None when there is none or it is no pose."""
        if self._paused_since:
            return None
        pose = self.stream.detector.peek_open()
        if pose is None:
            return None
        return self.stream.usable_pose(pose, self._segment_base)

    def _run(self, final: bool) -> None:
        if self.live and not final:
            self._run_live()
            return
        while self._buffered >= self.part_rows:
            t, accel, gyro, collecting = self._take(self.part_rows)
            waiting = (self.has_temperature and (self._latest_reading is None or self._latest_reading <= t.max())
                       and self._buffered + len(t) < self.MAX_LAG_PARTS * self.part_rows)
            if waiting and not final:  # the readings of this part's time have not all come yet
                self._samples.insert(0, (t, accel, gyro, collecting))
                self._buffered += len(t)
                return
            self._part(t, accel, gyro, collecting, final=final and self._buffered == 0)
        if final:
            if self._buffered:
                self._part(*self._take(self._buffered), final=True)
            elif self.stream.detector.continuing:
                self._part(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), None, final=True)

    def _run_live(self) -> None:
        """Each part as soon as its samples' temperature readings have come (a reading stamped after its
        last sample), or it has waited LIVE_TEMPERATURE_WAIT_NS of stamps; at once while no reading ever came."""
        while self._buffered:
            t, accel, gyro, collecting = self._take(min(self._buffered, self.part_rows))
            # No reading yet: no temperature topic (or not yet): nothing to wait for.
            waiting = self._latest_reading is not None and self._latest_reading <= t.max() \
                and int(t.max()) - int(t.min()) < self.LIVE_TEMPERATURE_WAIT_NS
            if waiting:
                self._samples.insert(0, (t, accel, gyro, collecting))
                self._buffered += len(t)
                return
            self._part(t, accel, gyro, collecting, final=False)

    def _take(self, rows: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
        """The first `rows` buffered samples as arrays (joined from the pieces that came)."""
        taken, count = [], 0
        while count < rows:
            piece = self._samples.pop(0)
            need = rows - count
            if len(piece[0]) > need:
                self._samples.insert(0, tuple(None if x is None else x[need:] for x in piece))  # type: ignore[arg-type]
                piece = tuple(None if x is None else x[:need] for x in piece)  # type: ignore[assignment]
            taken.append(piece)
            count += len(piece[0])
        self._buffered -= count
        if len(taken) == 1:
            t, accel, gyro, collecting = taken[0]
            return t, accel, gyro, collecting
        collecting = None
        if any(p[3] is not None for p in taken):  # a piece without a mask was collecting throughout
            collecting = np.concatenate([np.ones(len(p[0]), bool) if p[3] is None else p[3] for p in taken])
        return (np.concatenate([p[0] for p in taken]), np.concatenate([p[1] for p in taken]),
                np.concatenate([p[2] for p in taken]), collecting)

    def _readings_upto(self, last_ns: int | None) -> tuple[np.ndarray, np.ndarray] | None:
        """The buffered readings stamped at or before `last_ns` (all of them when None), taken out, in
        stamp order (stable: as the temperature filter takes a whole recording's). The buffer is kept
        sorted, so a part takes a prefix (a CSV brings a reading on every row: no copy per part)."""
        if self._readings:  # readings that came since: merged into the sorted buffer
            stamps = np.concatenate([self._sorted[0], *(r[0] for r in self._readings)])
            values = np.concatenate([self._sorted[1], *(r[1] for r in self._readings)])
            order = np.argsort(stamps, kind="stable")
            self._sorted = (stamps[order], values[order])
            self._readings = []
        stamps, values = self._sorted
        if not len(stamps):
            return None
        count = len(stamps) if last_ns is None else int(np.searchsorted(stamps, last_ns, side="right"))
        self._sorted = (stamps[count:], values[count:])
        return stamps[:count], values[:count]

    def _part(self, t: np.ndarray, accel: np.ndarray, gyro: np.ndarray, collecting: np.ndarray | None,
              final: bool) -> None:
        stream = self.stream
        detector = stream.detector
        fresh = not detector.continuing
        time_base = stream.screen.time_base
        keep, restart = stream.screen.screen_arrays(t, accel, gyro)
        paused = np.zeros(len(t), dtype=bool) if collecting is None else ~collecting
        stream.counters.samples_paused += int(np.count_nonzero(keep & paused))
        stream.motions.add(t, gyro, keep, paused, restart)
        rows = np.flatnonzero(keep & ~paused)  # what the detector sees
        # Before each detector row: a pause since the previous one drops the interval (DISCARD), else a
        # clock jump ends it (RESTART); a pause in force at the start changes nothing (nothing is open).
        breaks = np.zeros(len(rows), dtype=np.int64)
        if len(rows):
            previous = np.concatenate([[-1], rows[:-1]])
            paused_before = np.concatenate([[0], np.cumsum(paused)])
            jumps_before = np.concatenate([[0], np.cumsum(restart)])
            breaks[jumps_before[rows + 1] > jumps_before[previous + 1]] = RESTART
            breaks[paused_before[rows] > paused_before[previous + 1]] = DISCARD
            if self._restart_since and not breaks[0]:
                breaks[0] = RESTART
            if self._paused_since:
                breaks[0] = DISCARD
            self._paused_since = bool(np.any(paused[rows[-1] + 1:]))
            self._restart_since = bool(np.any(restart[rows[-1] + 1:]))
        else:
            self._paused_since = self._paused_since or bool(np.any(paused))
            self._restart_since = self._restart_since or bool(np.any(restart))
        temps = None
        if self.has_temperature:
            # Always an array (NaN: no temperature yet): the detector's parts keep one presence.
            readings = self._readings_upto(None if final or not len(t) else int(t.max()))
            stamps, values = readings if readings is not None else (np.zeros(0, np.int64), np.zeros(0))
            rejected = stream.temperature.rejected
            temps, stale = stream.temperature.series(stamps, values, t[rows])
            stream.counters.temperature_stale += stale
            stream.counters.temperature_bad += stream.temperature.rejected - rejected
        # Paused at the end: the interval then open was dropped when the pause began.
        found = detector.find(t[rows], accel[rows], gyro[rows], temps, breaks, flush=not self._paused_since,
                              final=final)
        # Each pose on the clock it was measured on (frozen runs of other clocks do not overlap it): the
        # segment in force when the part began, then one per break (the first part: from its first row).
        bases = time_base + np.concatenate([[0], np.cumsum(restart)])[rows + 1]
        if fresh:
            firsts = np.concatenate([[0], np.flatnonzero(breaks[1:]) + 1]) if len(rows) else np.zeros(0, int)
            segment_bases = bases[firsts]
        else:
            segment_bases = np.concatenate([[self._segment_base], bases[np.flatnonzero(breaks)]])
        if len(rows):
            self._segment_base = int(bases[-1])
        for each in found:
            stream.motions.pose_found(each.pose)
        self._found += [(each.pose, int(segment_bases[each.segment])) for each in found]
