"""Versioned YAML calibration files, written atomically.

Layout (keys other tools read are the first six; the rest is ours):

    accel_calibration:
      format_version: 1         # 2 when it holds a warm-up's spline temperature model
      model: sphere9
      gravity: 9.80665          # m/s^2
      bias: [bx, by, bz]        # m/s^2, a_true = M (a_raw - b)
      matrix: [[..], [..], [..]]
      quality: {residual_rms_mg: .., residual_max_mg: .., poses: .., condition_number: ..}
      uncertainty: {bias: [..], matrix: [[..]..]}   # 1 sigma
      quadratic: [qx, qy, qz]   # reference15 only, s^2/m
      gyro_bias_radps: [..]     # mean gyro output at rest (rad/s), when the poses had a gyro
      dividing_head: {scale, bias_mg, mounting_mrad, nonorthogonality_mrad, tilt_error_mrad, tilt_deg,
                      sigma: {..1 sigma of each..}, residual_sigma_mg}   # model dividing-head only
      gyro_matrix: [[..]..]     # w_true = gyro_matrix (w_raw - gyro_bias_radps), in the accelerometer's
                                # calibrated frame, when the motions between the poses were fitted
      gyro_quality: {matrix_sigma: [[..]..], residual_rms_mrad: .., residual_max_mrad: .., motions: ..}
      noise: {rate_hz: .., accel_density_mps2_per_sqrt_hz: .., gyro_density_radps_per_sqrt_hz: ..}
                                # white noise measured at the poses (Kalibr's *_noise_density)
      created: ISO 8601, frame_id, sensor_id, reference_temperature_degc
      accel_device_id, gyro_device_id: the devices fitted (an autopilot log's IDs), when the recording says them
      parameter_sources:        # fitted with a prior: where each parameter came from
        prior: old.yaml
        parameters: {b_x: {from: poses, share_from_poses: 0.998, sigma: .., prior_sigma: ..}, ..}
                                # + note: where the poses could not check it ("kept from the prior, not checked")
      fitted_to: what the fit saw, where a recording says (raw output, or a corrected stream as logged)
"""
from __future__ import annotations

import math
import os
import stat
import warnings
from pathlib import Path
from typing import Any, cast

import numpy as np
import yaml

from ..core.calibration import Calibration, GyroQuality, MeasuredNoise, Quality
from ..core.dividing_head import DividingHeadTerms
from ..core.errors import CalibrationError, DeprecatedInputWarning
from ..core.fit_result import ParameterSource
from ..core.temperature_models import TemperatureModel
from ..core.units import STANDARD_GRAVITY
from .output_paths import stale_temp_files, write_bytes_atomically


class CalibrationFileError(CalibrationError):
    """io: a calibration file that cannot be read, parsed, trusted or written (the message names the path)."""

FORMAT_VERSION = 2  # the newest this version reads
# What a file is written as: 1 unless it holds what a format-1 reader would misread (a warm-up's spline
# temperature model, which also corrects the gyro), so older installations keep reading the others.
SPLINE_FORMAT_VERSION = 2
ROOT_KEY = "accel_calibration"
MAX_CALIBRATION_BYTES = 1 << 20  # a calibration file is ~2 KB; a bigger one is something else
MAX_YAML_DEPTH = 32  # a calibration file nests 4 deep, a rosbag2 metadata.yaml 6
MAX_NUMBER = 1e12  # beyond any bias or gain, raw counts included: a corrupt or foreign file
MAX_POSES = 10**9
# The noise block's keys, each with its unit.
NOISE_KEYS = {"accel_density": "accel_density_mps2_per_sqrt_hz", "gyro_density": "gyro_density_radps_per_sqrt_hz"}


