"""FROZEN PEER for bench/bench_static_detector.py: a verbatim copy of
accel_calibration/core/static_detector_batch.py as it was before the speed work of issue 13, so the
bench can print new vs before on the same data in the same run. Do not edit or import elsewhere.

StaticDetector.process(): the streaming detector's rules applied to a whole recording with array
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
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from accel_calibration.core.pose import Pose
from accel_calibration.core.stream.detector_batch import HARD_LIMIT as _HARD_LIMIT
from accel_calibration.core.stream.noise_floor import BINS_PER_DECADE as _BINS_PER_DECADE
from accel_calibration.core.stream.noise_floor import LOG_MAX as _LOG_MAX
from accel_calibration.core.stream.noise_floor import LOG_MIN as _LOG_MIN
from accel_calibration.core.stream.noise_floor import NBINS as _NBINS

if TYPE_CHECKING:
    from typing import Any as StaticDetector  # the bench's view of the detector's settings, old names

_QUERY_EVERY = 64


def _floor_values(variances: np.ndarray, quantile: float, half_life: int) -> np.ndarray:
    """The floor value in force after each window, as _VarianceFloor would give it (it skips non-finite
    variances, which finite sums inside the guard cannot give; NaN until the first add)."""
    finite = np.isfinite(variances)
    if not finite.all():
        values = _floor_values_of_adds(variances[finite], quantile, half_life)
        last_add = np.cumsum(finite) - 1
        return np.where(last_add >= 0, values[np.maximum(last_add, 0)] if len(values) else np.nan, np.nan)
    return _floor_values_of_adds(variances, quantile, half_life)


def _floor_values_of_adds(variances: np.ndarray, quantile: float, half_life: int) -> np.ndarray:
    """The floor value in force after each add."""
    count = len(variances)
    if count == 0:
        return np.zeros(0)
    with np.errstate(divide="ignore", invalid="ignore"):
        index = np.floor((np.log10(variances) - _LOG_MIN) * _BINS_PER_DECADE)
    index = np.where(variances <= 0.0, 0, np.clip(np.nan_to_num(index, nan=0.0), 0, _NBINS - 1)).astype(np.int64)
    # Queries after add 1, 65, 129, ... (1-based); decays after add 200000, 400000, ...
    query_adds = np.arange(1, count + 1, _QUERY_EVERY)
    centres = 10.0 ** (_LOG_MIN + (np.arange(_NBINS) + 0.5) / _BINS_PER_DECADE)
    if count < half_life:
        # No decay yet: the histogram at each query is a cumulative sum over query blocks.
        block = np.searchsorted(query_adds, np.arange(1, count + 1), side="left")
        counted = block < len(query_adds)  # adds after the last query never reach one
        per_block = np.zeros((len(query_adds), _NBINS))
        np.add.at(per_block, (block[counted], index[counted]), 1.0)
        counts = np.cumsum(per_block, axis=0)
        running = np.cumsum(counts, axis=1)
        hit: np.ndarray = (running >= quantile * query_adds[:, None]) & (counts > 0)
        values = np.where(hit.any(axis=1), centres[np.argmax(hit, axis=1)], 10.0**_LOG_MAX)
        return values[(np.arange(1, count + 1) - 1) // _QUERY_EVERY]
    values = np.empty(len(query_adds))
    counts = np.zeros(_NBINS)
    total = 0.0
    done = 0  # adds already in `counts`
    for q, upto in enumerate(query_adds):
        while done < upto:
            next_decay = (done // half_life + 1) * half_life
            stop = min(int(upto), next_decay)
            counts += np.bincount(index[done:stop], minlength=_NBINS)
            total += stop - done
            done = stop
            if done == next_decay:
                counts *= 0.5
                total *= 0.5
        running = np.cumsum(counts)
        hit = np.flatnonzero((running >= quantile * total) & (counts > 0))
        values[q] = centres[hit[0]] if len(hit) else 10.0**_LOG_MAX
    return values[(np.arange(1, count + 1) - 1) // _QUERY_EVERY]


def _window_variance(values: np.ndarray, start: np.ndarray, segment_first: np.ndarray,
                     full: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total variance (sum over axes) and mean of values[start_i .. i] for each full window i (0 elsewhere:
    never used), about each segment's median.

    Blocks are as long as the shortest full window, so every full window holds a block boundary; it
    is summed from pieces that lie inside it: the end of the block holding its first sample, whole
    blocks between (only for a window longer than the shortest), the start of the block holding its
    last sample.
    """
    n_rows = len(values)
    variance = np.zeros(n_rows)
    mean = np.zeros((n_rows, 3))
    windows = np.flatnonzero(full)  # index of each full window's last sample
    if not len(windows):
        return variance, mean
    first = start[windows]
    block = int((windows - first).min()) + 1
    reference = np.empty_like(values)
    firsts = np.flatnonzero(segment_first == np.arange(n_rows))
    for begin, end in zip(firsts.tolist(), [*firsts[1:].tolist(), n_rows]):
        # Median, not the first sample: a glitch there would leave every window far from its reference.
        reference[begin:end] = np.median(values[begin:end], axis=0)
    shifted = values - reference
    rows = np.column_stack([shifted, np.einsum("ij,ij->i", shifted, shifted)])  # x y z |x|^2
    blocks = -(-n_rows // block)
    padded: np.ndarray = np.zeros((blocks * block, 4))
    padded[:n_rows] = rows
    padded = padded.reshape(blocks, block, 4)
    prefix = np.cumsum(padded, axis=1).reshape(-1, 4)  # from the block's first row to this one
    suffix = np.cumsum(padded[:, ::-1], axis=1)[:, ::-1].reshape(-1, 4)  # from this row to the block's last
    totals = np.vstack([padded.sum(axis=1), np.zeros((1, 4))])

    boundary = windows // block * block  # the last block boundary at or before the window's last row
    sums = prefix[windows].copy()  # [boundary, last]
    head = np.flatnonzero(boundary > first)  # the window starts before that boundary
    sums[head] += suffix[first[head]]  # [first, end of its block]
    first_block, last_block = first[head] // block + 1, boundary[head] // block
    between = first_block < last_block  # whole blocks in between
    if between.any():
        pairs = np.column_stack([first_block[between], last_block[between]]).reshape(-1)
        sums[head[between]] += np.add.reduceat(totals, pairs, axis=0)[::2]

    count = windows - first + 1
    s1, s2 = sums[:, :3], sums[:, 3]
    variance[windows] = (s2 - np.einsum("ij,ij->i", s1, s1) / count) / count
    mean[windows] = reference[windows] + s1 / count[:, None]
    return variance, mean


def _repeats_in_window(values: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Per row: how many rows of its window start_i .. i repeat their predecessor bit for bit (all three
    axes; the first row of the recording has none), as update() counts them."""
    repeat = np.zeros(len(values), dtype=np.int64)
    if len(values) > 1:
        repeat[1:] = np.all(values[1:] == values[:-1], axis=1)
    running = np.concatenate([[0], np.cumsum(repeat)])
    return np.asarray(running[1:] - running[start])


def _quietest(floor: np.ndarray, warm: np.ndarray) -> np.ndarray:
    """The lowest floor value in force after warm-up so far (inf before), per full window."""
    candidates = np.where(warm & ~np.isnan(floor), floor, np.inf)
    return np.asarray(np.minimum.accumulate(candidates)) if len(candidates) else candidates


def detect_batch(detector: StaticDetector, t_ns: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None,
                 temperature_degc: ArrayLike | None = None,
                 drop: ArrayLike | None = None, flush: bool = True) -> tuple[list[Pose], int, int]:
    """(poses, rejected samples, of which finite but out of range). `drop` (per sample, optional): the
    interval open before this sample is dropped, not emitted (discard(); the stamps must then make this
    sample start a new window). `flush` False: the interval open at the end is dropped too."""
    d = detector
    t_all = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    a_all = np.asarray(accel, dtype=float).reshape(-1, 3)
    g_all = None if gyro is None else np.asarray(gyro, dtype=float).reshape(-1, 3)
    temp_all = None if temperature_degc is None else np.asarray(temperature_degc, dtype=float).reshape(-1)
    if temp_all is not None:
        with np.errstate(invalid="ignore"):
            # NaN, inf or absurd: that sample has no temperature, as in update()
            temp_all = np.where(np.abs(temp_all) <= _HARD_LIMIT, temp_all, np.nan)
    with np.errstate(invalid="ignore"):
        # As update(): NaN/inf or beyond the limit on any axis rejects the sample (NaN compares False).
        valid = np.all(np.abs(a_all) <= d._accel_max, axis=1)
        finite = np.all(np.isfinite(a_all), axis=1)
        if g_all is not None:
            valid &= np.all(np.abs(g_all) <= d._gyro_max, axis=1)
            finite &= np.all(np.isfinite(g_all), axis=1)
    out_of_range = int(np.count_nonzero(finite & ~valid))
    t_f = t_all[valid]
    previous_max = np.concatenate([[np.iinfo(np.int64).min], np.maximum.accumulate(t_f)[:-1]]) if len(t_f) else t_f
    accepted = t_f > previous_max  # a stamp not after the last accepted one is skipped, as update() does
    rejected = len(t_all) - int(accepted.sum())
    keep = np.flatnonzero(valid)[accepted]
    dropped = None
    if drop is not None:
        # A discard before a rejected sample still applies to the next accepted one.
        marked = np.concatenate([[0], np.cumsum(np.asarray(drop, dtype=bool).reshape(-1))])
        upto = marked[keep + 1]
        dropped = (upto - np.concatenate([[0], upto[:-1]])) > 0
    t = t_all[keep]
    a = a_all[keep]
    g = None if g_all is None else g_all[keep]
    temps = None if temp_all is None else temp_all[keep]
    n = len(t)
    if n == 0:
        return [], rejected, out_of_range

    window_ns, trim_ns = d._window_ns, int(d.trim_s * 1e9)
    gaps = np.concatenate([[False], np.diff(t) > d._gap_ns])
    segment_first = np.maximum.accumulate(np.where(gaps | (np.arange(n) == 0), np.arange(n), 0))
    start = np.maximum(np.searchsorted(t, t - window_ns, side="right"), segment_first)
    count = np.arange(n) - start + 1
    full = ((t - t[start]) >= d._full_ns) & (count >= 5)
    # Windows mostly of repeated samples are no evidence of the noise (update(): 2 * repeats <= n).
    accel_evidence = 2 * _repeats_in_window(a, start) <= count
    gyro_evidence = None if g is None else 2 * _repeats_in_window(g, start) <= count
    accel_var, accel_mean = _window_variance(a, start, segment_first, full)
    gyro_var = None if g is None else _window_variance(g, start, segment_first, full)[0]
    # A window whose mean is no gravity (a dead sensor's quiet zeros) does not teach the floor either.
    plausible = np.einsum("ij,ij->i", accel_mean, accel_mean) >= d._min_magnitude_squared
    accel_evidence &= plausible
    if gyro_evidence is not None:
        gyro_evidence &= plausible
    dt = np.concatenate([[0], np.diff(t)])
    full_time = np.cumsum(np.where(full & accel_evidence, dt, 0))

    full_index = np.flatnonzero(full)
    accel_limit = np.full(n, np.nan)
    gyro_limit = np.full(n, np.nan)
    warm = full_time >= d._warmup_ns
    warm_full = warm[full_index]
    # NaN marks a window that does not feed the floor (_floor_values carries the last value over it).
    floor_a = _floor_values(np.where(accel_evidence, accel_var, np.nan)[full_index], d._accel_floor.quantile,
                            d._accel_floor.half_life)
    if d.accel_var_threshold is not None:
        accel_limit[full_index] = d.accel_var_threshold
    else:
        bounded = np.minimum(floor_a, _quietest(floor_a, warm_full) * d._rise_var)
        with np.errstate(invalid="ignore"):
            accel_limit[full_index] = np.where(warm_full, np.minimum(d.k_sigma * bounded, d._accel_cap), np.nan)
    if gyro_var is not None and gyro_evidence is not None:  # there is a gyro
        floor_g = _floor_values(np.where(gyro_evidence, gyro_var, np.nan)[full_index], d._gyro_floor.quantile,
                                d._gyro_floor.half_life)
        if d.gyro_var_threshold is not None:
            gyro_limit[full_index] = d.gyro_var_threshold
        else:
            bounded = np.minimum(floor_g, _quietest(floor_g, warm_full) * d._rise_var)
            with np.errstate(invalid="ignore"):
                gyro_limit[full_index] = np.where(warm_full, np.minimum(d.gyro_k_sigma * bounded, d._gyro_cap),
                                                  np.nan)
    learning = full & np.isnan(accel_limit)
    with np.errstate(invalid="ignore"):
        quiet_gyro = np.ones(n, bool) if g is None else (np.isnan(gyro_limit) | (gyro_var <= gyro_limit))
        still = full & ~learning & (accel_var <= accel_limit) & quiet_gyro

    poses: list[Pose] = []

    def emit(opened: int, last: int, trim_end: bool) -> None:
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

    # The interval rules, applied per run of samples in the same state (runs break at gaps and at
    # state changes): 0 window not full, 1 learning the floor, 2 still, 3 moving.
    state = np.where(~full, 0, np.where(learning, 1, np.where(still, 2, 3)))
    boundary = np.flatnonzero(np.concatenate([[True], (state[1:] != state[:-1]) | gaps[1:]]))
    ends = np.concatenate([boundary[1:], [n]]) - 1
    opened: int | None = None  # index that opened the current interval
    last = 0  # the last sample added to it (read only while one is open)
    warmup_open = d.accel_var_threshold is None
    loudest_accel = loudest_gyro = 0.0
    max_pose_ns = int(d.max_pose_s * 1e9) if math.isfinite(d.max_pose_s) else None
    for first, final in zip(boundary.tolist(), ends.tolist()):
        if gaps[first] and opened is not None:
            if dropped is None or not dropped[first]:
                emit(opened, last, True)
            opened = None
        kind = state[first]
        if kind == 0:
            continue
        if kind == 1:
            loudest_accel = max(loudest_accel, float(accel_var[first:final + 1].max()))
            if gyro_var is not None:
                loudest_gyro = max(loudest_gyro, float(gyro_var[first:final + 1].max()))
            if opened is None:
                opened = first
            last = final
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
        while i <= final:
            limit = None if max_pose_ns is None else t[start[opened]] + max_pose_ns
            split = final + 1 if limit is None else max(i, int(np.searchsorted(t, limit, side="left")))
            if split > final:
                last = final
                break
            emit(opened, split, True)
            opened = last = split
            i = split + 1
    if opened is not None and flush:
        emit(opened, last, False)
    return poses, rejected, out_of_range
