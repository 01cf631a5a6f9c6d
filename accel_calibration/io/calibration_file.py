"""Versioned YAML calibration files, written atomically.

Layout (keys other tools read are the first six; the rest is ours):

    accel_calibration:
      format_version: 1
      model: sphere9
      gravity: 9.80665          # m/s^2
      bias: [bx, by, bz]        # m/s^2, a_true = M (a_raw - b)
      matrix: [[..], [..], [..]]
      quality: {residual_rms_mg: .., residual_max_mg: .., poses: .., condition_number: ..}
      uncertainty: {bias: [..], matrix: [[..]..]}   # 1 sigma
      quadratic: [qx, qy, qz]   # reference15 only, s^2/m
      gyro_bias_radps: [..]     # mean gyro output at rest (rad/s), when the poses had a gyro
      created: ISO 8601, frame_id, sensor_id, reference_temperature_degc
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import cast

import numpy as np
import yaml

from ..core.calibration import Calibration, Quality
from ..core.errors import CalibrationError
from ..core.temperature_models import TemperatureModel


class CalibrationFileError(CalibrationError):
    """io: a calibration file that cannot be read, parsed, trusted or written (the message names the path)."""

FORMAT_VERSION = 1
ROOT_KEY = "accel_calibration"


def calibration_to_dict(calibration: Calibration) -> dict:
    c = calibration
    body = {
        "format_version": FORMAT_VERSION,
        "model": c.model,
        "gravity": c.gravity,
        "bias": c.bias.tolist(),
        "matrix": c.matrix.tolist(),
    }
    if c.quality is not None:
        body["quality"] = {
            "residual_rms_mg": float(c.quality.residual_rms_mg),
            "residual_max_mg": float(c.quality.residual_max_mg),
            "poses": int(c.quality.poses),
        }
        if c.quality.condition_number is not None:
            body["quality"]["condition_number"] = float(c.quality.condition_number)
    uncertainty = {}
    if c.bias_sigma is not None:
        uncertainty["bias"] = c.bias_sigma.tolist()
    if c.matrix_sigma is not None:
        uncertainty["matrix"] = c.matrix_sigma.tolist()
    if uncertainty:
        body["uncertainty"] = uncertainty
    if c.quadratic is not None:
        body["quadratic"] = c.quadratic.tolist()
    if c.gyro_bias_radps is not None:
        body["gyro_bias_radps"] = c.gyro_bias_radps.tolist()
    if c.temperature is not None:
        t = c.temperature
        block = {"model": t.kind, "reference_degc": t.reference_degc, "range_degc": list(t.range_degc)}
        if t.kind == "polynomial":
            block["bias_coefficients"] = t.bias_coefficients.tolist()  # row k: m/s^2 per degC^(k+1)
            block["scale_coefficients"] = t.scale_coefficients.tolist()  # row k: 1 per degC^(k+1)
        else:
            block["segment_edges_degc"] = t.segment_edges_degc.tolist()
            block["segment_coefficients"] = t.segment_coefficients.tolist()  # per segment: q0, q1, q2 rows
        body["temperature"] = block
    if c.reference_temperature_degc is not None:
        body["reference_temperature_degc"] = float(c.reference_temperature_degc)
    body["units"] = {"bias": "m/s^2", "matrix": "1", "gravity": "m/s^2", "quadratic": "s^2/m"}
    body["created"] = c.created
    body["frame_id"] = c.frame_id
    body["sensor_id"] = c.sensor_id
    return {ROOT_KEY: body}


def calibration_to_yaml(calibration: Calibration) -> str:
    return yaml.safe_dump(calibration_to_dict(calibration), sort_keys=False, default_flow_style=None)


def _number(value, name) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CalibrationFileError(f"{name} must be a finite number, got {value!r:.60}")
    return float(value)


def calibration_from_dict(document, source: str = "calibration") -> Calibration:
    """Validate a parsed document and build the Calibration; every problem is a CalibrationError."""
    if not isinstance(document, dict) or ROOT_KEY not in document:
        raise CalibrationFileError(f"{source}: not an accel_calibration file (no top-level '{ROOT_KEY}:' key)")
    body = document[ROOT_KEY]
    if not isinstance(body, dict):
        raise CalibrationFileError(f"{source}: '{ROOT_KEY}' must be a mapping")
    version = body.get("format_version", 1)
    if isinstance(version, bool) or not isinstance(version, int):
        raise CalibrationFileError(f"{source}: format_version must be an integer, got {version!r:.40}")
    if version > FORMAT_VERSION:
        raise CalibrationFileError(
            f"{source}: written by a newer accel_calibration (format {version}; this version reads up to "
            f"{FORMAT_VERSION}): upgrade to use it"
        )
    for key in ("model", "bias", "matrix"):
        if key not in body:
            raise CalibrationFileError(f"{source}: missing key '{key}'")
    try:
        quality = None
        if body.get("quality") is not None:
            q = body["quality"]
            if not isinstance(q, dict):
                raise CalibrationFileError("quality must be a mapping")
            poses = q.get("poses", 0)
            if isinstance(poses, bool) or not isinstance(poses, int) or poses < 0:
                raise CalibrationFileError(f"quality.poses must be a non-negative integer, got {poses!r:.40}")
            cond = q.get("condition_number")
            quality = Quality(
                residual_rms_mg=_number(q.get("residual_rms_mg", float("nan")), "quality.residual_rms_mg")
                if "residual_rms_mg" in q
                else float("nan"),
                residual_max_mg=_number(q.get("residual_max_mg"), "quality.residual_max_mg")
                if "residual_max_mg" in q
                else float("nan"),
                poses=poses,
                condition_number=None if cond is None else _number(cond, "quality.condition_number"),
            )
        uncertainty = body.get("uncertainty") or {}
        if not isinstance(uncertainty, dict):
            raise CalibrationFileError("uncertainty must be a mapping")
        ref_t = body.get("reference_temperature_degc")
        model = body["model"]
        if not isinstance(model, str):
            raise CalibrationFileError(f"model must be a name, got {model!r:.40}")
        temperature = None
        if body.get("temperature") is not None:
            t = body["temperature"]
            if not isinstance(t, dict) or "model" not in t:
                raise CalibrationFileError("temperature must be a mapping with a 'model' key")
            try:
                temperature = TemperatureModel(
                    kind=t["model"],
                    reference_degc=_number(t.get("reference_degc"), "temperature.reference_degc"),
                    # Any length: TemperatureModel rejects one that is not (low, high) with a ValueError.
                    range_degc=cast(tuple[float, float],
                                    tuple(_number(v, "temperature.range_degc") for v in t.get("range_degc", []))),
                    bias_coefficients=t.get("bias_coefficients") or np.zeros((0, 3)),
                    scale_coefficients=t.get("scale_coefficients") or np.zeros((0, 3)),
                    segment_edges_degc=t.get("segment_edges_degc") or np.zeros(0),
                    segment_coefficients=t.get("segment_coefficients") or np.zeros((0, 3, 3)),
                )
            except (TypeError, ValueError) as error:
                raise CalibrationFileError(f"temperature block: {error}") from None
        return Calibration(
            temperature=temperature,
            bias=body["bias"],
            matrix=body["matrix"],
            model=model,
            gravity=_number(body.get("gravity", 9.80665), "gravity"),
            quadratic=body.get("quadratic"),
            bias_sigma=uncertainty.get("bias"),
            matrix_sigma=uncertainty.get("matrix"),
            quality=quality,
            created=str(body.get("created", "")),
            frame_id=str(body.get("frame_id", "") or ""),
            sensor_id=str(body.get("sensor_id", "") or ""),
            reference_temperature_degc=None if ref_t is None else _number(ref_t, "reference_temperature_degc"),
            gyro_bias_radps=body.get("gyro_bias_radps"),
        )
    except CalibrationError as error:
        raise CalibrationFileError(f"{source}: {error}") from None


def calibration_from_yaml(text: str, source: str = "calibration") -> Calibration:
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as error:
        first = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise CalibrationFileError(f"{source}: not valid YAML ({first})") from None
    return calibration_from_dict(document, source)


def load_calibration(path) -> Calibration:
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise CalibrationFileError(f"calibration file {path} not found") from None
    except IsADirectoryError:
        raise CalibrationFileError(f"calibration file {path} is a directory") from None
    except OSError as error:
        raise CalibrationFileError(f"cannot read calibration file {path}: {error.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise CalibrationFileError(f"{path}: not a text file (binary content)") from None
    return calibration_from_yaml(text, str(path))


def _temp_prefix(path: Path) -> str:
    return f".{path.name}."


def write_text_atomically(path, text: str) -> None:
    """Write next to the target and rename over it, so a reader (or a crash) never sees half a file
    and the old file stays whole when the write fails. The temp file is removed on any failure,
    an interrupt included; one left by a killed process is removed by `remove_stale_temp_files`."""
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    tmp_name = None
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=_temp_prefix(path), suffix=".tmp", dir=directory)
        with os.fdopen(fd, "w", encoding="utf-8") as tmp:
            tmp.write(text)
            tmp.flush()
            os.fsync(tmp.fileno())
        os.replace(tmp_name, path)
        tmp_name = None
    except OSError as error:
        raise CalibrationFileError(f"cannot write {path}: {error.strerror or error}") from None
    finally:
        if tmp_name is not None:
            try:
                os.unlink(tmp_name)
            except OSError:
                pass


def remove_stale_temp_files(path) -> int:
    """Remove temp files a killed writer left beside `path` (ours only: `.<name>.*.tmp`); returns how many."""
    path = Path(path)
    removed = 0
    try:
        candidates = list(path.parent.glob(_temp_prefix(path) + "*.tmp"))
    except OSError:
        return 0
    for candidate in candidates:
        try:
            candidate.unlink()
            removed += 1
        except OSError:
            pass
    return removed


def save_calibration(calibration: Calibration, path) -> None:
    write_text_atomically(path, calibration_to_yaml(calibration))