def _first_absurd_number(value: object, where: str = "") -> str | None:
    """What is wrong with the first number too large for any calibration ("bias holds 1e+200, ..."),
    walking lists and mappings; also catches integers too large to become floats at all."""
    if isinstance(value, bool):
        return None
    if isinstance(value, (int, float)):
        if not abs(value) > MAX_NUMBER:  # NaN passes here: the finiteness checks name it
            return None
        if isinstance(value, float):
            text = f"{value:.3g}"
        elif value.bit_length() < 1000:
            text = f"{float(value):.3g}"
        else:
            text = f"an integer of about {int(value.bit_length() * 0.30103)} digits"
        return f"{where or 'a value'} holds {text}, beyond any calibration's range (|x| <= {MAX_NUMBER:g})"
    if isinstance(value, dict):
        for key, item in value.items():
            found = _first_absurd_number(item, f"{where}.{key}" if where else str(key))
            if found:
                return found
    elif isinstance(value, list):
        for item in value:
            found = _first_absurd_number(item, where)
            if found:
                return found
    return None


def calibration_to_dict(calibration: Calibration) -> dict[str, Any]:
    c = calibration
    body = {
        "format_version": SPLINE_FORMAT_VERSION if c.temperature is not None and c.temperature.kind == "spline" else 1,
        "model": c.model,
        "gravity": c.gravity,
        **({"gravity_source": c.gravity_source} if c.gravity_source else {}),
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
    if c.gyro_matrix is not None:
        body["gyro_matrix"] = c.gyro_matrix.tolist()
    if c.gyro_quality is not None:
        g = c.gyro_quality
        body["gyro_quality"] = {"matrix_sigma": g.matrix_sigma.tolist(), "residual_rms_mrad": g.residual_rms_mrad,
                                "residual_max_mrad": g.residual_max_mrad, "motions": g.motions}
        if g.bias_sigma_radps is not None:
            body["gyro_quality"]["bias_sigma_radps"] = g.bias_sigma_radps.tolist()
    if c.noise is not None:
        body["noise"] = {"rate_hz": c.noise.rate_hz, NOISE_KEYS["accel_density"]: c.noise.accel_density}
        if c.noise.gyro_density is not None:
            body["noise"][NOISE_KEYS["gyro_density"]] = c.noise.gyro_density
    if c.temperature is not None:
        t = c.temperature
        block = {"model": t.kind, "reference_degc": t.reference_degc, "range_degc": list(t.range_degc)}
        if t.kind == "polynomial":
            block["bias_coefficients"] = t.bias_coefficients.tolist()  # row k: m/s^2 per degC^(k+1)
            block["scale_coefficients"] = t.scale_coefficients.tolist()  # row k: 1 per degC^(k+1)
        elif t.kind == "spline":
            block.update(_spline_block(t))
        else:
            block["segment_bounds_degc"] = t.segment_bounds_degc.tolist()  # per segment: low, high
            block["segment_temperatures_degc"] = t.segment_temperatures_degc.tolist()  # each learned at
            block["segment_coefficients"] = t.segment_coefficients.tolist()  # per segment: l, m, n rows
            block["segment_poses"] = [int(p) for p in t.segment_poses]
            block["segment_blend"] = bool(t.segment_blend)
            block["units"] = dict(SEGMENT_UNITS)
        body["temperature"] = block
    if c.dividing_head is not None:
        body["dividing_head"] = _dividing_head_block(c.dividing_head)
    if c.reference_temperature_degc is not None:
        body["reference_temperature_degc"] = float(c.reference_temperature_degc)
    body["units"] = {"bias": "m/s^2", "matrix": "1", "gravity": "m/s^2", "quadratic": "s^2/m"}
    body["created"] = c.created
    body["frame_id"] = c.frame_id
    body["sensor_id"] = c.sensor_id
    for name in ("accel_device_id", "gyro_device_id"):  # null: none known (files without the keys are older)
        body[name] = None if getattr(c, name) is None else int(getattr(c, name))
    if c.fitted_to:
        body["fitted_to"] = c.fitted_to
    return {ROOT_KEY: body}


def _dividing_head_block(terms: DividingHeadTerms) -> dict[str, Any]:
    block: dict[str, Any] = {name: list(getattr(terms, name)) for name in (*DividingHeadTerms.VALUES, "tilt_deg")}
    block["sigma"] = {name: list(values) for name, values in terms.sigma.items()}
    block["residual_sigma_mg"] = terms.residual_sigma_mg
    return block


def _dividing_head_terms(block: object) -> DividingHeadTerms:
    """The `dividing_head:` block read back (DividingHeadTerms checks lengths, finiteness and signs)."""
    if not isinstance(block, dict):
        raise CalibrationFileError("dividing_head must be a mapping")
    names = (*DividingHeadTerms.VALUES, "tilt_deg", "sigma", "residual_sigma_mg")
    missing = [name for name in names if name not in block]
    if missing:
        raise CalibrationFileError(f"dividing_head is missing {', '.join(missing)}")
    sigma = block["sigma"]
    if not isinstance(sigma, dict):
        raise CalibrationFileError("dividing_head.sigma must be a mapping")
    lists = [(f"dividing_head.{name}", block[name]) for name in (*DividingHeadTerms.VALUES, "tilt_deg")]
    for name, values in lists + [(f"dividing_head.sigma.{key}", value) for key, value in sigma.items()]:
        for item in _list(values, name):  # numbers only: numpy would read text '1e5' or true as one
            if isinstance(item, bool) or not isinstance(item, (int, float)):
                raise CalibrationFileError(f"{name} must be a list of numbers, got {item!r:.40}")
    return DividingHeadTerms(**{name: block[name] for name in (*DividingHeadTerms.VALUES, "tilt_deg")},
                             sigma=dict(sigma), residual_sigma_mg=_number(block["residual_sigma_mg"],
                                                                            "dividing_head.residual_sigma_mg"))


# The segmented block (the seed paper's model): sigma_i = l_i a_i^2 + m_i a_i + n_i per segment and axis, a_i the raw
# output in m/s^2, added after M (a_raw - b). Written with every file, checked on reading.
SEGMENT_UNITS = {
    "segment_bounds_degc": "degC", "segment_temperatures_degc": "degC",
    "segment_coefficients": "per segment rows l (s^2/m), m (1), n (m/s^2); columns x, y, z; "
                            "sigma = l a_raw^2 + m a_raw + n added to M (a_raw - b)",
}
OLD_SEGMENTED = ("holds the earlier segmented temperature model (segment_edges_degc: a per-segment "
                 "quadratic in temperature), whose format changed to the seed paper's model (segment_bounds_degc: a "
                 "per-axis quadratic in the measured acceleration per segment) and is no longer read: refit it with "
                 "accel-calib fit --temperature-model segmented")


# The spline block (a warm-up's bias curves): a natural cubic spline through the values at the knots, zero at
# reference_degc, flat outside range_degc (its first and last knot); the gyro's on its own knots.
SPLINE_UNITS = {
    "knots_degc": "degC", "bias_mps2": "m/s^2 per knot, columns x, y, z; a_true = M (a_raw - b - drift(T))",
    "gyro_knots_degc": "degC", "gyro_bias_radps": "rad/s per knot, columns x, y, z; "
                                                  "w_true = gyro_matrix (w_raw - gyro_bias_radps - drift(T))",
}
SPLINE_KEYS = ("knots_degc", "bias_mps2", "gyro_knots_degc", "gyro_bias_radps")


def _spline_block(t: TemperatureModel) -> dict[str, Any]:
    block: dict[str, Any] = {"knots_degc": t.spline_knots_degc.tolist(), "bias_mps2": t.spline_bias.tolist()}
    if t.has_gyro:
        block["gyro_knots_degc"] = t.spline_gyro_knots_degc.tolist()
        block["gyro_bias_radps"] = t.spline_gyro_bias.tolist()
    block["units"] = dict(SPLINE_UNITS)
    return block


def _check_spline_block(block: dict[str, Any], version: object) -> None:
    """A spline block needs format 2 (a format-1 file never held one) and this reader's units."""
    if block.get("model") != "spline":
        return
    if isinstance(version, int) and version < SPLINE_FORMAT_VERSION:
        raise CalibrationFileError(f"temperature model spline needs format_version {SPLINE_FORMAT_VERSION}, "
                                   f"the file says {version}: a damaged or hand-edited file; refit the warm-up")
    units = block.get("units")
    if units is not None and units != SPLINE_UNITS:
        raise CalibrationFileError(f"temperature.units must be {SPLINE_UNITS} for the spline model, got {units!r:.120}")


def _check_segment_block(block: dict[str, Any]) -> None:
    """Refuse the segmented block of the earlier format, and units other than this reader's."""
    if block.get("model") != "segmented":
        return
    if "segment_edges_degc" in block and "segment_bounds_degc" not in block:
        raise CalibrationFileError(f"temperature block {OLD_SEGMENTED}")
    units = block.get("units")
    if units is not None and units != SEGMENT_UNITS:
        raise CalibrationFileError(f"temperature.units must be {SEGMENT_UNITS} for the segmented model, "
                                   f"got {units!r:.120}")


def calibration_to_yaml(calibration: Calibration, parameter_sources: tuple[ParameterSource, ...] = (),
                        prior: str | None = None) -> str:
    """parameter_sources (a fit with a prior, named by `prior`): written as the parameter_sources block,
    which says per parameter whether the poses or the prior set it (read by people; loading ignores it)."""
    document = calibration_to_dict(calibration)
    if parameter_sources:
        document[ROOT_KEY]["parameter_sources"] = parameter_sources_block(parameter_sources, prior)
    return str(yaml.safe_dump(document, sort_keys=False, default_flow_style=None))


def parameter_sources_block(parameter_sources: tuple[ParameterSource, ...], prior: str | None) -> dict[str, Any]:
    """Per parameter: from poses, prior or both, the share of its information from the poses
    (1 - (sigma / prior_sigma)^2), both sigma (raw units; M unitless) and, where the poses could not check
    it, a note: "kept from the prior, not checked", or the parameters it is not separable from."""
    parameters = {source.name: {"from": source.source, "share_from_poses": round(source.share_from_poses, 4),
                                "sigma": source.sigma, "prior_sigma": source.prior_sigma,
                                **({"note": source.note} if source.note else {})}
                  for source in parameter_sources}
    return {"prior": prior or "", "parameters": parameters}


def _number(value: object, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise CalibrationFileError(f"{name} must be a finite number, got {value!r:.60}")
    return float(value)


def _list(value: object, name: str) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise CalibrationFileError(f"{name} must be a list, got {value!r:.40}")
    return value


def _require_numbers(value: object, name: str, source: str) -> None:
    """Leaves of a numeric field are numbers: numpy would turn text such as '1e200' or 'inf' (YAML 1.1
    reads 1e200 without a dot as text) or true into a float, and the file would say what it does not."""
    if value is None:
        return
    stack = [value]
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            stack.extend(item)
        elif isinstance(item, bool) or not isinstance(item, (int, float)):
            hint = " (YAML reads 1e5 as text: write 1.0e+5)" if isinstance(item, str) else ""
            raise CalibrationFileError(f"{source}: {name} must be numbers, got {item!r:.40}{hint}")


def _require_no_negative_sigma(uncertainty: dict[str, Any]) -> None:
    """A 1-sigma is >= 0: a negative one would pass as a tight uncertainty (squared, it weighs as its size)."""
    for key in ("bias", "matrix"):
        values = uncertainty.get(key)
        if values is None:
            continue
        try:
            smallest = float(np.min(np.asarray(values, dtype=float)))
        except (TypeError, ValueError):
            continue  # the shape and numbers are Calibration's to refuse, with their own line
        if smallest < 0:
            raise CalibrationFileError(f"uncertainty.{key} has a negative value ({smallest:g}): a 1-sigma is >= 0")


def calibration_from_dict(document: object, source: str = "calibration") -> Calibration:
    """Validate a parsed document and build the Calibration; every problem is a CalibrationError."""
    body = _body(document, source)
    _require_block_numbers(body, source)
    try:
        quality = None if body.get("quality") is None else _quality(body["quality"])
        uncertainty = body.get("uncertainty") or {}
        if not isinstance(uncertainty, dict):
            raise CalibrationFileError("uncertainty must be a mapping")
        _require_no_negative_sigma(uncertainty)
        ref_t = body.get("reference_temperature_degc")
        model = body["model"]
        if not isinstance(model, str):
            raise CalibrationFileError(f"model must be a name, got {model!r:.40}")
        if isinstance(body.get("temperature"), dict):
            _check_spline_block(body["temperature"], body.get("format_version", 1))
        temperature = None if body.get("temperature") is None else _temperature(body["temperature"])
        dividing_head = None if body.get("dividing_head") is None else _dividing_head_terms(body["dividing_head"])
        return Calibration(
            dividing_head=dividing_head,
            gyro_matrix=body.get("gyro_matrix"),
            gyro_quality=_gyro_quality(body.get("gyro_quality")),
            noise=_noise(body.get("noise")),
            temperature=temperature,
            bias=body["bias"],
            matrix=body["matrix"],
            model=model,
            gravity=_number(body.get("gravity", STANDARD_GRAVITY), "gravity"),
            quadratic=body.get("quadratic"),
            bias_sigma=uncertainty.get("bias"),
            matrix_sigma=uncertainty.get("matrix"),
            quality=quality,
            created=str(body.get("created", "")),
            frame_id=str(body.get("frame_id", "") or ""),
            sensor_id=str(body.get("sensor_id", "") or ""),
            # Checked by Calibration; a file without the key is older: its sensor_id may name the device.
            accel_device_id=body["accel_device_id"] if "accel_device_id" in body else _older_device(body, source),
            gyro_device_id=body.get("gyro_device_id"),
            gravity_source=str(body.get("gravity_source", "") or ""),  # absent from older files
            fitted_to=str(body.get("fitted_to", "") or "")[:1024],
            reference_temperature_degc=None if ref_t is None else _number(ref_t, "reference_temperature_degc"),
            gyro_bias_radps=body.get("gyro_bias_radps"),
        )
    except CalibrationError as error:
        raise CalibrationFileError(f"{source}: {error}") from None


def _older_device(body: dict[str, Any], source: str) -> int | None:
    """The device a file written before accel_device_id names in its sensor_id, as the log readers wrote it
    then ('px4 device ID', 'ardupilot accel ID', the ID alone), said in a line (DeprecatedInputWarning);
    None when it names none. Files written since say their device, or none, in accel_device_id."""
    sensor_id = str(body.get("sensor_id", "") or "").strip()
    digits = next((sensor_id[len(p):] for p in ("px4 device ", "ardupilot accel ") if sensor_id.startswith(p)),
                  sensor_id)
    if not (digits.isascii() and digits.isdigit() and len(digits) <= 10 and 0 < int(digits) < 2**32):
        return None
    warnings.warn(f"{source}: names its device in sensor_id only ({sensor_id!r}, as files written before "
                  f"accel_device_id): read as accel_device_id {int(digits)}; save it again (or add "
                  f"'accel_device_id: {int(digits)}') to name it so", DeprecatedInputWarning, stacklevel=2)
    return int(digits)


def _body(document: object, source: str) -> dict[str, Any]:
    """The document's calibration mapping, once its root, its format version and its required keys are
    found, and no number in it is absurd."""
    if not isinstance(document, dict) or ROOT_KEY not in document:
        raise CalibrationFileError(f"{source}: not an accel_calibration file (no top-level '{ROOT_KEY}:' key)")
    body = document[ROOT_KEY]
    if not isinstance(body, dict):
        raise CalibrationFileError(f"{source}: '{ROOT_KEY}' must be a mapping")
    version = body.get("format_version", 1)
    if isinstance(version, bool) or not isinstance(version, int):
        raise CalibrationFileError(f"{source}: format_version must be an integer, got {version!r:.40}")
    if version < 1:
        raise CalibrationFileError(f"{source}: format_version must be 1 or more, got {version}")
    if version > FORMAT_VERSION:
        raise CalibrationFileError(
            f"{source}: written by a newer accel_calibration (format {version}; this version reads up to "
            f"{FORMAT_VERSION}): upgrade to use it"
        )
    for key in ("model", "bias", "matrix"):
        if key not in body:
            raise CalibrationFileError(f"{source}: missing key '{key}'")
    absurd = _first_absurd_number(body)
    if absurd is not None:
        raise CalibrationFileError(f"{source}: {absurd}")
    return body


def _require_block_numbers(body: dict[str, Any], source: str) -> None:
    """Every array of the body and of its blocks holds numbers only (a block that is no mapping is
    refused later, by its own reader)."""
    blocks = {key: body.get(key) for key in ("uncertainty", "temperature", "gyro_quality", "noise")}
    uncertainty_block: dict[str, Any] = blocks["uncertainty"] if isinstance(blocks["uncertainty"], dict) else {}
    temperature_block: dict[str, Any] = blocks["temperature"] if isinstance(blocks["temperature"], dict) else {}
    gyro_quality_block: dict[str, Any] = (blocks["gyro_quality"] if isinstance(blocks["gyro_quality"], dict)
                                          else {})
    noise_block: dict[str, Any] = blocks["noise"] if isinstance(blocks["noise"], dict) else {}
    for name, value in [(key, body.get(key)) for key in ("bias", "matrix", "quadratic", "gyro_bias_radps",
                                                          "gyro_matrix")] + [
            (f"gyro_quality.{key}", gyro_quality_block.get(key)) for key in (
                "matrix_sigma", "bias_sigma_radps", "residual_rms_mrad", "residual_max_mrad")] + [
            (f"uncertainty.{key}", uncertainty_block.get(key)) for key in ("bias", "matrix")] + [
            (f"noise.{key}", noise_block.get(key)) for key in ("rate_hz", *NOISE_KEYS.values())] + [
            (f"temperature.{key}", temperature_block.get(key)) for key in (
                "range_degc", "bias_coefficients", "scale_coefficients", "segment_bounds_degc",
                "segment_temperatures_degc", "segment_coefficients", "segment_poses", *SPLINE_KEYS)]:
        _require_numbers(value, name, source)


def _quality(q: object) -> Quality:
    """The quality block."""
    if not isinstance(q, dict):
        raise CalibrationFileError("quality must be a mapping")
    poses = q.get("poses", 0)
    if isinstance(poses, bool) or not isinstance(poses, int) or not 0 <= poses <= MAX_POSES:
        raise CalibrationFileError(f"quality.poses must be an integer 0..{MAX_POSES}, got {poses!r:.40}")
    cond = q.get("condition_number")
    return Quality(
        residual_rms_mg=_number(q.get("residual_rms_mg", float("nan")), "quality.residual_rms_mg")
        if "residual_rms_mg" in q
        else float("nan"),
        residual_max_mg=_number(q.get("residual_max_mg"), "quality.residual_max_mg")
        if "residual_max_mg" in q
        else float("nan"),
        poses=poses,
        condition_number=None if cond is None else _number(cond, "quality.condition_number"),
    )


def _temperature(t: object) -> TemperatureModel:
    """The temperature block."""
    if not isinstance(t, dict) or "model" not in t:
        raise CalibrationFileError("temperature must be a mapping with a 'model' key")
    _check_segment_block(t)
    try:
        return TemperatureModel(
            kind=t["model"],
            reference_degc=_number(t.get("reference_degc"), "temperature.reference_degc"),
            # Any length: TemperatureModel rejects one that is not (low, high) with a ValueError.
            range_degc=cast(tuple[float, float],
                            tuple(_number(v, "temperature.range_degc") for v in t.get("range_degc", []))),
            bias_coefficients=t.get("bias_coefficients") or np.zeros((0, 3)),
            scale_coefficients=t.get("scale_coefficients") or np.zeros((0, 3)),
            segment_bounds_degc=t.get("segment_bounds_degc") or np.zeros((0, 2)),
            segment_temperatures_degc=t.get("segment_temperatures_degc") or np.zeros(0),
            segment_coefficients=t.get("segment_coefficients") or np.zeros((0, 3, 3)),
            segment_poses=tuple(_list(t.get("segment_poses"), "temperature.segment_poses")),
            segment_blend=t.get("segment_blend", True),
            spline_knots_degc=t.get("knots_degc") or np.zeros(0),
            spline_bias=t.get("bias_mps2") or np.zeros((0, 3)),
            spline_gyro_knots_degc=t.get("gyro_knots_degc") or np.zeros(0),
            spline_gyro_bias=t.get("gyro_bias_radps") or np.zeros((0, 3)),
        )
    except (TypeError, ValueError) as error:
        raise CalibrationFileError(f"temperature block: {error}") from None


def _gyro_quality(block: object) -> GyroQuality | None:
    """The gyro_quality block (its numbers already checked to be numbers), or None when absent."""
    if block is None:
        return None
    if not isinstance(block, dict):
        raise CalibrationFileError(f"gyro_quality must be a mapping, got {block!r:.40}")
    missing = [key for key in ("matrix_sigma", "residual_rms_mrad", "residual_max_mrad", "motions") if key not in block]
    if missing:
        raise CalibrationFileError(f"gyro_quality is missing {', '.join(missing)}")
    motions = block["motions"]
    if isinstance(motions, bool) or not isinstance(motions, int) or not 0 <= motions <= MAX_POSES:
        raise CalibrationFileError(f"gyro_quality.motions must be an integer 0..{MAX_POSES}, got {motions!r:.40}")
    return GyroQuality(matrix_sigma=block["matrix_sigma"],
                       residual_rms_mrad=_number(block["residual_rms_mrad"], "gyro_quality.residual_rms_mrad"),
                       residual_max_mrad=_number(block["residual_max_mrad"], "gyro_quality.residual_max_mrad"),
                       motions=motions, bias_sigma_radps=block.get("bias_sigma_radps"))


def _noise(block: object) -> MeasuredNoise | None:
    """The noise block (its numbers already checked to be numbers), or None when absent."""
    if block is None:
        return None
    if not isinstance(block, dict):
        raise CalibrationFileError(f"noise must be a mapping, got {block!r:.40}")
    missing = [key for key in ("rate_hz", NOISE_KEYS["accel_density"]) if key not in block]
    if missing:
        raise CalibrationFileError(f"noise is missing {', '.join(missing)}")
    gyro = block.get(NOISE_KEYS["gyro_density"])
    return MeasuredNoise(rate_hz=block["rate_hz"], accel_density=block[NOISE_KEYS["accel_density"]],
                         gyro_density=gyro)


class _SafeLoader(yaml.SafeLoader):  # type: ignore[misc]  # yaml is untyped here (types-PyYAML not installed)
    """SafeLoader that refuses aliases (an alias bomb expands in whatever walks the result, not in the
    parser) and nesting beyond MAX_YAML_DEPTH (the composer recurses: deep input would exhaust the
    stack). Both are refused as soon as the parser reaches them, before the document is built."""

    depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, "aliases (*name) are not accepted here",
                                              event.start_mark)
        self.depth += 1
        try:
            if self.depth > MAX_YAML_DEPTH:
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_YAML_DEPTH} levels",
                                                  self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


