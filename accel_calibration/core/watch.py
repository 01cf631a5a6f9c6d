"""The calibration in force, watched: every still pose found since it was put in force is tested against
it by `accel-calib check`'s statistics and change rule (core/check.py, core/change_rule.py), so a bias
that moved shows while the vehicle stands, without a recording or a person. It only says; nothing here
applies anything."""
from __future__ import annotations

import collections
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .calibration import Calibration
from .change_rule import ChangeRule
from .check import CheckResult, check_calibration
from .pose import Pose
from .units import MG

# The latest poses kept for the check: a vehicle standing for hours still finds only one pose per still
# interval, so this holds many sessions' worth while bounding the check's cost (a few ms).
WATCH_CAPACITY = 64


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

    @property
    def poses(self) -> list[Pose]:
        return list(self._poses)

    def restart(self, calibration: Calibration | None) -> None:
        """A calibration put in force (loaded or applied): the poses before it no longer count."""
        self.calibration = calibration
        self._poses.clear()
        self.result = None
        self.state = WatchState(False, "no calibration in force" if calibration is None
                                else "watching: no still pose since the calibration was put in force")

    def add(self, poses: Iterable[Pose]) -> WatchState:
        """New still poses: the calibration in force checked against every pose since it was put in force."""
        new = list(poses)
        if self.calibration is None or not new:
            return self.state
        self._poses.extend(new)
        try:
            result = check_calibration(self.calibration, list(self._poses), self.rule)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError) as error:  # says so; never stops the worker
            self.state = WatchState(False, f"cannot check the calibration in force ({type(error).__name__}: {error})")
            return self.state
        self.result = result
        self.state = watch_state(result)
        return self.state


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
