"""StaticDetector.process(): the streaming detector's rules applied to a whole recording with array
operations, for bag replay and the CLI where per-sample Python would dominate the run time.

Equivalent to update() per sample then flush() (tested): the same validity rules, window
membership from timestamps, the noise floor's histogram queried at the same add counts (every 64
windows, halved every 200k) and fed by the same windows (not those mostly of repeated samples), its
bound by the quietest floor seen and the ceiling, the same warm-up adoption, trims, gap and
max_pose_s cuts. Only the window variances differ, by rounding (block sums instead of running sums).

Window sums are not differences of cumulative sums over the whole recording: one large value would
leave its rounding in every later difference (and a value beyond ~1e154 makes them inf - inf = NaN),
so the rest of the recording would be lost. Each window is split at a block boundary into the end of
one block and the start of the next (plus whole blocks between, for an unusually long window), each
summed within its block only, so a window's sums hold nothing but its own samples.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .pose import Pose
from .static_detector import _BINS_PER_DECADE, _HARD_LIMIT, _LOG_MAX, _LOG_MIN, _NBINS

if TYPE_CHECKING:
    from .static_detector import StaticDetector, _VarianceFloor

_QUERY_EVERY = 64



def _limit_per_window(var: np.ndarray, evidence: np.ndarray, full_index: np.ndarray, warm_full: np.ndarray,
                      floor: _VarianceFloor, fixed: float | None, k_sigma: float, rise_var: float,
                      cap: float, quietest: float) -> tuple[np.ndarray, float]:
    """One channel's stillness threshold at each full window: the fixed one, or k_sigma x the learned
    floor bounded above the quietest floor seen and by the absolute cap; NaN while still learning.
    `floor` is advanced past these windows; `quietest` is the lowest floor seen before them, returned
    updated."""
    # NaN marks a window that does not feed the floor (_floor_values carries the last value over it).
    # The floor is learned under a fixed threshold too, as update() learns it (diagnostics show it).
    values = _floor_values(np.where(evidence, var, np.nan)[full_index], floor)
    lowest = _quietest(values, warm_full, quietest)
    quietest = float(lowest[-1]) if len(lowest) else quietest
    if fixed is not None:
        return np.full(len(full_index), fixed), quietest
    bounded = np.minimum(values, lowest * rise_var)
    with np.errstate(invalid="ignore"):
        limit = np.where(warm_full, np.minimum(k_sigma * bounded, cap), np.nan)
    return limit, quietest


def _floor_values(variances: np.ndarray, floor: _VarianceFloor) -> np.ndarray:
    """The floor value in force after each window, as _VarianceFloor.add per window would give it (it
    skips non-finite variances, which finite sums inside the guard cannot give; NaN until the first
    add), starting from `floor`'s state and leaving `floor` as those adds would."""
    before = np.nan if floor.value is None else floor.value
    finite = np.isfinite(variances)
    if not finite.all():
        values = _floor_values_of_adds(variances[finite], floor)
        last_add = np.cumsum(finite) - 1
        return np.where(last_add >= 0, values[np.maximum(last_add, 0)] if len(values) else np.nan, before)
    return _floor_values_of_adds(variances, floor)


