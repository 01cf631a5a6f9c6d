"""The calibration history as a figure: one panel per sensor, bias (mg, left axis) and scale deviation
from 1 (ppm, right axis) per calibration against time, each with its 1-sigma bar, and the flagged
changes marked. matplotlib with the Agg backend: no display needed."""
from __future__ import annotations

import io
import math
import os

import numpy as np

from ..core.errors import CalibrationError
from ..core.units import AXES, MG
from .history import DriftFlag, HistoryRecord, sensor_series
from .output_paths import write_bytes_atomically

COLOURS = ("tab:red", "tab:green", "tab:blue")


def _known(values: tuple[float, float, float] | None) -> tuple[float, float, float]:
    assert values is not None, "sensor_series keeps only calibrated rows, which have a bias and a matrix"
    return values


def write_history_figure(records: list[HistoryRecord], flags: list[DriftFlag], path: str | os.PathLike[str]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    series = sensor_series(records)
    if not series:
        raise CalibrationError("no calibrated recordings in the history to draw")
    panels = len(series)
    figure, axes = plt.subplots(panels, 1, figsize=(12, 3.2 * panels + 0.8), squeeze=False)
    figure.suptitle(f"calibration history: {panels} sensor{'s' if panels != 1 else ''}, "
                    f"{sum(len(r) for r in series.values())} calibrations, {len(flags)} changes flagged")
    for panel, ((vehicle, sensor), rows) in zip(axes[:, 0], series.items()):
        # Time axis: the recording's start; rows without one are placed by their order.
        when = [np.datetime64(r.start_ns, "ns") if r.start_ns is not None else np.datetime64("NaT") for r in rows]
        x = np.array(when) if all(not np.isnat(w) for w in when) else np.arange(len(rows))
        scale_axis = panel.twinx()
        for k, axis in enumerate(AXES):
            bias = np.array([_known(r.bias)[k] for r in rows]) / MG
            bias_sigma = np.array([r.bias_sigma[k] if r.bias_sigma else math.nan for r in rows]) / MG
            panel.errorbar(x, bias, yerr=bias_sigma, fmt="o-", color=COLOURS[k], capsize=3, label=f"b_{axis}")
            scale = (np.array([_known(r.scale)[k] for r in rows]) - 1.0) * 1e6
            scale_sigma = np.array([r.scale_sigma[k] if r.scale_sigma else math.nan for r in rows]) * 1e6
            scale_axis.errorbar(x, scale, yerr=scale_sigma, fmt="s--", color=COLOURS[k], alpha=0.45, capsize=2,
                                markersize=4, label=f"M_{axis}{axis} - 1")
        for flag in flags:
            if (flag.vehicle, flag.sensor) != (vehicle, sensor):
                continue
            after = next(i for i, r in enumerate(rows) if r.recording_id == flag.after.recording_id)
            panel.axvline(x[after], color="k", linestyle=":", linewidth=1)
            panel.annotate(f"{flag.quantity} {flag.axis} "
                           + (f"{flag.change / MG:+.1f} mg" if flag.quantity == "bias" else f"{flag.change:+.2%}"),
                           (x[after], 0.95), xycoords=("data", "axes fraction"), rotation=90, va="top",
                           ha="right", fontsize=8)
        panel.set_title(f"vehicle {vehicle} {sensor}")
        panel.set_ylabel("bias, mg (o, ±1 sigma)")
        scale_axis.set_ylabel("scale - 1, ppm (s, dashed)")
        panel.legend(loc="upper left", fontsize=8, ncol=3)
        panel.grid(True, alpha=0.3)
    figure.autofmt_xdate()
    figure.tight_layout()
    rendered = io.BytesIO()
    try:
        figure.savefig(rendered, format="png", dpi=90)
    finally:
        plt.close(figure)
    write_bytes_atomically(path, rendered.getvalue())  # whole or not at all, like every output
