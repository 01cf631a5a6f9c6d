"""The words of the node's answers, without ROS: what /calibrate says when it applied a calibration."""
from __future__ import annotations

from .fit import FitResult

__all__ = ["calibrate_answer", "yaml_quoted"]


def calibrate_answer(result: FitResult, saved_message: str, gyro_refusal: str | None = None,
                     gyro_kept: bool = False) -> str:
    """/calibrate's answer when the calibration was applied: a YAML summary a person reads and a tool
    parses (poses, residual, bias and its sigma, M, the temperature model, outliers, the gyro's).
    `gyro_kept`: the fit's gyro part was not applied and the gyro calibration in force was kept."""
    c = result.calibration
    if c is None or c.quality is None or result.sigma is None:
        return f"saved: {saved_message}"
    lines = [
        f"model: {c.model}",
        f"poses: {result.poses}",
        f"residual_rms_mg: {c.quality.residual_rms_mg:.3f}",
        f"residual_max_mg: {c.quality.residual_max_mg:.3f}",
        "bias_mps2: [" + ", ".join(f"{v:.6f}" for v in c.bias) + "]",
        "bias_sigma_mps2: [" + ", ".join(f"{v:.2e}" for v in result.sigma.bias) + "]",
        "matrix: [" + ", ".join("[" + ", ".join(f"{v:.7f}" for v in row) + "]" for row in c.matrix) + "]",
        f"frame_id: '{c.frame_id}'",
    ]
    if c.temperature is not None:
        t = c.temperature
        lines.append(f"temperature_model: {{kind: {t.kind}, reference_degc: {t.reference_degc:.2f}, "
                     f"range_degc: [{t.range_degc[0]:.2f}, {t.range_degc[1]:.2f}]}}")
    if result.outliers:  # poses left out of the fit, numbered from 1 as the log numbers accepted poses
        lines.append("outliers: [" + ", ".join(
            f"{{pose: {o.index + 1}, residual_mg: {o.residual_mg:.1f}, orientation: '{o.orientation}'}}"
            for o in result.outliers) + "]")
    if c.gyro_matrix is not None and c.gyro_quality is not None:
        q = c.gyro_quality
        lines.append(f"gyro: {{applied: true, motions: {q.motions}, residual_rms_mrad: {q.residual_rms_mrad:.3f}, "
                     "matrix: [" + ", ".join("[" + ", ".join(f"{v:.7f}" for v in row) + "]" for row in c.gyro_matrix)
                     + "]}")
    elif gyro_kept:
        reason = gyro_refusal or "gyro: no gyro fit from these poses"
        lines.append(f"gyro: {{applied: false, kept: in force, reason: {yaml_quoted(reason)}}}")
    elif gyro_refusal is not None:
        lines.append(f"gyro: {{applied: false, reason: {yaml_quoted(gyro_refusal)}}}")
    if result.unchecked_line():  # a fit with a prior: what the poses could not check
        lines.append(f"prior: {yaml_quoted(result.unchecked_line())}")
    lines.append(f"saved: {saved_message}")
    return "\n".join(lines)


def yaml_quoted(text: str) -> str:
    """A YAML single-quoted scalar of one line (quotes doubled)."""
    return "'" + " ".join(text.splitlines()).replace("'", "''") + "'"