def _floor_values_of_adds(variances: np.ndarray, floor: _VarianceFloor) -> np.ndarray:
    """The floor value in force after each add, from `floor`'s state (its histogram, the adds since its
    last query and last halving), which is advanced to after the last add.

    Epoch by epoch (adds between two halvings), the queries of an epoch at once, each seeing the halved
    histogram carried in plus its epoch's adds so far. Counts are sums of halved integers, exact in
    floats, so the order of the additions does not change them: the values are _VarianceFloor's."""
    count = len(variances)
    if count == 0:
        return np.zeros(0)
    quantile, half_life = floor.quantile, floor.half_life
    with np.errstate(divide="ignore", invalid="ignore"):
        index = np.floor((np.log10(variances) - _LOG_MIN) * _BINS_PER_DECADE)
    index = np.where(variances <= 0.0, 0, np.clip(np.nan_to_num(index, nan=0.0), 0, _NBINS - 1)).astype(np.int64)
    # add() queries after the first add ever, then every _QUERY_EVERY adds; it halves every half_life adds
    # (before the query of the same add). Numbered 1.. within these adds.
    first_query = 1 if floor.value is None else _QUERY_EVERY - floor._since_query
    query_adds = np.arange(first_query, count + 1, _QUERY_EVERY)
    halvings = np.arange(half_life - floor._since_decay, count + 1, half_life)
    carried = np.asarray(floor.counts, dtype=float)
    hit_bins = np.flatnonzero(carried)
    # Only bins ever hit matter: empty bins below add nothing, and a hit needs counts.
    low = int(min(index.min(), hit_bins.min() if len(hit_bins) else _NBINS))
    high = int(max(index.max(), hit_bins.max() if len(hit_bins) else -1)) + 1
    width, index = high - low, index - low
    centres = 10.0 ** (_LOG_MIN + (np.arange(low, high) + 0.5) / _BINS_PER_DECADE)
    base = carried[low:high].copy()
    base_total = float(floor.total)
    values = np.empty(len(query_adds))
    epoch_of_query = np.searchsorted(halvings, query_adds, side="right")  # halvings done by each query
    epoch_starts = np.concatenate([[0], halvings])  # an epoch holds the adds after its start, to the next
    for epoch, begin in enumerate(epoch_starts.tolist()):
        end = int(epoch_starts[epoch + 1]) if epoch + 1 < len(epoch_starts) else count
        chosen = np.flatnonzero(epoch_of_query == epoch)
        if len(chosen):
            upto = query_adds[chosen]
            block = np.searchsorted(upto, np.arange(begin, end) + 1, side="left")  # its first query
            counted = block < len(chosen)  # adds after the last query never reach one
            per_block = np.bincount(block[counted] * width + index[begin:end][counted],
                                    minlength=len(chosen) * width).reshape(-1, width).astype(float)
            counts = base + np.cumsum(per_block, axis=0)
            total = base_total + (upto - begin).astype(float)
            running = np.cumsum(counts, axis=1)
            hit = (running >= quantile * total[:, None]) & (counts > 0)
            values[chosen] = np.where(hit.any(axis=1), centres[np.argmax(hit, axis=1)], 10.0**_LOG_MAX)
        base = base + np.bincount(index[begin:end], minlength=width)
        base_total += end - begin
        if epoch + 1 < len(epoch_starts):  # the halving after this epoch's last add
            base *= 0.5
            base_total *= 0.5
    previous = np.nan if floor.value is None else floor.value
    latest_query = np.searchsorted(query_adds, np.arange(1, count + 1), side="right") - 1
    per_add = np.where(latest_query >= 0, values[np.maximum(latest_query, 0)] if len(values) else np.nan, previous)
    # The state add() would leave.
    carried[low:high] = base
    floor.counts = carried.tolist()
    floor.total = base_total
    floor._since_decay = floor._since_decay + count if not len(halvings) else count - int(halvings[-1])
    floor._since_query = floor._since_query + count if not len(query_adds) else count - int(query_adds[-1])
    if len(values):
        floor.value = float(values[-1])
    return np.asarray(per_add)


