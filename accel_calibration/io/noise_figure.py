"""The Allan deviation figure of `accel-calib noise`: log-log curves per axis with their 95 % bands, the
fitted -1/2 (white noise), +1/2 (random walk) lines, the bias-instability floor and the whole model fitted."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.allan import BIAS_INSTABILITY_FACTOR, Z95, NoiseFit
from ..core.allan_model import design_columns
from ..core.units import AXES


def write_noise_figure(fits: dict[str, list[NoiseFit]], units: dict[str, str], path: str | Path, title: str) -> None:
    """One panel per sensor ("accelerometer", "gyroscope"), three axes each, written as a PNG to `path`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, panels = plt.subplots(1, len(fits), figsize=(6.5 * len(fits), 5), squeeze=False)
    colours = ("tab:red", "tab:green", "tab:blue")
    for panel, (sensor, axes) in zip(panels[0], fits.items()):
        for axis, fit, colour in zip(AXES, axes, colours):
            band = Z95 * fit.relative_error
            panel.loglog(fit.tau_s, fit.adev, "o-", color=colour, markersize=3, label=f"{axis}")
            panel.fill_between(fit.tau_s, fit.adev * np.maximum(1 - band, 1e-3), fit.adev * (1 + band),
                               color=colour, alpha=0.15)
            noise = fit.noise
            if noise.white_density.present:
                panel.loglog(fit.tau_s, noise.white_density.value / np.sqrt(fit.tau_s), "--", color=colour, lw=0.8)
            if noise.random_walk.resolved:
                panel.loglog(fit.tau_s, noise.random_walk.value * np.sqrt(fit.tau_s / 3.0), ":", color=colour, lw=0.8)
            if noise.bias_instability.present:
                panel.axhline(noise.bias_instability.value * BIAS_INSTABILITY_FACTOR, color=colour, lw=0.5, alpha=0.5)
            if fit.coefficients is not None and fit.white_from_tau_s is not None:  # the whole model fitted
                fitted = fit.tau_s >= fit.white_from_tau_s
                model = design_columns(fit.tau_s[fitted], "filter" in fit.terms) @ fit.coefficients
                panel.loglog(fit.tau_s[fitted], np.sqrt(np.maximum(model, 0.0)), "-", color=colour, lw=1.5, alpha=0.4)
        panel.set_xlabel("tau (s)")
        panel.set_ylabel(f"Allan deviation ({units[sensor]})")
        panel.set_title(f"{sensor}: -- white, : random walk, - bias floor, wide: the model")
        panel.grid(True, which="both", alpha=0.3)
        panel.legend()
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
