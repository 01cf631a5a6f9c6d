"""The temperature a sample is corrected and a pose is stamped with, from a slow temperature topic.

Sensor temperature registers update slowly and are quantised: readings are checked, low-pass
filtered (first order, tau 0.5 s of header time; a real warm-up moves < 0.1 degC/s, so the lag is
under 0.05 degC) and held until the next one; older than `timeout_s` they are stale and not used.
Readings come in batches (a recording whole, or the node's as they arrive): in any batching, the same
numbers to rounding (a scan over the batch: < 1e-12 degC).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

TAU_S = 0.5
PLAUSIBLE_DEGC = (-60.0, 150.0)


class TemperatureFilter:
    def __init__(self, timeout_s: float = 5.0) -> None:
        self.timeout_ns = int(timeout_s * 1e9)
        self.value: float | None = None
        self.stamp_ns = -1
        self.rejected = 0

    def series(self, stamps_ns: ArrayLike, degc: ArrayLike, sample_t_ns: ArrayLike) -> tuple[np.ndarray, int]:
        """For a recording (or the next part of one): the held filtered temperature at each sample stamp
        (NaN when missing or older than the timeout) and how many samples were stale. Readings are taken
        in stamp order after those already taken (the value held from them serves samples before the first
        new one)."""
        return self.held_at(*self.take(stamps_ns, degc), sample_t_ns)

    def take(self, stamps_ns: ArrayLike, degc: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """The first half of `series`: take the readings (state and `rejected` as series leaves them) and
        return the values held from them, (stamps, filtered values) in stamp order, the value held before
        first; empty when none is held. A caller asking for many stamps at different times looks them up
        with `held_at` without filtering the readings again."""
        order = np.argsort(stamps_ns, kind="stable")
        stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)[order]
        values = np.asarray(degc, dtype=float).reshape(-1)[order]
        plausible = np.isfinite(values) & (values > PLAUSIBLE_DEGC[0]) & (values < PLAUSIBLE_DEGC[1])
        self.rejected += int(len(values) - np.count_nonzero(plausible))
        kept, readings = stamps[plausible], values[plausible]
        held = self.value is not None  # from readings taken before
        if len(kept):
            filtered = self._filter(kept, readings)
            if held and self.stamp_ns <= kept[0]:  # (a reading older than the held one: in stamp order)
                kept = np.concatenate([[self.stamp_ns], kept])
                filtered = np.concatenate([[self.value], filtered])
            self.value, self.stamp_ns = float(filtered[-1]), int(kept[-1])
            return kept, filtered
        if held:
            return np.array([self.stamp_ns], dtype=np.int64), np.array([self.value])
        return np.zeros(0, np.int64), np.zeros(0)

    def held_at(self, stamps: np.ndarray, filtered: np.ndarray, sample_t_ns: ArrayLike) -> tuple[np.ndarray, int]:
        """The second half of `series`: the value held at each sample stamp from `take`'s (stamps, filtered
        values), NaN when none or stale, and how many samples were stale."""
        sample_t_ns = np.asarray(sample_t_ns, dtype=np.int64)
        out = np.full(len(sample_t_ns), np.nan)
        if not len(stamps):
            return out, 0
        index = np.searchsorted(stamps, sample_t_ns, side="right") - 1
        have = index >= 0
        fresh = have & (sample_t_ns - stamps[np.clip(index, 0, None)] <= self.timeout_ns)
        out[fresh] = filtered[index[fresh]]
        return out, int(np.count_nonzero(have & ~fresh))

    def _filter(self, stamps: np.ndarray, readings: np.ndarray) -> np.ndarray:
        """The filtered value after each (plausible, stamp-ordered) reading.

        The filter is the affine step v_k = (1 - a_k) v_(k-1) + a_k x_k, a_k = dt / (TAU_S + dt) (a reading
        after no state, or after one with a negative stamp, starts afresh: factor 0). Steps compose into
        steps, so all prefixes are found in log2(n) array passes (a Hillis-Steele scan), about the first
        reading so the terms stay small; factors are products of numbers in [0, 1], so nothing overflows.
        """
        previous = np.concatenate([[self.stamp_ns], stamps[:-1]])
        dt = np.maximum(0.0, (stamps - previous) * 1e-9)
        gain = dt / (TAU_S + dt)
        fresh_start = previous < 0
        if self.value is None:
            fresh_start[0] = True
        reference = readings[0]
        factor = np.where(fresh_start, 0.0, 1.0 - gain)
        offset = np.where(fresh_start, readings - reference, gain * (readings - reference))
        shift = 1
        while shift < len(readings):
            # Compose each step with the one `shift` before it: (f, o) after (f', o') = (f f', f o' + o).
            offset[shift:] = factor[shift:] * offset[:-shift] + offset[shift:]
            factor[shift:] = factor[shift:] * factor[:-shift]
            shift *= 2
        start = 0.0 if self.value is None else self.value - reference
        return np.asarray(reference + (factor * start + offset))
