"""Is a calibration fit to be put in force? What a calibration file must meet before the node, `apply` or
`report` use it: a well-formed file can still mirror the axes, contradict its model's name, or hold a
temperature block that drives the bias or the gain out of the gates somewhere in its calibrated range.
Each refusal is a value (core/refusal.Refusal): the bias or scale gate, or the plausibility gate for the rest."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from .calibration import Calibration
from .errors import CalibrationError
from .refusal import Gate, Refusal
from .units import AXES

# MEMS gyro zero-rate offsets are below ~0.35 rad/s (MPU-6050: +-20 deg/s); 1 rad/s leaves margin.
MAX_GYRO_BIAS_RADPS = 1.0
# A gyro matrix (rad/s in, rad/s out) whose axis gain is outside this is a gyro in other units or a bad fit:
# MEMS gyro scale errors are a few percent. The one band of the gyro's gain, `gyro.scale_min`..`gyro.scale_max`:
# the gyro gate's default (core/gyro_gates.GyroGates) and what a reader checks a file against.
GYRO_SCALE_BAND = (0.9, 1.1)
# The accelerometer's plausibility bounds (max_bias_mps2, scale_min..scale_max), the gates' defaults and what a
# reader checks a file against: MEMS zero-g offsets are below ~150 mg, gains within a few percent.
MAX_BIAS_MPS2 = 2.0
SCALE_BAND = (0.9, 1.1)
# Beyond any MEMS part's operating range (-40..125 degC); also keeps the polynomial in floating range.
PLAUSIBLE_TEMPERATURE_DEGC = (-100.0, 200.0)
# An entry this far from the structure's zero is a hand edit or another model, not rounding.
STRUCTURE_TOLERANCE = 1e-12
TEMPERATURE_BLOCK = "temperature block"  # the part of a calibration its temperature model is, as refusals say it
_TEMPERATURE_STEPS = 241  # grid over the calibrated range, every 0.5 degC over 120 degC


def structure_problem(calibration: Calibration) -> str | None:
    """The model's name and its parameters agree: `six` has a diagonal M, `sphere9` a lower-triangular
    one, `reference15` (and only it) a quadratic term."""
    matrix = calibration.matrix
    scale = float(np.abs(matrix).max())
    tolerance = STRUCTURE_TOLERANCE * scale
    if calibration.model == "six":
        off = matrix - np.diag(np.diag(matrix))
        if np.abs(off).max() > tolerance:
            return "model six has a diagonal matrix, but this one has off-diagonal entries"
    elif calibration.model == "sphere9":
        if np.abs(np.triu(matrix, 1)).max() > tolerance:
            return "model sphere9 has a lower-triangular matrix, but this one has entries above the diagonal"
    if calibration.model == "reference15" and calibration.quadratic is None:
        return "model reference15 needs its quadratic term, and this file has none"
    if calibration.model != "reference15" and calibration.quadratic is not None:
        return f"model {calibration.model} has no quadratic term, but this file has one"
    return None


def _orientation_problem(matrix: np.ndarray, what: str) -> str | None:
    """det M > 0, and not near zero relative to the rows' own size (no absolute limit: raw counts give
    a tiny M)."""
    row_size = np.abs(matrix).max(axis=1)
    if not (np.all(np.isfinite(row_size)) and np.all(row_size > 0)):
        return f"{what} has a zero or non-finite row: it would collapse the measurement"
    det = float(np.linalg.det(matrix / row_size[:, None]))  # scale-free; |det| <= 3^1.5
    if not np.isfinite(det):
        return f"{what} is not finite"
    if det < -1e-12:
        return f"{what} is mirrored (det M < 0): it would swap the handedness of the axes"
    if det <= 1e-12:
        return f"{what} is singular (det M = 0): it would collapse the measurement"
    return None


def bias_scale_refusal(bias: np.ndarray, matrix: np.ndarray, max_bias_mps2: float, scale_band: tuple[float, float],
                       where: str = "") -> Refusal | None:
    """The bias and scale gates at one point (bias (3,), M (3, 3)): what /calibrate and the file's readers
    both apply. Written as `not within`, so a NaN is refused, never passed."""
    worst_bias = float(np.max(np.abs(bias)))
    if not worst_bias <= max_bias_mps2:
        return Refusal(Gate.BIAS, f"|b| {worst_bias:.4g} m/s^2{where} above the plausible {max_bias_mps2:g} m/s^2")
    outside = gains_outside(matrix, scale_band, where)
    return None if outside is None else Refusal(Gate.SCALE, outside)


def gains_outside(matrix: np.ndarray, band: tuple[float, float], where: str = "") -> str | None:
    """The correction gain of each axis (row norm of M, the accelerometer's or the gyro's) outside `band`,
    said; None when every one is within (a NaN is outside). The one check of an axis gain against its band."""
    lo, hi = band
    gains = np.linalg.norm(matrix, axis=1)
    outside = [f"{AXES[i]} {g:.4f}" for i, g in enumerate(gains) if not lo <= g <= hi]
    return f"correction gain {', '.join(outside)}{where} outside {lo:g}..{hi:g}" if outside else None


def effective_terms(calibration: Calibration, temperatures_degc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(b_eff (T, 3), M_eff (T, 3, 3)): the affine map a_true = M_eff (a_raw - b_eff) that best matches
    the correction at each temperature over raw inputs of +-1 g per axis (the secant at 1 g), whatever
    the temperature model's form: the gates judge what the correction does, not its coefficients."""
    g = calibration.gravity
    probes = np.vstack([g * np.eye(3), -g * np.eye(3)])  # (6, 3): each axis up and down
    count = len(temperatures_degc)
    raw = np.tile(probes, (count, 1))
    corrected = calibration.apply(raw, np.repeat(temperatures_degc, len(probes))).reshape(count, 6, 3)
    up, down = corrected[:, :3, :], corrected[:, 3:, :]
    matrices = np.transpose((up - down) / (2 * g), (0, 2, 1))  # column j: d out / d raw_j
    centre = (up + down).mean(axis=1) / 2  # output at zero input, averaged over the axes
    bias = -np.linalg.solve(matrices, centre[:, :, None])[:, :, 0]
    return bias, matrices


