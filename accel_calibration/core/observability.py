"""What a set of still poses can see: the one rule `accel-calib check`, the node's watch and a fit's prior
use to decide which parameters the poses observe, and which they cannot tell apart.

Each parameter is measured by its effect: the change of |a| (m/s^2) at 1 g that a unit of it makes (a bias
of 1 mg moves |a| by up to 1 mg, a gain change of 1e-3 by up to 1 mg at 1 g). In those units the normal
matrix J^T J of the poses' |a| - g on the parameters is eigendecomposed: a direction whose curvature is
below 1/CONDITION_LIMIT of the strongest moves the poses' |a| by less than 1 % of what the best seen change
of the same size does, and is not observed (a vehicle standing level cannot tell a z bias from a z gain,
nor the x bias from M_zx). A parameter with more than UNOBSERVED_SHARE of itself in those directions is
not observed alone; the parameters sharing such a direction are named together ("bias z or scale z").
The effect scaling, not a Jacobi scaling, is what makes the rule physical: a gain change seen through
tilts of 3 deg moves |a| by 0.3 % of itself and is not observed, however well conditioned its column
looks once scaled to unit length.

Estimates are taken in the observed subspace only: a change there is fitted with the weak directions held
at zero, so a move the poses cannot place (a z bias or a z gain) stays in its own direction and is not
pushed onto the parameters that are observed.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .coverage import CONDITION_LIMIT

# A parameter is not observed when this share of it (a unit vector in effect units) lies in directions
# weaker than 1/CONDITION_LIMIT of the strongest; a parameter with this share in one such direction is
# one of those that direction mixes.
UNOBSERVED_SHARE = 0.05


@dataclass(frozen=True)
class Observability:
    """What poses observe of parameters named `names` ("bias x", "scale z", "misalignment zx").

    unit: each parameter's size whose effect on |a| is 1 m/s^2 at 1 g (raw bias units, M entries, gain
    fractions); basis: (p, k) orthonormal columns in effect units spanning the observed directions;
    observed: (p,) each parameter observed alone; groups: indices of parameters the poses cannot tell
    apart, each group sharing a direction they do not observe."""

    names: tuple[str, ...]
    unit: np.ndarray
    basis: np.ndarray
    observed: np.ndarray
    groups: tuple[tuple[int, ...], ...]

    @property
    def unobserved(self) -> list[str]:
        return [name for name, seen in zip(self.names, self.observed.tolist()) if not seen]

    def group_of(self, index: int) -> tuple[int, ...]:
        return next((group for group in self.groups if index in group), (index,))

    def said(self, group: Sequence[int], joint: str = "or") -> str:
        """'bias z or scale z', 'bias z, scale x or scale z'."""
        names = [self.names[i] for i in group]
        return names[0] if len(names) == 1 else ", ".join(names[:-1]) + f" {joint} " + names[-1]

    def estimator(self, jacobian: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """(p, n): the weighted least-squares change of the parameters (their own units) that explains the
        residuals r (n,) as E @ r, fitted in the observed directions only (zero along the rest)."""
        if self.basis.shape[1] == 0:
            return np.zeros((len(self.names), len(weights)))
        scaled = (jacobian * self.unit) @ self.basis  # (n, k)
        weighted = scaled * weights[:, None]
        coefficients = np.linalg.solve(scaled.T @ weighted, weighted.T)  # (k, n)
        estimator: np.ndarray = (self.basis @ coefficients) * self.unit[:, None]
        return estimator

    def group_directions(self, group: Sequence[int]) -> np.ndarray:
        """(m, p) unit rows in effect units: the combinations of the group's parameters the poses observe
        (for 'bias z or scale z' from level poses: one, the sum of their effects)."""
        index = list(group)
        inside = self.basis[index]  # the observed directions' components on the group
        left, values, _ = np.linalg.svd(inside, full_matrices=False)
        rows = np.zeros((int(np.sum(values > np.sqrt(0.5))), len(self.names)))
        for r, column in enumerate(np.flatnonzero(values > np.sqrt(0.5))):
            direction = left[:, column]
            rows[r, index] = direction * np.sign(direction[int(np.argmax(np.abs(direction)))])
        return rows


def observability(jacobian: np.ndarray, names: Sequence[str], unit: np.ndarray) -> Observability:
    """The rule, from the Jacobian (n, p) of the poses' |a| - g on the parameters in their own units and
    each parameter's `unit` (its size of 1 m/s^2 effect at 1 g)."""
    unit = np.asarray(unit, dtype=float)
    scaled = np.asarray(jacobian, dtype=float) * unit
    size = len(unit)
    if len(scaled) == 0 or not np.all(np.isfinite(scaled)):
        return Observability(tuple(names), unit, np.zeros((size, 0)), np.zeros(size, dtype=bool),
                             (tuple(range(size)),))
    values, vectors = np.linalg.eigh(scaled.T @ scaled)
    strong = values >= max(float(values.max()), 0.0) / CONDITION_LIMIT
    strong &= values > 0
    weak = vectors[:, ~strong]
    observed: np.ndarray = np.sum(weak**2, axis=1) < UNOBSERVED_SHARE
    return Observability(tuple(names), unit, vectors[:, strong], observed, _groups(weak, observed))


def _groups(weak: np.ndarray, observed: np.ndarray) -> tuple[tuple[int, ...], ...]:
    """The parameters not observed, joined where a weak direction mixes them (transitively)."""
    groups: list[set[int]] = []
    for column in weak.T:
        members = {int(i) for i in np.flatnonzero(column**2 >= UNOBSERVED_SHARE) if not observed[i]}
        if not members:
            continue
        touching = [g for g in groups if g & members]
        for g in touching:
            members |= g
            groups.remove(g)
        groups.append(members)
    alone = {int(i) for i in np.flatnonzero(~observed)} - set().union(*groups) if groups else \
        {int(i) for i in np.flatnonzero(~observed)}
    groups += [{i} for i in alone]
    return tuple(sorted(tuple(sorted(g)) for g in groups))
