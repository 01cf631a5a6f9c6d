"""A warm-up is a calibration: the biases' temperature curves, accelerometer and gyro, from recordings
where the sensor sits still (one orientation is enough) while its temperature changes, on top of the
calibration in force.

- Still stretches: the session's own screen and detector (its poses, cut at max_pose_s, are contiguous
  in a long still stretch; a slow drift does not move a half-second window's variance).
- Weighted by temperature, not by time: the still samples are binned by temperature (`bin_degc`), each
  bin's mean and standard error, and every bin counts alike in the curve (warmup_curve): the slow end
  of a warm-up, where most of the samples are, does not outweigh the fast rise.
- The curve: a natural cubic spline, its knot count chosen by cross-validation over the bins, with a
  sigma per temperature; held flat outside the range its bins cover (never extrapolated).
- Several recordings (a cold morning, a warm afternoon) pooled, each with its own turn-on offset; a run
  whose temperatures overlap no other's cannot be tied to them and is left out, said.
- The temperature sensor lags the sensing element while heating is fast: a first-order lag tau is
  estimated (die temperature = reading + tau d(reading)/dt) where the data hold two heating rates at one
  temperature (a warm-up and a cooling, two warm-ups); from one monotonic warm-up it cannot be seen, said.
- A step in the bias (a reset, a knock): found with its time (warmup_steps); a bump that comes back is
  left out, a lasting step cuts the recording into runs with their own offsets.
- One still orientation sees each accelerometer axis's bias and scale together along gravity (as the
  autopilots' bias-only models do): the level axes' curves are bias alone, the axis along gravity's is
  bias + scale drift x g. Said per axis.

The curves are in the frame the calibration in force corrects to (a_true = M (a_raw - b)), zero at the
reference temperature: the accelerometer's drift there is not observable in a level axis from one
orientation (the tilt hides it); the gyro's absolute bias is (at rest it reads zero but for the earth's
rate, 0.07 mrad/s at most, left in)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .calibration import Calibration
from .errors import CalibrationError
from .settings import Settings
from .temperature_models import TemperatureModel
from .units import AXES, MG
from .warmup_curve import BiasCurve, CurveFit, fit_bias_curve, misfit
from .warmup_steps import Step, bumps_and_breaks, find_steps

GAP_S = 5.0  # still samples further apart than this are separate stretches
ORIENTATION_DEG = 2.0  # stretches whose gravity directions differ more are separate runs
MIN_OVERLAP_DEGC = 1.0  # runs are tied together by their bins over at least this much common temperature
ALONG_GRAVITY_COSINE = 0.9
LEVEL_COSINE = 0.3
PASS_RATE = 0.005  # degC/s: slower is no pass of its own (a plateau's noise)
# Two heating rates at one temperature (within RATE_BIN_DEGC) differing by this much can show a lag of
# ~10 s as ~0.2 degC: beyond a bin's noise on a drift of ~1 mg/degC.
RATE_BIN_DEGC = 1.0
RATE_DIFFERENCE = 0.02  # degC/s
LAG_GRID_S = (0.0, 5.0, 10.0, 15.0, 20.0, 30.0, 40.0, 50.0, 60.0, 80.0, 100.0, 120.0)


@dataclass(frozen=True)
class WarmupRecording:
    """One recording: sample stamps (ns), raw acceleration (N, 3) m/s^2, raw angular rate (N, 3) rad/s
    or None, the sensor's temperature at each sample (N,) degC (NaN where none)."""

    t_ns: np.ndarray
    accel_mps2: np.ndarray
    gyro_radps: np.ndarray | None
    temperature_degc: np.ndarray
    name: str = ""


