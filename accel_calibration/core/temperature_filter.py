"""The temperature a sample is corrected and a pose is stamped with, from a slow temperature topic.

Sensor temperature registers update slowly and are quantised: readings are checked, low-pass
filtered (first order, tau 0.5 s of header time; a real warm-up moves < 0.1 degC/s, so the lag is
under 0.05 degC) and held until the next one; older than `timeout_s` they are stale and not used.
The live node feeds it message by message, replay a whole recording: same numbers either way.
"""
from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

TAU_S = 0.5
PLAUSIBLE_DEGC = (-60.0, 150.0)


class TemperatureFilter:
    def __init__(self, timeout_s: float = 5.0):
        self.timeout_ns = int(timeout_s * 1e9)
        self.value: float | None = None
        self.stamp_ns = -1
        self.rejected = 0

    def update(self, stamp_ns: int, degc: float) -> bool:
        """Take one reading; False (and counted) when it is not a plausible temperature."""
        if not (math.isfinite(degc) and PLAUSIBLE_DEGC[0] < degc < PLAUSIBLE_DEGC[1]):
            self.rejected += 1
            return False
        if self.value is None or self.stamp_ns < 0:
            self.value = degc
        else:
            dt = max(0.0, (stamp_ns - self.stamp_ns) * 1e-9)
            self.value += dt / (TAU_S + dt) * (degc - self.value)
        self.stamp_ns = stamp_ns
        return True

    def at(self, t_ns: int) -> float | None:
        """The filtered temperature for a sample at t_ns, or None when missing or stale."""
        if self.value is None or t_ns - self.stamp_ns > self.timeout_ns:
            return None
        return self.value

    def series(self, stamps_ns: ArrayLike, degc: ArrayLike, sample_t_ns: ArrayLike) -> tuple[np.ndarray, int]:
        """For a recording: the held filtered temperature at each sample stamp (NaN when missing or
        stale, as `at` says) and how many samples were stale. Readings are taken in stamp order."""
        order = np.argsort(stamps_ns, kind="stable")
        stamps = np.asarray(stamps_ns, dtype=np.int64)[order]
        values = np.asarray(degc, dtype=float)[order]
        kept_stamps, filtered = [], []
        for stamp, value in zip(stamps.tolist(), values.tolist()):
            if self.update(stamp, value):
                kept_stamps.append(stamp)
                filtered.append(self.value)
        sample_t_ns = np.asarray(sample_t_ns, dtype=np.int64)
        out = np.full(len(sample_t_ns), np.nan)
        if not kept_stamps:
            return out, 0
        kept = np.array(kept_stamps, dtype=np.int64)
        index = np.searchsorted(kept, sample_t_ns, side="right") - 1
        have = index >= 0
        fresh = have & (sample_t_ns - kept[np.clip(index, 0, None)] <= self.timeout_ns)
        out[fresh] = np.array(filtered)[index[fresh]]
        return out, int(np.count_nonzero(have & ~fresh))
