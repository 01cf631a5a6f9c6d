"""Gyroscope scale and misalignment from the motions between still poses (imu_tk's method, Tedaldi,
Pretto & Menegatti, ICRA 2014, on our sample path).

The sensor is turned by hand from one still pose to the next. The calibrated accelerometer gives the
gravity direction u_i of each pose (in its calibrated frame); the gyro's corrected rate
w = M_g (w_raw - b_g), integrated from the end of pose i to the start of pose i + 1, gives the motion's
rotation R_i (see rotation_integration: R maps the end frame into the start frame), and the right M_g
carries u_i onto u_{i+1}:  residual_i = R_i^T u_i - u_{i+1}  (imu_tk's residual, same convention).

M_g is a full 3 x 3 (scale and misalignment of the gyro axes into the accelerometer's calibrated
frame). b_g comes from the still poses: during a motion the bias is interpolated in time between the
gyro means of the two poses it joins (it follows a slow drift); optionally a small bias change common
to every motion is fitted too. Rotation about the vertical within a motion is not seen, so the
motions must turn about every axis: the sigma of each parameter says whether they did.

Gauss-Newton with the exact Jacobian (rotation_integration); each motion's residual is weighted by the
noise it should have (the poses' direction noise, the gyro's white noise integrated over the motion and
the bias's uncertainty times its duration), and sigma is scaled up by the measured scatter when that
is larger than the prediction.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import ArrayLike

from .calibration import Calibration, GyroQuality
from .coverage import condition_and_inverse
from .errors import CalibrationError
from .gauss_newton import gauss_newton
from .gyro_axes import gyro_axes_problem
from .gyro_scoring import motion_intervals
from .models import REFERENCE_MODELS, matrix_entries
from .pose import Pose
from .refusal import MotionProblem
from .rotation_integration import IntervalSet, skew
from .units import AXES


@dataclass(frozen=True, eq=False)
class Motion:
    """Raw gyro samples recorded between two consecutive still poses, gap-free, in stamp order.

    Samples from the end of the earlier pose to the start of the later one (a sample or two of the
    poses themselves on either side does no harm: the sensor is still there)."""

    stamps_ns: np.ndarray  # (n,) int64 header stamps
    gyro_radps: np.ndarray  # (n, 3) raw angular rate
    paused: bool = False  # collection was paused (armed, calibration/pause) during it
    saturated: bool = False  # the sample path saw a sample at or beyond the gyro's range
    broken: bool = False  # a sample in it was screened out (not finite, out of range, frozen) or the clock jumped


@dataclass(frozen=True)
class GyroFitOptions:
    max_motion_s: float = 30.0  # longer motions are not used (bias drift, the hand paused)
    gyro_range_radps: float = 34.9  # a sample at or beyond it is saturated (2000 deg/s)
    gap_factor: float = 5.0  # an interval this many times the motion's median interval is a gap
    fit_bias: bool = False  # also fit one bias change common to every motion
    max_iterations: int = 30

    def __post_init__(self) -> None:
        for name in ("max_motion_s", "gyro_range_radps", "gap_factor"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                    or value <= 0:
                raise CalibrationError(f"gyro {name} must be a positive number, got {value!r}")
        if self.gap_factor < 1.5:
            raise CalibrationError(f"gyro gap_factor must be at least 1.5, got {self.gap_factor!r}")
        if isinstance(self.max_iterations, bool) or not isinstance(self.max_iterations, int) \
                or self.max_iterations < 1:
            raise CalibrationError(f"gyro max_iterations must be a positive integer, got {self.max_iterations!r}")


@dataclass(frozen=True)
class RefusedMotion:
    """A motion not used, and why."""

    index: int  # motion k joins pose k and pose k + 1
    kind: MotionProblem
    reason: str

    def describe(self) -> str:
        return f"motion {self.index + 1} (pose {self.index + 1} to {self.index + 2}): {self.reason}"


@dataclass(frozen=True, eq=False)
class GyroFitResult:
    """What fit_gyro found. `matrix` and `bias_radps` are w_true = matrix (w_raw - bias_radps) in the
    accelerometer's calibrated frame; sigma is 1 sigma per entry. Residuals are |R^T u_i - u_{i+1}| per
    motion used (about the angle by which the motion misses the next pose), in mrad."""

    success: bool
    message: str
    iterations: int = 0
    matrix: np.ndarray | None = None
    bias_radps: np.ndarray | None = None
    matrix_sigma: np.ndarray | None = None
    bias_sigma_radps: np.ndarray | None = None
    residuals_mrad: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residuals_before_mrad: np.ndarray = field(default_factory=lambda: np.zeros(0))  # with the initial matrix
    used: tuple[int, ...] = ()  # indices of the motions fitted
    refused: tuple[RefusedMotion, ...] = ()
    turned_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))  # sum |raw rate| dt per axis, motions used
    condition_number: float = float("inf")
    scatter: float = float("nan")  # sqrt(chi^2 / dof): measured residual scatter over the predicted
    bias_fitted: bool = False

    @property
    def motions_used(self) -> int:
        return len(self.used)

    @property
    def residual_rms_mrad(self) -> float:
        r = self.residuals_mrad
        return float(np.sqrt(np.mean(r**2))) if len(r) else float("nan")

    @property
    def residual_max_mrad(self) -> float:
        return float(np.max(self.residuals_mrad)) if len(self.residuals_mrad) else float("nan")

    @property
    def residual_rms_before_mrad(self) -> float:
        r = self.residuals_before_mrad
        return float(np.sqrt(np.mean(r**2))) if len(r) else float("nan")

    def refused_counts(self) -> dict[MotionProblem, int]:
        return refused_counts(self.refused)

    def scale_sigma_ppm(self) -> np.ndarray:
        """1 sigma of each axis' scale (diagonal of M_g), ppm of the gain of its row."""
        if self.matrix is None or self.matrix_sigma is None:
            return np.full(3, np.inf)
        gains = np.linalg.norm(self.matrix, axis=1)
        result: np.ndarray = np.diag(self.matrix_sigma) / gains * 1e6
        return result

    def misalignment_sigma_mrad(self) -> np.ndarray:
        """1 sigma of each off-diagonal entry of M_g, mrad of the gain of its row (0 on the diagonal)."""
        if self.matrix is None or self.matrix_sigma is None:
            return np.full((3, 3), np.inf)
        gains = np.linalg.norm(self.matrix, axis=1)
        result: np.ndarray = self.matrix_sigma / gains[:, None] * 1e3
        np.fill_diagonal(result, 0.0)
        return result

    def quality(self) -> GyroQuality:
        """The gyro_quality block of a calibration (successful fits only)."""
        if self.matrix_sigma is None or not self.success:
            raise CalibrationError("only a successful gyro fit has a quality")
        return GyroQuality(matrix_sigma=self.matrix_sigma, residual_rms_mrad=self.residual_rms_mrad,
                           residual_max_mrad=self.residual_max_mrad, motions=self.motions_used,
                           bias_sigma_radps=self.bias_sigma_radps)

    def apply_to(self, calibration: Calibration) -> Calibration:
        """The accelerometer calibration with this gyro calibration beside it."""
        if self.matrix is None or self.bias_radps is None or not self.success:
            raise CalibrationError(f"the gyro fit did not succeed ({self.message}); nothing to apply")
        return calibration.replace(gyro_matrix=self.matrix, gyro_bias_radps=self.bias_radps,
                                   gyro_quality=self.quality())

    def summary(self) -> str:
        lines = [f"gyro: {'OK' if self.success else 'FAILED'} - {self.message}"]
        not_used = refused_text(self.refused)
        lines.append(f"motions used {self.motions_used}" + (f", not used: {not_used}" if not_used else ""))
        if self.matrix is not None and self.matrix_sigma is not None:
            lines.append("gyro matrix M_g (w_true = M_g (w_raw - b_g)), +- 1 sigma:")
            for i in range(3):
                lines.append("  [" + "  ".join(f"{self.matrix[i, j]:+.6f} ± {self.matrix_sigma[i, j]:.1e}"
                                               for j in range(3)) + "]")
        if self.bias_radps is not None:
            lines.append("gyro bias b_g (rad/s): " + "  ".join(f"{v:+.6f}" for v in self.bias_radps))
        if len(self.residuals_mrad):
            lines.append(f"motion residuals: rms {self.residual_rms_mrad:.3f} mrad, max {self.residual_max_mrad:.3f}"
                         f" mrad (before: rms {self.residual_rms_before_mrad:.3f} mrad)")
        return "\n".join(lines)


