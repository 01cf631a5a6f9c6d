"""Does a calibration still hold on the still poses of a new recording?

Per pose: the corrected magnitude |M (a - b)| - g with its sigma, from the pose's own noise (its sample
covariance over its sample count) and the calibration's uncertainty (its 1-sigma of b and M). Per axis:
the bias change and the scale change the poses can observe, by weighted least squares of those
residuals on the six changes. The calibration's error is common to every pose and the file keeps its
1-sigmas without their correlations, so its share is bounded by the sum of the absolute contributions.
A change the poses' directions cannot tell from another (a bias and the scale of an axis seen from one
side only) is named, not guessed. Each figure is judged by the change rule of `accel-calib history`
(core/change_rule.py)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .calibration import Calibration
from .change_rule import ChangeJudgement, ChangeRule
from .coverage import FACE_COSINE, orientation_advice
from .observability import Observability, observability
from .pose import Pose
from .units import AXES, MG

QUANTITIES = ("bias", "scale")
# A combination of changes the poses cannot tell apart is named by the changes with at least this share
# of it (a unit vector in effect units): "bias z or scale z", not every term with a trace in it.
GROUP_MEMBER_SHARE = 0.1


@dataclass(frozen=True)
class PoseCheck:
    direction: np.ndarray  # unit corrected specific force, sensor frame
    samples: int
    residual_mps2: float  # |corrected| - g
    sigma_mps2: float  # pose noise and calibration uncertainty together
    judgement: ChangeJudgement


@dataclass(frozen=True)
class AxisChange:
    quantity: str  # "bias" (b_new - b, m/s^2, raw axes) or "scale" (the axis' gain change, fraction)
    axis: str
    change: float | None  # None: the poses cannot observe it
    sigma: float | None
    judgement: ChangeJudgement | None

    @property
    def name(self) -> str:
        return f"{self.quantity} {self.axis}"


@dataclass(frozen=True)
class GroupChange:
    """A combination of changes the poses observe but cannot tell apart (a z bias or a z gain, from poses
    near level): its effect on |a| at 1 g (m/s^2), judged as a bias; the orientations that would part it."""

    members: tuple[str, ...]  # "bias z", "scale z"
    change: float
    sigma: float
    judgement: ChangeJudgement
    advice: tuple[str, ...]

    @property
    def name(self) -> str:
        return " or ".join(self.members) if len(self.members) < 3 else \
            ", ".join(self.members[:-1]) + " or " + self.members[-1]

    def said(self, mg: str = ".2f", sigmas: str = ".1f", sigma_word: str = "sigma") -> str:
        """'bias z or scale z moved (these poses cannot tell which) by +5.02 mg at 1 g (31.2 sigma): turn z down'."""
        which = " (these poses cannot tell which)" if len(self.members) > 1 else ""
        bound = "" if self.judgement.by_sigma else ", beyond the bound"
        turn = f": {'; '.join(self.advice)}" if self.advice else ""
        return (f"{self.name} moved{which} by {self.change / MG:+{mg}} mg at 1 g "
                f"({self.judgement.sigmas:{sigmas}} {sigma_word}{bound}){turn}")


@dataclass(frozen=True)
class CheckResult:
    gravity: float
    poses: tuple[PoseCheck, ...]
    changes: tuple[AxisChange, ...]
    advice: tuple[str, ...]  # orientations that would observe what is not observed
    groups: tuple[GroupChange, ...] = ()  # what the poses observe of the changes they cannot tell apart

    @property
    def moved(self) -> list[AxisChange]:
        return [c for c in self.changes if c.judgement is not None and c.judgement.flagged]

    @property
    def moved_groups(self) -> list[GroupChange]:
        return [g for g in self.groups if g.judgement.flagged and g.members]

    @property
    def poses_off(self) -> list[int]:
        return [i for i, p in enumerate(self.poses) if p.judgement.flagged]

    @property
    def unobserved(self) -> list[AxisChange]:
        return [c for c in self.changes if c.change is None]

    @property
    def verdict(self) -> str:
        """'moved', 'holds' or 'cannot tell'."""
        if self.moved or self.moved_groups or self.poses_off:
            return "moved"
        return "cannot tell" if self.unobserved or not self.poses else "holds"


def check_calibration(calibration: Calibration, poses: Sequence[Pose], rule: ChangeRule | None = None,
                      gravity: float | None = None) -> CheckResult:
    """The poses against the calibration (gravity: the local g; default the calibration's own)."""
    rule = rule or ChangeRule()
    g = calibration.gravity if gravity is None else float(gravity)
    if not poses:
        return CheckResult(g, (), tuple(AxisChange(q, a, None, None, None) for q in QUANTITIES for a in AXES),
                           tuple(orientation_advice(d) for d in _faces()))
    terms = _linearised(calibration, poses, g)
    sigma = np.sqrt(terms.noise + np.square(np.abs(terms.shared) @ terms.calibration_sigma))
    checks = tuple(PoseCheck(terms.directions[i], poses[i].samples, float(terms.residual[i]), float(sigma[i]),
                             rule.judge(float(terms.residual[i]), float(sigma[i]), np.inf))
                   for i in range(len(poses)))
    changes, groups = _axis_changes(terms, sigma, rule, calibration.matrix)
    unseen_axes = sorted({AXES.index(c.axis) for c in changes if c.change is None})
    advice = tuple(orientation_advice(d) for d in _faces()
                   if int(np.argmax(np.abs(d))) in unseen_axes and float(np.max(terms.directions @ d)) < FACE_COSINE)
    return CheckResult(g, checks, changes, advice, groups)


def _faces() -> np.ndarray:
    return np.concatenate([np.eye(3), -np.eye(3)])


@dataclass(frozen=True)
class _Terms:
    residual: np.ndarray  # (n,) |c| - g
    noise: np.ndarray  # (n,) variance of |c| from the pose's own noise
    jacobian: np.ndarray  # (n, 6) d|c| / d(bias change x, y, z of the raw axes, gain change x, y, z)
    shared: np.ndarray  # (n, 12) d|c| / d(b, M row-major): how the calibration's own error shows
    calibration_sigma: np.ndarray  # (12,) its 1-sigma of b and M
    directions: np.ndarray  # (n, 3) unit corrected force
    gravity: float


def _linearised(calibration: Calibration, poses: Sequence[Pose], g: float) -> _Terms:
    n = len(poses)
    matrix = calibration.matrix
    residual, noise, jacobian, shared = np.empty(n), np.empty(n), np.empty((n, 6)), np.empty((n, 12))
    directions = np.empty((n, 3))
    for i, pose in enumerate(poses):
        corrected = calibration.apply(pose.accel_mps2, pose.temperature_degc)
        magnitude = float(np.linalg.norm(corrected))
        u = corrected / magnitude
        deviation = np.linalg.solve(matrix, corrected)  # a - b as the correction sees it (drift included)
        row = u @ matrix  # d|c| / d(raw)
        residual[i], directions[i] = magnitude - g, u
        jacobian[i, :3], jacobian[i, 3:] = row, row * deviation
        noise[i] = float(row @ (np.asarray(pose.accel_cov) / max(pose.samples, 1)) @ row)
        shared[i, :3], shared[i, 3:] = -row, np.outer(u, deviation).ravel()
    calibration_sigma = np.concatenate([
        np.zeros(3) if calibration.bias_sigma is None else calibration.bias_sigma,
        np.zeros(9) if calibration.matrix_sigma is None else np.asarray(calibration.matrix_sigma).ravel()])
    return _Terms(residual, noise, jacobian, shared, calibration_sigma, directions, g)


def _axis_changes(terms: _Terms, pose_sigma: np.ndarray, rule: ChangeRule,
                  matrix: np.ndarray) -> tuple[tuple[AxisChange, ...], tuple[GroupChange, ...]]:
    """Weighted least squares of the residuals on the changes the poses observe (core/observability.py:
    the rule the watch and a fit's prior use too), in the observed directions only, so a move the poses
    cannot place stays in its own direction. The file keeps the calibration's 1-sigmas but not their
    correlations, so its share of a change's sigma is bounded by the sum of the absolute contributions
    (exact for a bias, which maps one to one)."""
    gain = float(np.mean(np.abs(np.diag(matrix))))
    unit = np.array([1.0 / gain] * 3 + [1.0 / terms.gravity] * 3)  # 1 m/s^2 of effect at 1 g
    seen = observability(terms.jacobian, [f"{q} {a}" for q in QUANTITIES for a in AXES], unit)
    estimator = seen.estimator(terms.jacobian, 1.0 / np.square(pose_sigma))
    bounds = {"bias": rule.max_bias_change_mg * MG, "scale": rule.max_scale_change}
    out = []
    for j in range(6):
        quantity, axis = QUANTITIES[j // 3], AXES[j % 3]
        if not seen.observed[j]:
            out.append(AxisChange(quantity, axis, None, None, None))
            continue
        value, s = _combination(estimator[j], terms)
        out.append(AxisChange(quantity, axis, value, s, rule.judge(value, s, bounds[quantity])))
    return tuple(out), _group_changes(seen, estimator, terms, rule)


def _combination(row: np.ndarray, terms: _Terms) -> tuple[float, float]:
    """A linear combination of the residuals (row @ residual) and its sigma: the poses' noise through it
    and the calibration's sigma carried the same way (bounded as _axis_changes says)."""
    from_noise = float(np.sum(row**2 * terms.noise))
    from_calibration = float(np.abs(row @ terms.shared) @ terms.calibration_sigma)
    return float(row @ terms.residual), float(np.sqrt(from_noise + from_calibration**2))


def _group_changes(seen: Observability, estimator: np.ndarray, terms: _Terms,
                   rule: ChangeRule) -> tuple[GroupChange, ...]:
    """Per group of changes the poses cannot tell apart, each combination of them they do observe (its
    effect on |a| at 1 g), named by the changes that make it up."""
    out = []
    for group in seen.groups:
        for direction in seen.group_directions(group):
            # Scaled so its largest member counts one to one: "5 mg at 1 g" is a 5 mg bias z or as much scale z.
            row = (direction / float(np.max(np.abs(direction))) / seen.unit) @ estimator
            value, s = _combination(row, terms)
            members = tuple(seen.names[i] for i in group if direction[i] ** 2 >= GROUP_MEMBER_SHARE)
            axes = sorted({AXES.index(name[-1]) for name in members})
            advice = tuple(orientation_advice(d) for d in _faces()
                           if int(np.argmax(np.abs(d))) in axes and float(np.max(terms.directions @ d)) < FACE_COSINE)
            out.append(GroupChange(members, value, s, rule.judge(value, s, rule.max_bias_change_mg * MG), advice))
    return tuple(out)


def describe(result: CheckResult) -> list[str]:
    """The verdict line, then the figures."""
    poses = len(result.poses)
    lines = [_verdict_line(result)]
    lines.append(f"poses ({poses}): direction of the corrected force, samples, |a| - g (g = {result.gravity:.7g} "
                 "m/s^2) and its 1 sigma, mg")
    for i, p in enumerate(result.poses, start=1):
        d = p.direction
        mark = "  <- off" if p.judgement.flagged else ""
        lines.append(f"  {i:3d}  [{d[0]:+.3f} {d[1]:+.3f} {d[2]:+.3f}] {p.samples:7d}  "
                     f"{p.residual_mps2 / MG:+8.3f} ± {p.sigma_mps2 / MG:.3f} ({p.judgement.sigmas:.1f} sigma){mark}")
    lines.append("changes these poses observe (bias: b_new - b, mg; scale: the axis' gain, ppm; ± 1 sigma):")
    for c in result.changes:
        if c.change is None or c.sigma is None or c.judgement is None:
            lines.append(f"  {c.name}: not observable from these poses")
            continue
        unit = 1 / MG if c.quantity == "bias" else 1e6
        mark = "  <- moved" if c.judgement.flagged else ""
        lines.append(f"  {c.name}: {c.change * unit:+.3f} ± {c.sigma * unit:.3f} "
                     f"{'mg' if c.quantity == 'bias' else 'ppm'} ({c.judgement.sigmas:.1f} sigma){mark}")
    for group in result.groups:
        if len(group.members) > 1:
            mark = "  <- moved" if group.judgement.flagged else ""
            lines.append(f"  {group.name} (not told apart; effect at 1 g): {group.change / MG:+.3f} ± "
                         f"{group.sigma / MG:.3f} mg ({group.judgement.sigmas:.1f} sigma){mark}")
    return lines


def _verdict_line(result: CheckResult) -> str:
    poses = len(result.poses)
    if result.verdict == "moved":
        said = [f"{c.name} changed by " + (f"{c.change / MG:+.2f} mg" if c.quantity == "bias" else
                                           f"{c.change * 100:+.3f} %")
                + f" ({c.judgement.sigmas:.1f} sigma{'' if c.judgement.by_sigma else ', beyond the bound'})"
                for c in result.moved if c.change is not None and c.judgement is not None]
        said += [group.said() for group in result.moved_groups]
        off = result.poses_off
        if off:
            said.append(f"{len(off)} of {poses} poses off |a| = g beyond the k-sigma rule")
        return "moved: " + "; ".join(said)
    if result.verdict == "holds":
        return (f"holds: {poses} poses agree with the calibration (bias and scale of every axis observed, none "
                "changed beyond the rule)")
    unseen = ", ".join(c.name for c in result.unobserved)
    advice = "; ".join(result.advice) or "add poses tilted between the axes"
    return (f"cannot tell: {poses} still pose{'' if poses == 1 else 's'} found, {unseen} not observable from "
            f"them; to decide: {advice}")