@dataclass(frozen=True)
class WarmupOptions:
    bin_degc: float = 0.5
    min_bin_samples: int = 20
    min_span_degc: float = 5.0
    reference_degc: float | None = None  # None: the calibration's reference, else the range's middle
    lag_s: float | None = None  # None: estimated where the data can show it; a number: taken as given
    step_floor_mg: float = 1.0  # smallest accelerometer step taken for one (beside its noise)
    step_floor_mradps: float = 0.2  # smallest gyro step


@dataclass(frozen=True)
class Run:
    """A stretch of one recording with one turn-on bias: a recording, or part of one between steps."""

    recording: int
    start_ns: int
    end_ns: int
    range_degc: tuple[float, float]


@dataclass(frozen=True, eq=False)
class WarmupFit:
    """The biases' temperature curves in the corrected frame, zero at `reference_degc`, held flat outside
    `range_degc`; `gyro_bias_radps`: the corrected gyro's mean bias at the reference over the runs."""

    accel: BiasCurve
    gyro: BiasCurve | None
    reference_degc: float
    gyro_bias_radps: np.ndarray | None
    accel_offsets: np.ndarray  # (R, 3) each run's accelerometer reading at the reference (its turn-on bias)
    gyro_offsets: np.ndarray | None
    runs: tuple[Run, ...]
    lag_s: float
    lag_seen: bool
    steps: tuple[tuple[int, Step], ...]  # (recording, step)
    left_out: tuple[str, ...]
    axes: tuple[str, ...]  # per accelerometer axis: what its curve is (bias alone, or bias + scale x g)
    bins: int
    accel_residual_mg: np.ndarray  # (3,) rms of the bins about the curve
    gyro_residual_mradps: np.ndarray | None

    @property
    def range_degc(self) -> tuple[float, float]:
        return self.accel.range_degc

    def describe(self) -> list[str]:
        """What was fitted and what it cannot see, as replay says it."""
        low, high = self.range_degc
        lines = [f"warm-up: bias curves over {low:.1f}..{high:.1f} degC from {self.bins} temperature bins in "
                 f"{len(self.runs)} run(s), zero at {self.reference_degc:.1f} degC; held flat outside the range"]
        accel_drift = np.ptp(self.accel.values, axis=0) / MG
        lines.append("  accelerometer drift over the range: " + ", ".join(
            f"{a} {d:.2f} mg" for a, d in zip(AXES, accel_drift)) + "; bins about the curve: "
            + ", ".join(f"{r:.3f}" for r in self.accel_residual_mg) + " mg rms")
        if self.gyro is not None and self.gyro_residual_mradps is not None:
            gyro_drift = np.ptp(self.gyro.values, axis=0) * 1e3
            lines.append("  gyro drift over the range: " + ", ".join(
                f"{a} {d:.3f} mrad/s" for a, d in zip(AXES, gyro_drift)) + "; bins about the curve: "
                + ", ".join(f"{r:.4f}" for r in self.gyro_residual_mradps) + " mrad/s rms")
        lines += [f"  {line}" for line in self.axes]
        if self.lag_seen:
            lines.append(f"  temperature sensor lag: {self.lag_s:.0f} s (estimated)")
        else:
            lag = f"taken as {self.lag_s:g} s" if self.lag_s else "not seen"
            lines.append(f"  temperature sensor lag: {lag} (it shows only where one temperature is passed at two "
                         "heating rates)")
        lines += [f"  step in the bias in recording {r + 1} at {s.time_ns * 1e-9:.1f} s "
                  f"({s.sigmas:.0f} sigma)" for r, s in self.steps]
        lines += [f"  left out: {why}" for why in self.left_out]
        return lines


@dataclass(frozen=True)
class WarmupResult:
    fit: WarmupFit | None
    refusal: str | None = None
    said: tuple[str, ...] = field(default=())


