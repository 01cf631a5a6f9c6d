"""The detector's noise floor: a low quantile of the window variances seen, from a decaying log-spaced
histogram, so no initial still period is needed and any raw unit (counts, g, m/s^2) works.

The floor is fed in batches (`VarianceFloor.add`): each variance goes into its histogram bin, the floor
value is re-read every QUERY_EVERY variances (and after the first one ever), and the histogram is halved
every `half_life_values` variances so old conditions fade (vibration, temperature). Counts are sums of
halved integers, exact in floats, so whatever the batching of the same variances the values and the
state left behind are the same, bit for bit (no BLAS: bincount and cumsum).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np

BINS_PER_DECADE = 10
# Variance range the histogram covers, decades (Final: 10 ** LOG_MAX is then known to be an int).
LOG_MIN: Final = -14
LOG_MAX: Final = 14
NBINS = (LOG_MAX - LOG_MIN) * BINS_PER_DECADE
QUERY_EVERY = 64
# Each histogram bin's value (Python's pow: numpy's power can differ from it in the last bit).
CENTRES = np.array([10 ** (LOG_MIN + (index + 0.5) / BINS_PER_DECADE) for index in range(NBINS)])


@dataclass(frozen=True)
class FloorConfig:
    """quantile: of the window variances, taken as the floor (the fraction of time the sensor must be still
    for it to be right); half_life_values: variances after which the histogram's counts are halved."""

    quantile: float
    half_life_values: int = 200_000


@dataclass
class VarianceFloor:
    """The floor's state: the histogram, its total, the variances since its last halving and since its
    last query, and the value read at that query (None before any variance)."""

    config: FloorConfig
    counts: np.ndarray = field(default_factory=lambda: np.zeros(NBINS))
    total: float = 0.0
    since_decay: int = 0
    since_query: int = 0
    value: float | None = None

    def add(self, variances: np.ndarray) -> np.ndarray:
        """Take these variances in order (non-finite ones are skipped: finite sums inside the detector's
        guard cannot give one); the floor value in force after each (NaN until the first ever)."""
        before = np.nan if self.value is None else self.value
        finite = np.isfinite(variances)
        if not finite.all():
            values = self._add_finite(variances[finite])
            last_add = np.cumsum(finite) - 1
            return np.where(last_add >= 0, values[np.maximum(last_add, 0)] if len(values) else np.nan, before)
        return self._add_finite(variances)

    def _add_finite(self, variances: np.ndarray) -> np.ndarray:
        """The floor value in force after each add, the state advanced to after the last.

        Epoch by epoch (adds between two halvings), the queries of an epoch at once, each seeing the halved
        histogram carried in plus its epoch's adds so far."""
        count = len(variances)
        if count == 0:
            return np.zeros(0)
        quantile, half_life = self.config.quantile, self.config.half_life_values
        index = _bin_of(variances)
        # A query after the first add ever, then every QUERY_EVERY adds; a halving every half_life adds
        # (before the query of the same add). Numbered 1.. within these adds.
        first_query = 1 if self.value is None else QUERY_EVERY - self.since_query
        query_adds = np.arange(first_query, count + 1, QUERY_EVERY)
        halvings = np.arange(half_life - self.since_decay, count + 1, half_life)
        carried = self.counts
        hit_bins = np.flatnonzero(carried)
        # Only bins ever hit matter: empty bins below add nothing, and a hit needs counts.
        low = int(min(index.min(), hit_bins.min() if len(hit_bins) else NBINS))
        high = int(max(index.max(), hit_bins.max() if len(hit_bins) else -1)) + 1
        width = high - low
        index -= low
        centres = CENTRES[low:high]
        base = carried[low:high].copy()
        base_total = float(self.total)
        values = np.empty(len(query_adds))
        epoch_of_query = np.searchsorted(halvings, query_adds, side="right")  # halvings done by each query
        epoch_starts = np.concatenate([[0], halvings])  # an epoch holds the adds after its start, to the next
        for epoch, begin in enumerate(epoch_starts.tolist()):
            end = int(epoch_starts[epoch + 1]) if epoch + 1 < len(epoch_starts) else count
            chosen = np.flatnonzero(epoch_of_query == epoch)
            if len(chosen):
                values[chosen] = _epoch_query_values(index, begin, query_adds[chosen], base, base_total, quantile,
                                                     centres)
            base = base + np.bincount(index[begin:end], minlength=width)
            base_total += end - begin
            if epoch + 1 < len(epoch_starts):  # the halving after this epoch's last add
                base *= 0.5
                base_total *= 0.5
        per_add = _value_after_each_add(values, first_query, count, np.nan if self.value is None else self.value)
        counts = carried.copy()
        counts[low:high] = base
        self.counts = counts
        self.total = base_total
        self.since_decay = self.since_decay + count if not len(halvings) else count - int(halvings[-1])
        self.since_query = self.since_query + count if not len(query_adds) else count - int(query_adds[-1])
        if len(values):
            self.value = float(values[-1])
        return per_add