def safe_yaml_load(text: str, source: str, error: type[Exception] | None = None) -> Any:
    """Parse untrusted YAML: no aliases, bounded depth, safe types only. Every failure is one
    `error` (CalibrationFileError by default) naming `source`."""
    error = error or CalibrationFileError
    loader = None
    try:
        loader = _SafeLoader(text)  # reads (and may refuse) the first characters already
        return loader.get_single_data()
    except yaml.YAMLError as problem:
        first = str(problem).splitlines()[0] if str(problem) else type(problem).__name__
        context = getattr(problem, "problem", None)
        mark = getattr(problem, "problem_mark", None)
        if context and mark is not None:
            first = f"{context} (line {mark.line + 1})"
        raise error(f"{source}: not valid YAML ({first})") from None
    except (ValueError, TypeError, OverflowError, RecursionError, MemoryError) as problem:
        # The safe constructors raise these for values the grammar accepts, e.g. a date 2024-13-45.
        raise error(f"{source}: not valid YAML ({type(problem).__name__}: {str(problem)[:80]})") from None
    finally:
        if loader is not None:
            loader.dispose()


def calibration_from_yaml(text: str, source: str = "calibration") -> Calibration:
    document = safe_yaml_load(text, source)
    return calibration_from_dict(document, source)


def read_regular_file(path: str | os.PathLike[str], max_bytes: int, what: str,
                      error: type[Exception] | None = None) -> bytes:
    """The bytes of a regular file of at most `max_bytes`, or one `error` naming the path. A FIFO, device,
    socket or directory is refused from its stat, before it is opened (opening a FIFO blocks until a
    writer comes); the open itself is non-blocking and the type checked again on the open file."""
    error = error or CalibrationFileError
    path = Path(path)
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except OSError as problem:
        raise error(f"{path}: cannot read the {what} ({problem.strerror or problem})") from None
    _require_regular(info, path, what, max_bytes, error)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as problem:
        raise error(f"{path}: cannot read the {what} ({problem.strerror or problem})") from None
    try:
        _require_regular(os.fstat(fd), path, what, max_bytes, error)  # replaced between stat and open
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(fd, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    except OSError as problem:
        raise error(f"{path}: cannot read the {what} ({problem.strerror or problem})") from None
    finally:
        os.close(fd)
    if size > max_bytes:
        raise error(f"{path}: larger than {max_bytes // 1024} KiB, too large for a {what}")
    return b"".join(chunks)


def _require_regular(info: os.stat_result, path: Path, what: str, max_bytes: int, error: type[Exception]) -> None:
    mode = info.st_mode
    if stat.S_ISDIR(mode):
        raise error(f"{path}: is a directory, expected a {what}")
    if not stat.S_ISREG(mode):
        kind = ("a FIFO (named pipe)" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
                else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
        raise error(f"{path}: is {kind}, expected a {what} (a regular file)")
    if info.st_size > max_bytes:
        raise error(f"{path}: larger than {max_bytes // 1024} KiB, too large for a {what}")


def load_calibration(path: str | os.PathLike[str]) -> Calibration:
    raw = read_regular_file(path, MAX_CALIBRATION_BYTES, "calibration file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise CalibrationFileError(f"{path}: not a text file (binary content)") from None
    return calibration_from_yaml(text, str(path))


def write_text_atomically(path: str | os.PathLike[str], text: str) -> None:
    """Write next to the target and rename over it, so a reader (or a crash) never sees half a file
    and the old file stays whole when the write fails (see io/output_paths.py: symlinks are written
    through, the old file's mode kept). A temp file left by a killed process is removed by
    `remove_stale_temp_files`."""
    write_bytes_atomically(path, text.encode("utf-8"))


def remove_stale_temp_files(path: str | os.PathLike[str]) -> int:
    """Remove temp files a killed writer left beside `path` (ours only: `.<name>.*.tmp`); returns how many."""
    removed = 0
    for candidate in stale_temp_files(path):
        try:
            candidate.unlink()
            removed += 1
        except OSError:
            pass
    return removed


def checked_calibration_text(calibration: Calibration, path: str | os.PathLike[str],
                             parameter_sources: tuple[ParameterSource, ...] = (), prior: str | None = None) -> str:
    """The file text of `calibration`, checked the way load_calibration will check it (size, then the
    whole parse), so that no file is put in place that its reader (the node at its next start) refuses."""
    text = calibration_to_yaml(calibration, parameter_sources, prior)
    size = len(text.encode("utf-8"))
    if size > MAX_CALIBRATION_BYTES:
        raise CalibrationFileError(f"{path}: not written: the calibration would take {size // 1024} KiB, "
                                   f"beyond the {MAX_CALIBRATION_BYTES // 1024} KiB a calibration file may have")
    try:
        calibration_from_yaml(text, str(path))
    except CalibrationError as error:
        raise CalibrationFileError(f"not written: it would not load back ({error})") from None
    return text


def save_calibration(calibration: Calibration, path: str | os.PathLike[str],
                     parameter_sources: tuple[ParameterSource, ...] = (), prior: str | None = None) -> None:
    """Write `calibration` whole (temp file + rename), only once its text loads back (checked_calibration_text);
    with the parameter_sources of a fit with a prior (calibration_to_yaml)."""
    write_text_atomically(path, checked_calibration_text(calibration, path, parameter_sources, prior))
