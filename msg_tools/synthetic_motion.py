"""A simulated IMU turned by hand from still pose to still pose: the gyro's scale and misalignment are
in the motions between the poses (what the gyro fit recovers), the accelerometer's in the poses.

Pure numpy (no ROS, nothing of accel_calibration). The orientation is analytic: a motion from pose
orientation C_i to C_{i+1} is C(t) = C_i exp(s(tau) rho) exp(w(tau)), rho = log(C_i^T C_{i+1}), s a
minimum-jerk ramp and w a wobble that vanishes with its rate at both ends (the hand's turn is not about
one axis), so the body rate is exact: exp(-w) s' rho + J_r(w) w'. The hand also moves the sensor a few
cm (linear acceleration in the specific force). Raw outputs invert the project's conventions:
w_raw = M_g^-1 w_true + b_g(t) + noise (b_g drifts as a random walk), a_raw = M_a^-1 f + b_a + noise.
The earth's rate is in the gyro's truth. Stamps carry jitter; each sample is taken at its stamp.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STANDARD_GRAVITY = 9.80665
EARTH_RATE_RADPS = 7.292115e-5


def _skew(v: np.ndarray) -> np.ndarray:
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2)


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    """exp([v]x), (..., 3) -> (..., 3, 3) (Rodrigues)."""
    angle = np.linalg.norm(rotvec, axis=-1)
    safe = np.where(angle < 1e-8, 1.0, angle)
    a = np.where(angle < 1e-8, 1.0 - angle**2 / 6, np.sin(safe) / safe)
    b = np.where(angle < 1e-8, 0.5 - angle**2 / 24, (1 - np.cos(safe)) / safe**2)
    k = _skew(rotvec)
    result: np.ndarray = np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)
    return result


def rotation_vector(matrix: np.ndarray) -> np.ndarray:
    """log of a rotation matrix (angle below pi)."""
    cosine = np.clip((np.trace(matrix) - 1) / 2, -1.0, 1.0)
    angle = np.arccos(cosine)
    axis = np.array([matrix[2, 1] - matrix[1, 2], matrix[0, 2] - matrix[2, 0], matrix[1, 0] - matrix[0, 1]])
    log: np.ndarray = axis / 2 if angle < 1e-8 else axis * angle / (2 * np.sin(angle))
    return log


def _right_jacobian(theta: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(theta, axis=-1)
    safe = np.where(angle < 1e-6, 1.0, angle)
    first = np.where(angle < 1e-6, 0.5, (1 - np.cos(safe)) / safe**2)
    second = np.where(angle < 1e-6, 1 / 6, (safe - np.sin(safe)) / safe**3)
    k = _skew(theta)
    result: np.ndarray = np.eye(3) - first[..., None, None] * k + second[..., None, None] * (k @ k)
    return result


@dataclass(frozen=True)
class GyroTruth:
    """The gyro errors a fit should recover: w_true = matrix (w_raw - bias)."""

    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    bias_radps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    noise_density: float = 8.7e-5  # rad/s/sqrt(Hz) (0.005 deg/s/sqrt(Hz), the MPU-6050 datasheet value)
    bias_walk: float = 5e-6  # rad/s/sqrt(s): bias instability as a random walk

    @classmethod
    def random(cls, rng: np.random.Generator, scale_error: tuple[float, float] = (0.01, 0.03),
               misalignment_rad: tuple[float, float] = (0.002, 0.020), **others: float) -> GyroTruth:
        """1-3 % scale error per axis, 2-20 mrad between every pair of axes, bias ~1 deg/s."""
        matrix = np.diag(1.0 + rng.uniform(*scale_error, 3) * rng.choice([-1.0, 1.0], 3))
        off = ~np.eye(3, dtype=bool)
        matrix[off] = rng.uniform(*misalignment_rad, 6) * rng.choice([-1.0, 1.0], 6)
        return cls(matrix=matrix, bias_radps=rng.normal(0.0, 0.02, 3), **others)


@dataclass(frozen=True)
class MotionSession:
    stamps_ns: np.ndarray  # (N,) int64
    accel_mps2: np.ndarray  # (N, 3) raw
    gyro_radps: np.ndarray  # (N, 3) raw
    still: tuple[tuple[int, int], ...]  # sample index ranges [first, last] of each still pose, in time order
    gyro: GyroTruth
    accel_matrix: np.ndarray
    accel_bias_mps2: np.ndarray
    rate_hz: float
    gyro_noise_radps: float  # white noise per sample
    accel_noise_mps2: float

    def motion_ranges(self) -> list[tuple[int, int]]:
        """Sample index ranges [first, last] from the end of each pose to the start of the next."""
        return [(self.still[i][1], self.still[i + 1][0]) for i in range(len(self.still) - 1)]


def _pose_orientations(rng: np.random.Generator, count: int, axes: np.ndarray) -> list[np.ndarray]:
    """Body-to-world rotations: each from the last by 60-150 deg about a random axis of the body (its
    components outside `axes`, a 0/1 mask, zero), so the turns go about those axes and the gravity
    directions spread over the sphere."""
    orientations = [rotation_matrix(rng.normal(size=3) * 1.5)]
    for _ in range(count - 1):
        axis = rng.normal(size=3) * axes
        axis /= np.linalg.norm(axis)
        orientations.append(orientations[-1] @ rotation_matrix(axis * np.radians(rng.uniform(60, 150))))
    return orientations


def simulate_session(
    rng: np.random.Generator,
    poses: int = 18,
    rate_hz: float = 400.0,
    gyro: GyroTruth | None = None,
    accel_noise_density: float = 1.5e-3,  # m/s^2/sqrt(Hz) (150 ug/sqrt(Hz))
    hold_s: tuple[float, float] = (2.0, 4.0),
    move_s: tuple[float, float] = (1.5, 3.5),
    first_hold_s: float = 10.0,
    jitter: float = 0.05,  # stamp jitter, fraction of the period
    latitude_deg: float = 48.0,
    earth_rate_radps: float = EARTH_RATE_RADPS,
    turn_axes: str = "xyz",  # the body axes the hand turns about (and wobbles about)
) -> MotionSession:
    gyro = GyroTruth.random(rng) if gyro is None else gyro
    axes = np.array([float(axis in turn_axes) for axis in "xyz"])
    accel_matrix = np.diag(1.0 + rng.uniform(-0.02, 0.02, 3))
    accel_matrix[np.tril_indices(3, -1)] = rng.uniform(-0.01, 0.01, 3)
    accel_bias = rng.uniform(-0.3, 0.3, 3)
    orientations = _pose_orientations(rng, poses, axes)
    # Timeline: hold, move, hold, ... with the move times drawn here.
    holds = [first_hold_s] + list(rng.uniform(*hold_s, poses - 1))
    moves = list(rng.uniform(*move_s, poses - 1))
    edges = [0.0]
    for i in range(poses):
        edges.append(edges[-1] + holds[i])
        if i < poses - 1:
            edges.append(edges[-1] + moves[i])
    total_s = edges[-1]
    period = 1.0 / rate_hz
    count = int(total_s * rate_hz)
    times = np.arange(count) * period + rng.uniform(-jitter, jitter, count) * period + period
    times = times[times < total_s]
    count = len(times)
    rotation = np.empty((count, 3, 3))
    body_rate = np.zeros((count, 3))
    linear_accel_world = np.zeros((count, 3))
    still: list[tuple[int, int]] = []
    for i in range(poses):
        start, end = edges[2 * i], edges[2 * i + 1]
        inside = np.flatnonzero((times >= start) & (times <= end))
        rotation[inside] = orientations[i]
        still.append((int(inside[0]), int(inside[-1])))
        if i == poses - 1:
            break
        move_end = edges[2 * i + 2]
        duration = move_end - end
        moving = np.flatnonzero((times > end) & (times < move_end))
        tau = (times[moving] - end) / duration
        rho = rotation_vector(orientations[i].T @ orientations[i + 1])
        ramp = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        ramp_rate = (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / duration
        c1, c2 = rng.normal(0, 0.25, 3) * axes, rng.normal(0, 0.25, 3) * axes
        bump = np.sin(np.pi * tau) ** 2
        bump_rate = 2 * np.pi * np.sin(np.pi * tau) * np.cos(np.pi * tau) / duration
        wave, wave_rate = np.sin(2 * np.pi * tau), 2 * np.pi * np.cos(2 * np.pi * tau) / duration
        wobble = bump[:, None] * (c1 + c2 * wave[:, None])
        wobble_rate = bump_rate[:, None] * (c1 + c2 * wave[:, None]) + bump[:, None] * c2 * wave_rate[:, None]
        turn = rotation_matrix(ramp[:, None] * rho)
        e2 = rotation_matrix(wobble)
        rotation[moving] = orientations[i] @ turn @ e2
        body_rate[moving] = (np.einsum("nba,b->na", e2, rho) * ramp_rate[:, None]
                             + np.einsum("nab,nb->na", _right_jacobian(wobble), wobble_rate))
        displacement = rng.normal(0, 0.05, 3)  # m
        s, c = np.sin(np.pi * tau), np.cos(np.pi * tau)
        linear_accel_world[moving] = displacement * (np.pi**2 * (12 * s**2 * c**2 - 4 * s**4) / duration**2)[:, None]
    latitude = np.radians(latitude_deg)
    earth_world = earth_rate_radps * np.array([0.0, np.cos(latitude), np.sin(latitude)])
    true_rate = body_rate + np.einsum("nba,b->na", rotation, earth_world)
    up = np.array([0.0, 0.0, STANDARD_GRAVITY])
    specific_force = np.einsum("nba,nb->na", rotation, up + linear_accel_world)
    gyro_noise = gyro.noise_density * np.sqrt(rate_hz)
    accel_noise = accel_noise_density * np.sqrt(rate_hz)
    steps = np.diff(times, prepend=0.0)
    bias = gyro.bias_radps + np.cumsum(rng.normal(0, 1, (count, 3)) * (gyro.bias_walk * np.sqrt(steps))[:, None],
                                       axis=0)
    gyro_raw = true_rate @ np.linalg.inv(gyro.matrix).T + bias + rng.normal(0, gyro_noise, (count, 3))
    accel_raw = specific_force @ np.linalg.inv(accel_matrix).T + accel_bias + rng.normal(0, accel_noise, (count, 3))
    return MotionSession(
        stamps_ns=np.round(times * 1e9).astype(np.int64), accel_mps2=accel_raw, gyro_radps=gyro_raw,
        still=tuple(still), gyro=gyro, accel_matrix=accel_matrix, accel_bias_mps2=accel_bias, rate_hz=rate_hz,
        gyro_noise_radps=gyro_noise, accel_noise_mps2=accel_noise)
