"""Has an IMU's calibration moved, flight after flight? The per-flight evidence of its still moments on the
ground (bag/flight_evidence.py: what the poses see of the calibration in force, e.g. "bias z or scale z" at
1 g, with check's sigma) as one series per IMU, judged by check's change rule (core/change_rule.py).

Two flights of one vehicle differ by more than their sigmas say (the ground's tilt under a scale error,
the temperature, the parking spot): that scatter is measured from the series itself and added to each
flight's own variance. The change is the step between the mean before a flight and the mean from it on, at
the split that explains the series best (chosen with the scatter of successive differences, by their median
absolute deviation, which a step barely moves), then measured with the scatter about the two means (n - 2
degrees of freedom) and its t statistic taken at the tail probability of normal sigmas, so that a scatter
known from few flights raises no alarm of its own; flagged by the rule (k sigma of the step, or the bias
bound whatever the sigma). Judged as flights arrive (`first_flagged`), a step is found at the first flight
after it and a steady drift once the mean since its start has moved k sigma from the mean before."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .change_rule import ChangeRule
from .units import MG

MIN_FLIGHTS = 10  # fewer flights with evidence: the scatter between flights is not known well enough
MIN_BEFORE = 5  # flights a change is measured from
# No healthy MEMS gyro's bias moves this much between flights (its turn-on repeatability is a fraction of it):
# the gyro's plausibility bound, as the rule's 50 mg is the accelerometer's.
MAX_GYRO_BIAS_CHANGE_RADPS = float(np.radians(3.0))


@dataclass(frozen=True)
class Trend:
    status: str  # moved | holds | cannot tell
    flights: int  # flights with evidence judged
    scatter: float  # between flights, beyond their own sigma (m/s^2)
    change: float | None = None  # the step of the best split (m/s^2 at 1 g), None without a verdict
    sigma: float | None = None
    sigmas: float = 0.0
    since: int | None = None  # index of the first flight after the change
    reason: str = ""


def scatter_between_flights(values: np.ndarray, sigmas: np.ndarray) -> float:
    """The flights' spread beyond their own sigma, from successive differences (robust to a step)."""
    differences = np.diff(values)
    if len(differences) < 2:
        return 0.0
    spread = 1.4826 * float(np.median(np.abs(differences - np.median(differences))))
    return float(np.sqrt(max(spread**2 / 2.0 - float(np.median(sigmas**2)), 0.0)))


def trend(values: np.ndarray, sigmas: np.ndarray, rule: ChangeRule | None = None, bound: float | None = None
          ) -> Trend:
    """The series (in flight order, with their 1-sigma; by default m/s^2 at 1 g) judged: moved, holds or
    cannot tell. `bound`: the plausibility bound in the values' units (default the rule's bias bound, in m/s^2;
    a gyro bias series passes its own, in rad/s)."""
    rule = rule or ChangeRule()
    bound = rule.max_bias_change_mg * MG if bound is None else bound
    z, s = np.asarray(values, dtype=float), np.asarray(sigmas, dtype=float)
    n = len(z)
    if n < MIN_FLIGHTS:
        return Trend("cannot tell", n, 0.0, reason=f"{n} flight{'s' if n != 1 else ''} with evidence, "
                                                    f"{MIN_FLIGHTS} needed to know the scatter between flights")
    weights = 1.0 / (s**2 + scatter_between_flights(z, s) ** 2)  # to choose the split
    weighted = np.cumsum(weights * z)
    total = np.cumsum(weights)
    splits = np.arange(MIN_BEFORE, n)  # the first flight after the change
    before_w, before_z = total[splits - 1], weighted[splits - 1]
    after_w, after_z = total[-1] - before_w, weighted[-1] - before_z
    steps = after_z / after_w - before_z / before_w
    step_sigmas = np.sqrt(1.0 / before_w + 1.0 / after_w)
    split = int(splits[int(np.argmax(np.abs(steps) / step_sigmas))])
    change, sigma, strength, scatter = _step_at(z, s, split)
    judged = rule.judge(change, abs(change) / strength if strength > 0 else np.inf, bound)
    return Trend("moved" if judged.flagged else "holds", n, scatter, change, sigma, judged.sigmas, split)


def _step_at(z: np.ndarray, s: np.ndarray, split: int) -> tuple[float, float, float, float]:
    """The step at `split` with the scatter measured about the two means (n - 2 degrees of freedom, so a
    step does not count as scatter), and its size in normal sigmas of the same tail probability as its t
    statistic: a scatter measured from few flights makes no false alarm of its own uncertainty."""
    from scipy.stats import norm, t

    n = len(z)
    residual = np.concatenate([z[:split] - np.mean(z[:split]), z[split:] - np.mean(z[split:])])
    tau2 = max(float(np.sum(residual**2)) / (n - 2) - float(np.mean(s**2)), 0.0)
    weights = 1.0 / (s**2 + tau2)
    before = float(np.sum(weights[:split] * z[:split]) / np.sum(weights[:split]))
    after = float(np.sum(weights[split:] * z[split:]) / np.sum(weights[split:]))
    sigma = float(np.sqrt(1.0 / np.sum(weights[:split]) + 1.0 / np.sum(weights[split:])))
    statistic = abs(after - before) / sigma
    strength = min(float(norm.isf(t.sf(statistic, n - 2))), statistic)
    return after - before, sigma, strength, float(np.sqrt(tau2))


def first_flagged(values: np.ndarray, sigmas: np.ndarray, rule: ChangeRule | None = None, bound: float | None = None
                  ) -> int | None:
    """The number of flights after which the series is first judged moved (as flights arrive), None: never."""
    for n in range(MIN_FLIGHTS, len(values) + 1):
        if trend(values[:n], sigmas[:n], rule, bound).status == "moved":
            return n
    return None
