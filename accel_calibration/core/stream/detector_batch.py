"""The static detector's rules over arrays, in parts of a recording of any length: window membership from
timestamps, window variances against a noise floor that cannot learn flight vibration, the interval rules
(warm-up adoption, trims, gaps, max_pose_s cuts). The detector's settings are a frozen `DetectorConfig`;
what it carries between parts (floors, quietest floors, warm-up, the rows an open interval and the next
windows need) is a `DetectorState` this module owns.

The rules (what a per-sample detector would do, stated once):
- a sample with a NaN/inf or a value beyond `accel_limit` / `gyro_limit` (always beyond HARD_LIMIT, where
  squares and sums could overflow), or a stamp not after the last accepted one, is skipped and counted;
- a window is the samples of the last `window_s` of stream time; it is full when it spans 0.9 window_s and
  holds 5 samples; a hole longer than a window ends the interval in progress and starts a new window;
- a full window is still when its variance (sum of the axes) is below k_sigma x the learned floor (gyro
  likewise), the floor bounded by max_floor_rise^2 x the quietest floor seen after warm-up and by the
  noise ceilings; a window mostly of repeated samples, or whose mean is no gravity, never feeds the floor;
- until the floor is warm, a provisional interval is kept and adopted if the warm-up's loudest windows
  pass the first threshold known;
- an interval ends when motion starts (trim_s dropped at both ends), at max_pose_s, or at the end of the
  recording (not trimmed there); it is a Pose when it lasted min_hold_s.

Window sums are not differences of cumulative sums over the whole recording: one large value would
leave its rounding in every later difference (and a value beyond ~1e154 makes them inf - inf = NaN),
so the rest of the recording would be lost. Each window is split at a block boundary into the end of
one block and the start of the next (plus whole blocks between, for an unusually long window), each
summed within its block only, so a window's sums hold nothing but its own samples. Parts cut elsewhere
give other blocks: window variances then differ by rounding (~1e-12 relative), never the pose sums,
which are elementwise numpy over the pose's own rows (no BLAS).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from ..errors import CalibrationError
from ..pose import Pose
from .noise_floor import FloorConfig, VarianceFloor

# Largest magnitude accepted on any axis (and for temperature) whatever the limits: its squares, summed
# over any window, stay far from overflow. Beyond it a sample is rejected (a temperature: ignored).
HARD_LIMIT = 1e12


def _positive(name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise CalibrationError(f"{name} must be a positive number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class DetectorConfig:
    """The detector's settings, checked once (a bad one raises CalibrationError naming it). Times in
    seconds of the stream's own clock.

      window_s: sliding window for the variance test.
      min_hold_s: shortest still interval kept as a pose.
      accel_var_threshold: explicit threshold on the window's total acceleration variance (sum of the
        three axes, input units squared); None = k_sigma * learned noise floor.
      gyro_var_threshold: same for the gyro (rad/s)^2; None = learned. Used only when gyro samples come.
      k_sigma: accel threshold as a multiple of the noise-floor variance.
      gyro_k_sigma: gyro threshold multiple. Looser: MEMS gyro noise is far less steady than the
        accelerometer's (a hand-held still pose varies 10-100x above the quietest windows), while
        rotation raises it 1000x and more.
      noise_quantile: quantile of window variances taken as the noise floor (the fraction of time the
        sensor must be still for the floor to be right).
      warmup_s: stream time of full windows needed before the learned floor is trusted.
      trim_s: dropped from both ends of each interval (None: window_s / 2).
      max_pose_s: a longer still interval is cut into poses of this length (tracks temperature drift).
      accel_limit, gyro_limit: largest absolute value per axis the sensor can read (input units); a
        sample beyond it is a glitch, skipped and counted. None = no limit but HARD_LIMIT.
      max_floor_rise: the learned floors may rise at most this factor (rms) above the quietest floor seen
        after warm-up: hours of flight vibration are never learned as noise.
      accel_noise_ceiling, gyro_noise_ceiling: largest noise (rms per axis, input units) of a still
        window; None = no ceiling (the unit is not known here; the session sets them in SI).
      floor_min_magnitude: smallest |mean acceleration| of a window that may teach the floor (input
        units; the session: 0.05 g): a dead sensor's quiet zeros must not become the quietest floor.
    """

    window_s: float = 0.5
    min_hold_s: float = 1.0
    accel_var_threshold: float | None = None
    gyro_var_threshold: float | None = None
    k_sigma: float = 6.0
    gyro_k_sigma: float = 300.0
    noise_quantile: float = 0.05
    warmup_s: float = 2.0
    trim_s: float | None = None
    max_pose_s: float = 60.0
    accel_limit: float | None = None
    gyro_limit: float | None = None
    max_floor_rise: float = 1.5
    accel_noise_ceiling: float | None = None
    gyro_noise_ceiling: float | None = None
    floor_min_magnitude: float | None = None

    def __post_init__(self) -> None:
        def put(name: str, value: object) -> None:
            object.__setattr__(self, name, value)

        for name in ("window_s", "min_hold_s", "k_sigma", "gyro_k_sigma", "warmup_s", "max_pose_s",
                     "max_floor_rise"):
            put(name, _positive(name, getattr(self, name)))
        for name in ("accel_var_threshold", "gyro_var_threshold", "accel_limit", "gyro_limit",
                     "accel_noise_ceiling", "gyro_noise_ceiling", "floor_min_magnitude"):
            if getattr(self, name) is not None:
                put(name, _positive(name, getattr(self, name)))
        trim = self.window_s / 2 if self.trim_s is None else self.trim_s
        if isinstance(trim, bool) or not isinstance(trim, (int, float)) or not 0.0 <= trim < self.min_hold_s:
            raise CalibrationError(f"trim_s must be in [0, min_hold_s), got {self.trim_s!r}")
        put("trim_s", float(trim))
        if self.max_pose_s < self.min_hold_s:
            raise CalibrationError("max_pose_s must be at least min_hold_s")
        if not (isinstance(self.noise_quantile, float) and 0.0 < self.noise_quantile < 0.5):
            raise CalibrationError(f"noise_quantile must be in (0, 0.5), got {self.noise_quantile!r}")
        if self.max_floor_rise < 1.0:
            raise CalibrationError(f"max_floor_rise must be at least 1, got {self.max_floor_rise!r}")

    # Derived, in the units the rules use (ns, window totals of three axes).
    @property
    def window_ns(self) -> int:
        return int(self.window_s * 1e9)

    @property
    def full_ns(self) -> int:
        return int(0.9 * self.window_s * 1e9)

    @property
    def trim_ns(self) -> int:
        return int(self.trim_s * 1e9)  # type: ignore[operator]  # set in __post_init__

    @property
    def warmup_ns(self) -> float:
        return self.warmup_s * 1e9

    @property
    def rise_var(self) -> float:
        return self.max_floor_rise ** 2

    @property
    def accel_max(self) -> float:
        return HARD_LIMIT if self.accel_limit is None else min(self.accel_limit, HARD_LIMIT)

    @property
    def gyro_max(self) -> float:
        return HARD_LIMIT if self.gyro_limit is None else min(self.gyro_limit, HARD_LIMIT)

    @property
    def accel_cap(self) -> float:
        """The largest learned accel threshold (a window total)."""
        return math.inf if self.accel_noise_ceiling is None else 3.0 * self.accel_noise_ceiling ** 2

    @property
    def gyro_cap(self) -> float:
        return math.inf if self.gyro_noise_ceiling is None else 3.0 * self.gyro_noise_ceiling ** 2

    @property
    def min_magnitude_squared(self) -> float:
        return 0.0 if self.floor_min_magnitude is None else self.floor_min_magnitude ** 2


@dataclass
class BatchCarry:
    """What a detect_batch call leaves for the next part of the same recording (final=False): the rows
    the next windows and the open interval still need (accepted rows: stamps, accel, gyro, temperature),
    where in them the open interval began (and its window's first row) and last grew, and from which row
    on the next windows need them (`window_from`: the rows before it are only the open interval's, kept
    for its pose, never passed through the window sums again)."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray | None
    temperature: np.ndarray | None
    opened: int | None
    opened_window: int  # the first row of the opened row's window (where its pose may start)
    last: int
    window_from: int
    # The rows above are views of these buffers from row `start` on, with room after them: the next part
    # is appended in place, so a long still interval is not copied again with every part (live: 20 times
    # a second). Never the caller's arrays.
    store: CarryStore | None = None


@dataclass
class CarryStore:
    """Growable buffers of the carried rows (stamps, accel, gyro, temperature): rows [start, used)."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray | None
    temperature: np.ndarray | None
    start: int
    used: int

    @classmethod
    def holding(cls, rows: int, t: np.ndarray, a: np.ndarray, g: np.ndarray | None,
                temps: np.ndarray | None) -> CarryStore:
        """Buffers with room for `rows` rows, the given ones first."""
        store = cls(np.empty(rows, np.int64), np.empty((rows, 3)), None if g is None else np.empty((rows, 3)),
                    None if temps is None else np.empty(rows), 0, 0)
        store.append(t, a, g, temps)
        return store

    def room(self) -> int:
        return len(self.t) - self.used

    def append(self, t: np.ndarray, a: np.ndarray, g: np.ndarray | None, temps: np.ndarray | None) -> None:
        end = self.used + len(t)
        self.t[self.used:end] = t
        self.accel[self.used:end] = a
        if self.gyro is not None and g is not None:
            self.gyro[self.used:end] = g
        if self.temperature is not None and temps is not None:
            self.temperature[self.used:end] = temps
        self.used = end

    def rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]:
        part = slice(self.start, self.used)
        return (self.t[part], self.accel[part], None if self.gyro is None else self.gyro[part],
                None if self.temperature is None else self.temperature[part])


def _carried_and_new(carry: BatchCarry, t: np.ndarray, a: np.ndarray, g: np.ndarray | None,
                     temps: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, CarryStore]:
    """The carried rows followed by the new ones, as views of the carry's store (appended in place when
    there is room, else into a store twice the size: amortised constant work per row)."""
    store = carry.store
    same_presence = store is not None and (store.gyro is None) == (g is None or carry.gyro is None) \
        and (store.temperature is None) == (temps is None or carry.temperature is None)
    if store is None or not same_presence or store.room() < len(t):
        rows = 2 * (len(carry.t) + len(t)) + 1024
        store = CarryStore.holding(rows, carry.t, carry.accel, None if g is None else carry.gyro,
                                   None if temps is None else carry.temperature)
    store.append(t, a, g, temps)
    joined_t, joined_a, joined_g, joined_temps = store.rows()
    return joined_t, joined_a, joined_g, joined_temps, store


@dataclass
class DetectorState:
    """What the detector learns and carries: the noise floors, the quietest floors seen after warm-up
    (window totals; inf before), the stream time of full windows that were evidence of the floor, the
    warm-up's loudest windows (accel, gyro; None once a threshold is known), and the carry of a recording
    going through in parts."""

    accel_floor: VarianceFloor
    gyro_floor: VarianceFloor
    full_time_ns: int = 0
    accel_quietest: float = math.inf
    gyro_quietest: float = math.inf
    warmup_max: tuple[float, float] | None = (0.0, 0.0)
    carry: BatchCarry | None = field(default=None)

    @classmethod
    def fresh(cls, config: DetectorConfig) -> DetectorState:
        floor = FloorConfig(config.noise_quantile)
        return cls(VarianceFloor(floor), VarianceFloor(floor),
                   warmup_max=(0.0, 0.0) if config.accel_var_threshold is None else None)


def _limit_per_window(var: np.ndarray, evidence: np.ndarray, full_index: np.ndarray | slice, warm_full: np.ndarray,
                      floor: VarianceFloor, fixed: float | None, k_sigma: float, rise_var: float,
                      cap: float, quietest: float) -> tuple[np.ndarray, float]:
    """One channel's stillness threshold at each full window: the fixed one, or k_sigma x the learned
    floor bounded above the quietest floor seen and by the absolute cap; NaN while still learning.
    `floor` is advanced past these windows; `quietest` is the lowest floor seen before them, returned
    updated."""
    # NaN marks a window that does not feed the floor (the floor carries the last value over it).
    # The floor is learned under a fixed threshold too (diagnostics show it).
    values = floor.add(np.where(evidence[full_index], var[full_index], np.nan))
    lowest = _quietest(values, warm_full, quietest)
    quietest = float(lowest[-1]) if len(lowest) else quietest
    if fixed is not None:
        return np.full(len(warm_full), fixed), quietest
    # min(k_sigma x min(floor, quietest x rise_var), cap), in place of `lowest` (its own array).
    limit = lowest
    limit *= rise_var
    with np.errstate(invalid="ignore"):
        np.minimum(values, limit, out=limit)
        limit *= k_sigma
        np.minimum(limit, cap, out=limit)
    np.copyto(limit, np.nan, where=~warm_full)
    return limit, quietest


def _window_variance(channels: list[np.ndarray], start: np.ndarray, firsts: np.ndarray,
                     full: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Per channel (accel, gyro: n x 3 each): the total variance (sum over axes) of values[start_i .. i]
    about the median of its segment (segments begin at rows `firsts`, the first at 0), for each full
    window i; and the squared norm of the first channel's window mean (both 0 elsewhere: never used).

    Blocks are as long as the shortest full window, so every full window holds a block boundary; it
    is summed from pieces that lie inside it (`_WindowBlocks`). Column by column (x, y, z, |x|^2 of a
    channel), laid out block row by block. A few buffers serve every column: touching fresh memory costs
    as much as the sums.
    """
    n_rows = len(channels[0])
    variances = [np.zeros(n_rows) for _ in channels]
    mean_square = np.zeros(n_rows)
    windows = np.flatnonzero(full)  # index of each full window's last sample
    if not len(windows):
        return variances, mean_square
    first = start[windows]
    count = windows.astype(float)  # samples in the window (exact)
    count -= first
    count += 1.0
    blocks = _WindowBlocks(n_rows, windows, first, int(count.min()))
    bounds = list(zip(firsts.tolist(), [*firsts[1:].tolist(), n_rows]))
    contiguous = windows[-1] - windows[0] + 1 == len(windows)  # the usual case: full from some row on
    at = slice(int(windows[0]), int(windows[-1]) + 1) if contiguous else windows
    segment = 0 if len(bounds) == 1 else np.searchsorted(firsts, windows, side="right") - 1
    lengths = np.diff([*firsts.tolist(), n_rows])
    for c, values in enumerate(channels):
        norm = variances[c][at] if contiguous else np.empty(len(windows))  # |window sum|^2, then the variance
        mean = mean_square[at] if contiguous else np.empty(len(windows))
        _channel_variance(blocks, values, bounds, lengths, segment, count, norm, mean if c == 0 else None)
        if not contiguous:
            variances[c][windows] = norm
            if c == 0:
                mean_square[windows] = mean
    return variances, mean_square


