"""The Allan variance fitted whole: sigma^2(tau) = 3 Q^2 / tau^2 + N^2 / tau + (2 ln 2 / pi) B^2 + K^2 tau / 3
+ R^2 tau^2 / 2 (IEEE Std 952 annex C: quantization, white noise, bias instability, random walk, rate ramp),
one weighted non-negative least squares over every tau instead of one reading per slope.

Reading each term off its own part of the curve reads the sum there: bias instability read as the minimum /
0.664 came out 12-27 % high where the random walk's rise reached the floor, and the random walk's interval,
simulated without the floor, held the truth in 65-72 % of cases with all three processes present.

- Weights: the standard error of the overlapping estimate at each tau from the model itself, each term's
  share with its own equivalent degrees of freedom (the overlapping estimator's edf for white, flicker and
  random-walk frequency noise), their standard deviations added in quadrature;
  reweighted from the fitted model (the first pass from the measured values).
- Quantization and rate ramp enter only when they lower the weighted misfit by more than TERM_CHI2: the
  short and long taus have too few degrees of freedom to carry five free terms.
- Intervals: by simulation, as the correlation between taus asks. White noise, flicker (bias instability)
  and random walk of unit size are simulated once per record length and cluster sizes (their cross Allan
  variances kept, so any mix of the three is a quadratic form of them, no new simulation); each mix is
  fitted as the data were. A term's 95 % interval is the test inversion: the values at which the fitted
  term would exceed (fall short of) the one measured in only 2.5 % of simulated records, the other terms at
  their fitted values. A term is resolved when, simulated absent, it is fitted at least as large as measured
  in under PRESENT_LEVEL of records; otherwise it is reported "not resolved" with the top of its 95 %
  interval (the value at which it would be fitted at most as small as measured in 2.5 % of records): an
  upper bound that holds at least 95 % of the time (the 5 % one-sided bound, with the cases a resolved
  interval misses, held the truth in 87 % of records).
- The nuisance terms are profiled: at each value tried for one term, the others are refitted to the data
  with it held there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

BIAS_FLOOR = 2.0 * math.log(2.0) / math.pi  # sigma^2 of the flat floor per B^2 (0.664^2)
TERMS = ("quantization", "white", "bias_instability", "random_walk", "rate_ramp")
SIMULATED = (1, 2, 3)  # the columns the simulation carries: white, bias instability, random walk
TERM_CHI2 = 9.0  # quantization / rate ramp: weighted misfit lowered by more than this (3 sigma) to enter
REPLICATES = 400
MAX_SIMULATED_SAMPLES = 1 << 13  # longer records simulated decimated (cluster sizes >= the decimation)
PRESENT_LEVEL = 0.01  # a term simulated absent fitted at least as large as measured: resolved below this
TWO_SIDED = 0.025
IRLS_PASSES = 3
BRACKET = math.log(1e4)
BISECTIONS = 11


def design_columns(tau: np.ndarray, filtered: bool = False) -> np.ndarray:
    """(T, 5): the Allan variance of each term per unit coefficient (Q^2, N^2, C, K^2, R^2), C = 0.664^2 B^2.
    `filtered`: the first column is a low-pass filter's deficit instead, -3 / tau^2: filtered white noise
    sits below N^2 / tau by a term in 1 / tau^2 at taus of a few filter time constants, and left out, the
    fit lowered N by ~2 % there and put what was missing into the floor (bias instability 8-10 % off)."""
    first = -3.0 / tau**2 if filtered else 3.0 / tau**2
    return np.column_stack([first, 1.0 / tau, np.ones_like(tau), tau / 3.0, tau**2 / 2.0])


def equivalent_dof(clusters: np.ndarray, samples: int) -> np.ndarray:
    """(T, 5): the overlapping estimator's equivalent degrees of freedom per term (Riley, Handbook of
    Frequency Stability Analysis, table 10): white FM for quantization and white noise, flicker FM for bias
    instability, random-walk FM for random walk and rate ramp; N the phase points, m the cluster size."""
    m = clusters.astype(float)
    n = float(samples + 1)
    white = (3.0 * (n - 1.0) / (2.0 * m) - 2.0 * (n - 2.0) / n) * 4.0 * m * m / (4.0 * m * m + 5.0)
    flicker = np.where(m == 1, 2.0 * (n - 2.0) / (2.3 * n - 4.9), 5.0 * n * n / (4.0 * m * (n + 3.0 * m)))
    walk = (n - 2.0) / m * ((n - 1.0) ** 2 - 3.0 * m * (n - 1.0) + 4.0 * m * m) / (n - 3.0) ** 2
    dof: np.ndarray = np.maximum(np.column_stack([white, white, flicker, walk, walk]), 1.0)
    return dof


def _solve_small(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Batched solve of k x k systems laid out (k, k, R) and (k, R) -> (k, R); k <= 3 by Cramer's rule on
    whole rows (np.linalg.solve costs ~100 us a call, and the simulated fits make thousands). A singular
    system gives non-finite x, which is never chosen."""
    k = len(rhs)
    with np.errstate(divide="ignore", invalid="ignore"):
        if k == 1:
            out: np.ndarray = rhs / gram[0]
            return out
        if k == 2:
            det = gram[0, 0] * gram[1, 1] - gram[0, 1] * gram[1, 0]
            return np.stack([(rhs[0] * gram[1, 1] - rhs[1] * gram[0, 1]) / det,
                             (rhs[1] * gram[0, 0] - rhs[0] * gram[1, 0]) / det])
        if k == 3:
            (a, b, c), (_, e, f), (_, _, i) = gram  # symmetric
            c00, c01, c02 = e * i - f * f, c * f - b * i, b * f - c * e
            c11, c12, c22 = a * i - c * c, b * c - a * f, a * e - b * b
            det = a * c00 + b * c01 + c * c02
            r0, r1, r2 = rhs
            return np.stack([(c00 * r0 + c01 * r1 + c02 * r2) / det, (c01 * r0 + c11 * r1 + c12 * r2) / det,
                             (c02 * r0 + c12 * r1 + c22 * r2) / det])
        moved = np.moveaxis(gram, -1, 0)
        try:
            return np.linalg.solve(moved, rhs.T[..., None])[..., 0].T
        except np.linalg.LinAlgError:
            return np.stack([np.linalg.lstsq(g, r, rcond=None)[0] for g, r in zip(moved, rhs.T)], axis=1)


