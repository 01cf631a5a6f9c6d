"""The node learns a warm-up: while the sensor is still and its temperature changes, the still samples are
binned by temperature (accelerometer and gyro, raw, in bounded memory); /diagnostics says the span so far and
what is still missing, and /calibrate adds the curves replay --warmup fits (core/warmup.fit_binned_warmup,
the same fit) on top of the calibration it applies or the one in force.

Only samples inside the detector's still intervals (its poses, and at /calibrate the hold in progress) are
binned: the samples wait here until the detector has judged them. Their temperature is the session's filter
on the readings (held, stale after temperature_timeout_s). A reading far off the trend (a jump, a glitch) is
left out with the samples it would label; readings that stay at a new level for SETTLE_S are believed and
start a run of their own (it is tied to the others only where their temperatures meet, core/warmup).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from ..core.answers import yaml_quoted
from ..core.calibration import Calibration
from ..core.gates import QualityGates
from ..core.pose import Pose
from ..core.stream.temperature_filter import TemperatureFilter
from ..core.warmup import (
    ORIENTATION_DEG,
    PASS_RATE,
    BinnedWarmup,
    Run,
    WarmupOptions,
    WarmupResult,
    fit_binned_warmup,
    warmup_calibration,
)

__all__ = ["WarmupWatch"]

JUMP_DEGC = 2.0  # a reading this far from the last good one (beyond MAX_RATE_DEGC_S since it) is off the trend
MAX_RATE_DEGC_S = 1.0  # faster than any warm-up of a powered board
SETTLE_S = 5.0  # readings agreeing at a new level this long are the temperature again: a run of its own
RATE_WINDOW_S = 10.0  # the heating rate (warming or cooling pass) over this much of the filtered temperature
# Samples wait until the detector has judged them: a pose is cut at 60 s, ends a window after its last
# sample, and a live part waits 1 s for its temperature readings.
KEEP_S = 75.0
STEADY_S = 60.0  # still this long within STEADY_DEGC: the temperature is steady, no warm-up
STEADY_DEGC = 0.5
MAX_RUNS = 8  # runs (orientation x temperature level) kept; beyond, the one of fewest samples is dropped, said
BLOCK_ROWS = 16_384
_COLUMNS = 27  # count, sum degC, sum rate, accel sum (3) and products (9), gyro sum (3) and products (9)


@dataclass(eq=False)
class _Run:
    """One orientation at one temperature level: its bins' sums about `shift` (numerically safe)."""

    epoch: int
    direction: np.ndarray  # gravity's direction at its latest samples
    shift: np.ndarray  # (6,) the first sample's accel and gyro
    start_ns: int
    end_ns: int
    bins: dict[int, np.ndarray] = field(default_factory=dict)  # key -> (_COLUMNS,) sums


