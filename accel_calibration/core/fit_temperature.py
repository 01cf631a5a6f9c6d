"""The temperature solvers of fit(): the polynomial drift fitted jointly with M and b on the sphere,
and the seed paper's segmented model (per segment the drift against a room-temperature calibration)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .calibration import Calibration
from .coverage import (
    CONDITION_LIMIT,
    scaled_condition_number,
)
from .fit_result import FitResult, Sigma
from .fit_solvers import (
    broken_reason,
    no_degree_of_freedom,
    not_finite,
    numerical_failure,
    quality_of,
    standard_deviations,
)
from .gauss_newton import gauss_newton
from .models import SphereModel, parameter_count
from .temperature_models import (
    TemperatureModel,
    TemperatureOptions,
    ThermalSphereModel,
    blend_weights,
    describe_needs,
    known_blended_drift,
    known_segment_drift,
    room_temperature_poses,
    segment_bounds,
    segment_keys,
    segment_needs,
    sphere_blended_drift,
    sphere_segment_drift,
    temperature_span_problem,
)
from .units import MG


def _fit_segmented(accel: np.ndarray, temps: np.ndarray, ref: np.ndarray | None, name: str, gravity: float,
                   options: TemperatureOptions, initial: Calibration | None, frame_id: str, *,
                   base_fit: Callable[..., FitResult], pose_sigma: np.ndarray | None = None) -> FitResult:
    """The seed paper's segmented model: the room-temperature calibration from the poses near T_ref (else
    near the temperature most poses share), then per segment the drift (l, m, n) of each axis against it:
    observed directly with known orientations (a linear fit per axis), on the sphere without."""
    n = len(accel)
    room_fit = _room_fit(accel, temps, ref, name, gravity, options, initial, frame_id, base_fit, pose_sigma)
    if isinstance(room_fit, FitResult):
        return room_fit
    base, in_base, reference_degc = room_fit
    assert base.calibration is not None
    room = base.calibration
    corrected = room.apply(accel)
    true = None if ref is None else gravity * ref
    segments = _segment_drifts(accel, temps, ref, corrected, in_base, reference_degc, gravity, options)
    if segments.refused and options.every_segment:
        return FitResult(False, "; ".join(segments.refused), name, poses=n, missing_directions=base.missing_directions)
    learned = segments.learned
    coefficients = segments.coefficients
    if options.segment_blend and len(segments.bounds) > 1:
        blended = _blended_drifts(accel, temps, true, corrected, segments, gravity, name)
        if isinstance(blended, FitResult):
            return blended
        coefficients = blended
    if not_finite(segment_coefficients=np.array(coefficients)):
        return numerical_failure(accel, temps, "segment drift coefficients not finite", model=name)
    temperature = TemperatureModel(
        "segmented", reference_degc, (float(temps[learned].min()), float(temps[learned].max())),
        segment_bounds_degc=np.array(segments.bounds), segment_temperatures_degc=np.array(segments.anchors),
        segment_coefficients=np.array(coefficients),
        segment_poses=tuple(segments.learned_poses), segment_blend=options.segment_blend)
    calibration = room.replace(temperature=temperature, reference_temperature_degc=temperature.reference_degc)
    # Judged on the poses the model describes; those of a segment not learned yet are reported, not fitted.
    fitted = calibration.apply(accel[learned], temps[learned])
    if true is not None:
        residuals_mg = np.linalg.norm(fitted - true[learned], axis=1) / MG
    else:
        residuals_mg = (np.linalg.norm(fitted, axis=1) - gravity) / MG
    if not_finite(residuals=residuals_mg):
        return numerical_failure(accel, temps, "residuals not finite", model=name)
    calibration = calibration.replace(quality=quality_of(residuals_mg, base.condition_number))
    count = len(segments.bounds)
    message = (f"segmented temperature model: {count} segment{'s' if count > 1 else ''} learned "
               f"({', '.join(temperature.segment_names())}; room temperature {reference_degc:.1f} degC)")
    if segments.refused:
        message += "; not yet: " + "; ".join(segments.refused)
    return FitResult(True, message, name, iterations=base.iterations, calibration=calibration, sigma=base.sigma,
                     residuals_mg=residuals_mg, cost=0.5 * float(np.sum((residuals_mg * MG) ** 2)),
                     condition_number=base.condition_number, missing_directions=base.missing_directions, poses=n)


def _room_fit(accel: np.ndarray, temps: np.ndarray, ref: np.ndarray | None, name: str, gravity: float,
              options: TemperatureOptions, initial: Calibration | None, frame_id: str,
              base_fit: Callable[..., FitResult], pose_sigma: np.ndarray | None
              ) -> tuple[FitResult, np.ndarray, float] | FitResult:
    """(the room-temperature fit, which poses it took, their mean temperature), or why there is none."""
    n = len(accel)
    width = options.segment_width_degc
    low_degc, high_degc = float(temps.min()), float(temps.max())
    # Each segment needs several poses: more segments than poses means a corrupt temperature, and
    # would have the segment loop lay out that many segments.
    spanned = segment_keys(np.array([high_degc]), width)[0] - segment_keys(np.array([low_degc]), width)[0] + 1
    if not spanned <= n:
        return FitResult(False, f"temperatures {low_degc:.4g}..{high_degc:.4g} degC span {spanned:.3g} segments of "
                         f"{width:g} degC, more than the {n} poses can fill: check the temperatures for a corrupt "
                         "value", name, poses=n)
    in_base = room_temperature_poses(temps, options)
    band = f"within {width / 4:g} degC of " + (f"{options.reference_degc:g} degC" if options.reference_degc is not None
                                                 else "the room temperature")
    if not in_base.any():
        return FitResult(False, f"no poses {band}: hold the room-temperature poses there, or give another "
                         "reference temperature", name, poses=n)
    reference_degc = float(temps[in_base].mean())
    base = base_fit(accel[in_base], model=name, gravity=gravity, reference=None if ref is None else ref[in_base],
                    initial=initial, frame_id=frame_id,
                    pose_sigma_mps2=None if pose_sigma is None else pose_sigma[in_base])
    if not base.success or base.calibration is None:  # a successful fit always carries its calibration
        return FitResult(False, f"room-temperature calibration from the {int(in_base.sum())} poses at "
                         f"{reference_degc:.1f} degC: {base.message}", name, poses=n,
                         missing_directions=base.missing_directions)
    return base, in_base, reference_degc


@dataclass
class _Segments:
    """The segments learned (their bounds, mean temperatures, drift coefficients and pose counts), the
    poses they hold, and why the others are not learned yet."""

    learned: np.ndarray  # (N,) bool
    bounds: list[tuple[float, float]] = field(default_factory=list)
    anchors: list[float] = field(default_factory=list)
    coefficients: list[np.ndarray] = field(default_factory=list)
    learned_poses: list[int] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)


def _segment_drifts(accel: np.ndarray, temps: np.ndarray, ref: np.ndarray | None, corrected: np.ndarray,
                    in_base: np.ndarray, reference_degc: float, gravity: float,
                    options: TemperatureOptions) -> _Segments:
    """Each occupied segment's drift against the room-temperature calibration (`corrected`: the poses
    through it), or why it cannot be determined yet."""
    width = options.segment_width_degc
    keys = segment_keys(temps, width)
    base_key = float(segment_keys(np.array([reference_degc]), width)[0])
    known = ref is not None
    if ref is not None:
        directions, true = ref, gravity * ref
    else:
        directions, true = corrected / np.linalg.norm(corrected, axis=1)[:, None], None
    segments = _Segments(learned=np.zeros(len(accel), dtype=bool))
    for key in np.unique(keys):
        inside = keys == key
        lo, hi = segment_bounds(float(key), width)
        here = f"segment {lo:g}..{hi:g} degC ({int(inside.sum())} poses at {float(temps[inside].mean()):.1f} degC)"
        needs = segment_needs(directions[inside], known, options.min_poses_per_segment)
        if key == base_key and (needs or (not known and in_base[inside].all())):
            # The room-temperature calibration stands for its own segment: no drift against itself (on the
            # sphere, poses spent on the calibration have none left to show; with known orientations the
            # quadratic is kept when determined).
            q = np.zeros((3, 3))
        elif needs:
            segments.refused.append(f"{here} cannot be determined: hold {describe_needs(needs)}")
            continue
        elif true is not None:
            q, _ = known_segment_drift(accel[inside], true[inside] - corrected[inside])
        else:
            solution = sphere_segment_drift(accel[inside], corrected[inside], gravity)
            if not solution.success or not_finite(drift=solution.x):
                segments.refused.append(f"{here}: its drift fit failed ({solution.message})")
                continue
            q = solution.x.reshape(3, 3)
        segments.bounds.append((lo, hi))
        segments.anchors.append(float(temps[inside].mean()))
        segments.coefficients.append(q)
        segments.learned_poses.append(int(inside.sum()))
        segments.learned |= inside
    return segments


def _blended_drifts(accel: np.ndarray, temps: np.ndarray, true: np.ndarray | None, corrected: np.ndarray,
                    segments: _Segments, gravity: float, name: str) -> list[np.ndarray] | FitResult:
    """Each segment alone is the paper's fit, and the least squares of the picked model. The blended one
    is fitted as applied: every pose at its own temperature, between its neighbouring segments (the same
    answer when each segment's poses share one temperature)."""
    learned, coefficients = segments.learned, segments.coefficients
    weights = blend_weights(temps[learned], np.array(segments.anchors))
    if true is not None:
        return list(known_blended_drift(accel[learned], (true - corrected)[learned], weights))
    free = np.array([not (q == 0).all() for q in coefficients])  # the room segment's drift stays zero
    solution = sphere_blended_drift(accel[learned], corrected[learned], gravity, weights,
                                    np.array(coefficients), free)
    if not solution.success or not_finite(drift=solution.x):
        return FitResult(False, f"the blended segment fit failed ({solution.message}); "
                         "fit with segment_blend off", name, poses=len(accel))
    joint = np.array(coefficients)
    joint[free] = solution.x.reshape(-1, 3, 3)
    return list(joint)


def fit_with_temperature(accel: np.ndarray, temps: np.ndarray, name: str, gravity: float,
                         options: TemperatureOptions, initial: Calibration | None, frame_id: str,
                         ref: np.ndarray | None = None, *, base_fit: Callable[..., FitResult],
                         pose_sigma: np.ndarray | None = None) -> FitResult:
    """A calibration with a temperature model (polynomial on the sphere, segmented on any model).
    `base_fit`: the room-temperature fit the drift is learned against -- fit() itself with the caller's
    outlier options, given by the caller, so its outlier test and uncertainty apply and this module does
    not import fit.py; `pose_sigma` (one per pose) weighs the poses in it as in any fit."""
    n = len(accel)
    size = {"reference12": 4, "reference15": 5}.get(name, parameter_count(name))
    if n < size:
        return FitResult(False, f"model {name} needs at least {size} poses, got {n}", name, poses=n)
    problem = temperature_span_problem(temps, options)
    if problem is not None:
        return FitResult(False, problem, name, poses=n)
    if options.model == "segmented":
        return _fit_segmented(accel, temps, ref, name, gravity, options, initial, frame_id, base_fit=base_fit,
                              pose_sigma=pose_sigma)
    reference_degc = options.reference_degc if options.reference_degc is not None else float(np.median(temps))
    span = (float(temps.min()), float(temps.max()))

    # Polynomial: bias and scale drift jointly with M and b, started from the temperature-blind fit.
    model = ThermalSphereModel(SphereModel(name), options.bias_order, options.scale_order, reference_degc)
    described = (f"model {name} with a polynomial temperature model (bias order {options.bias_order}, "
                 f"scale order {options.scale_order})")
    if n < model.size:
        return FitResult(False, f"{described} needs at least {model.size} poses, got {n}", name, poses=n)
    base = base_fit(accel, model=name, gravity=gravity, initial=initial, frame_id=frame_id, pose_sigma_mps2=pose_sigma)
    if not base.success or base.calibration is None:  # a successful fit always carries its calibration
        return FitResult(False, base.message, name, poses=n, missing_directions=base.missing_directions)
    solution = gauss_newton(lambda p: model.residual_and_jacobian(p, accel, temps, gravity),
                            model.pack(base.calibration.bias, base.calibration.matrix))
    condition = scaled_condition_number(solution.jacobian)
    residuals_mg = solution.residuals / MG
    common: dict[str, Any] = dict(model=name, iterations=solution.iterations, residuals_mg=residuals_mg,
                                  cost=solution.cost, condition_number=condition,
                                  missing_directions=base.missing_directions, poses=n)
    broken = not_finite(parameters=solution.x, residuals=solution.residuals, jacobian=solution.jacobian)
    if broken:
        return numerical_failure(accel, temps, broken_reason(broken, solution), **common)
    if condition > CONDITION_LIMIT * 100:  # temperature terms are smaller and more correlated by nature
        return FitResult(False, f"poses do not separate the temperature terms (condition number {condition:.3g}): "
                         "hold several orientations at each temperature", **common)
    if n <= model.size:
        return no_degree_of_freedom(n, f"{model.size} parameters of {described}", more="pose", **common)
    if not solution.success:
        return FitResult(False, solution.message, **common)
    bias, matrix, c, d = model.unpack(solution.x)
    if not np.linalg.det(matrix) > 0:
        return FitResult(False, "fit converged to a mirrored solution; check the poses", **common)
    stds = standard_deviations(solution, n)
    if not_finite(uncertainties=stds):
        return numerical_failure(accel, temps, "uncertainties not finite: the normal matrix is singular", **common)
    _, matrix_sigma = model.base.unpack(stds[: model.base.size])
    sigma = Sigma(bias=stds[:3], matrix=matrix_sigma)
    temperature = TemperatureModel("polynomial", reference_degc, span, bias_coefficients=c, scale_coefficients=d)
    _, scale = temperature.bias_and_scale(np.linspace(span[0], span[1], 101))
    if not np.all(scale > 0):
        return FitResult(False, "the fitted scale drift reaches zero within the calibrated temperature range "
                         f"{span[0]:.4g}..{span[1]:.4g} degC: check the temperatures, or fit with a lower scale order",
                         **common)
    calibration = Calibration(
        bias=bias, matrix=matrix, model=name, gravity=gravity, bias_sigma=sigma.bias, matrix_sigma=sigma.matrix,
        quality=quality_of(residuals_mg, condition), frame_id=frame_id, reference_temperature_degc=reference_degc,
        temperature=temperature,
    )
    return FitResult(True, solution.message, calibration=calibration, sigma=sigma, **common)
