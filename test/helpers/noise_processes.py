"""Noise processes of known Allan deviation for the noise tests, made here independently of the product's own
simulations (core/allan_model.py), so a test does not check the product against itself."""
from __future__ import annotations

import numpy as np


def flicker(rng: np.random.Generator, samples: int, rate_hz: float, floor_adev: float, channels: int) -> np.ndarray:
    """Flicker (1/f) noise whose Allan deviation is the flat `floor_adev` (S(f) = h / f one-sided, Allan
    variance 2 ln 2 h), shaped in the frequency domain."""
    h = floor_adev**2 / (2.0 * np.log(2.0))
    frequency = np.fft.rfftfreq(samples, 1.0 / rate_hz)
    frequency[0] = np.inf  # no mean
    amplitude = np.sqrt(h / frequency * rate_hz * samples / 2.0)
    shape = (len(frequency), channels)
    spectrum = amplitude[:, None] * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2.0)
    return np.fft.irfft(spectrum, samples, axis=0)