_SUBSETS: dict[int, list[list[int]]] = {}


def _subsets(columns: int) -> list[list[int]]:
    if columns not in _SUBSETS:
        _SUBSETS[columns] = [[j for j in range(columns) if mask >> j & 1] for mask in range(1, 1 << columns)]
    return _SUBSETS[columns]


def _nnls_batch(design: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """min |A_r x_r - b_r|, x_r >= 0, for a batch: design (R, T, P), rhs (R, T) -> (R, P). Exactly, for few
    columns: the optimum is the least-squares solution on some subset of the columns (KKT), so each subset
    is solved for the whole batch (normal equations of unit-norm columns) and the best feasible kept; a
    subset's cost is |b|^2 - x.A^T b at its own least-squares x."""
    scale = np.sqrt(np.einsum("rtp,rtp->pr", design, design))
    scale = np.where(scale > 0, scale, 1.0)
    gram = np.einsum("rtp,rtq->pqr", design, design) / (scale[:, None, :] * scale[None, :, :])
    projected = np.einsum("rtp,rt->pr", design, rhs) / scale
    columns, batch = projected.shape
    best = np.zeros((columns, batch))
    best_cost = np.einsum("rt,rt->r", rhs, rhs)
    length = best_cost
    for chosen in _subsets(columns):
        sub_rhs = projected[chosen]
        x = _solve_small(gram[np.ix_(chosen, chosen)], sub_rhs)
        cost = length - np.einsum("pr,pr->r", x, sub_rhs)
        with np.errstate(invalid="ignore"):
            better = (x >= 0).all(axis=0) & np.isfinite(x).all(axis=0) & (cost < best_cost)
        if better.any():
            best[:, better] = 0.0
            best[np.ix_(chosen, better)] = x[:, better]
            best_cost = np.where(better, cost, best_cost)
    solution: np.ndarray = (best / scale).T
    return solution


def variance_sd(coefficients: np.ndarray, columns: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """(R, T): the standard deviation of the overlapping Allan variance under each model (R, P): each term's
    sqrt(2 / edf) sigma_k^2 added in quadrature (as if the terms' estimates were independent; their plain
    sum, an upper bound, weighted the points where two terms meet too little: K's median error 10-12 %
    against 9-10 % at 2 h through a 10 Hz filter, the intervals being calibrated by simulation either way)."""
    sd: np.ndarray = np.sqrt(2.0 * np.einsum("rp,tp->rt", coefficients**2, columns**2 / dof))
    return sd


def fit_batch(variance: np.ndarray, columns: np.ndarray, dof: np.ndarray,
              known: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(R, P) coefficients fitted to Allan variances (R, T) by iteratively reweighted NNLS: weights 1 / the
    estimate's standard deviation, first from each point's own value, then from the fitted model. `known`:
    a term held fixed, (its sigma^2 (T,), its standard deviation (T,)), taken off the values and added to
    the weights' model."""
    level = variance * np.sqrt(2.0 / dof[:, 1])[None, :]  # white-noise edf for the first pass
    design = np.broadcast_to(columns, (len(variance), *columns.shape))
    target = variance if known is None else variance - known[0][None, :]
    for _ in range(IRLS_PASSES):
        weight = 1.0 / np.maximum(level, 1e-300)
        solution = _nnls_batch(design * weight[:, :, None], target * weight)
        modelled = variance_sd(solution, columns, dof)
        if known is not None:
            modelled = np.sqrt(modelled**2 + known[1][None, :] ** 2)
        level = np.where(modelled > 0, modelled, level)
    return solution


def weighted_misfit(variance: np.ndarray, coefficients: np.ndarray, columns: np.ndarray, dof: np.ndarray) -> float:
    sd = variance_sd(coefficients[None, :], columns, dof)[0]
    residual = (variance - columns @ coefficients) / np.maximum(sd, 1e-300)
    return float(residual @ residual)


def select_terms(variance: np.ndarray, columns: np.ndarray, dof: np.ndarray,
                 filtered: bool = False) -> tuple[list[int], np.ndarray]:
    """(the columns used, their coefficients as (5,)): white, bias instability and random walk always, and
    the filter's deficit when `filtered` (columns from design_columns(tau, filtered=True)); quantization
    (unfiltered) and rate ramp each when it lowers the weighted misfit by more than TERM_CHI2."""
    def fitted(chosen: list[int]) -> tuple[np.ndarray, float]:
        part = fit_batch(variance[None, :], columns[:, chosen], dof[:, chosen])[0]
        full = np.zeros(columns.shape[1])
        full[chosen] = part
        return full, weighted_misfit(variance, full, columns, dof)

    chosen = [0, *SIMULATED] if filtered else list(SIMULATED)
    best, misfit = fitted(chosen)
    if len(variance) > len(chosen) + 1:
        for extra in ((4,) if filtered else (0, 4)):
            trial = sorted([*chosen, extra])
            candidate, candidate_misfit = fitted(trial)
            if candidate[extra] > 0 and misfit - candidate_misfit > TERM_CHI2:
                chosen, best, misfit = trial, candidate, candidate_misfit
    return chosen, best


def flicker_unit(rng: np.random.Generator, samples: int, replicates: int) -> np.ndarray:
    """(samples, replicates) flicker (1/f) noise of flat Allan variance 1, shaped in the frequency domain over
    twice the length and the first half kept (a periodic record would lose its longest taus' variance)."""
    length = 2 * samples
    frequency = np.fft.rfftfreq(length)  # cycles per sample
    frequency[0] = np.inf  # no mean
    h = 1.0 / (2.0 * math.log(2.0))  # S(f) = h / f one-sided: Allan variance 2 ln 2 h
    amplitude = np.sqrt(h / frequency * length / 2.0)
    shape = (len(frequency), replicates)
    spectrum = amplitude[:, None] * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / math.sqrt(2.0)
    out: np.ndarray = np.fft.irfft(spectrum, length, axis=0)[:samples]
    return out


CHUNK = 50  # replicates simulated at a time (memory: 3 x samples x CHUNK doubles)


@lru_cache(maxsize=8)
def cross_allan(samples: int, clusters: tuple[int, ...], replicates: int = REPLICATES,
                seed: int = 0) -> np.ndarray:
    """(R, T, 3, 3): the cross Allan variances of unit white noise (density 1 per sample period), unit
    flicker (flat Allan variance 1) and a unit random walk (K = 1 per sample period), per replicate and
    cluster size, in units of the sample period (tau = m): the Allan variance of s_w w + s_b b + s_k k is
    s^T A s."""
    rng = np.random.default_rng(seed)
    m = np.asarray(clusters, dtype=np.int64)
    out = np.empty((replicates, len(m), 3, 3))
    for first in range(0, replicates, CHUNK):
        count = min(CHUNK, replicates - first)
        # (replicate, process, sample): the second differences run along contiguous rows and each
        # replicate's 3 x 3 sums of products are one batched matrix product (einsum took twice as long)
        theta = np.zeros((count, 3, samples + 1))
        theta[:, 0, 1:] = rng.standard_normal((count, samples))
        theta[:, 1, 1:] = flicker_unit(rng, samples, count).T
        theta[:, 2, 1:] = np.cumsum(rng.standard_normal((count, samples)), axis=1)
        np.cumsum(theta[:, :, 1:], axis=2, out=theta[:, :, 1:])
        for row, size in enumerate(m.tolist()):
            second = theta[:, :, 2 * size:] - 2.0 * theta[:, :, size:-size] + theta[:, :, :-2 * size]
            out[first:first + count, row] = (second @ second.transpose(0, 2, 1)) / (
                2.0 * size * size * (samples + 1 - 2 * size))
    return out


@dataclass(frozen=True)
class Simulation:
    """The unit processes' cross Allan variances at the kept cluster sizes of a record, and how to scale
    them to a model's coefficients: tau = m * period (period the decimated sample period)."""

    cross: np.ndarray  # (R, T, 3, 3)
    tau: np.ndarray  # (T,) seconds
    period: float
    columns: np.ndarray  # (T, 5)
    dof: np.ndarray  # (T, 5)
    kept: np.ndarray  # (T,) indices into the data's taus

    def variances(self, coefficients: np.ndarray) -> np.ndarray:
        """(R, T) simulated Allan variances for (Q^2, N^2, C, K^2, R^2) (only N^2, C, K^2 are simulated)."""
        white, floor, walk = (max(float(coefficients[j]), 0.0) for j in SIMULATED)
        # unit white: density sqrt(period) per sample -> N^2 / period; unit walk: K^2 period per step
        scale = np.sqrt([white / self.period, floor, walk * self.period])
        simulated: np.ndarray = np.einsum("rtij,i,j->rt", self.cross, scale, scale)
        return simulated

    def fitted(self, coefficients: np.ndarray, chosen: list[int]) -> np.ndarray:
        """(R, 5) the coefficients fitted to records simulated from `coefficients`, as the data were."""
        part = fit_batch(self.variances(coefficients), self.columns[:, chosen], self.dof[:, chosen])
        full = np.zeros((len(part), self.columns.shape[1]))
        full[:, chosen] = part
        return full


def simulation_for(clusters: np.ndarray, period_s: float, samples: int, replicates: int = REPLICATES,
                   filtered: bool = False) -> Simulation | None:
    """The simulation matching a record of `samples` at `period_s` fitted at `clusters` (sample counts); a
    long record decimated to <= MAX_SIMULATED_SAMPLES (cluster sizes below the decimation left out: they
    carry little of the bias instability and random walk). None when fewer than 4 cluster sizes remain."""
    decimation = 1
    while samples // decimation > MAX_SIMULATED_SAMPLES:
        decimation *= 2
    length = samples // decimation
    usable = (clusters >= decimation) & (clusters % decimation == 0) & (2 * (clusters // decimation) < length)
    kept = np.flatnonzero(usable)
    if len(kept) < 4:
        return None
    reduced = clusters[kept] // decimation
    period = decimation * period_s
    tau = reduced * period
    return Simulation(cross=cross_allan(length, tuple(reduced.tolist()), replicates), tau=tau, period=period,
                      columns=design_columns(tau, filtered), dof=equivalent_dof(reduced, length), kept=kept)


def profile(simulation: Simulation, observed: np.ndarray, chosen: list[int], term: int, value: float) -> np.ndarray:
    """(5,) the data's coefficients at the simulation's taus with `term` held at `value` and the others
    fitted (the nuisance terms follow the one tested: bias instability and random walk trade against each
    other, and holding the other at its best fit gave intervals that held too seldom)."""
    others = [j for j in chosen if j != term]
    full = np.zeros(simulation.columns.shape[1])
    full[term] = value
    column, dof = simulation.columns[:, term], simulation.dof[:, term]
    known = (value * column, math.sqrt(2.0) * value * column / np.sqrt(dof))
    if others:
        full[others] = fit_batch(observed[None, :], simulation.columns[:, others], simulation.dof[:, others],
                                 known)[0]
    return full


def _exceed_share(simulation: Simulation, observed: np.ndarray, chosen: list[int], term: int, value: float,
                  measured: float) -> tuple[float, float]:
    """(share of records simulated with the term at `value` (the others profiled) fitted at >= measured,
    share fitted <= measured)."""
    fitted = simulation.fitted(profile(simulation, observed, chosen, term, value), chosen)[:, term]
    return float(np.mean(fitted >= measured)), float(np.mean(fitted <= measured))


def _invert(simulation: Simulation, observed: np.ndarray, chosen: list[int], term: int, measured: float,
            side: int, level: float, reach: float) -> float:
    """The term's value at which the share of fits beyond `measured` (side 0: >=, 1: <=) is `level`, by
    bisection in log between reach / 1e4 and reach * 1e4 (to 0.9 % of the variance; the share moves
    monotonically with the value)."""
    low, high = math.log(reach) - BRACKET, math.log(reach) + BRACKET
    for _ in range(BISECTIONS):
        middle = 0.5 * (low + high)
        share = _exceed_share(simulation, observed, chosen, term, math.exp(middle), measured)[side]
        # side 0 (>=): the share grows with the value; side 1 (<=): it falls
        if (share < level) == (side == 0):
            low = middle
        else:
            high = middle
    return math.exp(0.5 * (low + high))


@dataclass(frozen=True)
class TermInterval:
    """A fitted coefficient (the variance's: N^2, C, K^2) and its 95 % interval; resolved False: `high` is a
    one-sided 95 % upper bound and `low` is 0."""

    value: float
    low: float
    high: float
    resolved: bool
    null_share: float  # share of records simulated without the term that fitted it at least as large


def term_interval(simulation: Simulation, observed: np.ndarray, statistic: np.ndarray, chosen: list[int],
                  term: int, value: float) -> TermInterval:
    """The 95 % interval of coefficient `term` by test inversion; `observed` the data's Allan variance at the
    simulation's taus, `statistic` its fit there, `value` the reported estimate."""
    measured = float(statistic[term])
    reach = max(measured, value, 1e-300)
    null_share = _exceed_share(simulation, observed, chosen, term, 0.0, measured)[0] if measured > 0 else 1.0
    if null_share >= PRESENT_LEVEL:
        if measured <= 0:  # the scale from the other terms: where this one would reach them
            reach = max(float(np.max(simulation.columns @ statistic)) / float(np.max(simulation.columns[:, term])),
                        1e-300)
        bound = _invert(simulation, observed, chosen, term, measured, 1, TWO_SIDED, reach)
        return TermInterval(value=value, low=0.0, high=max(bound, value), resolved=False, null_share=null_share)
    low = _invert(simulation, observed, chosen, term, measured, 0, TWO_SIDED, reach)
    high = _invert(simulation, observed, chosen, term, measured, 1, TWO_SIDED, reach)
    return TermInterval(value=value, low=min(low, value), high=max(high, value), resolved=True,
                        null_share=null_share)