def motion_problem(motion: Motion | None, index: int, poses: Sequence[Pose], options: GyroFitOptions
                   ) -> RefusedMotion | None:
    """Why motion `index` (between pose index and index + 1) cannot be used; None when it can."""
    def refuse(kind: MotionProblem, reason: str) -> RefusedMotion:
        return RefusedMotion(index, kind, reason)

    if motion is None:
        return refuse(MotionProblem.NOT_RECORDED, "not recorded")
    if motion.paused:
        return refuse(MotionProblem.PAUSED, "collection was paused during it")
    if motion.saturated:
        return refuse(MotionProblem.SATURATED, "the gyro saturated during it")
    if motion.broken:
        return refuse(MotionProblem.SCREENED, "a sample in it was screened out (not finite, out of range, frozen) "
                                  "or the clock jumped")
    stamps, rates = motion.stamps_ns, motion.gyro_radps
    if len(stamps) < 3:
        return refuse(MotionProblem.TOO_SHORT, f"{len(stamps)} samples")
    if not np.all(np.isfinite(rates)):
        return refuse(MotionProblem.NOT_FINITE, "a sample is not finite")
    intervals = np.diff(stamps)
    if np.any(intervals <= 0):
        return refuse(MotionProblem.STAMPS, "stamps not increasing")
    duration_s = float(stamps[-1] - stamps[0]) * 1e-9
    if duration_s > options.max_motion_s:
        return refuse(MotionProblem.LONG,
                      f"{duration_s:.1f} s, longer than gyro.max_motion_s={options.max_motion_s:g} s")
    median = float(np.median(intervals))
    widest = float(intervals.max())
    if widest > options.gap_factor * median:
        return refuse(MotionProblem.GAP, f"a gap of {widest * 1e-6:.1f} ms in samples {median * 1e-6:.2f} ms apart")
    peak = float(np.abs(rates).max())
    if peak >= options.gyro_range_radps:
        return refuse(MotionProblem.SATURATED,
                      f"|w| reached {peak:.2f} rad/s (gyro_range_radps={options.gyro_range_radps:g})")
    before, after = poses[index], poses[index + 1]
    slack = 2.0 * median
    late, early = stamps[0] - before.end_ns, after.start_ns - stamps[-1]
    if late > slack or early > slack:
        return refuse(MotionProblem.SPAN, f"its samples do not cover the time between the poses "
                              f"(start {late * 1e-9:+.3f} s after pose {index + 1} ends, end "
                              f"{early * 1e-9:+.3f} s before pose {index + 2} starts)")
    return None