def _window_variance(channels: list[np.ndarray], start: np.ndarray, segment_first: np.ndarray,
                     full: np.ndarray, mean_of: tuple[int, ...] = (0,)) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per channel (accel, gyro: n x 3 each): total variance (sum over axes) and mean of values[start_i .. i]
    for each full window i (0 elsewhere: never used; the mean only for the channels in `mean_of`), about
    each segment's median.

    Blocks are as long as the shortest full window, so every full window holds a block boundary; it
    is summed from pieces that lie inside it: the end of the block holding its first sample, whole
    blocks between (only for a window longer than the shortest), the start of the block holding its
    last sample. All channels go through one pass, laid out column-major (4 sums per channel) so the
    running sums run along contiguous memory; cumsum adds in order, so the sums are the row-major ones.
    """
    n_rows = len(channels[0])
    n_cols = 4 * len(channels)
    windows = np.flatnonzero(full)  # index of each full window's last sample
    if not len(windows):
        return [(np.zeros(n_rows), np.zeros((n_rows, 3))) for _ in channels]
    first = start[windows]
    block = int((windows - first).min()) + 1
    firsts = np.flatnonzero(segment_first == np.arange(n_rows))
    bounds = list(zip(firsts.tolist(), [*firsts[1:].tolist(), n_rows]))
    blocks = -(-n_rows // block)
    padded_rows = blocks * block
    columns = np.empty((n_cols, padded_rows))  # per channel: x y z |x|^2
    columns[:, n_rows:] = 0.0  # the padding of the last block
    references = []
    for c, values in enumerate(channels):
        reference = np.empty_like(values)
        for begin, end in bounds:
            # Median, not the first sample: a glitch there would leave every window far from its reference.
            for axis in range(3):  # column by column: the same medians, faster than axis=0 on rows of 3
                reference[begin:end, axis] = np.median(values[begin:end, axis])
        shifted = values - reference
        references.append(reference)
        columns[4 * c:4 * c + 3, :n_rows] = shifted.T
        columns[4 * c + 3, :n_rows] = np.einsum("ij,ij->i", shifted, shifted)
    prefix = np.cumsum(columns.reshape(n_cols, blocks, block), axis=2)  # from the block's first row to this one
    totals = np.concatenate([prefix[:, :, -1], np.zeros((n_cols, 1))], axis=1)
    prefix = prefix.reshape(n_cols, -1)
    # From a row to its block's last, summed backwards: running sums over the reversed rows (row r is
    # reversed row padded_rows - 1 - r; block boundaries coincide since padded_rows is whole blocks).
    backwards = np.cumsum(columns[:, ::-1].reshape(n_cols, blocks, block), axis=2).reshape(n_cols, -1)

    boundary = windows // block * block  # the last block boundary at or before the window's last row
    contiguous = windows[-1] - windows[0] + 1 == len(windows)  # the usual case: full from some row on
    upto_last = prefix[:, windows[0]:windows[-1] + 1] if contiguous else np.take(prefix, windows, axis=1)
    head_mask = boundary > first  # the window starts before that boundary
    head = np.flatnonzero(head_mask)
    suffix = np.take(backwards, padded_rows - 1 - first, axis=1)  # [first, end of its block]
    if len(head) == len(windows):
        sums = np.add(upto_last, suffix, out=suffix)  # [boundary, last] + [first, end of its block]
    else:
        sums = upto_last + np.where(head_mask, suffix, 0.0)
    first_block, last_block = first[head] // block + 1, boundary[head] // block
    between = first_block < last_block  # whole blocks in between
    if between.any():
        pairs = np.column_stack([first_block[between], last_block[between]]).reshape(-1)
        sums[:, head[between]] += np.add.reduceat(totals, pairs, axis=1)[:, ::2]

    count = windows - first + 1
    results = []
    for c in range(len(channels)):
        variance = np.zeros(n_rows)
        mean = np.zeros((n_rows, 3))
        s1, s2 = sums[4 * c:4 * c + 3].T, sums[4 * c + 3]
        variance[windows] = (s2 - np.einsum("ij,ij->i", s1, s1) / count) / count
        if c in mean_of:
            mean[windows] = references[c][windows] + s1 / count[:, None]
        results.append((variance, mean))
    return results


def _repeats_in_window(values: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Per row: how many rows of its window start_i .. i repeat their predecessor bit for bit (all three
    axes; the first row of the recording has none), as update() counts them."""
    repeat = np.zeros(len(values), dtype=np.int64)
    if len(values) > 1:
        same = values[1:] == values[:-1]
        repeat[1:] = same[:, 0] & same[:, 1] & same[:, 2]  # faster than all(axis=1) over 3 columns
    running = np.concatenate([[0], np.cumsum(repeat)])
    return np.asarray(running[1:] - running[start])


def _quietest(floor: np.ndarray, warm: np.ndarray, before: float = math.inf) -> np.ndarray:
    """The lowest floor value in force after warm-up so far (`before`: the lowest before these windows),
    per full window."""
    candidates = np.where(warm & ~np.isnan(floor), floor, np.inf)
    if len(candidates):
        candidates[0] = min(candidates[0], before)
    return np.asarray(np.minimum.accumulate(candidates)) if len(candidates) else candidates


