"""A prior is evidence, tested like any other: before a fit leans on it, what the poses observe of it
(core/observability.py, the rule `check` and the watch use) is compared with it.

Linearised at the prior, the poses' residuals |M0 (a - b0)| - g are fitted in the directions the poses
observe (effect units: m/s^2 at 1 g); that change y, k numbers, is the poses' own estimate of how far the
prior is from the sensor there. Its covariance is the poses' (s^2 (V^T J^T J V)^-1, s^2 from the residuals
of that fit over n - k) plus the prior's carried the same way (its file sigma, the bias's widened by the
drift allowance). chi^2 = y^T C^-1 y against k times the F(k, n - k) quantile at CONFLICT_K_SIGMA (s^2 is
estimated from few poses). A pose's noise is never taken below a floor known without the fit, the larger of
the poses' own noise (their sample covariance) and the prior's own fit residual (how closely this sensor's
poses lie on a sphere), which counts as FLOOR_DOF degrees of freedom beside the poses' n - k: with a few
poses the limit is then not so wide as to pass anything. Beyond it the prior is refused, naming the
parameters (or the combinations the poses cannot tell apart) furthest from it in sigmas, and by how much.

What the poses do not observe stays at the prior, and is said: each parameter of a fit with a prior gets a
note, "kept from the prior, not checked", or, for one the poses see only together with others, which ones
it is not separable from.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .models import SphereModel
from .observability import Observability, observability
from .units import AXES, MG

CONFLICT_K_SIGMA = 4.0
# A pose noise floor known without the fit counts as this many degrees of freedom beside the poses' own.
FLOOR_DOF = 10
# Named in a refusal: at most this many of the parameters furthest from the prior, those beyond this many sigmas.
NAMED = 4
NAMED_SIGMAS = 3.0
# A combination of parameters the poses cannot tell apart is named by those with at least this share of it.
MEMBER_SHARE = 0.1


@dataclass(frozen=True)
class PriorEvidence:
    """What the poses say of the prior: the rule's verdict per parameter, and the refusal (None: agrees)."""

    seen: Observability
    file_names: tuple[str, ...]  # b_x, M_zz, ... (the file's)
    refusal: str | None

    def note(self, index: int, source: str) -> str:
        """What a parameter's source says beyond its share: '' when the poses observe it alone."""
        if self.seen.observed[index]:
            return ""
        others = [self.file_names[i] for i in self.seen.group_of(index) if i != index]
        if source == "prior":
            return "kept from the prior, not checked" + (
                f" (these poses cannot tell it from {', '.join(others)})" if others else "")
        if others:
            return f"not separable from {', '.join(others)} by these poses: fitted given the prior's values of those"
        return "partly from the poses, not checked"


def display_names(model: SphereModel) -> list[str]:
    """bias x, scale y, misalignment zx: what a person reads (the file's b_x, M_yy, M_zx)."""
    return [f"bias {a}" for a in AXES] + [f"scale {AXES[i]}" if i == j else f"misalignment {AXES[i]}{AXES[j]}"
                                          for i, j in model.entries]


def prior_evidence(model: SphereModel, accel: np.ndarray, gravity: float, prior_values: np.ndarray,
                   prior_sigma: np.ndarray, fallback_variance: float, noise_floor: float = 0.0) -> PriorEvidence:
    """The poses' own estimate of what they observe, against the prior (module docstring).
    fallback_variance: one pose's residual variance where the poses leave no degree of freedom of their own
    and no noise_floor is known; noise_floor: one pose's noise never assumed smaller (raw units, 0: none)."""

    residual, jacobian = model.residual_and_jacobian(prior_values, accel, gravity)
    _, matrix = model.unpack(prior_values)
    gain = float(np.mean(np.abs(np.diag(matrix))))
    unit = np.concatenate([np.full(3, 1.0 / gain), np.full(len(model.entries), gain / gravity)])
    seen = observability(jacobian, display_names(model), unit)
    names = tuple(model.parameter_names())
    n, k = len(accel), seen.basis.shape[1]
    if k == 0 or not np.all(np.isfinite(jacobian)):
        return PriorEvidence(seen, names, None)
    change = -(seen.estimator(jacobian, np.ones(n)) @ residual)  # the prior moved to the poses, observed part
    after = residual + jacobian @ change
    dof = n - k
    variance, limit = _variance_and_limit(float(after @ after), dof, k, fallback_variance, noise_floor)
    scaled = (jacobian * unit) @ seen.basis
    poses_cov = variance * np.linalg.inv(scaled.T @ scaled)
    prior_cov = seen.basis.T @ (np.square(prior_sigma / unit)[:, None] * seen.basis)
    covariance = poses_cov + prior_cov  # (k, k), effect units
    y = seen.basis.T @ (change / unit)
    chi2 = float(y @ np.linalg.solve(covariance, y))
    if not (math.isfinite(chi2) and chi2 > limit):
        return PriorEvidence(seen, names, None)
    full = seen.basis @ covariance @ seen.basis.T  # effect units, every parameter (0 off the observed)
    named = _furthest(seen, change / unit, full, y, model.entries, np.linalg.norm(matrix, axis=1))
    return PriorEvidence(seen, names, (
        f"the poses disagree with the prior: what they observe of it is chi^2 = {chi2:.3g} away over {k} "
        f"directions ({CONFLICT_K_SIGMA:g}-sigma limit {limit:.3g}): {named}; the prior is not this sensor's, "
        "or it moved beyond the drift allowance (raise it)"))