def motions_between(poses: Sequence[Pose], stamps_ns: ArrayLike, gyro_radps: ArrayLike,
                    collecting: ArrayLike | None = None, saturated: ArrayLike | None = None) -> list[Motion]:
    """The motions between consecutive poses of a recording in arrays (stamps in increasing order): from
    the last sample at or before a pose's end to the first at or after the next pose's start.
    `collecting` (False where collection was paused) and `saturated` (True where a sample was at or beyond
    the gyro's range), one bool per sample, mark the motions that hold such a sample."""
    stamps = np.asarray(stamps_ns, dtype=np.int64).reshape(-1)
    rates = np.asarray(gyro_radps, dtype=float).reshape(-1, 3)
    if len(rates) != len(stamps):
        raise CalibrationError(f"gyro_radps must have one row per stamp ({len(stamps)}), got {len(rates)}")
    masks: list[np.ndarray | None] = []
    for name, mask, flag in (("collecting", collecting, False), ("saturated", saturated, True)):
        if mask is None:
            masks.append(None)
            continue
        array = np.asarray(mask, dtype=bool).reshape(-1)
        if len(array) != len(stamps):
            raise CalibrationError(f"{name} must have one value per stamp ({len(stamps)}), got {len(array)}")
        masks.append(array == flag)  # True where the sample spoils its motion
    motions = []
    for before, after in zip(poses[:-1], poses[1:]):
        first = max(int(np.searchsorted(stamps, before.end_ns, side="right")) - 1, 0)
        last = min(int(np.searchsorted(stamps, after.start_ns, side="left")), len(stamps) - 1)
        part = slice(first, last + 1)
        spoilt = [bool(m[part].any()) if m is not None else False for m in masks]
        motions.append(Motion(stamps[part], rates[part], paused=spoilt[0], saturated=spoilt[1]))
    return motions