@dataclass
class BatchCarry:
    """What a detect_batch call leaves for the next part of the same recording (final=False): the rows
    the next windows and the open interval still need (accepted rows: stamps, accel, gyro, temperature)
    and where in them the open interval began and last grew. The floors, the quietest floors, the
    full-window time and the warm-up's loudest windows live on the detector, as update() keeps them."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray | None
    temperature: np.ndarray | None
    opened: int | None
    last: int


def detect_batch(detector: StaticDetector, t_ns: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None,
                 temperature_degc: ArrayLike | None = None,
                 drop: ArrayLike | None = None, flush: bool = True, final: bool = True) -> tuple[list[Pose], int, int]:
    """(poses, rejected samples, of which finite but out of range). `drop` (per sample, optional): the
    interval open before this sample is dropped, not emitted (discard(); the stamps must then make this
    sample start a new window). `flush` False: the interval open at the end is dropped too.

    `final` False: more of the same recording follows (a later call, with the same gyro/temperature
    presence); the interval open at the end stays open and the rows it and the next windows need are kept
    on the detector (BatchCarry), so the parts give the poses one call would (window variances to
    rounding: their sums are taken over other blocks)."""
    d = detector
    carry: BatchCarry | None = d._batch_carry
    d._batch_carry = None
    t_all = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    # Contiguous rows (a column slice of a loaded table is not): every pass below runs faster on them.
    a_all = np.ascontiguousarray(np.asarray(accel, dtype=float).reshape(-1, 3))
    g_all = None if gyro is None else np.ascontiguousarray(np.asarray(gyro, dtype=float).reshape(-1, 3))
    temp_all = None if temperature_degc is None else np.asarray(temperature_degc, dtype=float).reshape(-1)
    if temp_all is not None:
        with np.errstate(invalid="ignore"):
            # NaN, inf or absurd: that sample has no temperature, as in update()
            temp_all = np.where(np.abs(temp_all) <= _HARD_LIMIT, temp_all, np.nan)
    with np.errstate(invalid="ignore"):
        # As update(): NaN/inf or beyond the limit on any axis rejects the sample (NaN propagates through
        # max and compares False).
        if np.abs(a_all).max(initial=0.0) <= d._accel_max and (
                g_all is None or np.abs(g_all).max(initial=0.0) <= d._gyro_max):
            valid = np.ones(len(a_all), bool)  # the usual recording: one reduction each says all are valid
        else:
            valid = np.abs(a_all).max(axis=1, initial=0.0) <= d._accel_max
            if g_all is not None:
                valid &= np.abs(g_all).max(axis=1, initial=0.0) <= d._gyro_max
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
        accepted = t_f > previous_max  # a stamp not after the last accepted one is skipped, as update() does
    rejected = len(t_all) - int(accepted.sum())
    keep = np.flatnonzero(valid)[accepted]
    everything = len(keep) == len(t_all)  # nothing rejected: the arrays as given, without copies
    dropped = None
    if drop is not None:
        # A discard before a rejected sample still applies to the next accepted one.
        marked = np.concatenate([[0], np.cumsum(np.asarray(drop, dtype=bool).reshape(-1))])
        upto = marked[keep + 1]
        dropped = (upto - np.concatenate([[0], upto[:-1]])) > 0
    t = t_all if everything else t_all[keep]
    a = a_all if everything else a_all[keep]
    g = None if g_all is None else g_all if everything else g_all[keep]
    temps = None if temp_all is None else temp_all if everything else temp_all[keep]
    # The rows kept from the part before come first; the interval rules run over the new rows only.
    context = 0
    if carry is not None:
        context = len(carry.t)
        t = np.concatenate([carry.t, t])
        a = np.concatenate([carry.accel, a])
        g = None if g is None or carry.gyro is None else np.concatenate([carry.gyro, g])
        temps = None if temps is None or carry.temperature is None else np.concatenate([carry.temperature, temps])
        if dropped is not None:
            dropped = np.concatenate([np.zeros(context, bool), dropped])
    n = len(t)
    if n == context:  # nothing new
        if carry is not None:
            d._batch_carry = carry
            if final:
                return _finish(d, [], carry, t, a, g, temps, flush), rejected, out_of_range
        return [], rejected, out_of_range

    window_ns, trim_ns = d._window_ns, int(d.trim_s * 1e9)
    gaps = np.concatenate([[False], np.diff(t) > d._gap_ns])
    segment_first = np.maximum.accumulate(np.where(gaps | (np.arange(n) == 0), np.arange(n), 0))
    start = np.maximum(np.searchsorted(t, t - window_ns, side="right"), segment_first)
    count = np.arange(n) - start + 1
    full = ((t - t[start]) >= d._full_ns) & (count >= 5)
    full[:context] = False  # decided in the part before
    # Windows mostly of repeated samples are no evidence of the noise (update(): 2 * repeats <= n).
    accel_evidence = 2 * _repeats_in_window(a, start) <= count
    gyro_evidence = None if g is None else 2 * _repeats_in_window(g, start) <= count
    window_stats = _window_variance([a] if g is None else [a, g], start, segment_first, full)
    accel_var, accel_mean = window_stats[0]
    gyro_var = None if g is None else window_stats[1][0]
    # A window whose mean is no gravity (a dead sensor's quiet zeros) does not teach the floor either.
    plausible = np.einsum("ij,ij->i", accel_mean, accel_mean) >= d._min_magnitude_squared
    accel_evidence &= plausible
    if gyro_evidence is not None:
        gyro_evidence &= plausible
    dt = np.concatenate([[0], np.diff(t)])
    full_time = d._full_time_ns + np.cumsum(np.where(full & accel_evidence, dt, 0))
    d._full_time_ns = int(full_time[-1])

    full_index = np.flatnonzero(full)
    accel_limit = np.full(n, np.nan)
    gyro_limit = np.full(n, np.nan)
    warm = full_time >= d._warmup_ns
    warm_full = warm[full_index]
    accel_limit[full_index], d._accel_quietest = _limit_per_window(
        accel_var, accel_evidence, full_index, warm_full, d._accel_floor, d.accel_var_threshold, d.k_sigma,
        d._rise_var, d._accel_cap, d._accel_quietest)
    if gyro_var is not None and gyro_evidence is not None:  # there is a gyro
        gyro_limit[full_index], d._gyro_quietest = _limit_per_window(
            gyro_var, gyro_evidence, full_index, warm_full, d._gyro_floor, d.gyro_var_threshold, d.gyro_k_sigma,
            d._rise_var, d._gyro_cap, d._gyro_quietest)
    learning = full & np.isnan(accel_limit)
    with np.errstate(invalid="ignore"):
        quiet_gyro = np.ones(n, bool) if g is None else (np.isnan(gyro_limit) | (gyro_var <= gyro_limit))
        still = full & ~learning & (accel_var <= accel_limit) & quiet_gyro

    poses: list[Pose] = []

    def emit(opened: int, last: int, trim_end: bool) -> None:
        _emit(poses, d, t, a, g, temps, start, opened, last, trim_end, trim_ns)

    # The interval rules, applied per run of samples in the same state (runs break at gaps and at
    # state changes): 0 window not full, 1 learning the floor, 2 still, 3 moving.
    state = np.where(~full, 0, np.where(learning, 1, np.where(still, 2, 3)))
    changes = (state[context + 1:] != state[context:-1]) | gaps[context + 1:]
    boundary = context + np.flatnonzero(np.concatenate([[True], changes]))
    ends = np.concatenate([boundary[1:], [n]]) - 1
    opened: int | None = None if carry is None else carry.opened  # index that opened the current interval
    last = 0 if carry is None else carry.last  # the last sample added to it (read only while one is open)
    warmup = d._warmup_max  # the loudest windows of the warm-up, until the threshold is known
    loudest_accel, loudest_gyro = (0.0, 0.0) if warmup is None else warmup
    warmup_open = warmup is not None
    max_pose_ns = int(d.max_pose_s * 1e9) if math.isfinite(d.max_pose_s) else None
    for first, final_row in zip(boundary.tolist(), ends.tolist()):
        if gaps[first] and opened is not None:
            if dropped is None or not dropped[first]:
                emit(opened, last, True)
            opened = None
        kind = state[first]
        if kind == 0:
            continue
        if kind == 1:
            loudest_accel = max(loudest_accel, float(accel_var[first:final_row + 1].max()))
            if gyro_var is not None:
                loudest_gyro = max(loudest_gyro, float(gyro_var[first:final_row + 1].max()))
            if opened is None:
                opened = first
            last = final_row
            continue
        if warmup_open:
            warmup_open = False
            limit_g = gyro_limit[first]
            if opened is not None and not (loudest_accel <= accel_limit[first]
                                           and (math.isnan(limit_g) or loudest_gyro <= limit_g)):
                opened = None  # it moved during warm-up: no pose from it
        if kind == 3:
            if opened is not None:
                emit(opened, last, True)
                opened = None
            continue
        # A run of still samples: open at its first sample if nothing is open, cut at max_pose_s.
        i = first
        if opened is None:
            opened = last = first
            i = first + 1
        while i <= final_row:
            limit = None if max_pose_ns is None else t[start[opened]] + max_pose_ns
            split = final_row + 1 if limit is None else max(i, int(np.searchsorted(t, limit, side="left")))
            if split > final_row:
                last = final_row
                break
            emit(opened, split, True)
            opened = last = split
            i = split + 1
    d._warmup_max = (loudest_accel, loudest_gyro) if warmup_open else None
    # What the next part needs: the window of the last row (the next rows' windows start no earlier), and
    # the open interval from its window's first row (emit trims from there).
    keep_from = int(start[n - 1]) if opened is None else min(int(start[n - 1]), int(start[opened]))
    left = BatchCarry(t[keep_from:].copy(), a[keep_from:].copy(), None if g is None else g[keep_from:].copy(),
                      None if temps is None else temps[keep_from:].copy(),
                      None if opened is None else opened - keep_from, max(last - keep_from, 0))
    if not final:
        d._batch_carry = left
        return poses, rejected, out_of_range
    return _finish(d, poses, left, t, a, g, temps, flush, opened, last, start, trim_ns), rejected, out_of_range


def _finish(d: StaticDetector, poses: list[Pose], carry: BatchCarry, t: np.ndarray, a: np.ndarray,
            g: np.ndarray | None, temps: np.ndarray | None, flush: bool, opened: int | None = None,
            last: int = 0, start: np.ndarray | None = None, trim_ns: int = 0) -> list[Pose]:
    """The end of the recording: the interval still open is a pose when `flush` (it was not moving)."""
    d._batch_carry = None
    if start is None:  # no new rows came: the open interval is the carried one
        opened = carry.opened
        last = carry.last
        trim_ns = int(d.trim_s * 1e9)
        segment_first = np.zeros(len(t), dtype=np.int64)
        start = np.maximum(np.searchsorted(t, t - d._window_ns, side="right"), segment_first)
    if opened is not None and flush:
        _emit(poses, d, t, a, g, temps, start, opened, last, False, trim_ns)
    return poses


def _emit(poses: list[Pose], d: StaticDetector, t: np.ndarray, a: np.ndarray, g: np.ndarray | None,
          temps: np.ndarray | None, start: np.ndarray, opened: int, last: int, trim_end: bool, trim_ns: int) -> None:
    """The interval opened at row `opened` (its window's first row gives the start, trimmed) up to row
    `last` (trimmed at the end when motion ended it) as a pose, when long enough."""
    first_time = t[start[opened]] + trim_ns
    k0 = int(np.searchsorted(t, first_time, side="left"))
    k0 = max(k0, int(start[opened]))
    k1 = int(np.searchsorted(t, t[last] - trim_ns, side="right")) - 1 if trim_end else last
    k1 = min(k1, last)
    if k1 - k0 + 1 < 2 or t[k1] - t[k0] < d.min_hold_s * 1e9:
        return
    rows = a[k0:k1 + 1]
    temperature = spread = None
    if temps is not None:
        known = temps[k0:k1 + 1][~np.isnan(temps[k0:k1 + 1])]
        if len(known):
            temperature, spread = float(known.mean()), float(known.max() - known.min())
    poses.append(Pose(
        accel_mps2=rows.mean(axis=0),
        accel_cov=np.cov(rows, rowvar=False),
        samples=k1 - k0 + 1,
        start_ns=int(t[k0]),
        end_ns=int(t[k1]),
        gyro_radps=None if g is None else g[k0:k1 + 1].mean(axis=0),
        temperature_degc=temperature,
        temperature_spread_degc=spread,
    ))