def _temperature_refusal(calibration: Calibration, max_bias_mps2: float,
                         scale_band: tuple[float, float]) -> Refusal | None:
    model = calibration.temperature
    assert model is not None
    lo, hi = model.range_degc
    low_limit, high_limit = PLAUSIBLE_TEMPERATURE_DEGC
    if not (low_limit <= lo <= hi <= high_limit):
        return _temperature_block(f"calibrated range {lo:.4g}..{hi:.4g} degC is not a sensor's "
                                  f"({low_limit:g}..{high_limit:g} degC)")
    if not low_limit <= model.reference_degc <= high_limit:
        return _temperature_block(f"reference temperature {model.reference_degc:.4g} degC is not a sensor's")
    grid = np.linspace(lo, hi, _TEMPERATURE_STEPS)
    try:
        with np.errstate(all="ignore"):  # absurd coefficients overflow: caught as non-finite below
            bias, matrices = effective_terms(calibration, grid)
            finite = bool(np.all(np.isfinite(bias)) and np.all(np.isfinite(matrices)))
    except (CalibrationError, np.linalg.LinAlgError):
        finite = False
    if not finite:
        return _temperature_block("its correction is not finite (or collapses) within its calibrated range")
    for k, temperature in enumerate(grid):
        where = f" at {temperature:.1f} degC"
        problem = _orientation_problem(matrices[k], f"the correction{where}")
        if problem is not None:
            return _temperature_block(problem)
        refusal = bias_scale_refusal(bias[k], matrices[k], max_bias_mps2, scale_band, where)
        if refusal is not None:
            return replace(refusal, part=TEMPERATURE_BLOCK)
    return None


def _temperature_block(text: str) -> Refusal:
    return Refusal(Gate.PLAUSIBILITY, text, part=TEMPERATURE_BLOCK)


