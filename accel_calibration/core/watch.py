"""The calibration in force, watched: every still pose found since it was put in force is tested against
it by `accel-calib check`'s statistics and change rule (core/check.py, core/change_rule.py), so a bias
that moved shows while the vehicle stands, without a recording or a person. A move while it watches is
judged on the poses since the move, so it reads at its size (all the poses since the calibration was put in
force would mix in those from before, which hold: a 5 mg move read +0.4 mg, then +1.5 mg 20 poses later).
It only says; nothing here applies anything (the session refuses to fit poses from before a move with those
after: core/session.py)."""
from __future__ import annotations

import collections
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .calibration import Calibration
from .change_rule import ChangeRule
from .check import CheckResult, _linearised, check_calibration
from .pose import Pose
from .units import MG

# The latest poses kept for the check: a vehicle standing for hours still finds only one pose per still
# interval, so this holds many sessions' worth while bounding the check's cost (a few ms).
WATCH_CAPACITY = 64
# A move is placed among the poses watched only with at least this many after it: fewer would place it at a
# pose that was merely knocked during its hold.
MIN_POSES_AFTER_MOVE = 3


@dataclass(frozen=True)
class WatchState:
    moved: bool  # a change (or a pose) beyond the rule: the node warns
    text: str  # "calibration holds (8 poses, 0.2 mg rms)", "bias y +5.1 mg (12 σ): recalibrate", ...


class CalibrationWatch:
    """The poses found since the calibration in force was put in force, and what the check says of them.
    The node's worker alone calls it; `state` is replaced whole (the diagnostics' thread reads it)."""

    def __init__(self, rule: ChangeRule | None = None, capacity: int = WATCH_CAPACITY):
        self.rule = rule or ChangeRule()
        self.calibration: Calibration | None = None
        self.result: CheckResult | None = None
        self._poses: collections.deque[Pose] = collections.deque(maxlen=capacity)
        self.state = WatchState(False, "no calibration in force")
        # While a change is flagged: when the first pose judged after the move began (stream time, ns); a pose
        # that began before is of the sensor before it. None while the calibration holds.
        self.moved_since_ns: int | None = None

    @property
    def poses(self) -> list[Pose]:
        return list(self._poses)

    def restart(self, calibration: Calibration | None) -> None:
        """A calibration put in force (loaded or applied): the poses before it no longer count."""
        self.calibration = calibration
        self._poses.clear()
        self.result = None
        self.moved_since_ns = None
        self.state = WatchState(False, "no calibration in force" if calibration is None
                                else "watching: no still pose since the calibration was put in force")

    def add(self, poses: Iterable[Pose]) -> WatchState:
        """New still poses: the calibration in force checked against every pose since it was put in force;
        when it moved, judged on the poses since the move."""
        new = list(poses)
        if self.calibration is None or not new:
            return self.state
        self._poses.extend(new)
        watched = list(self._poses)
        try:
            result = check_calibration(self.calibration, watched, self.rule)
            split = 0
            if result.verdict == "moved":
                split, result = self._since_the_move(self.calibration, watched, result)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as error:  # says so; never stops the worker
            self.state = WatchState(False, f"cannot check the calibration in force ({type(error).__name__}: {error})")
            self.moved_since_ns = None
            return self.state
        self.result = result
        state = watch_state(result)
        if split:
            state = WatchState(state.moved, f"{state.text}; it moved after {split} of the {len(watched)} poses "
                                            f"watched: judged on the {len(watched) - split} since")
        self.state = state
        # A pose off |a| = g alone (knocked during its hold) is no move to place.
        changed = bool(result.moved or result.moved_groups)
        self.moved_since_ns = watched[split].start_ns if changed else None
        return self.state

    def _since_the_move(self, calibration: Calibration, poses: list[Pose],
                        whole: CheckResult) -> tuple[int, CheckResult]:
        """Where among `poses` the calibration moved (the index of the first pose after it; 0: before them
        all) and the check of the poses since; `whole` is the check of them all."""
        split = move_split(calibration, poses, whole.gravity, self.rule.k_sigma ** 2)
        if split == 0:
            return 0, whole
        after = check_calibration(calibration, poses[split:], self.rule)
        if not (after.moved or after.moved_groups):
            return 0, whole
        return split, after