def _variance_and_limit(squares: float, dof: int, k: int, fallback: float, floor: float) -> tuple[float, float]:
    """One pose's variance and the chi^2 limit at CONFLICT_K_SIGMA, k F(k, dof) (the variance estimated).
    The residuals over n - k give it; a floor known without the fit (the poses' own noise, the prior's fit
    residual) counts as FLOOR_DOF degrees of freedom pooled with them, and the variance never goes below it.
    Without a degree of freedom or a floor: the fallback (the fit's own estimate)."""
    from .fit_outliers import critical_ratio  # scipy.stats, imported only when a fit has a prior

    if floor > 0:
        pooled = (squares + FLOOR_DOF * floor**2) / (max(dof, 0) + FLOOR_DOF)
        return max(pooled, floor**2), k * critical_ratio(CONFLICT_K_SIGMA, k, max(dof, 0) + FLOOR_DOF)
    if dof >= 1:
        return squares / dof, k * critical_ratio(CONFLICT_K_SIGMA, k, dof)
    return fallback, k * critical_ratio(CONFLICT_K_SIGMA, k, 1)


def _furthest(seen: Observability, moved: np.ndarray, covariance: np.ndarray, y: np.ndarray,
              entries: tuple[tuple[int, int], ...], gains: np.ndarray) -> str:
    """Where the poses put the prior furthest off: the combination of parameters they disagree on most
    (h = V C^-1 y, which is sqrt(chi^2) sigmas off), named by its larger members, then each parameter
    they observe alone that is NAMED_SIGMAS or more off; each with its distance in its units."""
    h = seen.basis @ np.linalg.solve(seen.basis.T @ covariance @ seen.basis, y)  # effect units
    h = h / float(np.max(np.abs(h)))
    value, sigma = float(h @ moved), math.sqrt(max(float(h @ covariance @ h), 1e-300))
    members = [j for j in range(len(h)) if h[j] ** 2 >= MEMBER_SHARE * float(h @ h)]
    if len(members) == 1:
        j = members[0]
        said = [f"{seen.names[j]} {_in_units(j, moved[j] * seen.unit[j], entries, gains)} "
                f"({abs(value) / sigma:.3g} sigma)"]
    else:
        combination = " ".join(f"{'+' if h[j] > 0 else '-'} {seen.names[j]}" for j in members).lstrip("+ ")
        said = [f"{combination} {value / MG:+.3g} mg at 1 g ({abs(value) / sigma:.3g} sigma)"]
    alone = []
    for j, name in enumerate(seen.names):
        sigmas = abs(moved[j]) / math.sqrt(max(covariance[j, j], 1e-300))
        if seen.observed[j] and sigmas >= NAMED_SIGMAS and members != [j]:
            distance = _in_units(j, moved[j] * seen.unit[j], entries, gains)
            alone.append((sigmas, f"{name} {distance} ({sigmas:.3g} sigma)"))
    alone.sort(key=lambda item: -item[0])
    return ", ".join(said + [text for _, text in alone[:NAMED - 1]])


def _in_units(index: int, value: float, entries: tuple[tuple[int, int], ...], gains: np.ndarray) -> str:
    """A change of parameter `index` (its own units) in mg (bias), % (scale) or mrad (misalignment)."""
    if index < 3:
        return f"{value / MG:+.3g} mg"
    i, j = entries[index - 3]
    relative = value / float(gains[i])
    return f"{relative * 100:+.3g} %" if i == j else f"{relative * 1e3:+.3g} mrad"
