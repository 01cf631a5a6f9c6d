"""The static-pose detector: windows in seconds of stream time, a noise floor that cannot learn flight.

A sliding window (default 0.5 s of header time) is still when its variance is below k * the measured
noise floor -- as imu_tk thresholds at k * sigma^2 of an initial still period, but the floor here is
learned continuously as a low quantile of all window variances seen (noise_floor.py), so no initial still
period is needed and any raw unit (counts, g, m/s^2) works. Explicit thresholds override.

The floor cannot learn flight vibration: it may rise at most `max_floor_rise` (rms) above the quietest
floor seen since start, and a window noisier than `accel_noise_ceiling` / `gyro_noise_ceiling` (rms
per axis, a value every MEMS part at rest stays below and motor vibration does not) is never still.
A window in which more than half of the samples repeat their predecessor exactly (a frozen driver, a
gyro reading 0 while it warms up) is no evidence of the noise: it never feeds the floor.

A still interval becomes a Pose when motion starts again (or at `max_pose_s`), if it lasted
`min_hold_s`; `trim_s` is dropped at both ends (settling after the last motion, the onset of the
next one before the window noticed it).

Samples go in as arrays, a recording whole or in parts (`find(..., final=False)`, which the stream side
calls: each pose with its segment; `process` is its poses alone, for a caller that needs no segments): the rules are in
detector_batch.py, over a `DetectorConfig` (frozen) and a `DetectorState` (what is learned and carried).
Here: the clocks (a re-synchronised or paused stream, as `breaks`) and what the node and session read.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike

from ..errors import CalibrationError
from ..pose import Pose
from .detector_batch import DetectorConfig, DetectorState, detect_batch, end_carry, peek_carry

# Marks for process(breaks=...): before this sample the clock was re-synchronised, or collection was
# paused and resumed (the interval open then is dropped).
RESTART = 1
DISCARD = 2
_INT64_MAX = 2**63 - 1


@dataclass(frozen=True)
class FoundPose:
    """A pose and the segment (between breaks) it was measured in, numbered from the segment in force when
    the process call began (0): the clock its stamps are on."""

    pose: Pose
    segment: int


class StaticDetector:
    """Still intervals of a stream, as Poses, by the rules of a `DetectorConfig` (the defaults when None;
    a bad setting raises CalibrationError naming it where the config is built)."""

    def __init__(self, config: DetectorConfig | None = None) -> None:
        self.config = config if config is not None else DetectorConfig()
        self.state = DetectorState.fresh(self.config)
        self.rejected_samples = 0  # every sample skipped: NaN/inf, stamp not increasing, out of range
        self.rejected_out_of_range = 0  # of those, the finite ones beyond accel_limit/gyro_limit/the guard
        # Between process() calls on parts of one recording: the clocks' layout (the current segment's
        # offset, the latest virtual stamp).
        self._layout: tuple[int, int] | None = None

    @property
    def continuing(self) -> bool:
        """A recording is going through process() in parts: the next call continues it."""
        return self.state.carry is not None or self._layout is not None

    @property
    def noise_floor_accel_var(self) -> float | None:
        """Per-axis variance of the acceleration noise (window total / 3), when learned: the floor in
        force, bounded as the thresholds are."""
        config, state = self.config, self.state
        value = state.accel_floor.value
        if value is None or state.full_time_ns < config.warmup_ns:
            return None
        return min(value, state.accel_quietest * config.rise_var, config.accel_cap) / 3.0

    @property
    def quietest_floors(self) -> tuple[float | None, float | None]:
        """(accel, gyro) lowest window-total floors seen after warm-up; None before."""
        a, g = self.state.accel_quietest, self.state.gyro_quietest
        return (None if a == math.inf else a), (None if g == math.inf else g)

    @property
    def noise_near_ceilings(self) -> tuple[float | None, float | None]:
        """(accel m/s^2, gyro rad/s) rms noise per axis of the quietest floor learned, where it is at least
        half its ceiling (accel_noise_ceiling, gyro_noise_ceiling): the floor is a low quantile of the
        windows' noise, so windows still enough for a pose were then the exception (a hand-held sensor,
        vibration). None where it is not, or not known yet."""
        accel, gyro = self.quietest_floors
        return (None if accel is None or not accel >= self.config.accel_cap / 4 else math.sqrt(accel / 3.0),
                None if gyro is None or not gyro >= self.config.gyro_cap / 4 else math.sqrt(gyro / 3.0))

    @property
    def learned_beyond_ceilings(self) -> tuple[float | None, float | None]:
        """(accel m/s^2, gyro rad/s) rms per axis the learned threshold alone (k x the noise floor) would take,
        where the ceiling (accel_noise_ceiling, gyro_noise_ceiling) is below it and so decides instead; None
        where it does not, where an explicit threshold is set, or before warm-up."""
        config, state = self.config, self.state
        if state.full_time_ns < config.warmup_ns:
            return None, None

        def beyond(fixed: float | None, value: float | None, quietest: float, k: float, cap: float) -> float | None:
            if fixed is not None or value is None or quietest == math.inf:
                return None
            learned = k * min(value, quietest * config.rise_var)
            return math.sqrt(learned / 3.0) if learned > cap else None

        return (beyond(config.accel_var_threshold, state.accel_floor.value, state.accel_quietest, config.k_sigma,
                       config.accel_cap),
                beyond(config.gyro_var_threshold, state.gyro_floor.value, state.gyro_quietest, config.gyro_k_sigma,
                       config.gyro_cap))

    @property
    def thresholds(self) -> tuple[float | None, float | None]:
        """(accel, gyro) window-variance thresholds in force; None where not yet known."""
        config, state = self.config, self.state
        warm = state.full_time_ns >= config.warmup_ns
        accel = config.accel_var_threshold
        value = state.accel_floor.value
        if accel is None and warm and value is not None:
            # The operations of detector_batch._limit_per_window, in its order.
            accel = min(config.k_sigma * min(value, state.accel_quietest * config.rise_var), config.accel_cap)
        gyro = config.gyro_var_threshold
        value = state.gyro_floor.value
        if gyro is None and warm and value is not None:
            gyro = min(config.gyro_k_sigma * min(value, state.gyro_quietest * config.rise_var), config.gyro_cap)
        return accel, gyro

    @property
    def holding_still(self) -> bool:
        """After process(..., final=False): a still interval is open at the end of what was processed."""
        carry = self.state.carry
        return carry is not None and carry.opened is not None

    def peek_open(self) -> Pose | None:
        """After process(..., final=False): the interval still open as the pose process() would end it as
        if the recording ended here, without ending it (a live /calibrate counts the pose being held)."""
        pose = peek_carry(self.config, self.state)
        if pose is None or self._layout is None:
            return pose
        offset = self._layout[0]  # the open interval is on the last segment's clock
        return replace(pose, start_ns=pose.start_ns - offset, end_ns=pose.end_ns - offset)

    def process(self, t_ns: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None,
                temperature_degc: ArrayLike | None = None, breaks: ArrayLike | None = None,
                flush: bool = True, final: bool = True) -> list[Pose]:
        """The poses of `find` alone (for a caller that needs no segments)."""
        return [found.pose for found in self.find(t_ns, accel, gyro, temperature_degc, breaks, flush, final)]

    def find(self, t_ns: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None,
             temperature_degc: ArrayLike | None = None, breaks: ArrayLike | None = None,
             flush: bool = True, final: bool = True) -> list[FoundPose]:
        """The poses of a recording (or of its next part), with array operations. Needs a fresh detector,
        or one whose last call had `final` False.

        `breaks` (one per sample, optional): RESTART before a sample whose clock was re-synchronised (the
        interval open then ends as at a gap), DISCARD before one after a pause in collection (the interval
        open then is dropped); the learned floor is kept across both.
        Each segment runs on a clock of its own, laid end to end with a gap longer than a window.
        `flush` False: the interval still open at the end is dropped (collection paused there).
        `final` False: a part of a recording, more follows in the next call (same gyro and temperature
        presence); the interval open at its end stays open. A long recording goes through in parts of
        bounded memory with the poses of one call. Each pose comes with its segment, numbered from the one
        in force when the call began (0)."""
        continuing = self.continuing
        if not continuing and self.state.full_time_ns:
            raise CalibrationError("process() needs a fresh StaticDetector (this one has seen samples)")
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        marks = None if breaks is None else np.asarray(breaks, dtype=np.int64).reshape(-1)
        if marks is not None and len(marks) != len(t):
            raise CalibrationError(f"breaks must have one entry per sample ({len(t)}), got {len(marks)}")
        if marks is not None and not continuing:
            marks = marks.copy()
            marks[:1] = 0  # a break before the first sample changes nothing
        if self._layout is None and (marks is None or not np.any(marks)):
            poses, rejected, out_of_range = detect_batch(self.config, self.state, t, accel, gyro, temperature_degc,
                                                         flush=flush, final=final)
            found = [FoundPose(pose, 0) for pose in poses]
        else:
            if marks is None:
                marks = np.zeros(len(t), dtype=np.int64)
            previous = self._layout
            if previous is None and self.state.carry is not None:  # parts so far on their own clock
                previous = (0, int(self.state.carry.t[-1]))
            laid = self._end_to_end(t, marks, previous)
            if laid is None:  # the clocks laid end to end would not fit in int64 ns
                return self._by_segment(t, accel, gyro, temperature_degc, marks, flush, final)
            virtual, segment_starts, offsets, self._layout = laid
            drop = marks == DISCARD
            poses, rejected, out_of_range = detect_batch(self.config, self.state, virtual, accel, gyro,
                                                         temperature_degc, drop, flush, final)
            found = []
            for pose in poses:
                segment = int(np.searchsorted(segment_starts, pose.start_ns, side="right")) - 1
                offset = int(offsets[segment])
                found.append(FoundPose(replace(pose, start_ns=pose.start_ns - offset, end_ns=pose.end_ns - offset),
                                       segment))
        if final:
            self._layout = None
        self.rejected_samples += rejected
        self.rejected_out_of_range += out_of_range
        return found

    def _end_to_end(self, t: np.ndarray, marks: np.ndarray, previous: tuple[int, int] | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]] | None:
        """Stamps of segments (split before each marked sample) laid end to end, each starting a window
        and a nanosecond after everything before it: (stamps, first virtual stamp of each segment, the
        offset added to each segment, (the last offset, the latest virtual stamp) for a next part). The
        first segment continues `previous` (offset, latest stamp) of the part before, when given. None
        when that does not fit in int64."""
        cuts = [int(c) for c in np.flatnonzero(marks) if c > 0 or previous is not None]
        bounds = [0, *cuts, len(t)]
        virtual = np.empty_like(t)
        starts, offsets = [], []
        top: int | None = None if previous is None else previous[1]  # the latest virtual stamp so far
        for index, (first, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
            segment = t[first:stop]
            if index == 0 and previous is not None:  # the segment in force before this part goes on
                offset = previous[0]
                base = -_INT64_MAX - 1  # every pose before the first mark belongs to it
                if len(segment):
                    high = int(segment.max()) + offset
                    if high > _INT64_MAX or int(segment.min()) + offset < -_INT64_MAX:
                        return None
                    top = high if top is None else max(top, high)
            else:
                low, high = int(segment.min()), int(segment.max())
                base = low if top is None else top + self.config.window_ns + 1
                offset = base - low
                top = base + (high - low)
                if top > _INT64_MAX or not -_INT64_MAX <= offset <= _INT64_MAX:
                    return None
            virtual[first:stop] = segment + np.int64(offset)
            starts.append(base)
            offsets.append(offset)
        assert top is not None  # some segment had rows, or a previous part did
        return virtual, np.array(starts, dtype=np.int64), np.array(offsets, dtype=np.int64), (offsets[-1], top)

    def _by_segment(self, t: np.ndarray, accel: ArrayLike, gyro: ArrayLike | None,
                    temperature_degc: ArrayLike | None, marks: np.ndarray, flush: bool, final: bool
                    ) -> list[FoundPose]:
        """process() one segment (between breaks) at a time, each on its own clock: for stamps whose
        segments laid end to end would not fit in int64 ns (slower with many breaks, the same rules). The
        first segment continues what is carried only when its layout is not shifted (else it is lost)."""
        a = np.asarray(accel, dtype=float).reshape(-1, 3)
        g = None if gyro is None else np.asarray(gyro, dtype=float).reshape(-1, 3)
        temps = None if temperature_degc is None else np.asarray(temperature_degc, dtype=float).reshape(-1)
        if self._layout is not None and self._layout[0] != 0:  # the carried rows' clock is a shifted one
            self.state.carry = None
        self._layout = None
        cuts = [int(c) for c in np.flatnonzero(marks) if c > 0 or self.state.carry is not None]
        bounds = [0, *cuts, len(t)]
        found: list[FoundPose] = []
        for index, (first, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
            if first in cuts:  # the break before this segment
                ended = end_carry(self.config, self.state) if marks[first] == RESTART else None
                self.state.carry = None
                if ended is not None:
                    found.append(FoundPose(ended, index - 1))
            last = stop == len(t)
            rows = slice(first, stop)
            poses, rejected, out_of_range = detect_batch(
                self.config, self.state, t[rows], a[rows], None if g is None else g[rows],
                None if temps is None else temps[rows], flush=flush or not last, final=final and last)
            self.rejected_samples += rejected
            self.rejected_out_of_range += out_of_range
            found += [FoundPose(pose, index) for pose in poses]
        return found