def _bin_of(variances: np.ndarray) -> np.ndarray:
    """The histogram bin of each variance (a variance <= 0 or below the range: bin 0; above: the last)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        position = np.log10(variances)
    position -= LOG_MIN
    position *= BINS_PER_DECADE
    np.floor(position, out=position)
    np.fmax(position, 0.0, out=position)  # a variance <= 0 gives -inf or NaN (fmax takes 0 over NaN): bin 0
    np.minimum(position, NBINS - 1, out=position)
    index: np.ndarray = position.astype(np.int64)
    return index


def _epoch_query_values(index: np.ndarray, begin: int, upto: np.ndarray, base: np.ndarray, base_total: float,
                        quantile: float, centres: np.ndarray) -> np.ndarray:
    """The floor value at each query of one epoch (its adds begin+1 .., the queries after adds `upto`),
    each seeing the histogram carried in (`base`, `base_total`) plus the epoch's adds up to it."""
    width = len(base)
    # Adds begin+1 .. the epoch's last query (later ones never reach one), each keyed by (its
    # first query at or after it, its bin): those up to the first query, then QUERY_EVERY per query.
    head, reached = int(upto[0]) - begin, int(upto[-1]) - begin
    keys = index[begin:begin + reached].copy()
    keys[head:].reshape(len(upto) - 1, QUERY_EVERY)[...] += width * np.arange(1, len(upto))[:, None]
    # Per query, this epoch's adds per bin so far (integers: a fast cumsum), plus the carried
    # counts: the histogram it sees; then its running count over the bins.
    adds = np.bincount(keys, minlength=len(upto) * width).reshape(-1, width)
    np.cumsum(adds, axis=0, out=adds)
    running = adds + base
    np.cumsum(running, axis=1, out=running)
    total = base_total + (upto - begin).astype(float)
    # The first bin reaching quantile x total that holds counts: the first bin reaching a target
    # above 0 does (the running count rose there); a target of 0, the first bin holding any.
    target = np.maximum(quantile * total, 5e-324)
    first_hit = np.count_nonzero(running < target[:, None], axis=1)
    values: np.ndarray = np.where(first_hit < width, centres[np.minimum(first_hit, width - 1)], 10.0**LOG_MAX)
    return values


def _value_after_each_add(values: np.ndarray, first_query: int, count: int, previous: float) -> np.ndarray:
    """After each of `count` adds: the value of the latest query at or before it (the queries every
    QUERY_EVERY adds from `first_query`, giving `values`), `previous` before the first."""
    before_first = min(first_query - 1, count)
    per_add = np.empty(count)
    per_add[:before_first] = previous
    after = per_add[before_first:]
    runs = len(after) // QUERY_EVERY
    after[:runs * QUERY_EVERY].reshape(runs, QUERY_EVERY)[:] = values[:runs, None]
    after[runs * QUERY_EVERY:] = values[runs] if len(after) > runs * QUERY_EVERY else 0.0
    return per_add