class WarmupWatch:
    def __init__(self, temperature_timeout_s: float, options: WarmupOptions | None = None):
        self.options = options or WarmupOptions()
        self._timeout_s = temperature_timeout_s
        self.reset()

    def reset(self) -> None:
        """Drop everything collected (calibration/reset)."""
        self._chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # samples not yet judged
        self._history: list[tuple[np.ndarray, np.ndarray, int]] = []  # filtered readings, their epoch
        self._filter = TemperatureFilter(self._timeout_s)
        self._good: tuple[int, float] | None = None  # the last reading on the trend (stamp, degC)
        self._pending: list[tuple[int, float]] = []  # readings off the trend, agreeing among themselves
        self._off_trend: list[int] = []  # their stamps: a sample labelled by a reading before one is left out
        self._epoch = 0
        self._runs: list[_Run] = []
        self._binned_until = -(2**62)
        self._origin_ns: int | None = None
        self.readings = 0
        self.readings_not_finite = 0
        self.readings_off_trend = 0
        self.jumps: list[str] = []
        self.still_binned = 0
        self.still_without_temperature = 0
        self.runs_dropped = 0

    # ------------------------------------------------------------------ what comes in
    def add_readings(self, stamps_ns: np.ndarray, degc: np.ndarray) -> None:
        order = np.argsort(stamps_ns, kind="stable")
        stamps, values = np.asarray(stamps_ns, np.int64)[order], np.asarray(degc, float)[order]
        self.readings += len(values)
        finite = np.isfinite(values)
        self.readings_not_finite += int(np.count_nonzero(~finite))
        good_t: list[int] = []
        good_v: list[float] = []
        for stamp, value in zip(stamps[finite].tolist(), values[finite].tolist()):
            if self._on_trend(stamp, value):
                good_t.append(stamp)
                good_v.append(value)
            elif self._settled(stamp, value):  # a lasting jump: the new level is the temperature now
                self._take_filtered(good_t, good_v)
                good_t, good_v = [stamp], [value]
        self._take_filtered(good_t, good_v)

    def _on_trend(self, stamp: int, value: float) -> bool:
        if self._good is not None:
            allowed = JUMP_DEGC + MAX_RATE_DEGC_S * max(stamp - self._good[0], 0) * 1e-9
            if abs(value - self._good[1]) > allowed:
                self.readings_off_trend += 1
                self._off_trend.append(stamp)
                return False
        self._good, self._pending = (stamp, value), []
        return True

    def _settled(self, stamp: int, value: float) -> bool:
        """An off-trend reading: kept pending; once readings agree at the new level for SETTLE_S, believed."""
        pending = [(t, v) for t, v in self._pending if abs(v - value) <= JUMP_DEGC] + [(stamp, value)]
        self._pending = pending
        if (stamp - pending[0][0]) * 1e-9 < SETTLE_S:
            return False
        assert self._good is not None
        self.jumps.append(f"temperature reading jumped {self._good[1]:.1f} -> {value:.1f} degC at "
                          f"{self._seconds(pending[0][0]):.1f} s")
        self._epoch += 1
        self._filter = TemperatureFilter(self._timeout_s)  # not filtered across the jump
        self._good, self._pending = (stamp, value), []
        return True

    def _take_filtered(self, stamps: list[int], values: list[float]) -> None:
        if not stamps:
            return
        kept, filtered = self._filter.take(np.array(stamps, np.int64), np.array(values))
        last = self._history[-1][0][-1] if self._history and self._history[-1][2] == self._epoch else None
        new = kept > last if last is not None else np.ones(len(kept), bool)
        if np.any(new):
            self._history.append((kept[new], filtered[new], self._epoch))

    def add_samples(self, t_ns: np.ndarray, accel_mps2: np.ndarray, gyro_radps: np.ndarray) -> None:
        """Raw samples: kept until the detector has judged them (KEEP_S)."""
        if not len(t_ns):
            return
        if self._origin_ns is None:
            self._origin_ns = int(t_ns[0])
        self._chunks.append((np.asarray(t_ns, np.int64), np.asarray(accel_mps2, float),
                             np.asarray(gyro_radps, float)))

    def add_still(self, poses: list[Pose]) -> None:
        """The detector's still intervals (after each feed, none too): their samples not binned yet go into
        the bins; then what no interval can still claim is let go."""
        for pose in sorted(poses, key=lambda p: p.start_ns):
            self._bin_interval(pose)
        self._prune()

    def _prune(self) -> None:
        """Samples binned, or older than KEEP_S; readings older than the rate window and the timeout before
        the oldest sample kept (its temperature and heating rate read them)."""
        if not self._chunks:
            return
        newest = int(self._chunks[-1][0][-1])
        cutoff = max(newest - int(KEEP_S * 1e9), self._binned_until)
        self._chunks = [chunk for chunk in self._chunks if chunk[0][-1] > cutoff]
        first = int(self._chunks[0][0][0]) if self._chunks else newest
        oldest = first - int((RATE_WINDOW_S + self._timeout_s) * 1e9)
        self._history = [entry for entry in self._history if entry[0][-1] >= oldest] or self._history[-1:]
        self._off_trend = [stamp for stamp in self._off_trend if stamp >= oldest]

    # ------------------------------------------------------------------ binning
    def _bin_interval(self, pose: Pose) -> None:
        start = max(pose.start_ns, self._binned_until + 1)
        if pose.end_ns < start:
            return
        parts = [(t[(t >= start) & (t <= pose.end_ns)], a[(t >= start) & (t <= pose.end_ns)],
                  g[(t >= start) & (t <= pose.end_ns)]) for t, a, g in self._chunks]
        self._binned_until = pose.end_ns
        t = np.concatenate([p[0] for p in parts]) if parts else np.zeros(0, np.int64)
        if not len(t):
            return
        values = np.hstack([np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])])
        degc, rate, epoch = self._temperature_at(t)
        known = np.isfinite(degc)
        self.still_without_temperature += int(np.count_nonzero(~known))
        direction = pose.accel_mps2 / np.linalg.norm(pose.accel_mps2)
        for level in np.unique(epoch[known]).tolist():
            rows = known & (epoch == level)
            run = self._run_for(int(level), direction, values[rows][0], int(t[rows][0]))
            run.end_ns = int(t[rows][-1])
            self._accumulate(run, degc[rows], rate[rows], values[rows])
            self.still_binned += int(np.count_nonzero(rows))

    def _temperature_at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The held filtered temperature (NaN: none, stale, or a reading off the trend came since), its
        heating rate (degC/s over RATE_WINDOW_S of its level) and the epoch (temperature level) of each sample."""
        degc, rate, epoch = np.full(len(t), np.nan), np.zeros(len(t)), np.full(len(t), -1)
        if not self._history:
            return degc, rate, epoch
        stamps = np.concatenate([entry[0] for entry in self._history])
        values = np.concatenate([entry[1] for entry in self._history])
        levels = np.concatenate([np.full(len(entry[0]), entry[2]) for entry in self._history])
        index = np.searchsorted(stamps, t, side="right") - 1
        held = np.clip(index, 0, None)
        off = np.array(self._off_trend, dtype=np.int64)
        fresh = (index >= 0) & (t - stamps[held] <= int(self._timeout_s * 1e9)) & (
            np.searchsorted(off, t, side="right") == np.searchsorted(off, stamps[held], side="right"))
        degc[fresh], epoch[fresh] = values[held[fresh]], levels[held[fresh]]
        for level in np.unique(epoch[fresh]).tolist():
            at, mine = epoch == level, levels == level
            # Over the readings before each sample only: the rate must not depend on what came after it.
            since = (t[at] - stamps[mine][0]) * 1e-9
            window = np.minimum(RATE_WINDOW_S, since)
            before = np.interp(since - window, (stamps[mine] - stamps[mine][0]) * 1e-9, values[mine])
            rate[at] = np.where(window >= 1.0, (degc[at] - before) / np.maximum(window, 1.0), 0.0)
        return degc, rate, epoch

    def _run_for(self, epoch: int, direction: np.ndarray, first: np.ndarray, start_ns: int) -> _Run:
        """The run these samples belong to: the one at their orientation (within ORIENTATION_DEG of its
        latest samples: a bias drifting over a long warm-up turns gravity's direction slowly, a turn of the
        sensor does not) and temperature level (core/warmup joins a stretch at one orientation after a
        motion alike: one turn-on), else a new one; beyond MAX_RUNS the run of fewest samples gives way."""
        for run in self._runs:
            if run.epoch == epoch and float(np.dot(run.direction, direction)) > np.cos(np.radians(ORIENTATION_DEG)):
                run.direction = direction
                return run
        if len(self._runs) >= MAX_RUNS:
            counts = [sum(row[0] for row in run.bins.values()) for run in self._runs]
            del self._runs[int(np.argmin(counts))]
            self.runs_dropped += 1
        self._runs.append(_Run(epoch, direction, first.copy(), start_ns, start_ns))
        return self._runs[-1]

    def _accumulate(self, run: _Run, degc: np.ndarray, rate: np.ndarray, values: np.ndarray) -> None:
        """Sums per bin of bin_degc, warming and cooling apart (core/warmup bins by pass), a block of
        BLOCK_ROWS samples at a time (a minute's pose at 4 kHz is 240,000 samples)."""
        for start in range(0, len(degc), BLOCK_ROWS):
            block = slice(start, start + BLOCK_ROWS)
            key = np.floor(degc[block] / self.options.bin_degc).astype(np.int64) * 2 + (rate[block] <= -PASS_RATE)
            centred = values[block] - run.shift
            accel, gyro = centred[:, :3], centred[:, 3:]
            columns = np.hstack([np.ones((len(key), 1)), degc[block, None], rate[block, None], accel,
                                 (accel[:, :, None] * accel[:, None, :]).reshape(-1, 9), gyro,
                                 (gyro[:, :, None] * gyro[:, None, :]).reshape(-1, 9)])
            keys, inverse = np.unique(key, return_inverse=True)
            sums = np.stack([np.bincount(inverse, columns[:, c], len(keys)) for c in range(_COLUMNS)], axis=1)
            for k, row in zip(keys.tolist(), sums):
                run.bins[k] = run.bins[k] + row if k in run.bins else row

    # ------------------------------------------------------------------ what it says and fits
    def _binned(self, calibration: Calibration | None) -> BinnedWarmup:
        """The bins as core/warmup takes them, in the frame `calibration` corrects to (its temperature part
        left out: the warm-up's curves replace it)."""
        base = Calibration.identity() if calibration is None else calibration.replace(temperature=None)
        gyro_matrix = np.eye(3) if base.gyro_matrix is None else base.gyro_matrix
        parts, runs, directions = [], [], []
        for index, run in enumerate(self._runs):
            sums = np.array([run.bins[k] for k in sorted(run.bins)]).reshape(-1, _COLUMNS)
            n = sums[:, 0]
            means = sums[:, [3, 4, 5, 15, 16, 17]] / n[:, None]
            cov_a = sums[:, 6:15].reshape(-1, 3, 3) / n[:, None, None] - means[:, :3, None] * means[:, None, :3]
            cov_g = sums[:, 18:27].reshape(-1, 3, 3) / n[:, None, None] - means[:, 3:, None] * means[:, None, 3:]
            unbiased = (n / np.maximum(n - 1, 1))[:, None, None]
            accel = base.apply(means[:, :3] + run.shift[:3])
            gyro = base.apply_gyro(means[:, 3:] + run.shift[3:])
            errors_a = np.sqrt(np.maximum(np.einsum("ij,bjk,ik->bi", base.matrix, cov_a * unbiased, base.matrix), 0)
                               / n[:, None])
            errors_g = np.sqrt(np.maximum(np.einsum("ij,bjk,ik->bi", gyro_matrix, cov_g * unbiased, gyro_matrix), 0)
                               / n[:, None])
            degc = sums[:, 1] / n
            kept = degc[n >= self.options.min_bin_samples]
            span = (float(kept.min()), float(kept.max())) if len(kept) else (float(degc.min()), float(degc.min()))
            runs.append(Run(0, run.start_ns - (self._origin_ns or 0), run.end_ns - (self._origin_ns or 0), span))
            directions.append(run.direction)
            parts.append((degc, sums[:, 2] / n, np.full(len(n), index), n, accel, errors_a, gyro, errors_g))
        joined = [np.concatenate([p[i] for p in parts]) if parts else np.zeros((0, 3) if i in (4, 5, 6, 7) else 0)
                  for i in range(8)]
        return BinnedWarmup(joined[0], joined[1], joined[2].astype(np.int64), joined[3], (joined[4], joined[5]),
                            (joined[6], joined[7]), tuple(runs), tuple(directions))

    def span(self) -> tuple[float, float] | None:
        """The temperatures the still samples cover (bins with enough samples), over every run."""
        degc = [row[1] / row[0] for run in self._runs for row in run.bins.values()
                if row[0] >= self.options.min_bin_samples]
        return (min(degc), max(degc)) if degc else None

    def fit(self, calibration: Calibration | None, reference_degc: float | None = None) -> WarmupResult:
        options = self.options if reference_degc is None else replace(self.options, reference_degc=reference_degc)
        return fit_binned_warmup(self._binned(calibration), calibration, options)

    def _seconds(self, stamp_ns: int) -> float:
        return (stamp_ns - (self._origin_ns if self._origin_ns is not None else stamp_ns)) * 1e-9

    def state(self, still: bool) -> str:
        """What the warm-up is so far, and what it still needs, one line."""
        span, needed = self.span(), self.options.min_span_degc
        if self.readings == 0:
            text = "no warm-up: no Temperature messages (a warm-up's curves need the sensor's temperature)"
        elif self.readings_not_finite == self.readings:
            text = f"no warm-up: the {self.readings} temperature readings are not numbers (NaN or Inf)"
        elif span is None:
            text = ("no warm-up yet: " + ("still; the still samples wait for the detector's interval"
                                           if still else "the sensor is moving (only still samples count)"))
            if self.still_without_temperature:
                text += f"; {self.still_without_temperature} still samples had no fresh temperature"
        elif span[1] - span[0] >= needed:
            text = f"ready: /calibrate adds the temperature curves over {span[0]:.1f}..{span[1]:.1f} degC"
        elif span[1] - span[0] < STEADY_DEGC and self.still_binned_s() >= STEADY_S:
            text = (f"no warm-up: the temperature is steady at {0.5 * (span[0] + span[1]):.1f} degC over "
                    f"{self.still_binned_s():.0f} s still (a frozen register reads so too); a warm-up needs "
                    f"{needed:g} degC of span")
        else:
            text = f"collecting: needs {needed:g} degC of span, has {span[1] - span[0]:.1f}" + (
                "" if still else " (the sensor is moving: only still samples count)")
        if self.jumps:
            text += (f"; {self.jumps[-1]} ({len(self.jumps)} jump(s); the readings off the trend left out, the "
                     "new level a run of its own)")
        elif self.readings_off_trend:
            text += f"; {self.readings_off_trend} temperature readings off the trend left out"
        if self.runs_dropped:
            text += f"; {self.runs_dropped} short still runs dropped (of other orientations: {MAX_RUNS} are kept)"
        return text

    def still_binned_s(self) -> float:
        return sum((run.end_ns - run.start_ns) * 1e-9 for run in self._runs)

    def values(self, still: bool) -> dict[str, str]:
        """The diagnostics' warm-up values."""
        span = self.span()
        bins = sum(1 for run in self._runs for row in run.bins.values() if row[0] >= self.options.min_bin_samples)
        return {"warmup": self.state(still),
                "warmup_span_degc": "" if span is None else f"{span[0]:.1f}..{span[1]:.1f}",
                "warmup_bins": "" if not self._runs else
                f"{bins} bins of {self.options.bin_degc:g} degC, {self.still_binned} still samples, "
                f"{len(self._runs)} run(s)"}

    def collected(self) -> bool:
        """Whether there is a warm-up to speak of: temperature readings came (else /calibrate says nothing of it)."""
        return self.readings > 0

    def added(self, calibration: Calibration | None, gates: QualityGates, poses: Sequence[Pose] = ()
              ) -> tuple[Calibration | None, str]:
        """`calibration` (None: the raw output) with the warm-up's curves as its temperature model, and the
        /calibrate answer's line on it; None and the reason when none is added (and "" when nothing was
        collected: no warm-up to speak of). `poses`: those `calibration` was fitted from: its bias is theirs
        at their mean temperature, where the curves are zero (else its own reference, else the middle)."""
        if not self.collected():
            return None, ""
        if not self._runs:
            return None, _line(self.state(still=False))
        if calibration is not None and calibration.temperature is not None and calibration.temperature.kind != "spline":
            return None, _line(f"the calibration has a {calibration.temperature.kind} temperature model (poses at "
                               "several temperatures); the warm-up's curves are not added")
        result = self.fit(calibration, _poses_degc(calibration, poses))
        if result.fit is None:
            return None, _line(result.refusal or "warm-up: no curve")
        added = warmup_calibration(result.fit, calibration)
        loadable, left_aside = gates.loadable(added)
        if loadable is None or left_aside is not None:
            why = left_aside or "it fails the plausibility gates over its temperature range"
            return None, _line(f"the calibration with the warm-up's curves is not applied: {why}")
        low, high = result.fit.range_degc
        said = "; ".join(line.strip() for line in result.said)
        return added, (f"warmup: {{added: true, range_degc: [{low:.2f}, {high:.2f}], reference_degc: "
                       f"{result.fit.reference_degc:.2f}, bins: {result.fit.bins}, held_flat_outside: true, "
                       f"said: {yaml_quoted(said)}}}")


def _poses_degc(calibration: Calibration | None, poses: Sequence[Pose]) -> float | None:
    """Where a calibration fitted from `poses` holds: its own reference temperature, else the poses' mean
    temperature (their median: the many orientations held at one temperature decide the bias, not a few poses
    held while it warmed), None when neither is known."""
    if calibration is not None and calibration.reference_temperature_degc is not None:
        return calibration.reference_temperature_degc
    degc = [pose.temperature_degc for pose in poses if pose.temperature_degc is not None]
    return float(np.median(degc)) if degc else None


def _line(reason: str) -> str:
    """The answer's line when no temperature model was added."""
    return f"warmup: {{added: false, reason: {yaml_quoted(reason)}}}"