def _corrected(recording: WarmupRecording, calibration: Calibration | None) -> tuple[np.ndarray, np.ndarray | None]:
    accel = np.asarray(recording.accel_mps2, dtype=float).reshape(-1, 3)
    gyro = None if recording.gyro_radps is None else np.asarray(recording.gyro_radps, dtype=float).reshape(-1, 3)
    if calibration is None:
        return accel, gyro
    base = calibration.replace(temperature=None)
    return base.apply(accel), None if gyro is None else base.apply_gyro(gyro)


def still_mask(recording: WarmupRecording, settings: Settings) -> np.ndarray:
    """Which samples lie in a still interval the session's screen and detector find (its poses)."""
    from .session import CalibrationSession  # the session imports the fit's modules; this one is beside it

    t = np.asarray(recording.t_ns, dtype=np.int64)
    gyro = np.zeros((len(t), 3)) if recording.gyro_radps is None else recording.gyro_radps
    temps = np.asarray(recording.temperature_degc, dtype=float)
    known = np.isfinite(temps)
    poses = CalibrationSession(settings).add_recording(t, recording.accel_mps2, gyro, t[known], temps[known])
    mask = np.zeros(len(t), dtype=bool)
    for pose in poses:
        mask[np.searchsorted(t, pose.start_ns, side="left"):np.searchsorted(t, pose.end_ns, side="right")] = True
    still: np.ndarray = mask & known
    return still


