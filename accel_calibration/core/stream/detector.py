"""Streaming static-pose detector: O(1) per sample, windows in seconds of stream time.

A sliding window (default 0.5 s of header time) keeps running sums of the acceleration (and gyro)
so its variance costs a few float operations per sample, whatever the rate (50 Hz..2 kHz). The
window is still when its variance is below k * the measured noise floor -- as imu_tk thresholds at
k * sigma^2 of an initial still period, but the floor here is learned continuously as a low
quantile of all window variances seen (a log-spaced histogram), so no initial still period is
needed and any raw unit (counts, g, m/s^2) works. Explicit thresholds override.

The floor cannot learn flight vibration: it may rise at most `max_floor_rise` (rms) above the quietest
floor seen since start, and a window noisier than `accel_noise_ceiling` / `gyro_noise_ceiling` (rms
per axis, a value every MEMS part at rest stays below and motor vibration does not) is never still.
A window in which more than half of the samples repeat their predecessor exactly (a frozen driver, a
gyro reading 0 while it warms up) is no evidence of the noise: it never feeds the floor.

A still interval becomes a Pose when motion starts again (or at `max_pose_s`), if it lasted
`min_hold_s`; `trim_s` is dropped at both ends (settling after the last motion, the onset of the
next one before the window noticed it).

Hostile input: a sample with a NaN/inf, a stamp not after the last one, or a value beyond `accel_limit`
/ `gyro_limit` (always beyond _HARD_LIMIT, where squares and sums could overflow) is skipped and
counted. A large value that is accepted cannot poison the running sums either: they are rebuilt from
the window, about its mean, when a sample whose square dwarfs what remains leaves it (the subtraction
would leave its rounding behind, far above the noise) and when the shift is far from the window's data
(a glitch as the first sample), so once it has left the window the detector behaves as if it had never
been there. A temperature that is NaN, inf or beyond the guard counts as no temperature.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any, Final, overload

import numpy as np
from numpy.typing import ArrayLike

from .errors import CalibrationError
from .pose import Pose

_BINS_PER_DECADE = 10
# Variance range the histogram covers, decades (Final: 10 ** _LOG_MAX is then known to be an int).
_LOG_MIN: Final = -14
_LOG_MAX: Final = 14
_NBINS = (_LOG_MAX - _LOG_MIN) * _BINS_PER_DECADE
# Largest magnitude accepted on any axis (and for temperature) whatever the limits: its squares, summed
# over any window, stay far from overflow. Beyond it a sample is rejected (a temperature: ignored).
_HARD_LIMIT = 1e12
# A sample leaving the window whose square exceeds this multiple of what remains in the running sum
# of squares makes the sums be rebuilt: the subtraction leaves rounding of ~1e-16 of it behind.
_CANCELLATION = 1e4
_CANCELLATION_INV = 1.0 / _CANCELLATION
# The sums are rebuilt about the window's mean when the sum of squares exceeds this multiple of
# n * variance (the shift is far from the data: the variance would be a small difference of large
# numbers, ~1e-16 * this relative error). Below _TINY_SQUARES nothing is worth rebuilding.
_REBASE = 1e6
_TINY_SQUARES = 1e-150
_INF = math.inf
# One accepted sample: t_ns, ax ay az, gx gy gz (None without gyro), temperature (None without), then
# the differences from the shift: dx dy dz, ex ey ez, then repeat flags (_ACCEL_REPEAT | _GYRO_REPEAT:
# the accel / gyro triple equals the previous accepted sample's, bit for bit).
_Sample = tuple[int, float, float, float, float | None, float | None, float | None, float | None,
                float, float, float, float, float, float, int]
_ACCEL_REPEAT = 1
_GYRO_REPEAT = 2
# Marks for process(breaks=...): before this sample the clock was re-synchronised (restart()), or
# collection was paused and resumed (discard()).
RESTART = 1
DISCARD = 2
_INT64_MAX = 2**63 - 1


class _VarianceFloor:
    """Low quantile of a stream of variances, via a decaying log histogram (O(1) per value)."""

    def __init__(self, quantile: float, half_life_values: int = 200_000):
        self.quantile = quantile
        self.counts = [0.0] * _NBINS
        self.total = 0.0
        self.half_life = half_life_values
        self._since_decay = 0
        self.value: float | None = None
        self._since_query = 0

    def add(self, variance: float) -> None:
        if 0.0 < variance < _INF:
            index = int((math.log10(variance) - _LOG_MIN) * _BINS_PER_DECADE)
            index = 0 if index < 0 else (_NBINS - 1 if index >= _NBINS else index)
        elif -_INF < variance <= 0.0:
            index = 0
        else:  # NaN or inf: finite sums cannot give one; never let it into the histogram
            return
        self.counts[index] += 1.0
        self.total += 1.0
        self._since_decay += 1
        self._since_query += 1
        if self._since_decay >= self.half_life:  # old conditions fade: vibration, temperature
            self.counts = [c * 0.5 for c in self.counts]
            self.total *= 0.5
            self._since_decay = 0
        if self._since_query >= 64 or self.value is None:
            self._since_query = 0
            self.value = self._query()

    def _query(self) -> float:
        target = self.quantile * self.total
        running = 0.0
        for index, count in enumerate(self.counts):
            running += count
            if running >= target and count > 0:
                return 10 ** (_LOG_MIN + (index + 0.5) / _BINS_PER_DECADE)
        return 10 ** _LOG_MAX


class StaticDetector:
    """Feed samples in time order with `update`; it returns a Pose when a still interval ends.

    Parameters (all times in seconds of the stream's own clock):
      window_s: sliding window for the variance test.
      min_hold_s: shortest still interval kept as a pose.
      accel_var_threshold: explicit threshold on the window's total acceleration variance (sum of the
        three axes, input units squared); None = k_sigma * learned noise floor.
      gyro_var_threshold: same for the gyro (rad/s)^2; None = learned. Used only when gyro samples come.
      k_sigma: accel threshold as a multiple of the noise-floor variance.
      gyro_k_sigma: gyro threshold multiple. Looser: MEMS gyro noise is far less steady than the
        accelerometer's (a hand-held still pose varies 10-100x above the quietest windows), while
        rotation raises it 1000x and more.
      noise_quantile: quantile of window variances taken as the noise floor (the fraction of time the
        sensor must be still for the floor to be right).
      warmup_s: stream time of full windows needed before the learned floor is trusted.
      trim_s: dropped from the end of each interval (motion onset inside the window).
      max_pose_s: a longer still interval is cut into poses of this length (tracks temperature drift).
      accel_limit, gyro_limit: largest absolute value per axis the sensor can read (input units); a
        sample beyond it is a glitch, skipped and counted in rejected_samples and rejected_out_of_range.
        None = no limit but the hard guard of 1e12 (which always applies).
      max_floor_rise: the learned floors may rise at most this factor (rms, so its square in variance)
        above the quietest floor seen after warm-up: hours of flight vibration are never learned as noise.
      accel_noise_ceiling, gyro_noise_ceiling: largest noise (rms per axis, input units) of a still
        window; the learned threshold never exceeds it, so vibration is never still even when the stream
        starts in flight. None = no ceiling (the unit is not known here; the session sets them in SI).
      floor_min_magnitude: smallest |mean acceleration| of a window that may teach the floor (input
        units; the session: 0.05 g): a dead sensor's quiet zeros must not become the quietest floor.
        None = any.
    """

    def __init__(
        self,
        *,
        window_s: float = 0.5,
        min_hold_s: float = 1.0,
        accel_var_threshold: float | None = None,
        gyro_var_threshold: float | None = None,
        k_sigma: float = 6.0,
        gyro_k_sigma: float = 300.0,
        noise_quantile: float = 0.05,
        warmup_s: float = 2.0,
        trim_s: float | None = None,
        max_pose_s: float = 60.0,
        accel_limit: float | None = None,
        gyro_limit: float | None = None,
        max_floor_rise: float = 1.5,
        accel_noise_ceiling: float | None = None,
        gyro_noise_ceiling: float | None = None,
        floor_min_magnitude: float | None = None,
    ) -> None:
        def positive(name: str, value: object) -> float:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise CalibrationError(f"{name} must be a positive number, got {value!r}")
            return float(value)

        self.window_s = positive("window_s", window_s)
        self.min_hold_s = positive("min_hold_s", min_hold_s)
        self.k_sigma = positive("k_sigma", k_sigma)
        self.gyro_k_sigma = positive("gyro_k_sigma", gyro_k_sigma)
        self.warmup_s = positive("warmup_s", warmup_s)
        self.max_pose_s = positive("max_pose_s", max_pose_s)
        self.trim_s = self.window_s / 2 if trim_s is None else float(trim_s)
        if not (0.0 <= self.trim_s < self.min_hold_s):
            raise CalibrationError(f"trim_s must be in [0, min_hold_s), got {trim_s!r}")
        if self.max_pose_s < self.min_hold_s:
            raise CalibrationError("max_pose_s must be at least min_hold_s")
        if not (isinstance(noise_quantile, float) and 0.0 < noise_quantile < 0.5):
            raise CalibrationError(f"noise_quantile must be in (0, 0.5), got {noise_quantile!r}")
        self.accel_var_threshold = (None if accel_var_threshold is None
                                    else positive("accel_var_threshold", accel_var_threshold))
        self.gyro_var_threshold = (None if gyro_var_threshold is None
                                   else positive("gyro_var_threshold", gyro_var_threshold))
        self.accel_limit = None if accel_limit is None else positive("accel_limit", accel_limit)
        self.gyro_limit = None if gyro_limit is None else positive("gyro_limit", gyro_limit)
        self._accel_max = _HARD_LIMIT if self.accel_limit is None else min(self.accel_limit, _HARD_LIMIT)
        self.max_floor_rise = positive("max_floor_rise", max_floor_rise)
        if self.max_floor_rise < 1.0:
            raise CalibrationError(f"max_floor_rise must be at least 1, got {max_floor_rise!r}")
        self._rise_var = self.max_floor_rise ** 2
        self.accel_noise_ceiling = (None if accel_noise_ceiling is None
                                    else positive("accel_noise_ceiling", accel_noise_ceiling))
        self.gyro_noise_ceiling = (None if gyro_noise_ceiling is None
                                   else positive("gyro_noise_ceiling", gyro_noise_ceiling))
        self.floor_min_magnitude = (None if floor_min_magnitude is None
                                    else positive("floor_min_magnitude", floor_min_magnitude))
        self._min_magnitude_squared = 0.0 if self.floor_min_magnitude is None else self.floor_min_magnitude ** 2
        # As window totals (three axes): the largest learned threshold.
        self._accel_cap = _INF if self.accel_noise_ceiling is None else 3.0 * self.accel_noise_ceiling ** 2
        self._gyro_cap = _INF if self.gyro_noise_ceiling is None else 3.0 * self.gyro_noise_ceiling ** 2
        self._gyro_max = _HARD_LIMIT if self.gyro_limit is None else min(self.gyro_limit, _HARD_LIMIT)
        self._window_ns = int(self.window_s * 1e9)
        self._max_pose_ns = int(self.max_pose_s * 1e9)  # in whole ns, as process() has it
        self._full_ns = int(0.9 * self.window_s * 1e9)
        self._gap_ns = self._window_ns  # a hole longer than a window breaks continuity
        self._accel_floor = _VarianceFloor(noise_quantile)
        self._gyro_floor = _VarianceFloor(noise_quantile)
        self.rejected_samples = 0  # every sample skipped: NaN/inf, stamp not increasing, out of range
        self.rejected_out_of_range = 0  # of those, the finite ones beyond accel_limit/gyro_limit/the guard
        self._full_time_ns = 0  # stream time with a full window that is evidence of the noise floor
        self._warmup_ns = self.warmup_s * 1e9
        # Lowest floor values seen after warm-up: the learned floors may rise only max_floor_rise above.
        self._accel_quietest = _INF
        self._gyro_quietest = _INF
        self.pose_segments: list[int] = []  # after process(): the segment (between breaks) of each pose
        # Between process() calls on parts of one recording: the rows still needed (BatchCarry) and the
        # clocks' layout (the current segment's offset, the latest virtual stamp).
        self._batch_carry: Any = None
        self._layout: tuple[int, int] | None = None
        self.reset()

    # ---------------------------------------------------------------- state
    def reset(self) -> None:
        """Forget the stream (not the learned noise floor)."""
        self._window: deque[_Sample] = deque()
        self._sums = [0.0] * 8  # ax ay az |a|^2 gx gy gz |g|^2, of values minus the shift
        self._repeats = [0, 0]  # samples in the window repeating their predecessor: accel, gyro
        self._shift: tuple[float, float, float, float, float, float] | None = None
        self._refresh_countdown = 10_000
        self._last_ns: int | None = None
        self._interval: dict[str, Any] | None = None  # running sums of the current still interval
        self._pending: deque[_Sample] = deque()  # the interval's newest trim_s of samples, not yet committed
        # Samples of an open interval whose window was not full (a hole in the stamps shorter than a gap,
        # e.g. a rejected sample): no verdict on them; they join the interval if it goes on.
        self._undecided: list[_Sample] = []
        self._warmup_max: tuple[float, float] | None = (0.0, 0.0) if self.thresholds[0] is None else None
        self._previous: tuple[float, float, float, float | None, float | None, float | None] | None = None
        self.state = "waiting"

    @property
    def continuing(self) -> bool:
        """A recording is going through process() in parts: the next call continues it."""
        return self._batch_carry is not None or self._layout is not None

    @property
    def noise_floor_accel_var(self) -> float | None:
        """Per-axis variance of the acceleration noise (window total / 3), when learned: the floor in
        force, bounded as the thresholds are."""
        value = self._accel_floor.value
        if value is None or self._full_time_ns < self._warmup_ns:
            return None
        return min(value, self._accel_quietest * self._rise_var, self._accel_cap) / 3.0

    @property
    def quietest_floors(self) -> tuple[float | None, float | None]:
        """(accel, gyro) lowest window-total floors seen after warm-up; None before."""
        a, g = self._accel_quietest, self._gyro_quietest
        return (None if a == _INF else a), (None if g == _INF else g)

    @property
    def noise_near_ceilings(self) -> tuple[float | None, float | None]:
        """(accel m/s^2, gyro rad/s) rms noise per axis of the quietest floor learned, where it is at least
        half its ceiling (accel_noise_ceiling, gyro_noise_ceiling): the floor is a low quantile of the
        windows' noise, so windows still enough for a pose were then the exception (a hand-held sensor,
        vibration). None where it is not, or not known yet."""
        accel, gyro = self.quietest_floors
        return (None if accel is None or not accel >= self._accel_cap / 4 else math.sqrt(accel / 3.0),
                None if gyro is None or not gyro >= self._gyro_cap / 4 else math.sqrt(gyro / 3.0))

    @property
    def thresholds(self) -> tuple[float | None, float | None]:
        """(accel, gyro) window-variance thresholds in force; None where not yet known."""
        warm = self._full_time_ns >= self._warmup_ns
        accel = self.accel_var_threshold
        value = self._accel_floor.value
        if accel is None and warm and value is not None:
            # Same operations, in the same order, as static_detector_batch: the two paths agree bit for bit.
            accel = min(self.k_sigma * min(value, self._accel_quietest * self._rise_var), self._accel_cap)
        gyro = self.gyro_var_threshold
        value = self._gyro_floor.value
        if gyro is None and warm and value is not None:
            gyro = min(self.gyro_k_sigma * min(value, self._gyro_quietest * self._rise_var), self._gyro_cap)
        return accel, gyro

    # ---------------------------------------------------------------- per sample
    @overload
    def update(self, t_ns: int, ax: float, ay: float, az: float, gx: None = None, gy: None = None,
               gz: None = None, temperature_degc: float | None = None) -> Pose | None: ...

    @overload
    def update(self, t_ns: int, ax: float, ay: float, az: float, gx: float, gy: float, gz: float,
               temperature_degc: float | None = None) -> Pose | None: ...

    # The overloads are the contract: the gyro's three axes come together or not at all. The body tests
    # `gx is not None` once (has_gyro) and then uses all three, which mypy cannot follow: Any here.
    def update(self, t_ns: int, ax: float, ay: float, az: float, gx: Any = None, gy: Any = None, gz: Any = None,
               temperature_degc: float | None = None) -> Pose | None:
        """One sample (plain floats; called per message). Returns a Pose when a still interval ends."""
        # One test rejects NaN, inf and out-of-range values alike (comparisons with NaN are False).
        a, g = self._accel_max, self._gyro_max
        has_gyro = gx is not None
        if not (-a <= ax <= a and -a <= ay <= a and -a <= az <= a) or (
            has_gyro and not (-g <= gx <= g and -g <= gy <= g and -g <= gz <= g)
        ):
            self.rejected_samples += 1
            values = (ax, ay, az, gx, gy, gz) if has_gyro else (ax, ay, az)
            if all(math.isfinite(v) for v in values):
                self.rejected_out_of_range += 1
            return None
        if temperature_degc is not None and not (-_HARD_LIMIT <= temperature_degc <= _HARD_LIMIT):
            temperature_degc = None  # NaN, inf or absurd: no temperature for this sample, the motion is fine
        last = self._last_ns
        if last is not None and t_ns <= last:
            self.rejected_samples += 1
            return None
        emitted = None
        if last is not None and t_ns - last > self._gap_ns:
            emitted = self._end_interval()
            self._clear_window()
        self._last_ns = t_ns
        previous = self._previous
        flags = 0
        if previous is not None:
            if ax == previous[0] and ay == previous[1] and az == previous[2]:
                flags = _ACCEL_REPEAT
            if has_gyro and gx == previous[3] and gy == previous[4] and gz == previous[5]:
                flags |= _GYRO_REPEAT
        self._previous = (ax, ay, az, gx, gy, gz)
        shift = self._shift
        if shift is None:
            shift = self._shift = (ax, ay, az, gx or 0.0, gy or 0.0, gz or 0.0)
        sx, sy, sz, sgx, sgy, sgz = shift
        dx, dy, dz = ax - sx, ay - sy, az - sz
        if has_gyro:
            ex, ey, ez = gx - sgx, gy - sgy, gz - sgz
        else:
            ex = ey = ez = 0.0
        sample = (t_ns, ax, ay, az, gx, gy, gz, temperature_degc, dx, dy, dz, ex, ey, ez, flags)
        window = self._window
        window.append(sample)
        if flags:
            repeats = self._repeats
            repeats[0] += flags & _ACCEL_REPEAT
            repeats[1] += flags >> 1
        s = self._sums
        s[0] += dx; s[1] += dy; s[2] += dz; s[3] += dx * dx + dy * dy + dz * dz  # noqa: E702
        s[4] += ex; s[5] += ey; s[6] += ez; s[7] += ex * ex + ey * ey + ez * ez  # noqa: E702
        horizon = t_ns - self._window_ns
        stale = False
        while window[0][0] <= horizon:
            old = window.popleft()
            dx, dy, dz, ex, ey, ez = old[8:14]
            if old[14]:
                repeats = self._repeats
                repeats[0] -= old[14] & _ACCEL_REPEAT
                repeats[1] -= old[14] >> 1
            qa = dx * dx + dy * dy + dz * dz
            qg = ex * ex + ey * ey + ez * ez
            s[0] -= dx; s[1] -= dy; s[2] -= dz; s[3] -= qa  # noqa: E702
            s[4] -= ex; s[5] -= ey; s[6] -= ez; s[7] -= qg  # noqa: E702
            qa *= _CANCELLATION_INV
            qg *= _CANCELLATION_INV
            if -qa < s[3] < qa or -qg < s[7] < qg:
                stale = True  # a big value left: what remains is mostly its rounding debris
        self._refresh_countdown -= 1
        if stale or self._refresh_countdown <= 0:
            self._refresh_sums()
            s = self._sums
        span = t_ns - window[0][0]
        if span < self._full_ns or len(window) < 5:
            self.state = "filling"
            if self._interval is not None:
                self._undecided.append(sample)
            return emitted
        n = len(window)
        accel_var = (s[3] - (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / n) / n
        gyro_var = (s[7] - (s[4] * s[4] + s[5] * s[5] + s[6] * s[6]) / n) / n if has_gyro else None
        if not (  # all False for NaN
            -_INF < accel_var < _INF and s[3] <= _REBASE * n * accel_var + _TINY_SQUARES
            and (gyro_var is None or (-_INF < gyro_var < _INF and s[7] <= _REBASE * n * gyro_var + _TINY_SQUARES))
        ):
            # The shift is far from the window (its first sample was a glitch, or the sensor turned a
            # long way), or, which values inside the guard cannot cause, something is not finite.
            self._refresh_sums()
            s = self._sums
            accel_var = (s[3] - (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / n) / n
            gyro_var = (s[7] - (s[4] * s[4] + s[5] * s[5] + s[6] * s[6]) / n) / n if has_gyro else None
        # A window that is mostly repeated samples (a frozen driver, a gyro stuck at 0) says nothing
        # about the noise: it neither feeds the floor nor counts toward the warm-up.
        # A window whose mean is no gravity (a dead sensor's quiet zeros) says nothing about it either.
        repeats = self._repeats
        shift = self._shift  # (rebuilt with the sums, when they were)
        assert shift is not None  # set by the window's first sample
        mx, my, mz = shift[0] + s[0] / n, shift[1] + s[1] / n, shift[2] + s[2] / n
        if mx * mx + my * my + mz * mz >= self._min_magnitude_squared:
            if 2 * repeats[0] <= n:
                self._full_time_ns += t_ns - last if last is not None else 0
                self._accel_floor.add(accel_var)
            if gyro_var is not None and 2 * repeats[1] <= n:  # has_gyro
                self._gyro_floor.add(gyro_var)
        if self._full_time_ns >= self._warmup_ns:
            value = self._accel_floor.value
            if value is not None and value < self._accel_quietest:
                self._accel_quietest = value
            value = self._gyro_floor.value
            if value is not None and value < self._gyro_quietest:
                self._gyro_quietest = value
        accel_limit, gyro_limit = self.thresholds
        if accel_limit is None:
            # Learning the noise floor. The stream usually starts still (a vehicle on the ground): keep a
            # provisional interval and the loudest windows seen, and adopt it once the threshold is known.
            self.state = "learning noise"
            warmup_max = self._warmup_max
            assert warmup_max is not None  # set by reset() while the accel threshold is unknown
            self._warmup_max = (max(warmup_max[0], accel_var), max(warmup_max[1], gyro_var or 0.0))
            if self._interval is None:
                self._start_interval()
            else:
                self._extend_interval(sample)
            return emitted
        if self._warmup_max is not None:
            loudest_accel, loudest_gyro = self._warmup_max
            self._warmup_max = None
            if self._interval is not None and not (
                loudest_accel <= accel_limit and (gyro_limit is None or loudest_gyro <= gyro_limit)
            ):
                # It moved during warm-up: no pose from it.
                self._interval, self._pending, self._undecided = None, deque(), []
        still = accel_var <= accel_limit and (gyro_var is None or gyro_limit is None or gyro_var <= gyro_limit)
        if still:
            if self._interval is None:
                self._start_interval()
            else:
                self._extend_interval(sample)
                if t_ns - self._interval["opened_ns"] >= self._max_pose_ns:
                    # Parked for long: cut here so slow drifts (temperature) show up as separate poses.
                    emitted = self._end_interval() or emitted
                    self._start_interval()
            self.state = "still"
        else:
            if self._interval is not None:
                emitted = self._end_interval() or emitted
            self.state = "moving"
        return emitted

    def restart(self) -> Pose | None:
        """The stream's clock was re-synchronised (a stamp jump): the interval in progress ends as at a
        gap (returned when long enough) and the next sample starts a new window, whatever its stamp."""
        emitted = self._end_interval()
        self._clear_window()
        self._last_ns = None
        return emitted

    def discard(self) -> None:
        """Collection paused (armed, flying, or asked to): the interval in progress is dropped, not
        emitted, and the next sample starts a new window. The learned floor is kept."""
        self._interval, self._pending, self._undecided = None, deque(), []
        self._clear_window()
        self._last_ns = None

    def peek(self) -> Pose | None:
        """The ongoing still interval as a pose, as flush() would give it, without ending it: what a
        person holding the last pose expects /calibrate to count."""
        interval = self._interval
        if interval is None:
            return None
        saved = {key: (value.copy() if isinstance(value, np.ndarray) else value) for key, value in interval.items()}
        pending, undecided = self._pending, self._undecided
        try:
            return self._end_interval(keep_pending=True)
        finally:
            self._interval, self._pending, self._undecided = saved, pending, undecided

    @property
    def holding_still(self) -> bool:
        """After process(..., final=False): a still interval is open at the end of what was processed."""
        carry = self._batch_carry
        return carry is not None and carry.opened is not None

    def peek_open(self) -> Pose | None:
        """After process(..., final=False): the interval still open as the pose process() would end it as
        if the recording ended here, without ending it (a live /calibrate counts the pose being held)."""
        from .static_detector_batch import peek_carry

        pose = peek_carry(self)
        if pose is None or self._layout is None:
            return pose
        offset = self._layout[0]  # the open interval is on the last segment's clock
        return replace(pose, start_ns=pose.start_ns - offset, end_ns=pose.end_ns - offset)

    def flush(self) -> Pose | None:
        """End of stream: the ongoing still interval, if long enough."""
        return self._end_interval(keep_pending=True)

    def process_streaming(self, t_ns: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None,
                          temperature_degc: ArrayLike | None = None, breaks: ArrayLike | None = None,
                          flush: bool = True) -> list[Pose]:
        """update() sample by sample (restart() / discard() where `breaks` says), then flush() (discard()
        when not `flush`): the reference `process` must agree with."""
        t_ns = np.asarray(t_ns, dtype=np.int64)
        poses = []
        update = self.update
        a = np.asarray(accel, dtype=float).tolist()
        g = None if gyro is None else np.asarray(gyro, dtype=float).tolist()
        temps = None if temperature_degc is None else np.asarray(temperature_degc, dtype=float).tolist()
        marks = None if breaks is None else np.asarray(breaks, dtype=np.int64).reshape(-1).tolist()
        segments: list[int] = []
        segment = 0
        for i, t in enumerate(t_ns.tolist()):
            if marks is not None and marks[i] and i > 0:
                if marks[i] == RESTART:
                    ended = self.restart()
                    if ended is not None:
                        poses.append(ended)
                else:
                    self.discard()
                segments += [segment] * (len(poses) - len(segments))
                segment += 1
            ax, ay, az = a[i]
            temperature = None if temps is None else temps[i]
            if g is None:
                pose = update(t, ax, ay, az, None, None, None, temperature)
            else:
                gx, gy, gz = g[i]
                pose = update(t, ax, ay, az, gx, gy, gz, temperature)
            if pose is not None:
                poses.append(pose)
        if not flush:
            self.discard()
        last = self.flush()
        if last is not None:
            poses.append(last)
        self.pose_segments = segments + [segment] * (len(poses) - len(segments))
        return poses

    def process(self, t_ns: ArrayLike, accel: ArrayLike, gyro: ArrayLike | None = None,
                temperature_degc: ArrayLike | None = None, breaks: ArrayLike | None = None,
                flush: bool = True, final: bool = True) -> list[Pose]:
        """A whole recording at once (bag replay, CLI): the poses update() would give sample by sample
        followed by flush(), computed with array operations (window sums from sums within blocks, the noise
        floor's histogram queried at the same points, the interval rules applied per run of still
        samples). Needs a fresh detector, or one whose last process() call had `final` False. Agreement
        with update() is tested; window variances differ only by rounding (~1e-12 relative).

        `breaks` (one per sample, optional): RESTART where restart() comes before the sample (a clock
        re-synchronised), DISCARD where discard() does (collection paused since the previous sample).
        Each segment runs on a clock of its own, laid end to end with a gap longer than a window.
        `flush` False: the interval still open at the end is dropped (collection paused there).
        `final` False: a part of a recording, more follows in the next call (same gyro and temperature
        presence); the interval open at its end stays open. A long recording goes through in parts of
        bounded memory with the poses of one call. `pose_segments` then numbers the segments from the one
        in force when the call began (0)."""
        from .static_detector_batch import detect_batch

        continuing = self.continuing
        if not continuing and (self._last_ns is not None or self._full_time_ns):
            raise CalibrationError("process() needs a fresh StaticDetector (this one has seen samples)")
        t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
        marks = None if breaks is None else np.asarray(breaks, dtype=np.int64).reshape(-1)
        if marks is not None and len(marks) != len(t):
            raise CalibrationError(f"breaks must have one entry per sample ({len(t)}), got {len(marks)}")
        if marks is not None and not continuing:
            marks = marks.copy()
            marks[:1] = 0  # a break before the first sample changes nothing
        if self._layout is None and (marks is None or not np.any(marks)):
            poses, rejected, out_of_range = detect_batch(self, t, accel, gyro, temperature_degc, flush=flush,
                                                         final=final)
            self.pose_segments = [0] * len(poses)
        else:
            if marks is None:
                marks = np.zeros(len(t), dtype=np.int64)
            previous = self._layout
            if previous is None and self._batch_carry is not None:  # parts so far on their own clock
                previous = (0, int(self._batch_carry.t[-1]))
            laid = self._end_to_end(t, marks, previous)
            if laid is None:  # the clocks laid end to end would not fit in int64 ns
                if not continuing and final:
                    return self.process_streaming(t, accel, gyro, temperature_degc, marks, flush)
                # Part of a long recording whose stamps reach the ends of int64: what is open is lost.
                self._batch_carry, self._layout = None, None
                self.rejected_samples += len(t)
                self.pose_segments = []
                return []
            virtual, segment_starts, offsets, self._layout = laid
            drop = marks == DISCARD
            poses, rejected, out_of_range = detect_batch(self, virtual, accel, gyro, temperature_degc, drop, flush,
                                                         final)
            shifted, segments = [], []
            for pose in poses:
                segment = int(np.searchsorted(segment_starts, pose.start_ns, side="right")) - 1
                offset = int(offsets[segment])
                shifted.append(replace(pose, start_ns=pose.start_ns - offset, end_ns=pose.end_ns - offset))
                segments.append(segment)
            poses, self.pose_segments = shifted, segments
        if final:
            self._layout = None
        self.rejected_samples += rejected
        self.rejected_out_of_range += out_of_range
        return poses

    def _end_to_end(self, t: np.ndarray, marks: np.ndarray, previous: tuple[int, int] | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]] | None:
        """Stamps of segments (split before each marked sample) laid end to end, each starting a window
        and a nanosecond after everything before it: (stamps, first virtual stamp of each segment, the
        offset added to each segment, (the last offset, the latest virtual stamp) for a next part). The
        first segment continues `previous` (offset, latest stamp) of the part before, when given. None
        when that does not fit in int64."""
        cuts = [int(c) for c in np.flatnonzero(marks) if c > 0 or previous is not None]
        bounds = [0, *cuts, len(t)]
        virtual = np.empty_like(t)
        starts, offsets = [], []
        top: int | None = None if previous is None else previous[1]  # the latest virtual stamp so far
        for index, (first, stop) in enumerate(zip(bounds[:-1], bounds[1:])):
            segment = t[first:stop]
            if index == 0 and previous is not None:  # the segment in force before this part goes on
                offset = previous[0]
                base = -_INT64_MAX - 1  # every pose before the first mark belongs to it
                if len(segment):
                    high = int(segment.max()) + offset
                    if high > _INT64_MAX or int(segment.min()) + offset < -_INT64_MAX:
                        return None
                    top = high if top is None else max(top, high)
            else:
                low, high = int(segment.min()), int(segment.max())
                base = low if top is None else top + self._window_ns + 1
                offset = base - low
                top = base + (high - low)
                if top > _INT64_MAX or not -_INT64_MAX <= offset <= _INT64_MAX:
                    return None
            virtual[first:stop] = segment + np.int64(offset)
            starts.append(base)
            offsets.append(offset)
        assert top is not None  # some segment had rows, or a previous part did
        return virtual, np.array(starts, dtype=np.int64), np.array(offsets, dtype=np.int64), (offsets[-1], top)

    # ---------------------------------------------------------------- internals
    def _clear_window(self) -> None:
        self._window.clear()
        self._sums = [0.0] * 8
        self._repeats = [0, 0]  # samples in the window repeating their predecessor: accel, gyro
        self._shift = None

    def _refresh_sums(self) -> None:
        """Recompute the running sums from the window: they drift by rounding over millions of updates,
        a big value leaving them leaves its rounding behind, and a shift far from the data (a glitch as
        first sample, a long turn) makes the variance a small difference of large numbers. So the shift
        becomes the window's mean and the window's samples get their differences anew. O(window)."""
        self._refresh_countdown = 10_000
        window = self._window
        n = len(window)
        if not n:
            self._sums = [0.0] * 8
            return
        # A sample has the gyro's three axes or none (sample[4] is None exactly when sample[5:7] are).
        gyros = [(gx, gy, gz) for _, _, _, _, gx, gy, gz, *_ in window
                 if gx is not None and gy is not None and gz is not None]
        old_shift = self._shift
        assert old_shift is not None  # set by the window's first sample
        shift = (
            sum(sample[1] for sample in window) / n,
            sum(sample[2] for sample in window) / n,
            sum(sample[3] for sample in window) / n,
            *((sum(g[0] for g in gyros) / len(gyros), sum(g[1] for g in gyros) / len(gyros),
               sum(g[2] for g in gyros) / len(gyros)) if gyros else old_shift[3:6]),
        )
        sx, sy, sz, sgx, sgy, sgz = self._shift = shift
        rebuilt = []
        s = [0.0] * 8
        for sample in window:
            t_ns, ax, ay, az, gx, gy, gz, temperature = sample[:8]
            flags = sample[14]
            dx, dy, dz = ax - sx, ay - sy, az - sz
            if gx is None or gy is None or gz is None:  # no gyro (its three axes come together)
                ex = ey = ez = 0.0
            else:
                ex, ey, ez = gx - sgx, gy - sgy, gz - sgz
            rebuilt.append((t_ns, ax, ay, az, gx, gy, gz, temperature, dx, dy, dz, ex, ey, ez, flags))
            s[0] += dx; s[1] += dy; s[2] += dz; s[3] += dx * dx + dy * dy + dz * dz  # noqa: E702
            s[4] += ex; s[5] += ey; s[6] += ez; s[7] += ex * ex + ey * ey + ez * ez  # noqa: E702
        window.clear()  # in place: callers hold the deque
        window.extend(rebuilt)
        self._sums = s

    def _new_interval(self, reference_sample: _Sample) -> dict[str, Any]:
        return {
            "n": 0, "start_ns": None, "end_ns": None,
            "a": np.zeros(3), "aa": np.zeros((3, 3)), "g": np.zeros(3), "gn": 0,
            "t": 0.0, "tn": 0, "tmin": math.inf, "tmax": -math.inf,
            "ref": np.array(reference_sample[1:4]),  # shift: keeps sums of raw counts ~32768 exact
        }

    def _commit(self, interval: dict[str, Any], samples: list[_Sample]) -> None:
        """Add samples to the interval's sums (numpy over a batch: this runs once per trim_s, not per sample)."""
        if not samples:
            return
        accel = np.array([s[1:4] for s in samples]) - interval["ref"]
        interval["a"] += accel.sum(axis=0)
        interval["aa"] += accel.T @ accel
        gyros = [(gx, gy, gz) for _, _, _, _, gx, gy, gz, *_ in samples
                 if gx is not None and gy is not None and gz is not None]  # all three or none
        if gyros:
            interval["g"] += np.sum(gyros, axis=0)
            interval["gn"] += len(gyros)
        temps = [s[7] for s in samples if s[7] is not None]
        if temps:
            interval["t"] += sum(temps)
            interval["tn"] += len(temps)
            interval["tmin"] = min(interval["tmin"], min(temps))
            interval["tmax"] = max(interval["tmax"], max(temps))
        if interval["start_ns"] is None:
            interval["start_ns"] = samples[0][0]
        interval["end_ns"] = samples[-1][0]
        interval["n"] += len(samples)

    def _start_interval(self) -> None:
        """The whole window is still, but its oldest part may hold the tail of the last motion (the
        variance fell below the threshold before the sensor fully settled): skip its first trim_s.
        Its newest trim_s stays pending like every later sample, so the motion onset can be dropped."""
        samples = list(self._window)
        first = samples[0][0] + int(self.trim_s * 1e9)
        # The sums' reference: a sample of the interval itself, not the skipped oldest one, which may be
        # far from it (a glitch accepted during the warm-up) and would cost the mean its precision.
        own = next((s for s in samples if s[0] >= first), samples[-1])
        self._interval = self._new_interval(own)
        self._interval["opened_ns"] = samples[0][0]
        cut = samples[-1][0] - int(self.trim_s * 1e9)
        self._commit(self._interval, [s for s in samples if first <= s[0] <= cut])
        self._pending = deque(s for s in samples if s[0] > cut and s[0] >= first)
        self._undecided = []

    def _extend_interval(self, sample: _Sample) -> None:
        pending = self._pending
        if self._undecided:  # the window is full again and the interval goes on: they were in it
            pending.extend(self._undecided)
            self._undecided = []
        pending.append(sample)
        trim_ns = int(self.trim_s * 1e9)
        cut = sample[0] - trim_ns
        # Commit in batches of ~trim_s (numpy over a list), once the pending span reaches 2 trim_s.
        if pending[0][0] <= cut - trim_ns:
            ready = []
            while pending and pending[0][0] <= cut:
                ready.append(pending.popleft())
            interval = self._interval
            assert interval is not None  # extended only while an interval is open
            self._commit(interval, ready)

    def _end_interval(self, keep_pending: bool = False) -> Pose | None:
        """Close the still interval. Pending samples (the newest trim_s) are dropped when motion ended
        it; at the end of a stream (`keep_pending`) nothing was moving, so they count."""
        interval = self._interval
        self._interval = None
        pending, self._pending = self._pending, deque()
        self._undecided = []  # after the interval's last decided sample: not in it, as in process()
        if interval is None:
            return None
        if keep_pending:
            self._commit(interval, list(pending))
        elif pending:
            cut = pending[-1][0] - int(self.trim_s * 1e9)
            self._commit(interval, [s for s in pending if s[0] <= cut])
        n = interval["n"]
        if n < 2 or interval["start_ns"] is None or interval["end_ns"] - interval["start_ns"] < self.min_hold_s * 1e9:
            return None
        mean_shifted = interval["a"] / n
        cov = interval["aa"] / n - np.outer(mean_shifted, mean_shifted)
        cov *= n / (n - 1)
        gyro = interval["g"] / interval["gn"] if interval["gn"] else None
        temperature = interval["t"] / interval["tn"] if interval["tn"] else None
        return Pose(
            accel_mps2=mean_shifted + interval["ref"],
            accel_cov=cov,
            samples=n,
            start_ns=int(interval["start_ns"]),
            end_ns=int(interval["end_ns"]),
            gyro_radps=gyro,
            temperature_degc=temperature,
            temperature_spread_degc=(interval["tmax"] - interval["tmin"]) if interval["tn"] else None,
        )
