"""The noise a sensor has in operation (motors on, hovering, driving) beside the one it has on a desk: users of
Kalibr, allan_variance_ros and imu_utils multiply the static Allan figures by 10-20 before their estimator
works, because vibration and temperature add noise the still recording never sees.

Both stretches' spectral density (Welch, one-sided, per axis) is averaged over the band an estimator uses:
from MOTION_BELOW_HZ, under which the vehicle's own motion lies and is left out, to BAND_TOP_SHARE of the
sample rate, under the anti-alias filters' roll-off. The ratio of the two, taken over the same band by the
same method, scales the static white-noise density (the Allan fit's, which sees past a filter's shape) to
the density in operation."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import CalibrationError

MOTION_BELOW_HZ = 5.0
BAND_TOP_SHARE = 0.4
SEGMENT_S = 2.0  # Welch segments: 0.5 Hz resolution, the motion's leakage (Hann) far below the band
MIN_SEGMENTS = 4  # Welch segments overlap by half: 4 s at 2 s each, ~190 bins x 3 segments averaged


def band_density(samples: np.ndarray, rate_hz: float, low_hz: float = MOTION_BELOW_HZ,
                 high_hz: float | None = None) -> np.ndarray:
    """(C,) the white-noise density equivalent of each channel's one-sided spectral density averaged over
    [low_hz, high_hz] (default BAND_TOP_SHARE of the rate): sqrt(mean S(f) / 2), the density N of white
    noise whose S is 2 N^2."""
    from scipy.signal import butter, sosfiltfilt, welch

    values = np.asarray(samples, dtype=float)
    values = values[:, None] if values.ndim == 1 else values
    top = BAND_TOP_SHARE * rate_hz if high_hz is None else high_hz
    if not low_hz < top <= rate_hz / 2.0:
        raise CalibrationError(f"the band {low_hz:g}..{top:g} Hz is empty or beyond half the rate ({rate_hz:g} Hz)")
    segment = 1 << max(4, int(math.log2(max(SEGMENT_S * rate_hz, 1.0))))
    if len(values) < MIN_SEGMENTS * segment // 2:
        raise CalibrationError(f"{len(values) / rate_hz:.1f} s: too short for a spectral density over "
                               f"{low_hz:g}..{top:g} Hz (needs {MIN_SEGMENTS * segment / 2 / rate_hz:.0f} s)")
    if not np.all(np.isfinite(values)):
        raise CalibrationError("samples must be finite")
    # The motion taken off first (zero-phase high-pass at half the band's foot, 4th order: its gain in the
    # band >= 0.996): a 3 m/s^2 swing at 1.5 Hz leaked 13 % into the band through Welch's window alone.
    high_pass = butter(4, 0.5 * low_hz, btype="highpass", fs=rate_hz, output="sos")
    values = sosfiltfilt(high_pass, values, axis=0)
    frequency, density = welch(values, fs=rate_hz, nperseg=segment, detrend="linear", axis=0)
    band = (frequency >= low_hz) & (frequency <= top)
    result: np.ndarray = np.sqrt(density[band].mean(axis=0) / 2.0)
    return result


@dataclass(frozen=True)
class OperatingNoise:
    """Per axis: the band densities still and running, their ratio, and the static white-noise density
    scaled by it (the figure an estimator meets in operation)."""

    static_band: np.ndarray
    operating_band: np.ndarray
    ratio: np.ndarray
    operating_density: np.ndarray
    band_hz: tuple[float, float]


def operating_noise(still: np.ndarray, running: np.ndarray, rate_hz: float,
                    static_density: np.ndarray) -> OperatingNoise:
    """The noise in operation from a still and a running stretch of one sensor at `rate_hz`, beside its
    static white-noise density (C,)."""
    top = BAND_TOP_SHARE * rate_hz
    static_band = band_density(still, rate_hz)
    operating_band = band_density(running, rate_hz)
    if not np.all(static_band > 0):
        raise CalibrationError("no noise in the still stretch's band: no ratio to scale by")
    ratio = operating_band / static_band
    return OperatingNoise(static_band=static_band, operating_band=operating_band, ratio=ratio,
                          operating_density=np.asarray(static_density, dtype=float) * ratio,
                          band_hz=(MOTION_BELOW_HZ, top))