def _check_inputs(poses: Sequence[Pose], motions: Sequence[Motion | None], accel: Calibration,
                  gyro_noise_radps: float | ArrayLike | None, initial_matrix: ArrayLike | None
                  ) -> tuple[np.ndarray | None, np.ndarray]:
    if not isinstance(accel, Calibration):
        raise CalibrationError("accel must be the accelerometer's Calibration (its frame is the gyro's target)")
    if len(poses) < 2:
        raise CalibrationError(f"a gyro fit needs consecutive still poses, got {len(poses)}")
    if len(motions) != len(poses) - 1:
        raise CalibrationError(f"motions must be one per pair of consecutive poses ({len(poses) - 1}), "
                               f"got {len(motions)}")
    for i, pose in enumerate(poses):
        if not isinstance(pose, Pose):
            raise CalibrationError(f"pose {i + 1} is not a Pose")
        if pose.gyro_radps is None:
            raise CalibrationError(f"pose {i + 1} has no gyro mean: the recording has no gyro")
        if i and pose.start_ns < poses[i - 1].end_ns:
            raise CalibrationError(f"poses must be in time order, each as detected (pose {i + 1} starts before "
                                   f"pose {i} ends); not the merged pose store")
    for i, motion in enumerate(motions):
        if motion is None:
            continue
        if not isinstance(motion, Motion):
            raise CalibrationError(f"motion {i + 1} is not a Motion or None")
        stamps, rates = np.shape(motion.stamps_ns), np.shape(motion.gyro_radps)
        if len(stamps) != 1 or rates != (stamps[0], 3):
            raise CalibrationError(f"motion {i + 1}: stamps_ns must be (n,) and gyro_radps (n, 3), got {stamps} "
                                   f"and {rates}")
    noise = None
    if gyro_noise_radps is not None:
        try:
            noise = np.broadcast_to(np.asarray(gyro_noise_radps, dtype=float), (3,)).copy()
        except (TypeError, ValueError):
            raise CalibrationError(f"gyro_noise_radps must be a number or 3 numbers, got {gyro_noise_radps!r:.40}"
                                   ) from None
        if not (np.all(np.isfinite(noise)) and np.all(noise > 0)):
            raise CalibrationError(f"gyro_noise_radps must be positive and finite, got {noise.tolist()}")
    if initial_matrix is None:
        initial = np.eye(3)
    else:
        try:
            initial = np.array(initial_matrix, dtype=float)
        except (TypeError, ValueError):
            raise CalibrationError("initial_matrix must be a 3 x 3 array of numbers") from None
        if initial.shape != (3, 3) or not np.all(np.isfinite(initial)) or abs(np.linalg.det(initial)) < 1e-300:
            raise CalibrationError("initial_matrix must be a finite, non-singular 3 x 3 array")
    return noise, initial


