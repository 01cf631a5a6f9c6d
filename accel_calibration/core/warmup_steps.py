"""Steps in a warm-up's bias (a sensor reset, a knock, a bump that comes back): found in time, where the
bias jumps between two neighbouring stretches by more than their noise and more than a smooth drift
could. One-second block means; at every block boundary a line is fitted to the blocks before and one
to the blocks after, both carried to the boundary; their difference is the jump there."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BLOCK_S = 1.0
SIDE_BLOCKS = 15  # blocks on each side of a boundary (a line through each)
STEP_SIGMAS = 8.0  # a jump this many of its sigmas is no noise
BUMP_MAX_S = 120.0  # two opposite jumps this close that cancel: a bump, its stretch left out


@dataclass(frozen=True)
class Step:
    """A jump in the bias at `time_ns` (of the recording's clock), per axis, in the input units."""

    time_ns: int
    jump: np.ndarray  # (C,) per channel, in the input units
    sigma: np.ndarray  # (C,) one sigma of each channel's jump

    @property
    def sigmas(self) -> float:
        """The largest channel's jump in its sigmas."""
        return float(np.max(np.abs(self.jump) / self.sigma))


def _line_weights() -> tuple[np.ndarray, np.ndarray]:
    """Weights that carry a least-squares line through SIDE_BLOCKS block means to the boundary: the
    blocks before (at -L..-1) and after (0..L-1), the boundary at -0.5."""
    x_before = np.arange(-SIDE_BLOCKS, 0, dtype=float)
    x_after = np.arange(SIDE_BLOCKS, dtype=float)
    weights = []
    for x in (x_before, x_after):
        design = np.column_stack([np.ones_like(x), x])
        weights.append(np.array([1.0, -0.5]) @ np.linalg.pinv(design))
    return weights[0], weights[1]


def _block_means(t_ns: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of consecutive one-second blocks holding samples: block start times, (B, C) means and the
    count in each."""
    block = (t_ns - t_ns[0]) // int(BLOCK_S * 1e9)
    starts = np.flatnonzero(np.concatenate([[True], np.diff(block) != 0]))
    counts = np.diff(np.concatenate([starts, [len(t_ns)]]))
    sums = np.add.reduceat(values, starts, axis=0)
    return t_ns[starts], sums / counts[:, None], counts


def find_steps(t_ns: np.ndarray, values: np.ndarray, floor: np.ndarray) -> list[Step]:
    """Jumps in `values` (N, C) sampled at `t_ns` (still samples of one recording, in time order) larger
    than STEP_SIGMAS of their noise and than `floor` (C,), one per run of boundaries above both, at the
    largest."""
    starts, means, _ = _block_means(t_ns, values)
    if len(means) < 2 * SIDE_BLOCKS + 1:
        return []
    before, after = _line_weights()
    windows = np.lib.stride_tricks.sliding_window_view(means, SIDE_BLOCKS, axis=0)  # (B-L+1, C, L)
    jumps = np.einsum("bcl,l->bc", windows[SIDE_BLOCKS:], after) - np.einsum("bcl,l->bc", windows[:-SIDE_BLOCKS],
                                                                               before)
    # Noise of one block mean, robustly, from second differences (a smooth drift cancels in them).
    second = np.diff(means, n=2, axis=0)
    block_sigma = 1.4826 * np.median(np.abs(second - np.median(second, axis=0)), axis=0) / np.sqrt(6.0)
    jump_sigma = np.maximum(block_sigma * np.sqrt(before @ before + after @ after), 1e-300)
    ratio = np.abs(jumps) / jump_sigma
    above = np.any((ratio > STEP_SIGMAS) & (np.abs(jumps) > floor), axis=1)
    strength = np.max(ratio, axis=1)
    # The largest first; a boundary within SIDE_BLOCKS of a larger one is its side lobe (a line through
    # blocks that straddle a step carries part of it to the boundaries near it).
    candidates = sorted(np.flatnonzero(above), key=lambda b: -strength[b])
    peaks: list[int] = []
    for candidate in candidates:
        if all(abs(int(candidate) - peak) > SIDE_BLOCKS for peak in peaks):
            peaks.append(int(candidate))
    steps = []
    for peak in sorted(peaks):
        boundary = peak + SIDE_BLOCKS  # the first block after the jump
        steps.append(Step(int(starts[boundary]), jumps[peak].copy(), jump_sigma.copy()))
    return steps


def bumps_and_breaks(steps: list[Step]) -> tuple[list[tuple[int, int]], list[Step]]:
    """Pairs of consecutive steps within BUMP_MAX_S that cancel (the bias came back): the stretches to
    leave out, (start_ns, end_ns); the other steps: lasting jumps, where a recording is cut."""
    bumps: list[tuple[int, int]] = []
    breaks: list[Step] = []
    index = 0
    while index < len(steps):
        step = steps[index]
        if index + 1 < len(steps):
            following = steps[index + 1]
            close = (following.time_ns - step.time_ns) <= BUMP_MAX_S * 1e9
            # In sigmas over all channels: what is left of the two jumps together is small beside either.
            left = float(np.linalg.norm((step.jump + following.jump) / step.sigma))
            larger = max(float(np.linalg.norm(s.jump / step.sigma)) for s in (step, following))
            cancels = left <= 0.3 * larger + STEP_SIGMAS
            if close and cancels:
                bumps.append((step.time_ns, following.time_ns))
                index += 2
                continue
        breaks.append(step)
        index += 1
    return bumps, breaks