def plausibility_refusal(calibration: Calibration, *, max_bias_mps2: float = MAX_BIAS_MPS2,
                          scale_band: tuple[float, float] = SCALE_BAND,
                          max_gyro_bias_radps: float = MAX_GYRO_BIAS_RADPS,
                          gyro_scale_band: tuple[float, float] = GYRO_SCALE_BAND) -> Refusal | None:
    """None when the calibration may be put in force, else the first refusal: the bias or scale gate's when
    the bias or a gain is out of its band (at T_ref or anywhere in the temperature block's range), the
    plausibility gate's for anything else. The bias and scale gates take the node's settings
    (`max_bias_mps2`, `scale_min`, `scale_max`, `gyro.scale_min`, `gyro.scale_max`); with a temperature model
    they must hold over the whole calibrated range, not only at T_ref."""
    problem = structure_problem(calibration) or _orientation_problem(calibration.matrix, "the matrix M")
    if problem is not None:
        return Refusal(Gate.PLAUSIBILITY, problem)
    if calibration.temperature is not None:
        refusal = _temperature_refusal(calibration, max_bias_mps2, scale_band)
    else:
        refusal = bias_scale_refusal(calibration.bias, calibration.matrix, max_bias_mps2, scale_band)
    if refusal is not None:
        return refusal
    problem = _beyond_gyro_and_quadratic(calibration, max_gyro_bias_radps, gyro_scale_band)
    return None if problem is None else Refusal(Gate.PLAUSIBILITY, problem)


def _beyond_gyro_and_quadratic(calibration: Calibration, max_gyro_bias_radps: float,
                               gyro_scale_band: tuple[float, float]) -> str | None:
    if calibration.gyro_bias_radps is not None:
        worst = float(np.max(np.abs(calibration.gyro_bias_radps)))
        if not worst <= max_gyro_bias_radps:
            return (f"gyro bias {worst:.4g} rad/s is beyond any MEMS gyro's zero-rate offset "
                    f"(plausible up to {max_gyro_bias_radps:g} rad/s)")
    if calibration.gyro_matrix is not None:
        problem = _orientation_problem(calibration.gyro_matrix, "the gyro matrix")
        if problem is not None:
            return problem
        outside = gyro_gain_outside(calibration, gyro_scale_band)
        if outside is not None:
            return (f"gyro matrix: {outside} (gyro.scale_min..gyro.scale_max; a MEMS gyro's scale error is a few "
                    "percent: a gyro in other units than rad/s, or a bad fit)")
    if calibration.quadratic is not None:
        # q a^2 at 1 g beyond 10 % of g is not a quadratic error but another model (e.g. a file in g).
        worst = float(np.max(np.abs(calibration.quadratic))) * calibration.gravity
        if not worst <= 0.1:
            return f"quadratic term {worst * 100:.3g} % of g at 1 g: implausible for an accelerometer"
    return None


def implausible_text(refusal: Refusal) -> str:
    """A refusal as a file's reader says it after "implausible" or "left out": those words are the
    plausibility gate, so only the bias and scale gates are named."""
    return refusal.said(gate_named=refusal.gate is not Gate.PLAUSIBILITY)


def gyro_gain_outside(calibration: Calibration, gyro_scale_band: tuple[float, float] = GYRO_SCALE_BAND) -> str | None:
    """The gyro matrix's axis gains outside gyro.scale_min..gyro.scale_max, said; None when within (or none)."""
    return None if calibration.gyro_matrix is None else gains_outside(calibration.gyro_matrix, gyro_scale_band)


def without_gyro(calibration: Calibration) -> Calibration:
    """The accelerometer part alone: no gyro bias, matrix or quality."""
    return calibration.replace(gyro_bias_radps=None, gyro_matrix=None, gyro_quality=None)


def loadable_part(calibration: Calibration, **bounds: object) -> tuple[Calibration | None, Refusal | None]:
    """What of `calibration` may be saved so that `apply`, `report` and the node will put it in force:
    (the calibration, None) when all of it; (the accelerometer part, the gyro part's refusal) when only
    that; (None, the refusal) when not even that. `bounds` are plausibility_refusal's keywords."""
    refusal = plausibility_refusal(calibration, **bounds)  # type: ignore[arg-type]
    if refusal is None:
        return calibration, None
    has_gyro = calibration.gyro_bias_radps is not None or calibration.gyro_matrix is not None
    if has_gyro:
        accel_only = without_gyro(calibration)
        if plausibility_refusal(accel_only, **bounds) is None:  # type: ignore[arg-type]
            return accel_only, refusal
    return None, refusal