def _directions(poses: Sequence[Pose], accel: Calibration) -> tuple[np.ndarray, np.ndarray]:
    """Gravity directions u of the poses in the accelerometer's calibrated frame (n, 3), and how the noise of
    the poses' accelerometer means moves them: D (3n, 3n) with du = D xi, xi independent unit normals (3 per
    pose, scaled by the pose's covariance over its sample count). For the sphere models the accelerometer's
    own fit is linearised too: the same pose means set its bias and matrix, so every direction moves with
    every pose's noise (the calibrated frame itself is uncertain). The reference models' frame comes from
    the reference directions: each direction moves with its own pose only."""
    raw = np.array([p.accel_mps2 for p in poses], dtype=float)
    temps = [p.temperature_degc for p in poses]
    corrected = accel.apply(raw, None if any(t is None for t in temps) else np.array(temps, dtype=float))
    norms = np.linalg.norm(corrected, axis=1)
    directions = corrected / norms[:, None]
    count = len(poses)
    matrix, bias = accel.matrix, accel.bias
    roots = np.zeros((count, 3, 3))  # square roots of each pose mean's covariance
    for i, pose in enumerate(poses):
        covariance = np.asarray(pose.accel_cov, dtype=float) / max(pose.samples, 1)
        values, vectors = np.linalg.eigh(0.5 * (covariance + covariance.T))
        roots[i] = vectors * np.sqrt(np.clip(values, 0.0, None))
    # du_i = (I - u u^T) / |c_i| dc_i, c_i = M (a_i - b)
    tangential = (np.eye(3) - directions[:, :, None] * directions[:, None, :]) / norms[:, None, None]
    own = np.zeros((3 * count, 3 * count))  # dc_i / d xi from pose i's own noise: M L_i
    for i in range(count):
        own[3 * i:3 * i + 3, 3 * i:3 * i + 3] = matrix @ roots[i]
    d_corrected = own
    if accel.model not in REFERENCE_MODELS:
        # The sphere fit: residual_i = |c_i| - g over p = (b, free entries of M); dp = -(Ja^T Ja)^-1 Ja^T da_res
        entries = matrix_entries(accel.model)
        offsets = raw - bias
        d_c_d_p = np.zeros((count, 3, 3 + len(entries)))
        d_c_d_p[:, :, :3] = -matrix
        for column, (row, col) in enumerate(entries):
            d_c_d_p[:, row, 3 + column] = offsets[:, col]
        fit_jacobian = np.einsum("ia,iap->ip", directions, d_c_d_p)  # d|c_i| / dp
        d_residual = np.zeros((count, 3 * count))
        for i in range(count):
            d_residual[i] = directions[i] @ own[3 * i:3 * i + 3]
        d_parameters = -np.linalg.lstsq(fit_jacobian, d_residual, rcond=None)[0]  # (P, 3n)
        d_corrected = own + (d_c_d_p.reshape(3 * count, -1) @ d_parameters)
    sensitivity = np.zeros((3 * count, 3 * count))
    for i in range(count):
        sensitivity[3 * i:3 * i + 3] = tangential[i] @ d_corrected[3 * i:3 * i + 3]
    return directions, sensitivity


def _plain_directions(poses: Sequence[Pose], accel: Calibration) -> np.ndarray:
    """The poses' unit gravity directions in the accelerometer's calibrated frame (no noise model)."""
    raw = np.array([p.accel_mps2 for p in poses], dtype=float)
    temps = [p.temperature_degc for p in poses]
    corrected = accel.apply(raw, None if any(t is None for t in temps) else np.array(temps, dtype=float))
    directions: np.ndarray = corrected / np.linalg.norm(corrected, axis=1)[:, None]
    return directions


def fit_gyro(
    poses: Sequence[Pose],
    motions: Sequence[Motion | None],
    accel: Calibration,
    *,
    options: GyroFitOptions | None = None,
    gyro_noise_radps: float | ArrayLike | None = None,
    initial_matrix: ArrayLike | None = None,
) -> GyroFitResult:
    """Fit M_g (and, with options.fit_bias, a bias change) to the motions between consecutive poses.

    poses: still poses in time order, as detected (each with its gyro mean); motions[k]: the raw gyro
    between pose k and k + 1 (None when it was not kept). accel: the accelerometer's calibration (it gives
    the gravity directions, and its frame is the frame M_g maps into). gyro_noise_radps: the raw gyro's
    white noise, 1 sigma per sample (scalar or per axis, e.g. from the still poses); without it the
    residuals are weighted equally and sigma comes from their scatter alone. initial_matrix: start of
    M_g (identity by default: raw rates in rad/s).

    Bad arguments raise CalibrationError; everything the data do wrong is reported in the result."""
    options = GyroFitOptions() if options is None else options
    if not isinstance(options, GyroFitOptions):
        raise CalibrationError("options must be GyroFitOptions or None")
    noise, initial = _check_inputs(poses, motions, accel, gyro_noise_radps, initial_matrix)
    refused: list[RefusedMotion] = []
    used: list[int] = []
    for k, motion in enumerate(motions):
        problem = motion_problem(motion, k, poses, options)
        if problem is None:
            used.append(k)
        else:
            refused.append(problem)
    # A gyro in deg/s reads 57 times its rate and is refused as saturated: the check sees those motions too.
    saturated = {m.index for m in refused if m.kind is MotionProblem.SATURATED}
    checked = [motion if k in used or (k in saturated and motion is not None and not motion.saturated) else None
               for k, motion in enumerate(motions)]
    axes = gyro_axes_problem(poses, checked, _plain_directions(poses, accel), initial)
    if axes is not None:
        return GyroFitResult(False, axes, used=tuple(used), refused=tuple(refused),
                             bias_fitted=options.fit_bias)
    parameters = 12 if options.fit_bias else 9
    need = parameters // 2 + 1  # two residual components per motion, one degree of freedom left
    if len(used) < need:
        counts = refused_text(refused)
        return GyroFitResult(False, f"{len(used)} usable motions, need at least {need}"
                             + (f" ({counts} not used)" if counts else ""), used=tuple(used), refused=tuple(refused),
                             bias_fitted=options.fit_bias)
    with np.errstate(all="ignore"):
        return _fit(poses, [m for m in motions], used, refused, accel, noise, initial, options)


