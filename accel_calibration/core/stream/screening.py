"""Screening: which samples may reach the detector, over arrays (a recording whole or in parts, the
node's buffer alike), counted in one `Counters` record.

A sample is kept out of the calibration (it is still passed on, corrected, by the node) when
- any accel or gyro value is NaN or infinite (`non_finite`),
- its acceleration is exactly (0, 0, 0) (`zero_accel`): no accelerometer reads that under gravity;
  it is an empty message from a driver with nothing to say,
- its stamp is not after the last usable-stamped sample (`stamp_backwards`), unless it lies more than
  a few windows (`STAMP_JUMP_WINDOWS`) before it: then the clock was re-synchronised (`stamp_jumps`:
  a publisher restarting with earlier stamps, or the sample after one stamped far ahead), the sample
  is kept and the detector starts a new window, so one bad stamp costs one still interval, not a day,
- an accel axis is at or beyond 99.5 % of full scale (`saturated`), or a gyro axis beyond its
  full scale (`gyro_out_of_range`): a finite 2e154 is as wrong as a NaN,
- its acceleration repeats the previous sample's bit for bit `frozen_samples` times or more
  (`frozen`): a live MEMS part always shows noise, so a repeated value is a stuck driver or bus.
  Still intervals that overlap a frozen run are dropped as well (their variance was the run's zero).
A gyro that repeats its value that long while the acceleration varies (a gyro reading exactly 0
while it warms up, an IMU without one) is counted (`gyro_frozen`) and its samples still count: the
accelerometer judges stillness, and the detector never learns its noise floor from such windows.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import ClassVar

import numpy as np

from ..settings import Settings

SATURATION_FRACTION = 0.995
# A stamp this many detector windows (or more) before the last one re-synchronises the clock.
STAMP_JUMP_WINDOWS = 4
_INT64_MIN = np.iinfo(np.int64).min
_FIRST_CHUNK = 256  # screen_arrays looks for the next stamp jump in chunks growing from this


@dataclass
class Counters:
    """What the session set aside, by reason (one record for node, replay and diagnostics)."""

    samples: int = 0
    non_finite: int = 0
    zero_accel: int = 0
    stamp_backwards: int = 0
    stamp_jumps: int = 0
    saturated: int = 0
    gyro_out_of_range: int = 0
    frozen: int = 0
    gyro_frozen: int = 0
    frozen_poses_dropped: int = 0
    implausible_poses: int = 0  # still intervals whose |mean accel| is no gravity (0.5..1.5 g): dropped
    temperature_bad: int = 0
    temperature_stale: int = 0
    samples_paused: int = 0  # screened while collection was paused (armed, flying, calibration/pause)
    merge_disagreements: int = 0  # poses at a held orientation whose mean disagreed: kept apart

    # Counts of normal operation, not of faults (a person re-holding a face at a slightly different tilt
    # gives a merge disagreement; a flight gives paused samples).
    INFORMATIONAL: ClassVar[frozenset[str]] = frozenset({"samples", "samples_paused", "merge_disagreements"})

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def problems(self) -> int:
        return sum(v for k, v in self.as_dict().items() if k not in self.INFORMATIONAL)


class SampleScreen:
    """The screen's rules and what it carries from one part to the next (the last stamp, the clock, the
    runs of repeated values in progress, the frozen runs found)."""

    def __init__(self, settings: Settings, counters: Counters):
        self.accel_limit = SATURATION_FRACTION * settings.accel_range_mps2
        self.gyro_limit = settings.gyro_range_radps
        self.frozen_samples = settings.frozen_samples
        self.jump_ns = int(STAMP_JUMP_WINDOWS * settings.static_window_s * 1e9)
        self.counters = counters
        self.last_ns: int | None = None
        self.time_base = 0  # how many times the clock was re-synchronised
        self._previous_accel: tuple[float, float, float] | None = None
        self._previous_gyro: tuple[float, float, float] | None = None
        self._accel_run = 0  # identical accelerations so far in the current run (1 = just this one)
        self._gyro_run = 0
        self._run_start_ns = 0
        # (first, last, time base) stamps of frozen runs, newest last
        self.frozen_spans: list[tuple[int, int, int]] = []

    def overlaps_frozen(self, start_ns: int, end_ns: int, time_base: int | None = None) -> bool:
        """A frozen run on the clock `time_base` (default: the current one) overlaps start..end."""
        base = self.time_base if time_base is None else time_base
        return any(first <= end_ns and start_ns <= last and span_base == base
                   for first, last, span_base in self.frozen_spans)

    def screen_arrays(self, t_ns: np.ndarray, accel: np.ndarray, gyro: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rules over the next samples (arrival order): (mask of the samples that may reach the
        detector, mask of those before which the clock was re-synchronised); counters, frozen spans and
        the clock advanced. The same samples in any parts give the same masks and state."""
        c = self.counters
        n = len(t_ns)
        c.samples += n
        finite = np.all(np.isfinite(accel), axis=1) & np.all(np.isfinite(gyro), axis=1)
        c.non_finite += int(n - np.count_nonzero(finite))
        zero = finite & np.all(accel == 0.0, axis=1)
        c.zero_accel += int(np.count_nonzero(zero))
        in_order, restart = self._stamp_rule(t_ns, np.flatnonzero(finite & ~zero))
        with np.errstate(invalid="ignore"):
            saturated = in_order & np.any(np.abs(accel) >= self.accel_limit, axis=1)
            gyro_bad = in_order & ~saturated & np.any(np.abs(gyro) > self.gyro_limit, axis=1)
        c.saturated += int(np.count_nonzero(saturated))
        c.gyro_out_of_range += int(np.count_nonzero(gyro_bad))
        candidate = np.flatnonzero(in_order & ~saturated & ~gyro_bad)
        keep = np.zeros(n, dtype=bool)
        keep[candidate] = True
        if len(candidate):
            # The clock each candidate is on: runs never continue across a re-synchronisation.
            base = self.time_base + np.cumsum(restart)[candidate]
            new_clock = np.ones(len(candidate), dtype=bool)
            new_clock[1:] = base[1:] != base[:-1]
            new_clock[0] = bool(base[0] != self.time_base)  # a jump forgets the last values
            accel_run, accel_start = self._runs(accel[candidate], new_clock, self._previous_accel, self._accel_run)
            gyro_run, _ = self._runs(gyro[candidate], new_clock, self._previous_gyro, self._gyro_run)
            frozen = accel_run >= self.frozen_samples
            keep[candidate[frozen]] = False
            c.frozen += int(np.count_nonzero(frozen))
            c.gyro_frozen += int(np.count_nonzero(~frozen & (gyro_run >= self.frozen_samples)))
            start_ns = np.where(accel_start >= 0, t_ns[candidate[np.maximum(accel_start, 0)]], self._run_start_ns)
            for first in np.unique(accel_start[frozen]):
                members = np.flatnonzero((accel_start == first) & frozen)
                last = members[-1]
                self.frozen_spans.append((int(start_ns[last]), int(t_ns[candidate[last]]), int(base[last])))
            last = len(candidate) - 1
            self._previous_accel = tuple(float(v) for v in accel[candidate[last]])  # type: ignore[assignment]
            self._previous_gyro = tuple(float(v) for v in gyro[candidate[last]])  # type: ignore[assignment]
            self._accel_run, self._gyro_run = int(accel_run[last]), int(gyro_run[last])
            self._run_start_ns = int(start_ns[last])
        self.time_base += int(np.count_nonzero(restart))
        return keep, restart

    @staticmethod
    def _runs(values: np.ndarray, new_clock: np.ndarray, previous: tuple[float, float, float] | None,
              previous_run: int) -> tuple[np.ndarray, np.ndarray]:
        """Per row: length of the run of identical rows it ends, and the index of the run's first row
        (-1 when the run began before these rows, continuing `previous`)."""
        count = len(values)
        same = np.zeros(count, dtype=bool)
        same[1:] = np.all(values[1:] == values[:-1], axis=1)
        if previous is not None:
            same[0] = bool(np.all(values[0] == np.array(previous)))
        same &= ~new_clock
        index = np.arange(count)
        run_start = np.maximum.accumulate(np.where(same, -1, index))
        carried = run_start < 0  # still the run that began before these rows
        run = np.where(carried, index + 1 + previous_run, index - run_start + 1)
        return run, run_start

    def _stamp_rule(self, t_ns: np.ndarray, usable: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The stamp rule over the usable rows: (in order, re-synchronised here). Sequential
        over stamp jumps, vectorised between them (chunks growing from _FIRST_CHUNK find the next one)."""
        n = len(t_ns)
        in_order = np.zeros(n, dtype=bool)
        restart = np.zeros(n, dtype=bool)
        stamps = t_ns[usable]
        last = self.last_ns
        position, chunk = 0, _FIRST_CHUNK
        while position < len(stamps):
            block = stamps[position:position + chunk]
            before = np.maximum.accumulate(np.concatenate(([_INT64_MIN if last is None else last], block[:-1])))
            # t < before - jump, without overflow where `before` is the no-stamp-yet sentinel
            jumps = (before != _INT64_MIN) & (block < np.maximum(before, _INT64_MIN + self.jump_ns) - self.jump_ns)
            if not jumps.any():
                in_order[usable[position:position + len(block)]] = block > before
                last = int(max(before[-1], block[-1]))
                position += len(block)
                chunk *= 2
                continue
            first = int(np.argmax(jumps))
            in_order[usable[position:position + first]] = block[:first] > before[:first]
            row = usable[position + first]
            in_order[row] = restart[row] = True
            self.counters.stamp_jumps += 1
            last = int(block[first])
            position += first + 1
            chunk = _FIRST_CHUNK
        self.counters.stamp_backwards += int(len(stamps) - np.count_nonzero(in_order[usable]))
        self.last_ns = last
        return in_order, restart
