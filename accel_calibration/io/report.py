"""A calibration report a person would rather look at than read: the pose directions on the sphere,
|a| - g per pose before and after (mg), the residuals, and the bias against temperature when the
calibration has a temperature model; with a gyro fit, a row of its per-motion residuals before (the bias
alone) and after (M_g). matplotlib with the Agg backend: no display needed."""
from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from ..core.calibration import Calibration
from ..core.correction import correct_rows
from ..core.errors import CalibrationError
from ..core.pose_map import holes
from ..core.units import AXES, MG

if TYPE_CHECKING:
    from ..core.gyro_fit import GyroFitResult


def write_report(calibration: Calibration, accel_mps2: npt.ArrayLike, temperature_degc: Sequence[float | None] | None,
                 path: str | os.PathLike[str], title: str = "", gyro: GyroFitResult | None = None) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    accel = np.asarray(accel_mps2, dtype=float).reshape(-1, 3)
    temps = None
    if temperature_degc is not None and all(t is not None for t in temperature_degc):
        temps = np.asarray(temperature_degc, dtype=float)
    g = calibration.gravity
    corrected = correct_rows(calibration, accel, temps)  # as the node corrects each pose's samples
    before = (np.linalg.norm(accel, axis=1) - g) / MG
    after = (np.linalg.norm(corrected, axis=1) - g) / MG
    directions = corrected / np.linalg.norm(corrected, axis=1)[:, None]

    motions = gyro is not None and len(gyro.residuals_mrad) > 0
    rows = 3 if motions else 2
    figure = plt.figure(figsize=(13, 4.5 * rows))
    figure.suptitle(f"accel_calibration report {title}\nmodel {calibration.model}, {len(accel)} poses, "
                    f"residual {np.sqrt(np.mean(after ** 2)):.2f} mg rms (raw {np.sqrt(np.mean(before ** 2)):.1f} mg)")

    _sphere_panel(figure.add_subplot(rows, 2, 1, projection="3d"), figure, directions,
                  temps if temps is not None else np.abs(after), temps is not None)
    _pose_panels(figure.add_subplot(rows, 2, 2), figure.add_subplot(rows, 2, 3), before, after)
    _parameter_panel(figure.add_subplot(rows, 2, 4), calibration)
    if motions and gyro is not None:
        _gyro_row(figure, gyro, rows)
    figure.tight_layout()
    path = Path(path)
    temporary = path.with_name(f".{path.name}.tmp.png")
    try:
        figure.savefig(temporary, dpi=90)
        temporary.replace(path)
    except OSError as error:
        temporary.unlink(missing_ok=True)
        raise CalibrationError(f"cannot write {path}: {error.strerror}") from None
    finally:
        plt.close(figure)


# The panels take matplotlib's Figure and Axes (untyped here).
def _sphere_panel(sphere: Any, figure: Any, directions: np.ndarray, colour: np.ndarray, by_temperature: bool) -> None:
    """The poses' directions on the unit sphere, coloured by temperature or residual, and the holes."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    sphere.plot_wireframe(np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v), color="0.85", linewidth=0.5)
    points = sphere.scatter(*directions.T, c=colour, cmap="coolwarm", s=30, depthshade=False)
    figure.colorbar(points, ax=sphere, shrink=0.6,
                    label="pose temperature, degC" if by_temperature else "|residual|, mg")
    empty = holes(directions)  # the same holes calibration/markers shows: orientations no pose came near
    if len(empty):
        sphere.scatter(*empty.T, color="0.55", marker="x", s=20, depthshade=False)
    sphere.set_title("pose directions (gravity in the sensor frame)" + ("; x: no pose near" if len(empty) else ""))
    sphere.set_xlabel("x")
    sphere.set_ylabel("y")
    sphere.set_zlabel("z")


def _pose_panels(bars: Any, residuals: Any, before: np.ndarray, after: np.ndarray) -> None:
    """The magnitude error of each pose, raw and calibrated, and the residuals after calibration."""
    index = np.arange(len(before))
    bars.bar(index - 0.2, before, width=0.4, label="raw", color="tab:red")
    bars.bar(index + 0.2, after, width=0.4, label="calibrated", color="tab:blue")
    bars.axhline(0, color="k", linewidth=0.5)
    bars.set_xlabel("pose")
    bars.set_ylabel("|a| - g, mg")
    bars.set_title("magnitude error per pose")
    bars.legend()

    residuals.plot(index, after, "o-", color="tab:blue")
    residuals.axhline(0, color="k", linewidth=0.5)
    residuals.set_xlabel("pose")
    residuals.set_ylabel("residual, mg")
    residuals.set_title(f"residuals after calibration (max {np.max(np.abs(after)):.2f} mg)")


def _parameter_panel(drift: Any, calibration: Calibration) -> None:
    """The bias against temperature with a temperature model, else the parameters as text."""
    if calibration.temperature is not None:
        lo, hi = calibration.temperature.range_degc
        grid = np.linspace(lo, hi, 200)
        bias_t, _ = calibration.temperature.bias_and_scale(grid)
        for axis in range(3):
            drift.plot(grid, (calibration.bias[axis] + bias_t[:, axis]) / MG, label=f"b_{AXES[axis]}(T)")
        drift.set_xlabel("temperature, degC")
        drift.set_ylabel("bias, mg")
        drift.set_title(f"bias against temperature ({calibration.temperature.kind} model)")
        drift.legend()
    else:
        drift.axis("off")
        text = ["b (mg): " + "  ".join(f"{v / MG:+.2f}" for v in calibration.bias), "M:"]
        text += ["  " + "  ".join(f"{v:+.6f}" for v in row) for row in calibration.matrix]
        if calibration.bias_sigma is not None:
            text.append("sigma b (mg): " + "  ".join(f"{v / MG:.3f}" for v in calibration.bias_sigma))
        drift.text(0.0, 0.9, "\n".join(text), family="monospace", va="top")
        drift.set_title("parameters (no temperature model)")


def _gyro_row(figure: Any, gyro: GyroFitResult, rows: int) -> None:  # a matplotlib Figure (untyped here)
    """Per motion used: by how much it misses the next pose with the gyro bias alone and with M_g."""
    from ..core.gyro_fit import refused_text

    panel = figure.add_subplot(rows, 1, rows)
    index = np.array(gyro.used) + 1
    panel.bar(index - 0.2, gyro.residuals_before_mrad, width=0.4, label="bias only", color="tab:red")
    panel.bar(index + 0.2, gyro.residuals_mrad, width=0.4, label="with M_g", color="tab:blue")
    panel.set_yscale("log")
    panel.set_xlabel("motion (pose k to k + 1)")
    panel.set_ylabel("miss of the next pose, mrad")
    refused = refused_text(gyro.refused)
    panel.set_title(f"gyro: {gyro.motions_used} motions, residual {gyro.residual_rms_mrad:.2f} mrad rms "
                    f"(bias only {gyro.residual_rms_before_mrad:.1f})" + (f"; not used: {refused}" if refused else ""))
    panel.legend()
