"""Screening: which samples may reach the detector. The same rules per sample (live node) and over a
whole recording (replay), counted in one `Counters` record.

A sample is kept out of the calibration (it is still passed on, corrected, by the node) when
- any accel or gyro value is NaN or infinite (`non_finite`),
- its stamp does not increase over the last usable-stamped sample (`stamp_backwards`),
- an accel axis is at or beyond 99.5 % of full scale (`saturated`), or a gyro axis beyond its
  full scale (`gyro_out_of_range`): a finite 2e154 is as wrong as a NaN,
- it repeats the previous sample bit for bit `frozen_samples` times or more (`frozen`): a live
  MEMS part always shows noise, so a repeated value is a stuck driver or bus. Still intervals that
  overlap a frozen run are dropped as well (their variance was the frozen run's zero).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from .settings import Settings

SATURATION_FRACTION = 0.995


@dataclass
class Counters:
    """What the session set aside, by reason (one record for node, replay and diagnostics)."""

    samples: int = 0
    non_finite: int = 0
    stamp_backwards: int = 0
    saturated: int = 0
    gyro_out_of_range: int = 0
    frozen: int = 0
    frozen_poses_dropped: int = 0
    temperature_bad: int = 0
    temperature_stale: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def problems(self) -> int:
        return sum(v for k, v in self.as_dict().items() if k != "samples")


class SampleScreen:
    """Per-sample screening (plain floats, O(1)); `screen_arrays` is the same over arrays."""

    def __init__(self, settings: Settings, counters: Counters):
        self.accel_limit = SATURATION_FRACTION * settings.accel_range_mps2
        self.gyro_limit = settings.gyro_range_radps
        self.frozen_samples = settings.frozen_samples
        self.counters = counters
        self.last_ns: int | None = None
        self._previous: tuple[float, ...] | None = None
        self._run = 0  # identical samples so far in the current run (1 = just this one)
        self._run_start_ns = 0
        self.frozen_spans: list[tuple[int, int]] = []  # (first, last) stamps of frozen runs, newest last

    def check(self, t_ns: int, ax: float, ay: float, az: float, gx: float, gy: float, gz: float) -> bool:
        """True when the sample may reach the detector; otherwise counted under its reason."""
        c = self.counters
        c.samples += 1
        if not (math.isfinite(ax) and math.isfinite(ay) and math.isfinite(az)
                and math.isfinite(gx) and math.isfinite(gy) and math.isfinite(gz)):
            c.non_finite += 1
            return False
        last = self.last_ns
        if last is not None and t_ns <= last:
            c.stamp_backwards += 1
            return False
        self.last_ns = t_ns
        limit = self.accel_limit
        if abs(ax) >= limit or abs(ay) >= limit or abs(az) >= limit:
            c.saturated += 1
            return False
        limit = self.gyro_limit
        if abs(gx) > limit or abs(gy) > limit or abs(gz) > limit:
            c.gyro_out_of_range += 1
            return False
        values = (ax, ay, az, gx, gy, gz)
        if values == self._previous:
            self._run += 1
        else:
            self._previous, self._run, self._run_start_ns = values, 1, t_ns
        if self._run >= self.frozen_samples:
            c.frozen += 1
            if self._run == self.frozen_samples:
                self.frozen_spans.append((self._run_start_ns, t_ns))
                del self.frozen_spans[:-16]  # only recent runs can overlap a pose still to come
            else:
                self.frozen_spans[-1] = (self._run_start_ns, t_ns)
            return False
        return True

    def overlaps_frozen(self, start_ns: int, end_ns: int) -> bool:
        return any(first <= end_ns and start_ns <= last for first, last in self.frozen_spans)

    def screen_arrays(self, t_ns: np.ndarray, accel: np.ndarray, gyro: np.ndarray) -> np.ndarray:
        """The `check` rules over a whole recording in one go (fresh screen only): a mask of the
        samples that may reach the detector; counters and frozen spans as `check` leaves them."""
        c = self.counters
        n = len(t_ns)
        c.samples += n
        finite = np.all(np.isfinite(accel), axis=1) & np.all(np.isfinite(gyro), axis=1)
        c.non_finite += int(n - np.count_nonzero(finite))
        # A finite sample passes the stamp rule when it is later than every finite sample before it.
        stamps = np.where(finite, t_ns, np.iinfo(np.int64).min)
        previous_max = np.maximum.accumulate(np.concatenate(([np.iinfo(np.int64).min], stamps[:-1])))
        in_order = finite & (t_ns > previous_max)
        c.stamp_backwards += int(np.count_nonzero(finite & ~in_order))
        if np.any(in_order):
            self.last_ns = int(t_ns[in_order][-1])
        with np.errstate(invalid="ignore"):
            saturated = in_order & np.any(np.abs(accel) >= self.accel_limit, axis=1)
            gyro_bad = in_order & ~saturated & np.any(np.abs(gyro) > self.gyro_limit, axis=1)
        c.saturated += int(np.count_nonzero(saturated))
        c.gyro_out_of_range += int(np.count_nonzero(gyro_bad))
        candidate = np.flatnonzero(in_order & ~saturated & ~gyro_bad)
        keep = np.zeros(n, dtype=bool)
        keep[candidate] = True
        if len(candidate):
            values = np.hstack([accel[candidate], gyro[candidate]])
            same = np.zeros(len(candidate), dtype=bool)
            same[1:] = np.all(values[1:] == values[:-1], axis=1)
            run_start = np.maximum.accumulate(np.where(same, 0, np.arange(len(candidate))))
            run_length = np.arange(len(candidate)) - run_start + 1
            frozen = run_length >= self.frozen_samples
            keep[candidate[frozen]] = False
            c.frozen += int(np.count_nonzero(frozen))
            for first in np.unique(run_start[frozen]):
                members = candidate[(run_start == first) & frozen]
                self.frozen_spans.append((int(t_ns[candidate[first]]), int(t_ns[members[-1]])))
            if len(candidate):
                last = len(candidate) - 1
                self._previous = tuple(float(v) for v in values[last])
                self._run = int(run_length[last])
                self._run_start_ns = int(t_ns[candidate[run_start[last]]])
        return keep