class _WindowBlocks:
    """The rows laid out in blocks of `block` (a column as block rows x blocks) and where each full window's
    pieces lie: the end of the block holding its first sample, whole blocks between (only for a window
    longer than the shortest), the start of the block holding its last sample; with the buffers the sums
    reuse."""

    def __init__(self, n_rows: int, windows: np.ndarray, first: np.ndarray, block: int) -> None:
        self.block = block
        self.blocks, self.tail = -(-n_rows // block), n_rows % block
        self.whole = n_rows // block  # blocks without padding
        last_block, last_at = np.divmod(windows, block)
        last_at *= self.blocks  # the last row's place in a column laid out (block row, block)
        last_at += last_block
        first_block, first_at = np.divmod(first, block)
        first_at *= self.blocks
        first_at += first_block
        self.last_at, self.first_at = last_at, first_at
        spans = last_block - first_block
        self.one_block = np.flatnonzero(spans == 0)  # it starts at the boundary: no piece before it
        self.between = np.flatnonzero(spans > 1)  # whole blocks in between
        self.pairs = np.column_stack([first_block[self.between] + 1, last_block[self.between]]).reshape(-1)
        self.column_rows, self.squares, self.backwards = np.empty((3, block, self.blocks))
        self.total, self.piece = np.empty((2, len(windows)))

    def window_sums(self, rows: np.ndarray) -> None:
        """`total` := each window's sum of the column laid out in `rows` (turned into its running sums)."""
        block, backwards, total, piece = self.block, self.backwards, self.total, self.piece
        if self.blocks >= 128:  # enough blocks that one add per block row beats cumsum's per-element loop
            backwards[block - 1] = rows[block - 1]  # row r: from row r to the block's last, from the last
            for r in range(block - 2, -1, -1):
                np.add(backwards[r + 1], rows[r], out=backwards[r])
            for r in range(1, block):
                rows[r] += rows[r - 1]  # from the block's first row to this one (cumsum's order)
        else:
            backwards[::-1] = np.cumsum(rows[::-1], axis=0)
            np.cumsum(rows, axis=0, out=rows)
        np.take(rows.reshape(-1), self.last_at, out=total)
        np.take(backwards.reshape(-1), self.first_at, out=piece)
        piece[self.one_block] = 0.0
        np.add(total, piece, out=total)
        if len(self.between):
            total[self.between] += np.add.reduceat(np.append(rows[block - 1], 0.0), self.pairs)[::2]

    def lay_out(self, column: np.ndarray, reference: float | np.ndarray) -> None:
        """`column_rows` := the column minus `reference` (a number, or one per row), laid out, zero-padded."""
        whole, block, tail = self.whole, self.block, self.tail
        if isinstance(reference, np.ndarray):
            np.subtract(column[:whole * block].reshape(whole, block).T,
                        reference[:whole * block].reshape(whole, block).T, out=self.column_rows[:, :whole])
        else:
            np.subtract(column[:whole * block].reshape(whole, block).T, reference, out=self.column_rows[:, :whole])
        if tail:
            np.subtract(column[whole * block:],
                        reference[whole * block:] if isinstance(reference, np.ndarray) else reference,
                        out=self.column_rows[:tail, whole])
            self.column_rows[tail:, whole] = 0.0  # the padding of the last block


def _channel_variance(blocks: _WindowBlocks, values: np.ndarray, bounds: list[tuple[int, int]],
                      lengths: np.ndarray, segment: int | np.ndarray, count: np.ndarray, norm: np.ndarray,
                      mean: np.ndarray | None) -> None:
    """`norm` := each full window's total variance of one channel (n x 3); `mean` (when given) := the
    squared norm of its window mean."""
    column_rows, squares, backwards = blocks.column_rows, blocks.squares, blocks.backwards
    total, piece = blocks.total, blocks.piece
    for axis in range(3):
        column = values[:, axis]
        medians = np.array([_median(column[begin:end]) for begin, end in bounds])
        # Median, not the first sample: a glitch there would leave every window far from its reference.
        # Per row of the column: its segment's median (one number for the usual single segment).
        blocks.lay_out(column, np.repeat(medians, lengths) if len(bounds) > 1 else medians[0])
        if axis == 0:
            np.multiply(column_rows, column_rows, out=squares)
        else:
            np.multiply(column_rows, column_rows, out=backwards)
            squares += backwards
        blocks.window_sums(column_rows)
        if mean is not None:  # the window mean: its median plus the mean about it
            np.divide(total, count, out=piece)
            piece += medians[segment]
            piece *= piece
            if axis == 0:
                mean[...] = piece
            else:
                mean += piece
        np.multiply(total, total, out=piece)
        if axis == 0:
            norm[...] = piece
        else:
            norm += piece
    blocks.window_sums(squares)
    norm /= count
    np.subtract(total, norm, out=norm)
    norm /= count


def _median(values: np.ndarray) -> float:
    """np.median of finite values, bit for bit: the order statistics it averages are picked among the
    values between two quantiles of a sample (a partition of a small part instead of all: the full
    partition was the largest cost of a long recording), or by np.median itself when they lie outside."""
    size = len(values)
    if size < 4096:
        return float(np.median(values))
    sample = np.sort(values[::size // 1024])
    middle = len(sample) // 2
    # The sample median's rank is off by ~sqrt(1024) / 2 = 16 sample positions: 4 standard deviations.
    low, high = sample[max(middle - 64, 0)], sample[min(middle + 64, len(sample) - 1)]
    below = int(np.count_nonzero(values < low))
    near = values[(values >= low) & (values <= high)]
    lower_rank, upper_rank = (size - 1) // 2 - below, size // 2 - below  # np.median averages these two
    if lower_rank < 0 or upper_rank >= len(near):
        return float(np.median(values))
    part = np.partition(near, [lower_rank, upper_rank])
    if lower_rank == upper_rank:
        return float(part[lower_rank])
    return float((part[lower_rank] + part[upper_rank]) / 2)


def _repeats_in_window(values: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Per row: twice how many rows of its window start_i .. i repeat their predecessor bit for bit (all
    three axes; the first row of the recording has none)."""
    # running[k + 1]: repeats among rows 0 .. k (exact in int32 below 2**31 rows)
    running = np.zeros(len(values) + 1, dtype=np.int32 if len(values) < 2**31 else np.int64)
    if len(values) > 1:
        same = values[1:] == values[:-1]
        np.cumsum(same[:, 0] & same[:, 1] & same[:, 2], out=running[2:])  # & beats all(axis=1) over 3 columns
    twice = running[start]
    np.subtract(running[1:], twice, out=twice)
    twice *= 2
    return np.asarray(twice)


def _within(values: np.ndarray, limit: float) -> bool:
    """Every value in [-limit, limit] (none NaN)."""
    return bool(values.max(initial=-math.inf) <= limit and values.min(initial=math.inf) >= -limit)


def _quietest(floor: np.ndarray, warm: np.ndarray, before: float = math.inf) -> np.ndarray:
    """The lowest floor value in force after warm-up so far (`before`: the lowest before these windows),
    per full window."""
    candidates = np.where(warm & ~np.isnan(floor), floor, np.inf)
    if len(candidates):
        candidates[0] = min(candidates[0], before)
    return np.asarray(np.minimum.accumulate(candidates, out=candidates))


def detect_batch(config: DetectorConfig, state: DetectorState, t_ns: ArrayLike, accel: ArrayLike,
                 gyro: ArrayLike | None = None, temperature_degc: ArrayLike | None = None,
                 drop: ArrayLike | None = None, flush: bool = True, final: bool = True) -> tuple[list[Pose], int, int]:
    """(poses, rejected samples, of which finite but out of range), `state` advanced. `drop` (per sample,
    optional): the interval open before this sample is dropped, not emitted (the stamps must then make
    this sample start a new window). `flush` False: the interval open at the end is dropped too.

    `final` False: more of the same recording follows (a later call, with the same gyro/temperature
    presence); the interval open at the end stays open and the rows it and the next windows need are kept
    in `state.carry`, so the parts give the poses one call would (window variances to rounding: their
    sums are taken over other blocks)."""
    carry: BatchCarry | None = state.carry
    state.carry = None
    t, a, g, temps, dropped, rejected, out_of_range = _accepted(config, carry, t_ns, accel, gyro, temperature_degc,
                                                                drop)
    # The rows kept from the part before come first; the interval rules run over the new rows only.
    context = 0
    store: CarryStore | None = None
    if carry is not None:
        context = len(carry.t)
        if len(t) == 0:
            store = carry.store
            g = None if g is None or carry.gyro is None else carry.gyro
            temps = None if temps is None or carry.temperature is None else carry.temperature
            t, a = carry.t, carry.accel
        else:
            t, a, g, temps, store = _carried_and_new(carry, t, a, g, temps)
        if dropped is not None:
            dropped = np.concatenate([np.zeros(context, bool), dropped])
    if len(t) == context:  # nothing new
        if carry is not None:
            state.carry = carry
            if final:
                return _finish(config, state, [], carry, t, a, g, temps, flush), rejected, out_of_range
        return [], rejected, out_of_range
    # The window rules run over the rows from `held` on (the rows before it are an open interval's only);
    # indices below are of those rows, `held` + index in the whole.
    held = 0 if carry is None else carry.window_from
    intervals = _Intervals(config, carry, held, t, a, g, temps)
    if held:
        t, a = t[held:], a[held:]
        g = None if g is None else g[held:]
        dropped = None if dropped is None else dropped[held:]
        context -= held
    windows = _window_states(config, state, t, a, g, context)
    intervals.start = windows.start
    opened, last = intervals.run(state, windows, t, context, dropped)
    poses = intervals.poses
    full_t, full_a, full_g, full_temps = intervals.t, intervals.a, intervals.g, intervals.temps
    # What the next part needs: the window of the last row (the next rows' windows start no earlier), and
    # the open interval from its window's first row (emit trims from there).
    windows_from = intervals.window_of(held + len(t) - 1)
    keep_from = windows_from if opened is None else min(windows_from, intervals.window_of(opened))
    if carry is None or store is None:  # the first part: the caller's arrays, never kept
        rows = len(full_t) - keep_from
        store = CarryStore.holding(2 * rows + 1024, full_t[keep_from:], full_a[keep_from:],
                                   None if full_g is None else full_g[keep_from:],
                                   None if full_temps is None else full_temps[keep_from:])
    else:
        store.start += keep_from
    kept_t, kept_a, kept_g, kept_temps = store.rows()
    left = BatchCarry(kept_t, kept_a, kept_g, kept_temps,
                      None if opened is None else opened - keep_from,
                      0 if opened is None else intervals.window_of(opened) - keep_from,
                      max(last - keep_from, 0), windows_from - keep_from, store)
    if not final:
        state.carry = left
        return poses, rejected, out_of_range
    return _finish(config, state, poses, left, full_t, full_a, full_g, full_temps, flush, opened, last,
                   None if opened is None else intervals.window_of(opened), config.trim_ns), rejected, out_of_range


def _accepted(config: DetectorConfig, carry: BatchCarry | None, t_ns: ArrayLike, accel: ArrayLike,
              gyro: ArrayLike | None, temperature_degc: ArrayLike | None, drop: ArrayLike | None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None, np.ndarray | None, int, int]:
    """The rows accepted (stamps, accel, gyro, temperature: the arrays as given when all are), per row
    whether the interval open before it is dropped (None without `drop`), and how many rows were rejected,
    of which finite but out of range. A row is rejected for a NaN/inf or a value beyond the limits on any
    axis, or a stamp not after the last accepted one (the carry's included); a temperature beyond
    HARD_LIMIT is NaN (no temperature), the row kept."""
    t_all = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    # Contiguous rows (a column slice of a loaded table is not): every pass below runs faster on them.
    a_all = np.ascontiguousarray(np.asarray(accel, dtype=float).reshape(-1, 3))
    g_all = None if gyro is None else np.ascontiguousarray(np.asarray(gyro, dtype=float).reshape(-1, 3))
    temp_all = None if temperature_degc is None else np.asarray(temperature_degc, dtype=float).reshape(-1)
    if temp_all is not None:
        with np.errstate(invalid="ignore"):
            # NaN, inf or absurd: that sample has no temperature, the motion is fine
            temp_all = np.where(np.abs(temp_all) <= HARD_LIMIT, temp_all, np.nan)
    with np.errstate(invalid="ignore"):
        # NaN/inf or beyond the limit on any axis rejects the sample (NaN propagates through
        # max and min and compares False; no |x| copy: fresh memory is slow to touch).
        if _within(a_all, config.accel_max) and (g_all is None or _within(g_all, config.gyro_max)):
            valid = np.ones(len(a_all), bool)  # the usual recording: one reduction each says all are valid
        else:
            valid = np.abs(a_all).max(axis=1, initial=0.0) <= config.accel_max
            if g_all is not None:
                valid &= np.abs(g_all).max(axis=1, initial=0.0) <= config.gyro_max
    invalid = np.flatnonzero(~valid)  # few: finiteness is checked on these only
    finite = np.all(np.isfinite(a_all[invalid]), axis=1)
    if g_all is not None:
        finite &= np.all(np.isfinite(g_all[invalid]), axis=1)
    out_of_range = int(np.count_nonzero(finite))
    t_f = t_all[valid] if len(invalid) else t_all
    latest = np.iinfo(np.int64).min if carry is None else int(carry.t[-1])  # the last accepted stamp
    in_order = len(t_f) == 0 or (int(t_f[0]) > latest and bool(np.all(t_f[1:] > t_f[:-1])))
    if in_order:  # the usual recording: every valid stamp after the previous one
        accepted = np.ones(len(t_f), bool)
    else:
        previous_max = np.concatenate([[latest], np.maximum.accumulate(t_f)[:-1]])
        previous_max[1:] = np.maximum(previous_max[1:], latest)
        accepted = t_f > previous_max  # a stamp not after the last accepted one is skipped
    rejected = len(t_all) - int(accepted.sum())
    everything = rejected == 0  # nothing rejected: the arrays as given, without copies
    keep = None if everything else np.flatnonzero(valid)[accepted]
    dropped = None
    if drop is not None:
        # A discard before a rejected sample still applies to the next accepted one.
        marked = np.concatenate([[0], np.cumsum(np.asarray(drop, dtype=bool).reshape(-1))])
        upto = marked[1:] if keep is None else marked[keep + 1]
        dropped = (upto - np.concatenate([[0], upto[:-1]])) > 0
    t = t_all if keep is None else t_all[keep]
    a = a_all if keep is None else a_all[keep]
    g = None if g_all is None else g_all if keep is None else g_all[keep]
    temps = None if temp_all is None else temp_all if keep is None else temp_all[keep]
    return t, a, g, temps, dropped, rejected, out_of_range


@dataclass
class _Windows:
    """Per row of a part (from `held` on): its window's first row, whether a gap longer than a window came
    before it, whether its window is full, the window variances (total over the axes), the thresholds
    in force (NaN: none yet), whether it is learning the floor (full, no threshold yet) or still."""

    start: np.ndarray
    gaps: np.ndarray
    full: np.ndarray
    accel_var: np.ndarray
    gyro_var: np.ndarray | None
    accel_limit: np.ndarray
    gyro_limit: np.ndarray
    learning: np.ndarray
    still: np.ndarray


def _window_states(config: DetectorConfig, state: DetectorState, t: np.ndarray, a: np.ndarray,
                   g: np.ndarray | None, context: int) -> _Windows:
    """Each row's window and its state, the floors, quietest floors and full-window time in `state`
    advanced past them; the first `context` rows were decided in the part before (never full here)."""
    n = len(t)
    window_ns = config.window_ns
    dt = np.zeros(n, dtype=np.int64)
    np.subtract(t[1:], t[:-1], out=dt[1:])
    gaps = dt > config.window_ns
    segment_firsts = np.flatnonzero(gaps)  # the first row of each segment after the first
    start = np.searchsorted(t, t - window_ns, side="right")
    if len(segment_firsts):  # a window starts no earlier than its segment
        segment_firsts = np.concatenate([[0], segment_firsts])
        np.maximum(start, np.repeat(segment_firsts, np.diff(np.append(segment_firsts, n))), out=start)
    else:
        segment_firsts = np.zeros(1, dtype=np.int64)
    count = np.arange(1, n + 1)
    count -= start
    span = t[start]
    np.subtract(t, span, out=span)
    full = span >= config.full_ns
    full &= count >= 5
    full[:context] = False  # decided in the part before
    # Windows mostly of repeated samples are no evidence of the noise (2 * repeats <= n).
    accel_evidence = _repeats_in_window(a, start) <= count
    gyro_evidence = None if g is None else _repeats_in_window(g, start) <= count
    variances, accel_mean_square = _window_variance([a] if g is None else [a, g], start, segment_firsts, full)
    accel_var = variances[0]
    gyro_var = None if g is None else variances[1]
    # A window whose mean is no gravity (a dead sensor's quiet zeros) does not teach the floor either.
    plausible = accel_mean_square >= config.min_magnitude_squared
    accel_evidence &= plausible
    if gyro_evidence is not None:
        gyro_evidence &= plausible
    full_time = dt  # dt is not needed any more: the full-window time in its place
    full_time *= full & accel_evidence
    np.cumsum(full_time, out=full_time)
    full_time += state.full_time_ns
    state.full_time_ns = int(full_time[-1])

    full_rows = np.flatnonzero(full)
    full_index: np.ndarray | slice = full_rows
    if len(full_rows) and full_rows[-1] - full_rows[0] + 1 == len(full_rows):  # full from some row on
        full_index = slice(int(full_rows[0]), int(full_rows[-1]) + 1)  # views instead of copies
    accel_limit = np.full(n, np.nan)
    gyro_limit = np.full(n, np.nan)
    warm_full = full_time[full_index] >= config.warmup_ns
    accel_limit[full_index], state.accel_quietest = _limit_per_window(
        accel_var, accel_evidence, full_index, warm_full, state.accel_floor, config.accel_var_threshold,
        config.k_sigma, config.rise_var, config.accel_cap, state.accel_quietest)
    if gyro_var is not None and gyro_evidence is not None:  # there is a gyro
        gyro_limit[full_index], state.gyro_quietest = _limit_per_window(
            gyro_var, gyro_evidence, full_index, warm_full, state.gyro_floor, config.gyro_var_threshold,
            config.gyro_k_sigma, config.rise_var, config.gyro_cap, state.gyro_quietest)
    learning = full & np.isnan(accel_limit)
    with np.errstate(invalid="ignore"):
        quiet_gyro = np.ones(n, bool) if g is None else (np.isnan(gyro_limit) | (gyro_var <= gyro_limit))
        still = full & ~learning & (accel_var <= accel_limit) & quiet_gyro
    return _Windows(start, gaps, full, accel_var, gyro_var, accel_limit, gyro_limit, learning, still)


class _Intervals:
    """The interval rules over a part's rows (the carried ones first: `t`, `a`, `g`, `temps` are the whole),
    the poses they end in `poses`."""

    def __init__(self, config: DetectorConfig, carry: BatchCarry | None, held: int, t: np.ndarray, a: np.ndarray,
                 g: np.ndarray | None, temps: np.ndarray | None) -> None:
        self.config, self.carry, self.held = config, carry, held
        self.t, self.a, self.g, self.temps = t, a, g, temps
        self.start = np.zeros(0, dtype=np.int64)  # each row's window's first row, from `held` on
        self.poses: list[Pose] = []
        self.max_pose_ns = int(config.max_pose_s * 1e9) if math.isfinite(config.max_pose_s) else None

    def window_of(self, row: int) -> int:
        """The first row of a row's window, both in the whole. The carried open interval's row keeps the
        window it had (its window may begin before the rows passed through the window sums here)."""
        carry = self.carry
        if carry is not None and row == carry.opened:
            return carry.opened_window
        return int(self.start[row - self.held]) + self.held

    def emit(self, opened: int, last: int, trim_end: bool) -> None:
        _emit(self.poses, self.config, self.t, self.a, self.g, self.temps, self.window_of(opened), opened, last,
              trim_end, self.config.trim_ns)

    def run(self, state: DetectorState, windows: _Windows, t: np.ndarray, context: int,
            dropped: np.ndarray | None) -> tuple[int | None, int]:
        """The rules applied per run of samples in the same state (runs break at gaps and at state changes):
        0 window not full, 1 learning the floor, 2 still, 3 moving. `t`: the stamps from `held` on. Returns
        the row that opened the interval open at the end (None: none) and the last row added to it, in the
        whole's rows; the warm-up's loudest windows in `state` advanced."""
        held, carry, gaps = self.held, self.carry, windows.gaps
        accel_var, gyro_var = windows.accel_var, windows.gyro_var
        row_kind = windows.full.view(np.int8) * np.int8(3)  # learning and still are parts of full, apart
        row_kind -= windows.learning.view(np.int8) * np.int8(2)
        row_kind -= windows.still.view(np.int8)
        changes = (row_kind[context + 1:] != row_kind[context:-1]) | gaps[context + 1:]
        boundary = context + np.flatnonzero(np.concatenate([[True], changes]))
        ends = np.concatenate([boundary[1:], [len(t)]]) - 1
        # In the whole's rows (held + index): the row that opened the current interval, the last one added
        # to it (read only while one is open).
        opened: int | None = None if carry is None else carry.opened
        last = 0 if carry is None else carry.last
        warmup = state.warmup_max  # the loudest windows of the warm-up, until the threshold is known
        loudest_accel, loudest_gyro = (0.0, 0.0) if warmup is None else warmup
        warmup_open = warmup is not None
        for first, final_row in zip(boundary.tolist(), ends.tolist()):
            if gaps[first] and opened is not None:
                if dropped is None or not dropped[first]:
                    self.emit(opened, last, True)
                opened = None
            kind = row_kind[first]
            if kind == 0:
                continue
            if kind == 1:
                loudest_accel = max(loudest_accel, float(accel_var[first:final_row + 1].max()))
                if gyro_var is not None:
                    loudest_gyro = max(loudest_gyro, float(gyro_var[first:final_row + 1].max()))
                if opened is None:
                    opened = first + held
                last = final_row + held
                continue
            if warmup_open:
                warmup_open = False
                limit_g = windows.gyro_limit[first]
                if opened is not None and not (loudest_accel <= windows.accel_limit[first]
                                               and (math.isnan(limit_g) or loudest_gyro <= limit_g)):
                    opened = None  # it moved during warm-up: no pose from it
            if kind == 3:
                if opened is not None:
                    self.emit(opened, last, True)
                    opened = None
                continue
            opened, last = self._still_run(t, first, final_row, opened, last)
        state.warmup_max = (loudest_accel, loudest_gyro) if warmup_open else None
        return opened, last

    def _still_run(self, t: np.ndarray, first: int, final_row: int, opened: int | None,
                   last: int) -> tuple[int, int]:
        """A run of still samples: open at its first sample if nothing is open, cut at max_pose_s. Returns
        the interval open after it and its last row (the whole's rows)."""
        held, max_pose_ns = self.held, self.max_pose_ns
        i = first
        if opened is None:
            opened = last = first + held
            i = first + 1
        while i <= final_row:
            limit = None if max_pose_ns is None else self.t[self.window_of(opened)] + max_pose_ns
            split = final_row + 1 if limit is None else max(i, int(np.searchsorted(t, limit, side="left")))
            if split > final_row:
                last = final_row + held
                break
            self.emit(opened, split + held, True)
            opened = last = split + held
            i = split + 1
        return opened, last


def _finish(config: DetectorConfig, state: DetectorState, poses: list[Pose], carry: BatchCarry, t: np.ndarray,
            a: np.ndarray, g: np.ndarray | None, temps: np.ndarray | None, flush: bool, opened: int | None = None,
            last: int = 0, opened_window: int | None = None, trim_ns: int = 0, trim_end: bool = False) -> list[Pose]:
    """The end of the recording: the interval still open is a pose when `flush` (it was not moving;
    `trim_end`: it ends as at a gap, its newest trim_s dropped)."""
    state.carry = None
    if opened_window is None:  # no new rows came: the open interval is the carried one
        opened, opened_window, last = carry.opened, carry.opened_window, carry.last
        trim_ns = config.trim_ns
    if opened is not None and flush:
        _emit(poses, config, t, a, g, temps, opened_window, opened, last, trim_end, trim_ns)
    return poses


def peek_carry(config: DetectorConfig, state: DetectorState) -> Pose | None:
    """The pose the carried open interval would end as at the end of the recording (flushed), the carry
    left as it was."""
    carry = state.carry
    if carry is None or carry.opened is None:
        return None
    poses: list[Pose] = []
    _finish(config, state, poses, carry, carry.t, carry.accel, carry.gyro, carry.temperature, True)
    state.carry = carry
    return poses[0] if poses else None


def end_carry(config: DetectorConfig, state: DetectorState) -> Pose | None:
    """The clock was re-synchronised: the carried open interval ends as at a gap (its newest trim_s
    dropped), returned when it is a pose; nothing is carried on (the next rows start a new window)."""
    carry = state.carry
    if carry is None:
        return None
    poses: list[Pose] = []
    _finish(config, state, poses, carry, carry.t, carry.accel, carry.gyro, carry.temperature, True, trim_end=True)
    return poses[0] if poses else None


def _emit(poses: list[Pose], config: DetectorConfig, t: np.ndarray, a: np.ndarray, g: np.ndarray | None,
          temps: np.ndarray | None, opened_window: int, opened: int, last: int, trim_end: bool, trim_ns: int) -> None:
    """The interval opened at row `opened` (its window's first row, `opened_window`, gives the start,
    trimmed) up to row `last` (trimmed at the end when motion ended it) as a pose, when long enough."""
    first_time = t[opened_window] + trim_ns
    k0 = int(np.searchsorted(t, first_time, side="left"))
    k0 = max(k0, opened_window)
    k1 = int(np.searchsorted(t, t[last] - trim_ns, side="right")) - 1 if trim_end else last
    k1 = min(k1, last)
    if k1 - k0 + 1 < 2 or t[k1] - t[k0] < config.min_hold_s * 1e9:
        return
    rows = a[k0:k1 + 1]
    samples = k1 - k0 + 1
    # Elementwise sums in a fixed order over the pose's own rows, no BLAS: the same pose gives the same
    # numbers whatever part it was found in and on any CPU.
    mean = np.add.reduce(rows, axis=0) / samples
    centred = np.ascontiguousarray((rows - mean).T)
    cov = np.empty((3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[i, j] = cov[j, i] = np.add.reduce(centred[i] * centred[j])
    cov /= samples - 1
    temperature = spread = None
    if temps is not None:
        known = temps[k0:k1 + 1][~np.isnan(temps[k0:k1 + 1])]
        if len(known):
            temperature, spread = float(known.mean()), float(known.max() - known.min())
    poses.append(Pose(
        accel_mps2=mean,
        accel_cov=cov,
        samples=samples,
        start_ns=int(t[k0]),
        end_ns=int(t[k1]),
        gyro_radps=None if g is None else np.add.reduce(g[k0:k1 + 1], axis=0) / samples,
        temperature_degc=temperature,
        temperature_spread_degc=spread,
    ))