def refused_counts(refused: Sequence[RefusedMotion]) -> dict[MotionProblem, int]:
    """How many motions were not used, by why, in the order first met."""
    counts: dict[MotionProblem, int] = {}
    for motion in refused:
        counts[motion.kind] = counts.get(motion.kind, 0) + 1
    return counts


def refused_text(refused: Sequence[RefusedMotion]) -> str:
    """'2 not recorded, 1 long': the motions not used, by why, as people read it ("" when none)."""
    return ", ".join(f"{n} {kind.value}" for kind, n in refused_counts(refused).items())


def _tangent_basis(directions: np.ndarray) -> np.ndarray:
    """(n, 3, 2): two unit vectors perpendicular to each direction and to each other."""
    helper = np.where(np.abs(directions[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    first = np.cross(directions, helper)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    second = np.cross(directions, first)
    basis: np.ndarray = np.stack([first, second], axis=2)
    return basis


@dataclass(frozen=True)
class _Problem:
    """What the residuals need besides the parameters."""

    intervals: IntervalSet
    start: np.ndarray  # (K, 3) u_i of each motion used
    end: np.ndarray  # (K, 3) u_{i+1}
    projection: np.ndarray  # (K, 3, 2) basis of the plane perpendicular to u_{i+1}
    used: list[int]
    with_bias: bool

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return x[:9].reshape(3, 3), (x[9:] if self.with_bias else np.zeros(3))

    def evaluate(self, x: np.ndarray) -> _Evaluation:
        matrix, bias_change = self.unpack(x)
        rotations, d_phi, d_pose_bias = self.intervals.rotations_and_derivatives(matrix, bias_change, self.with_bias)
        moved = np.einsum("kba,kb->ka", rotations, self.start)  # R^T u_i
        residual = np.einsum("kai,ka->ki", self.projection, moved - self.end)
        # d(R^T u) = [R^T u]x d phi
        jacobian = np.einsum("kai,kab,kbp->kip", self.projection, skew(moved), d_phi)
        return _Evaluation(residual.ravel(), jacobian.reshape(-1, d_phi.shape[2]), rotations, moved, d_pose_bias)


@dataclass(frozen=True)
class _Evaluation:
    # (2K,) R^T u_i - u_{i+1} in the plane perpendicular to u_{i+1} (its third component is second order)
    residual: np.ndarray
    jacobian: np.ndarray  # (2K, P)
    rotations: np.ndarray  # (K, 3, 3)
    moved: np.ndarray  # (K, 3) R^T u_i
    d_pose_bias: np.ndarray  # (K, 2, 3, 3) d phi / d (earlier, later) pose's gyro mean

    def residuals_mrad(self, end: np.ndarray) -> np.ndarray:
        """|R^T u_i - u_{i+1}| per motion, mrad."""
        result: np.ndarray = np.linalg.norm(self.moved - end, axis=1) * 1e3
        return result


@dataclass(frozen=True)
class _Noise:
    """What is known of the noise: how the poses' accelerometer noise moves the gravity directions, the
    gyro's white noise per sample (raw, per axis), the poses' sample counts and each motion's sum of dt^2."""

    direction_noise: np.ndarray  # (3n, 3n): du = D xi
    gyro_radps: np.ndarray
    samples: np.ndarray
    sum_dt2: np.ndarray

    def covariance(self, problem: _Problem, evaluation: _Evaluation, matrix: np.ndarray) -> np.ndarray:
        """Covariance (2K, 2K) of the projected residuals: each pose's accelerometer mean (through its own
        direction and the accelerometer's fit, see _directions), each pose's gyro mean (the bias is
        interpolated from it: the gyro noise over its samples) and the gyro's white noise integrated over
        each motion. A pose joins two motions, so neighbouring residuals are correlated."""
        motions, poses = len(problem.used), len(self.samples)
        white = float(np.mean(self.gyro_radps**2))
        bias_sigma = np.sqrt(white / np.maximum(self.samples, 1.0))
        used = np.array(problem.used)
        rows = np.arange(motions)
        # Sources: 3 accelerometer components per pose (u_i enters rotated, R^T u_i, and u_{i+1} as it is,
        # with a minus), then 3 gyro-bias components per pose.
        by_pose = self.direction_noise.reshape(poses, 3, 3 * poses)
        accel_part = np.transpose(evaluation.rotations, (0, 2, 1)) @ by_pose[used] - by_pose[used + 1]
        bias_part = np.zeros((motions, poses, 3, 3))
        moved_skew = skew(evaluation.moved)
        bias_part[rows, used] = moved_skew @ evaluation.d_pose_bias[:, 0] * bias_sigma[used, None, None]
        bias_part[rows, used + 1] = moved_skew @ evaluation.d_pose_bias[:, 1] * bias_sigma[used + 1, None, None]
        sources = np.concatenate([accel_part, np.transpose(bias_part, (0, 2, 1, 3)).reshape(motions, 3, -1)], axis=2)
        projected = np.einsum("kai,kas->kis", problem.projection, sources).reshape(2 * motions, -1)
        covariance: np.ndarray = projected @ projected.T
        # The white noise integrated (each sample weighs about dt), isotropic: M_g M_g^T ~ |M_g|^2 / 3.
        gain = float(np.sum(matrix**2) / 3.0)
        covariance[np.diag_indices_from(covariance)] += np.repeat(white * gain * self.sum_dt2, 2)
        return covariance


def _fit(poses: Sequence[Pose], motions: Sequence[Motion | None], used: list[int], refused: list[RefusedMotion],
         accel: Calibration, noise: np.ndarray | None, initial: np.ndarray, options: GyroFitOptions
         ) -> GyroFitResult:
    directions, direction_noise = _directions(poses, accel)
    pose_gyro = np.array([p.gyro_radps for p in poses], dtype=float)
    samples = np.array([p.samples for p in poses], dtype=float)
    mean_bias = (samples / samples.sum()) @ pose_gyro
    intervals = motion_intervals(poses, motions, used)
    sum_dt2 = np.add.reduceat(intervals.dt_s**2, intervals.first)  # per motion
    later = [k + 1 for k in used]
    problem = _Problem(intervals, directions[used], directions[later], _tangent_basis(directions[later]), used,
                       options.fit_bias)
    turned_deg = np.degrees(intervals.turned_rad())
    x0 = np.concatenate([initial.ravel(), np.zeros(3 if options.fit_bias else 0)])
    evaluations: dict[bytes, _Evaluation] = {}

    def evaluate(x: np.ndarray) -> _Evaluation:
        key = x.tobytes()
        if key not in evaluations:
            evaluations.clear()  # the last point is all that is asked again
            evaluations[key] = problem.evaluate(x)
        return evaluations[key]

    known = None if noise is None else _Noise(direction_noise, noise, samples, sum_dt2)
    # Weights: the noise covariance at the start (whitened by its Cholesky factor); without the gyro's
    # noise, imu_tk's equal weights.
    whitening = None if known is None else _whitening(known.covariance(problem, evaluate(x0), initial))

    def residual_and_jacobian(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        evaluation = evaluate(x)
        if whitening is None:
            return evaluation.residual, evaluation.jacobian
        return whitening @ evaluation.residual, whitening @ evaluation.jacobian

    residuals_before = evaluate(x0).residuals_mrad(problem.end)
    used_, refused_ = tuple(used), tuple(refused)
    # ftol 1e-10: the last step then moves M_g by ~1e-6 of its sigma; a tighter one costs an evaluation more.
    solution = gauss_newton(residual_and_jacobian, x0, ftol=1e-10, max_iterations=options.max_iterations)
    if not solution.success:
        return GyroFitResult(False, f"the fit did not converge ({solution.message})", solution.iterations,
                             used=used_, refused=refused_, turned_deg=turned_deg,
                             residuals_before_mrad=residuals_before, bias_fitted=options.fit_bias)
    x = solution.x
    matrix, bias_change = problem.unpack(x)
    final = evaluate(x)
    dof = len(final.residual) - len(x)
    # sigma of the estimate with the weights used and the noise covariance at the solution (the
    # sandwich (J'WJ)^-1 J'W C W J (J'WJ)^-1), scaled up when the residuals scatter more than C says.
    weighted = final.jacobian if whitening is None else whitening @ final.jacobian
    condition, inverse = condition_and_inverse(weighted.T @ weighted)
    middle = None
    if known is None:
        scatter_squared = float(final.residual @ final.residual) / dof if dof > 0 else math.inf
        factor = scatter_squared
    else:
        assert whitening is not None
        covariance = known.covariance(problem, final, matrix)
        scatter_squared = (float(np.sum((_whitening(covariance) @ final.residual) ** 2)) / dof if dof > 0
                           else math.inf)
        factor = max(1.0, scatter_squared)
        applied = whitening.T @ weighted  # C0^-1 J
        middle = applied.T @ covariance @ applied
    if inverse is None or not math.isfinite(factor):
        sigma = np.full(len(x), np.inf)
    else:
        parameter_covariance = inverse if middle is None else inverse @ middle @ inverse
        sigma = np.sqrt(np.maximum(np.diag(parameter_covariance), 0.0) * factor)
    result = GyroFitResult(
        True, "fitted", solution.iterations, matrix=matrix, bias_radps=mean_bias + bias_change,
        matrix_sigma=sigma[:9].reshape(3, 3), bias_sigma_radps=sigma[9:] if options.fit_bias else None,
        residuals_mrad=final.residuals_mrad(problem.end), residuals_before_mrad=residuals_before, used=used_,
        refused=refused_, turned_deg=turned_deg, condition_number=condition, scatter=math.sqrt(scatter_squared),
        bias_fitted=options.fit_bias)
    loose = unobserved_axes(result)
    if loose:
        return replace(result, success=False, message=turn_advice(loose))
    return result


def _whitening(covariance: np.ndarray) -> np.ndarray:
    """L^-1 for covariance = L L^T: residuals times it have unit covariance."""
    lower = np.linalg.cholesky(covariance)
    result: np.ndarray = np.linalg.inv(lower)
    return result


# Beyond this the data do not determine a parameter at all (10 % of scale or 100 mrad), whatever the gates.
_UNOBSERVED_RELATIVE_SIGMA = 0.1


def unobserved_axes(result: GyroFitResult, scale_ppm: float = _UNOBSERVED_RELATIVE_SIGMA * 1e6,
                    misalignment_mrad: float = _UNOBSERVED_RELATIVE_SIGMA * 1e3) -> tuple[int, ...]:
    """The raw gyro axes q whose column of M_g (scale q and what q leaks into the other axes; pinned down
    only by turns about q) has a sigma beyond the bounds. Default bounds: not determined at all."""
    scale = result.scale_sigma_ppm()
    misalignment = result.misalignment_sigma_mrad()
    loose = []
    for q in range(3):
        column = [misalignment[p, q] for p in range(3) if p != q]
        if not (scale[q] <= scale_ppm and all(m <= misalignment_mrad for m in column)):
            loose.append(q)
    return tuple(loose)


def _axes_text(axes: Sequence[int]) -> str:
    names = [AXES[q] for q in axes]
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def turn_advice(loose: Sequence[int]) -> str:
    """'motions turned about x and y only; turn about z' for the axes not pinned down."""
    turned = [q for q in range(3) if q not in loose]
    if not turned:
        return ("the motions pin down no axis well enough; turn about each of x, y and z between poses "
                "(not about the vertical), in more motions")
    return (f"motions turned about {_axes_text(turned)} only; turn about {_axes_text(loose)} between poses "
            "(not about the vertical)")
