"""A recording into the session's stream side in parts (replay's reader, or the node's buffer every few
tens of milliseconds): screening, temperature filter and detector over arrays, the poses judged by the
stream side's rule. One sample path for node and replay: live equals replay by construction."""
from __future__ import annotations

import numpy as np

from ..pose import Pose
from .stream_side import StreamPart, StreamSide


class RecordingFeed:
    """One recording into a stream side in parts of `part_rows` samples: the cut points depend only on the
    sample count, so any reader's chunking gives the same, deterministic poses (and a recording shorter
    than a part is one detector call). A part is processed once the temperature readings of its time have
    come (readings after its last stamp), or when the temperature stream lags by MAX_LAG_PARTS parts.

    Each part goes to the stream side whole (`StreamSide.take`), with the temperature readings of its time;
    what is carried between parts is the stream side's. Poses are checked against frozen runs at the end,
    when every run is known (a run found later may overlap a pose)."""

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
        return self.stream.holding()

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
        readings = None
        if self.has_temperature:  # the readings of the part's time; all that are left with the last part
            readings = self._readings_upto(None if final or not len(t) else int(t.max())) \
                or (np.zeros(0, np.int64), np.zeros(0))
        self._found += self.stream.take(StreamPart(t, accel, gyro, collecting, readings, final))