def move_split(calibration: Calibration, poses: list[Pose], gravity: float, threshold: float) -> int:
    """The first pose after a move among `poses` (in the order found), 0 when none is placed: the split
    whose poses after it, their six changes fitted alone, explain most of the residuals (chi-square), the
    poses before it held to no change. A split is placed only when it explains more than `threshold` beyond
    the changes fitted to all the poses (the poses before it then disagree with the move at that
    chi-square): the likelihood ratio of one step in the calibration against none since it was put in force,
    in units of what the split leaves unexplained per degree of freedom when that is more than its noise (a
    change the six do not describe, another sensor's misalignment, is no step to place)."""
    if len(poses) <= MIN_POSES_AFTER_MOVE:
        return 0
    terms = _linearised(calibration, poses, gravity)
    sigma = np.sqrt(terms.noise + np.square(np.abs(terms.shared) @ terms.calibration_sigma))
    weighted, design = terms.residual / sigma, terms.jacobian / sigma[:, None]
    explained = np.array([_explained(design[split:], weighted[split:])
                          for split in range(len(poses) - MIN_POSES_AFTER_MOVE + 1)])
    # Poses that see none of what moved fit either side: the latest split within 4 of the best chi-square
    # (its 2-sigma interval) leaves them before, so the poses judged after the move are its own.
    best = int(np.flatnonzero(explained >= explained.max() - 4.0)[-1])
    freedom = len(poses) - min(design.shape[1], len(poses) - best) - 1
    if best == 0 or freedom < 1:
        return 0
    dispersion = max(1.0, (float(weighted @ weighted) - explained[best]) / freedom)
    return best if explained[best] - explained[0] > threshold * dispersion else 0


def _explained(design: np.ndarray, weighted: np.ndarray) -> float:
    """The chi-square of the weighted residuals the changes explain, fitted by least squares (columns scaled
    to one, so a combination the poses cannot see is cut off, not fitted to their noise)."""
    norms = np.linalg.norm(design, axis=0)
    columns = design[:, norms > 0] / norms[norms > 0]
    if columns.shape[1] == 0:
        return 0.0
    fitted = columns @ np.linalg.lstsq(columns, weighted, rcond=1e-6)[0]
    return float(fitted @ fitted)


def watch_state(result: CheckResult) -> WatchState:
    """One line for /diagnostics: what moved, with its sigmas, or that the calibration holds."""
    poses = len(result.poses)
    rms = float(np.sqrt(np.mean([p.residual_mps2**2 for p in result.poses]))) / MG if poses else 0.0
    if result.verdict == "moved":
        said = [f"{c.name} " + (f"{c.change / MG:+.1f} mg" if c.quantity == "bias" else f"{c.change * 100:+.2f} %")
                + f" ({c.judgement.sigmas:.0f} σ)"
                for c in result.moved if c.change is not None and c.judgement is not None]
        said += [group.said(mg=".1f", sigmas=".0f", sigma_word="σ") for group in result.moved_groups]
        off = result.poses_off
        if off:
            said.append(f"{len(off)} of {poses} poses off |a| = g")
        return WatchState(True, ", ".join(said) + f": recalibrate ({poses} poses, {rms:.1f} mg rms)")
    unseen = [c.name for c in result.unobserved]
    return WatchState(False, f"calibration holds ({poses} pose{'' if poses == 1 else 's'}, {rms:.1f} mg rms"
                      + (f"; not observable from them: {', '.join(unseen)}" if unseen else "") + ")")