def _stretches(t_ns: np.ndarray) -> list[slice]:
    """Index slices of the still samples (in time order) between gaps longer than GAP_S."""
    cuts = np.flatnonzero(np.diff(t_ns) > GAP_S * 1e9) + 1
    edges = np.concatenate([[0], cuts, [len(t_ns)]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def _heating_rate(t_ns: np.ndarray, degc: np.ndarray) -> np.ndarray:
    """d(temperature)/dt per sample, degC/s, from 5-second means (the register is quantised)."""
    if len(t_ns) < 2 or t_ns[-1] - t_ns[0] < 10e9:
        return np.zeros(len(t_ns))
    block = (t_ns - t_ns[0]) // int(5e9)
    starts = np.flatnonzero(np.concatenate([[True], np.diff(block) != 0]))
    counts = np.diff(np.concatenate([starts, [len(t_ns)]]))
    times = np.add.reduceat(t_ns.astype(float) - t_ns[0], starts) / counts * 1e-9
    means = np.add.reduceat(degc, starts) / counts
    rate: np.ndarray = np.interp((t_ns - t_ns[0]) * 1e-9, times, np.gradient(means, times))
    return rate


@dataclass(frozen=True)
class _RunSamples:
    """A run's still samples, corrected: stamps, temperature, heating rate, accel (N, 3), gyro or None."""

    run: Run
    degc: np.ndarray
    rate: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray | None


def _step_floor(options: WarmupOptions, has_gyro: bool) -> np.ndarray:
    floor = [options.step_floor_mg * MG] * 3
    return np.array(floor + ([options.step_floor_mradps * 1e-3] * 3 if has_gyro else []))


def _recording_runs(index: int, recording: WarmupRecording, calibration: Calibration | None,
                    settings: Settings, options: WarmupOptions) -> tuple[list[_RunSamples], list[Step], list[str]]:
    """One recording's still samples cut into runs (at steps, gaps between orientations), the lasting
    steps found, and what was left out."""
    keep = still_mask(recording, settings)
    accel, gyro = _corrected(recording, calibration)
    t = np.asarray(recording.t_ns, dtype=np.int64)[keep]
    degc = np.asarray(recording.temperature_degc, dtype=float)[keep]
    accel = accel[keep]
    gyro = None if gyro is None else gyro[keep]
    channels = accel if gyro is None else np.hstack([accel, gyro])
    name = recording.name or f"recording {index + 1}"
    runs: list[_RunSamples] = []
    lasting: list[Step] = []
    left_out: list[str] = []
    for stretch in _stretches(t):
        steps = find_steps(t[stretch], channels[stretch], _step_floor(options, gyro is not None))
        bumps, breaks = bumps_and_breaks(steps)
        lasting += breaks
        use = np.ones(stretch.stop - stretch.start, dtype=bool)
        for start, end in bumps:
            use &= ~((t[stretch] >= start) & (t[stretch] < end))
            left_out.append(f"{name} {start * 1e-9:.1f}..{end * 1e-9:.1f} s: a bump in the bias that came back")
        cuts = np.searchsorted(t[stretch], [b.time_ns for b in breaks])
        rows = np.arange(stretch.start, stretch.stop)
        rate = _heating_rate(t[stretch], degc[stretch])
        for part in np.split(np.arange(len(rows)), cuts):
            part = part[use[part]]
            if len(part) < options.min_bin_samples:
                continue
            at = rows[part]
            span = (float(degc[at].min()), float(degc[at].max()))
            runs.append(_RunSamples(Run(index, int(t[at[0]]), int(t[at[-1]]), span), degc[at], rate[part],
                                    accel[at], None if gyro is None else gyro[at]))
    return _join_orientations(runs), lasting, left_out


def _join_orientations(runs: list[_RunSamples]) -> list[_RunSamples]:
    """Consecutive stretches of one recording at one orientation (no step between them) are one run: the
    turn-on bias is the same; a new orientation is a run of its own (gravity's share on each axis moves)."""
    joined: list[_RunSamples] = []
    for run in runs:
        if joined:
            last = joined[-1]
            cosine = float(np.dot(_direction(last.accel), _direction(run.accel)))
            if last.run.recording == run.run.recording and cosine > np.cos(np.radians(ORIENTATION_DEG)) \
                    and run.run.start_ns - last.run.end_ns > GAP_S * 1e9:
                # Apart by a gap (a motion), not cut by a step (a step's cut leaves no gap): one turn-on.
                joined[-1] = _RunSamples(
                    Run(run.run.recording, last.run.start_ns, run.run.end_ns,
                        (min(last.run.range_degc[0], run.run.range_degc[0]),
                         max(last.run.range_degc[1], run.run.range_degc[1]))),
                    np.concatenate([last.degc, run.degc]), np.concatenate([last.rate, run.rate]),
                    np.vstack([last.accel, run.accel]),
                    None if last.gyro is None or run.gyro is None else np.vstack([last.gyro, run.gyro]))
                continue
        joined.append(run)
    return joined


def _direction(accel: np.ndarray) -> np.ndarray:
    mean = accel.mean(axis=0)
    direction: np.ndarray = mean / max(float(np.linalg.norm(mean)), 1e-300)
    return direction


@dataclass(frozen=True)
class _Bins:
    degc: np.ndarray  # (B,) mean temperature of each bin (the register's; lag-corrected by `at_lag`)
    rate: np.ndarray  # (B,) mean heating rate in each bin, degC/s
    runs: np.ndarray  # (B,) index of the run each bin is of
    accel: tuple[np.ndarray, np.ndarray]  # means (B, 3), standard errors (B, 3)
    gyro: tuple[np.ndarray, np.ndarray] | None

    def at_lag(self, lag_s: float) -> _Bins:
        """The same bins at the sensing element's temperature for a register lagging it by `lag_s`
        (first order: element = register + lag x its rate)."""
        return _Bins(self.degc + lag_s * self.rate, self.rate, self.runs, self.accel, self.gyro)


def _bin_means(key: np.ndarray, values: np.ndarray, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Means and standard errors of `values` (N, C) per bin key (0..K-1), for the bins `kept`."""
    counts = np.bincount(key)[kept]
    sums = np.stack([np.bincount(key, values[:, c]) for c in range(values.shape[1])], axis=1)[kept]
    squares = np.stack([np.bincount(key, values[:, c] ** 2) for c in range(values.shape[1])], axis=1)[kept]
    means = sums / counts[:, None]
    variance = np.maximum(squares / counts[:, None] - means**2, 0.0) * counts[:, None] / (counts[:, None] - 1)
    return means, np.sqrt(variance / counts[:, None])


def _bins(runs: list[_RunSamples], options: WarmupOptions) -> _Bins:
    """Every run's still samples binned by temperature and pass (warming and then cooling through one
    temperature give two bins: their disagreement is what shows a lag): each bin's mean and standard
    error; bins of fewer than min_bin_samples samples left out."""
    degc, rate, run_of, accel, gyro = [], [], [], [], []
    for index, run in enumerate(runs):
        key = np.floor(run.degc / options.bin_degc).astype(np.int64)
        key -= key.min()
        passes = _passes(run.rate)
        key = key * (int(passes[-1]) + 1) + passes
        kept = np.flatnonzero(np.bincount(key) >= options.min_bin_samples)
        if not len(kept):
            continue
        degc.append(_bin_means(key, run.degc[:, None], kept)[0][:, 0])
        rate.append(_bin_means(key, run.rate[:, None], kept)[0][:, 0])
        run_of.append(np.full(len(kept), index))
        accel.append(_bin_means(key, run.accel, kept))
        if run.gyro is not None:
            gyro.append(_bin_means(key, run.gyro, kept))
    if not degc:
        return _Bins(np.zeros(0), np.zeros(0), np.zeros(0, np.int64), (np.zeros((0, 3)), np.zeros((0, 3))), None)
    joined_gyro = None
    if len(gyro) == len(accel):
        joined_gyro = (np.vstack([g[0] for g in gyro]), np.vstack([g[1] for g in gyro]))
    return _Bins(np.concatenate(degc), np.concatenate(rate), np.concatenate(run_of),
                 (np.vstack([a[0] for a in accel]), np.vstack([a[1] for a in accel])), joined_gyro)


def _tied_runs(runs: list[Run]) -> tuple[list[int], list[str]]:
    """The indices of the runs tied together by common temperature (MIN_OVERLAP_DEGC) to the run of widest
    span; each other run's offset against them cannot be known: left out, said."""
    order = sorted(range(len(runs)), key=lambda i: -np.ptp(runs[i].range_degc))
    tied = [order[0]]
    low, high = runs[order[0]].range_degc
    grown = True
    while grown:
        grown = False
        for i in order:
            a, b = runs[i].range_degc
            if i not in tied and min(b, high) - max(a, low) >= MIN_OVERLAP_DEGC:
                tied.append(i)
                low, high = min(low, a), max(high, b)
                grown = True
    left_out = [f"recording {runs[i].recording + 1} {runs[i].start_ns * 1e-9:.1f}.."
                f"{runs[i].end_ns * 1e-9:.1f} s ({runs[i].range_degc[0]:.1f}..{runs[i].range_degc[1]:.1f} "
                "degC): its temperatures overlap none of the others', so its turn-on offset cannot be told "
                "from the drift" for i in sorted(set(range(len(runs))) - set(tied))]
    return sorted(tied), left_out


def _curves(bins: _Bins, reference_degc: float) -> tuple[CurveFit, CurveFit | None]:
    accel = fit_bias_curve(bins.degc, *bins.accel, bins.runs, reference_degc)
    gyro = None if bins.gyro is None else fit_bias_curve(bins.degc, *bins.gyro, bins.runs, reference_degc)
    return accel, gyro


def _misfit(bins: _Bins) -> tuple[float, int]:
    """Chi-square and degrees of freedom of the bins about rich curves, accelerometer and gyro together."""
    chi_square, dof = misfit(bins.degc, *bins.accel, bins.runs)
    if bins.gyro is not None:
        gyro_chi_square, gyro_dof = misfit(bins.degc, *bins.gyro, bins.runs)
        chi_square, dof = chi_square + gyro_chi_square, dof + gyro_dof
    return chi_square, dof


def _passes(rate: np.ndarray) -> np.ndarray:
    """Per sample, the index of its pass: a new one each time the temperature turns (warming to cooling
    or back, at a rate of PASS_RATE or more)."""
    sign = np.sign(np.where(np.abs(rate) >= PASS_RATE, rate, 0.0))
    moving = np.flatnonzero(sign)
    turns = np.zeros(len(rate), dtype=np.int64)
    if len(moving) > 1:
        turned = moving[1:][sign[moving[1:]] != sign[moving[:-1]]]
        turns[turned] = 1
    passes: np.ndarray = np.cumsum(turns)
    return passes


def _two_heating_rates(runs: list[_RunSamples]) -> bool:
    """Whether some temperature is passed at two heating rates (by two runs, or warming then cooling):
    only then does a lag show (one history's lag only relabels its temperatures)."""
    passes = []
    for run in runs:
        key = np.floor(run.degc / RATE_BIN_DEGC).astype(np.int64)
        for value in np.unique(key):
            rates = run.rate[key == value]
            passes.append((int(value), float(np.median(rates)), float(np.ptp(rates))))
    by_degree: dict[int, list[tuple[float, float]]] = {}
    for value, rate, spread in passes:
        by_degree.setdefault(value, []).append((rate, spread))
    for each in by_degree.values():
        rates = [rate for rate, _ in each]
        if max(rates) - min(rates) > RATE_DIFFERENCE or max(spread for _, spread in each) > RATE_DIFFERENCE:
            return True
    return False


def _choose_lag(bins: _Bins, runs: list[_RunSamples], options: WarmupOptions) -> tuple[float, bool]:
    """The lag whose corrected temperatures make the bins of different heating rates agree best (their
    chi-square about a rich curve), and whether it is seen: better than no lag by more than noise."""
    if options.lag_s is not None:
        return options.lag_s, False
    if not _two_heating_rates(runs):
        return 0.0, False
    no_lag, dof = _misfit(bins)
    # The bins' standard errors hold what the drift inside a bin adds: a chi-square within noise of
    # its degrees of freedom says the passes agree as they are; a lag is then not seen.
    if no_lag <= dof + 5.0 * np.sqrt(2.0 * dof):
        return 0.0, False
    scores = {lag: _misfit(bins.at_lag(lag))[0] for lag in LAG_GRID_S}
    best = min(scores, key=lambda lag: scores[lag])
    for lag in np.arange(max(best - 10.0, 0.0), best + 11.0, 1.0):
        scores[float(lag)] = _misfit(bins.at_lag(float(lag)))[0]
    best = min(scores, key=lambda lag: scores[lag])
    seen = no_lag - scores[best] > 25.0  # five sigma of a one-parameter chi-square drop
    return (best, True) if seen and best > 0 else (0.0, False)


def _axes_text(directions: list[np.ndarray]) -> tuple[str, ...]:
    """Per accelerometer axis, what one orientation (each run's gravity direction) lets its curve be: bias
    alone when level, bias and scale drift x g together when along gravity (as the autopilots' models), a
    mix when tilted."""
    if any(float(np.dot(directions[0], d)) < np.cos(np.radians(30.0)) for d in directions[1:]):
        return ("accelerometer: several orientations, each run's curve seen along its own gravity; the "
                "scale drift is not separated from the bias (a fit with poses at several orientations and "
                "temperatures does: --temperature-model polynomial)",)
    texts = []
    for axis, share in zip(AXES, np.abs(directions[0])):
        if share >= ALONG_GRAVITY_COSINE:
            texts.append(f"accelerometer {axis}: along gravity, its curve is bias + scale drift x g together "
                         "(one orientation cannot separate them; right at this orientation)")
        elif share <= LEVEL_COSINE:
            texts.append(f"accelerometer {axis}: level, its curve is the bias drift alone")
        else:
            texts.append(f"accelerometer {axis}: tilted ({np.degrees(np.arccos(share)):.0f} deg from gravity), its "
                         "curve mixes bias and scale drift")
    return tuple(texts)


def _reference(options: WarmupOptions, calibration: Calibration | None, low: float, high: float) -> float:
    """Where the curves are zero: as given, else the calibration's reference temperature, else the middle
    of the range; held inside the range (the drift beyond it is not known)."""
    reference = options.reference_degc
    if reference is None and calibration is not None:
        reference = calibration.reference_temperature_degc
        if reference is None and calibration.temperature is not None:
            reference = calibration.temperature.reference_degc
    if reference is None:
        reference = 0.5 * (low + high)
    return float(min(max(reference, low), high))


def fit_warmup(recordings: list[WarmupRecording], calibration: Calibration | None = None,
               options: WarmupOptions | None = None, settings: Settings | None = None) -> WarmupResult:
    """The biases' temperature curves from still recordings over a temperature span, on top of
    `calibration` (applied first, its temperature model left out). Never raises on data: a refusal says
    why."""
    options = options or WarmupOptions()
    settings = settings or Settings()
    runs: list[_RunSamples] = []
    steps: list[tuple[int, Step]] = []
    left_out: list[str] = []
    for index, recording in enumerate(recordings):
        found, lasting, dropped = _recording_runs(index, recording, calibration, settings, options)
        runs += found
        steps += [(index, step) for step in lasting]
        left_out += dropped
    if not runs:
        return WarmupResult(None, "warm-up: no still stretch with a temperature in the recording(s)")
    tied, untied = _tied_runs([run.run for run in runs])
    runs = [runs[i] for i in tied]
    left_out += untied
    refusal = _span_refusal([run.run for run in runs], options, left_out)
    if refusal is not None:
        return refusal
    measured = _bins(runs, options)
    lag, seen = _choose_lag(measured, runs, options)
    return _fitted(measured.at_lag(lag), [run.run for run in runs], [_direction(run.accel) for run in runs],
                   calibration, options, lag, seen, steps, left_out)


def _span_refusal(runs: list[Run], options: WarmupOptions, left_out: list[str]) -> WarmupResult | None:
    low = min(run.range_degc[0] for run in runs)
    high = max(run.range_degc[1] for run in runs)
    if high - low >= options.min_span_degc:
        return None
    return WarmupResult(None, f"warm-up: the still samples span {high - low:.1f} degC ({low:.1f}..{high:.1f}); "
                              f"a temperature curve needs {options.min_span_degc:g} degC",
                        tuple(f"left out: {why}" for why in left_out))


def _fitted(bins: _Bins, runs: list[Run], directions: list[np.ndarray], calibration: Calibration | None,
            options: WarmupOptions, lag: float, seen: bool, steps: list[tuple[int, Step]],
            left_out: list[str]) -> WarmupResult:
    """The curves through the bins (of the tied runs, indexed 0..R-1 in `runs`) and what they are."""
    reference = _reference(options, calibration, float(bins.degc.min()), float(bins.degc.max()))
    try:
        accel, gyro = _curves(bins, reference)
    except CalibrationError as error:
        return WarmupResult(None, f"warm-up: {error}")
    fit = WarmupFit(
        accel=accel.curve, gyro=None if gyro is None else gyro.curve, reference_degc=reference,
        gyro_bias_radps=None if gyro is None else gyro.offsets.mean(axis=0), accel_offsets=accel.offsets,
        gyro_offsets=None if gyro is None else gyro.offsets, runs=tuple(runs),
        lag_s=lag, lag_seen=seen, steps=tuple(steps), left_out=tuple(left_out), axes=_axes_text(directions),
        bins=len(bins.degc), accel_residual_mg=accel.residual_rms / MG,
        gyro_residual_mradps=None if gyro is None else gyro.residual_rms * 1e3)
    return WarmupResult(fit, None, tuple(fit.describe()))


@dataclass(frozen=True)
class BinnedWarmup:
    """Still samples already binned by temperature (as a node collects them, in bounded memory), in the
    frame the curves are fitted in: per bin its mean temperature (B,), mean heating rate (B,), the index
    of its run in `runs` (B,), its sample count (B,), accelerometer means and standard errors (B, 3) each,
    the gyro's or None; per run its Run (its range from its bins) and its mean gravity direction."""

    degc: np.ndarray
    rate: np.ndarray
    run_of: np.ndarray
    counts: np.ndarray
    accel: tuple[np.ndarray, np.ndarray]
    gyro: tuple[np.ndarray, np.ndarray] | None
    runs: tuple[Run, ...]
    directions: tuple[np.ndarray, ...]


def fit_binned_warmup(binned: BinnedWarmup, calibration: Calibration | None = None,
                      options: WarmupOptions | None = None) -> WarmupResult:
    """fit_warmup's curves from samples binned beforehand (bins of fewer than min_bin_samples left out;
    `calibration` only names the reference temperature: the bins are in its corrected frame already).
    The lag is taken as options.lag_s (0: not seen; binned samples keep no heating history to show it)."""
    options = options or WarmupOptions()
    keep = binned.counts >= options.min_bin_samples
    present = sorted({int(r) for r in binned.run_of[keep]})
    if not present:
        return WarmupResult(None, "warm-up: no still samples with a temperature yet")
    runs = [binned.runs[i] for i in present]
    tied, left_out = _tied_runs(runs)
    chosen = [present[i] for i in tied]
    refusal = _span_refusal([binned.runs[i] for i in chosen], options, left_out)
    if refusal is not None:
        return refusal
    keep &= np.isin(binned.run_of, chosen)
    index = np.searchsorted(np.array(chosen), binned.run_of[keep])
    lag = options.lag_s or 0.0
    bins = _Bins(binned.degc[keep], binned.rate[keep], index, (binned.accel[0][keep], binned.accel[1][keep]),
                 None if binned.gyro is None else (binned.gyro[0][keep], binned.gyro[1][keep])).at_lag(lag)
    return _fitted(bins, [binned.runs[i] for i in chosen], [binned.directions[i] for i in chosen], calibration,
                   options, lag, False, [], left_out)


def warmup_calibration(fit: WarmupFit, calibration: Calibration | None = None) -> Calibration:
    """The calibration in force (identity when none) with the warm-up's curves as its temperature model
    (a `spline`): the curves, fitted in its corrected frame, taken back to raw units (a_true = M (a_raw -
    b - drift(T)), so M drift = curve), the gyro bias moved to the one measured at the reference. A
    temperature model the calibration had is replaced (the warm-up was fitted with it left out)."""
    base = calibration if calibration is not None else Calibration.identity()
    accel_raw = np.linalg.solve(base.matrix, fit.accel.values.T).T
    gyro_bias = base.gyro_bias_radps
    gyro_knots, gyro_raw = np.zeros(0), np.zeros((0, 3))
    if fit.gyro is not None and fit.gyro_bias_radps is not None:
        gyro_matrix = np.eye(3) if base.gyro_matrix is None else base.gyro_matrix
        gyro_knots = fit.gyro.knots_degc
        gyro_raw = np.linalg.solve(gyro_matrix, fit.gyro.values.T).T
        moved = np.linalg.solve(gyro_matrix, fit.gyro_bias_radps)
        gyro_bias = moved if gyro_bias is None else gyro_bias + moved
    model = TemperatureModel("spline", fit.reference_degc, fit.range_degc, spline_knots_degc=fit.accel.knots_degc,
                             spline_bias=accel_raw, spline_gyro_knots_degc=gyro_knots, spline_gyro_bias=gyro_raw)
    return base.replace(temperature=model, gyro_bias_radps=gyro_bias,
                        reference_temperature_degc=fit.reference_degc)
