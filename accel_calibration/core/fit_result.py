"""The result of a fit and its parts: the parameters' 1-sigma (Sigma), the outlier test's settings
(OutlierOptions) and a pose it left out (Outlier), and FitResult with its summary text."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .calibration import Calibration
from .coverage import (
    Uncertainty,
)
from .errors import CalibrationError
from .units import AXES, MG, STANDARD_GRAVITY


@dataclass(frozen=True)
class Sigma:
    """One-sigma uncertainties, from the normal matrix and the residual variance."""

    bias: np.ndarray
    matrix: np.ndarray  # zero where the model fixes the entry
    quadratic: np.ndarray | None = None


@dataclass(frozen=True)
class OutlierOptions:
    """When fit() leaves a pose out as an outlier: its residual against the fit of the other poses (its
    deleted residual) exceeds `threshold_mg` and is as improbable as `k_sigma` Gaussian sigmas given
    the spread those poses predict for it (their residual scatter, floored at the poses' own noise,
    with their degrees of freedom and the pose's leverage). At most `max_fraction` of the poses are
    left out, one at a time, and a pose only when the others still determine the model with a degree
    of freedom. threshold_mg 0 turns it off."""

    threshold_mg: float = 5.0  # well above the few-mg residuals of a clean MEMS session
    k_sigma: float = 5.0
    max_fraction: float = 0.2

    def __post_init__(self) -> None:
        for name, low in (("threshold_mg", 0.0), ("k_sigma", 1.0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < low:
                raise CalibrationError(f"outlier {name} must be a number >= {low:g}, got {value!r}")
        if not (isinstance(self.max_fraction, (int, float)) and 0.0 <= self.max_fraction <= 0.5):
            raise CalibrationError(f"outlier max_fraction must be within 0..0.5, got {self.max_fraction!r}")


DEFAULT_OUTLIER_OPTIONS = OutlierOptions()  # frozen: one instance serves every fit that gives none

# A parameter is said to come from the poses (the prior) when at least this share of its information
# (1 - posterior variance / prior variance) came from the poses (the prior); from both in between.
SOURCE_SHARE = 0.9


@dataclass(frozen=True)
class ParameterSource:
    """Where one parameter of a fit with a prior came from: its posterior and prior 1-sigma and the share
    of its information the poses gave, 1 - (sigma / prior_sigma)^2 (0: the prior alone, 1: the poses)."""

    name: str  # b_x, M_zy, ... (SphereModel.parameter_names)
    sigma: float
    prior_sigma: float
    # What the poses could not check of it (core/prior_evidence.py): "kept from the prior, not checked", or
    # the parameters it is not separable from; "" when the poses observe it alone.
    note: str = ""

    @property
    def share_from_poses(self) -> float:
        return float(min(max(1.0 - (self.sigma / self.prior_sigma) ** 2, 0.0), 1.0))

    @property
    def source(self) -> str:
        share = self.share_from_poses
        return "poses" if share >= SOURCE_SHARE else "prior" if share <= 1.0 - SOURCE_SHARE else "poses+prior"


@dataclass(frozen=True)
class Outlier:
    """A pose fit() left out: it does not lie on the sphere (or its reference direction) with the rest."""

    index: int  # into the poses given to fit()
    residual_mg: float  # against the fit of the other poses: |a| - g (sphere), |a - g ref| (reference)
    orientation: str  # the face it is nearest, e.g. "x down"
    off: str = "the sphere"

    def describe(self, number: int | None = None) -> str:
        """`number`: how the caller counts its poses (default: the index into fit()'s input)."""
        return (f"pose {self.index if number is None else number} ({self.orientation}, "
                f"{abs(self.residual_mg):.1f} mg off {self.off}) left out as an outlier")


@dataclass(frozen=True)
class FitResult:
    success: bool
    message: str
    model: str
    iterations: int = 0
    calibration: Calibration | None = None
    sigma: Sigma | None = None
    residuals_mg: np.ndarray = field(default_factory=lambda: np.zeros(0))  # of the poses fitted
    cost: float = float("nan")
    condition_number: float = float("nan")
    missing_directions: tuple[str, ...] = ()
    poses: int = 0  # fitted (outliers not counted)
    outliers: tuple[Outlier, ...] = ()  # poses left out, by their index into the input
    uncertainty: Uncertainty | None = None  # sphere models: what the sigma gate and its advice use
    # Leverage of each pose fitted (sphere fits without a temperature model): lets the outlier test
    # see at once that no pose can be one, without forming the Jacobian and its inverse again.
    leverage: np.ndarray | None = field(default=None, repr=False, compare=False)
    # Poses weighted by 1 / (s_i^2 + tau^2) (their own noise given, unequal): tau, the common extra error
    # per pose estimated so that chi^2/dof = 1 (raw units); None for an unweighted fit.
    pose_extra_sigma: float | None = None
    # Fitted with a prior: each parameter's posterior and prior sigma, in the model's parameter order.
    parameter_sources: tuple[ParameterSource, ...] = ()

    @property
    def outlier_indices(self) -> tuple[int, ...]:
        return tuple(o.index for o in self.outliers)

    def summary(self) -> str:
        """A readable multi-line summary: parameters with +-sigma and residuals in mg."""
        lines = [f"model {self.model}: {'OK' if self.success else 'FAILED'} - {self.message}"]
        lines += [o.describe() for o in self.outliers]
        if self.calibration is None:
            return "\n".join(lines)
        c, s = self.calibration, self.sigma
        # fit() builds every result that has a calibration with its sigma and quality.
        assert s is not None and c.quality is not None
        left_out = f" (and {len(self.outliers)} left out)" if self.outliers else ""
        lines.append(f"poses {self.poses}{left_out}, iterations {self.iterations}, "
                     f"condition number {self.condition_number:.3g}")
        if self.pose_extra_sigma is not None:
            lines.append("poses weighted by their own noise and a common extra error of "
                         f"{self.pose_extra_sigma / MG:.3f} mg per pose (1 / (s_i^2 + tau^2))")
        lines.append(
            "bias b (raw units; m/s^2 for SI input):  "
            + "  ".join(f"{AXES[i]} {c.bias[i]:+.6g} ± {s.bias[i]:.2g}" for i in range(3))
        )
        lines.append("matrix M (a_true = M (a_raw - b)), ± 1 sigma:")
        for i in range(3):
            lines.append(
                "  [" + "  ".join(f"{c.matrix[i, j]:+.7g} ± {s.matrix[i, j]:.2g}" for j in range(3)) + "]"
            )
        if c.quadratic is not None:
            assert s.quadratic is not None  # reference15 reports the quadratic term's sigma with it
            lines.append(
                "quadratic q (s^2/m): "
                + "  ".join(f"{AXES[i]} {c.quadratic[i]:+.4g} ± {s.quadratic[i]:.2g}" for i in range(3))
            )
        lines.append(
            f"residuals: rms {c.quality.residual_rms_mg:.3f} mg, max {c.quality.residual_max_mg:.3f} mg"
        )
        if c.temperature is not None:
            t = c.temperature
            lines.append(f"temperature model {t.kind}: T_ref {t.reference_degc:.1f} degC, calibrated range "
                         f"{t.range_degc[0]:.1f}..{t.range_degc[1]:.1f} degC")
            if t.kind == "polynomial":
                for k, row in enumerate(t.bias_coefficients, start=1):
                    lines.append(f"  bias drift dT^{k}: " + "  ".join(f"{v / MG:+.4g}" for v in row)
                                 + f" mg/degC^{k}")
                for k, row in enumerate(t.scale_coefficients, start=1):
                    lines.append(f"  scale drift dT^{k}: " + "  ".join(f"{v:+.3g}" for v in row) + f" /degC^{k}")
            else:
                lines.append(f"  {len(t.segment_coefficients)} segments, "
                             + ("blended between the temperatures they were learned at" if t.segment_blend
                                else "the one holding the temperature picked")
                             + "; drift l a^2 + m a + n per axis (a raw m/s^2): l mg/g^2, m ppm, n mg")
                for (lo, hi), at, poses, (quad, lin, offset) in zip(
                        t.segment_bounds_degc, t.segment_temperatures_degc, t.segment_poses, t.segment_coefficients):
                    lines.append(f"  {lo:g}..{hi:g} degC (at {at:.1f}, {poses} poses): l "
                                 + " ".join(f"{v * STANDARD_GRAVITY**2 / MG:+.3g}" for v in quad) + "  m "
                                 + " ".join(f"{v * 1e6:+.0f}" for v in lin) + "  n "
                                 + " ".join(f"{v / MG:+.2f}" for v in offset))
        if self.parameter_sources:
            lines += self._source_lines()
        if self.missing_directions:
            lines.append("not covered (fit still observable): " + ", ".join(self.missing_directions))
        return "\n".join(lines)

    def _source_lines(self) -> list[str]:
        """Which parameters the poses determined and which stayed at the prior."""
        lines = ["with a prior: share of each parameter's information from the poses "
                 "(1 - (sigma / prior sigma)^2), and where it came from:"]
        for source in self.parameter_sources:
            lines.append(f"  {source.name:5s} {source.share_from_poses:6.1%}  sigma {source.sigma:.2g} "
                         f"(prior {source.prior_sigma:.2g})  from {source.source}"
                         + (f": {source.note}" if source.note else ""))
        if self.unchecked_line():
            lines.append(self.unchecked_line())
        return lines

    def unchecked_line(self) -> str:
        """With a prior: what the poses could not check, in one line ('' when they observe every parameter)."""
        kept = [s.name for s in self.parameter_sources if s.note.startswith("kept from the prior")]
        joint = [s.name for s in self.parameter_sources if s.note.startswith("not separable")]
        said = ([f"kept from the prior, not checked (these poses do not observe them): {', '.join(kept)}"] if kept
                else []) + ([f"not separable by these poses, fitted given the prior's values of the rest: "
                             f"{', '.join(joint)}"] if joint else [])
        return "; ".join(said)
