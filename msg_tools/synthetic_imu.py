"""A simulated accelerometer + gyro with known errors, turned by hand through a sequence of poses.

Pure numpy/scipy (no ROS). Static dwells are joined by smooth rotations (slerp with smooth-step
timing); during a move the specific force is gravity rotated into the body frame (hand-held
turns: translation ignored) and the gyro reads the body rate. Raw output follows the project's
convention inverted: a_raw = M^-1 a_true + b (+ temperature drift) + noise.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

STANDARD_GRAVITY = 9.80665
FACE_DIRECTIONS = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 0, -1], [-1, 0, 0], [0, -1, 0]], dtype=float)


@dataclass(frozen=True)
class SensorErrors:
    """The truth a calibration should recover (SI units)."""

    bias_mps2: np.ndarray = field(default_factory=lambda: np.zeros(3))
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))  # M, a_true = M (a_raw - b)
    noise_mps2: float = 0.0  # white noise per sample per axis
    gyro_bias_radps: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_noise_radps: float = 0.0
    # Temperature drift about t_ref_degc: bias b(T) = b + sum_k bias_drift[k-1] (T - T_ref)^k (per axis,
    # m/s^2/degC^k); scale of the raw output (1 + sum_k scale_drift[k-1] (T - T_ref)^k) per axis.
    bias_drift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    scale_drift: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    t_ref_degc: float = 25.0

    def raw_from_true(self, accel_true_mps2: ArrayLike, temperature_degc: ArrayLike | None = None) -> np.ndarray:
        raw: np.ndarray = np.asarray(accel_true_mps2, dtype=float) @ np.linalg.inv(self.matrix).T
        if temperature_degc is not None and (len(self.bias_drift) or len(self.scale_drift)):
            dt = (np.asarray(temperature_degc, dtype=float) - self.t_ref_degc).reshape(-1, 1)
            scale = np.ones_like(raw)
            for k, row in enumerate(self.scale_drift, start=1):
                scale = scale + row * dt**k
            raw = raw * scale
            bias = self.bias_mps2 + sum(row * dt**k for k, row in enumerate(self.bias_drift, start=1))
            drifted: np.ndarray = raw + bias
            return drifted
        biased: np.ndarray = raw + self.bias_mps2
        return biased

    @classmethod
    def mpu6050_like(cls, rng: np.random.Generator, noise_mps2: float = 0.04) -> SensorErrors:
        """A badly calibrated MPU-6050-class part: bias 20-50 mg, scale 1-3 %, non-orthogonality ~0.5-1 deg,
        ~4 mg noise per sample, gyro bias ~1 deg/s."""
        bias = rng.uniform(0.2, 0.5, 3) * rng.choice([-1.0, 1.0], 3)
        scale = 1.0 + rng.uniform(0.01, 0.03, 3) * rng.choice([-1.0, 1.0], 3)
        matrix = np.diag(scale)
        matrix[1, 0], matrix[2, 0], matrix[2, 1] = rng.uniform(-0.015, 0.015, 3)
        return cls(
            bias_mps2=bias,
            matrix=matrix,
            noise_mps2=noise_mps2,
            gyro_bias_radps=rng.normal(0.0, 0.02, 3),
            gyro_noise_radps=0.002,
        )


def rotation_with_up(direction: ArrayLike) -> Rotation:
    """A body->world rotation under which the body vector `direction` points up (reads +g)."""
    direction = np.asarray(direction, dtype=float)
    rotation, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [direction / np.linalg.norm(direction)])
    return rotation


def spread_orientations(count: int, rng: np.random.Generator) -> list[Rotation]:
    """The six faces first, then random orientations: well spread for a sphere fit."""
    rotations = [rotation_with_up(d) for d in FACE_DIRECTIONS[:count]]
    while len(rotations) < count:
        rotations.append(Rotation.random(random_state=rng))
    return rotations


@dataclass(frozen=True)
class SyntheticSamples:
    t_ns: np.ndarray  # (N,) stream time from 0
    accel_raw: np.ndarray  # (N, 3) m/s^2
    gyro_raw: np.ndarray  # (N, 3) rad/s
    temperature_degc: np.ndarray  # (N,)
    accel_true: np.ndarray  # (N, 3) the true specific force
    static: np.ndarray  # (N,) bool, True inside a dwell


class SyntheticImu:
    """`rotations` are held for `dwell_s` each and joined by `move_s` turns, at `rate_hz`.

    `temperature_degc` is a number or a function of stream time in seconds.
    """

    def __init__(
        self,
        errors: SensorErrors,
        rotations: list[Rotation],
        *,
        dwell_s: float = 3.0,
        move_s: float = 1.5,
        rate_hz: float = 200.0,
        gravity: float = STANDARD_GRAVITY,
        temperature_degc: float | Callable[[np.ndarray], np.ndarray] = 25.0,
        seed: int = 0,
    ) -> None:
        if len(rotations) < 1 or dwell_s <= 0 or move_s <= 0 or rate_hz <= 0:
            raise ValueError("need at least one rotation and positive dwell_s, move_s, rate_hz")
        self.errors = errors
        self.rotations = list(rotations)
        self.dwell_s, self.move_s, self.rate_hz, self.gravity = dwell_s, move_s, rate_hz, gravity
        self.temperature = (temperature_degc if callable(temperature_degc)
                            else (lambda t, c=float(temperature_degc): np.full_like(t, c)))
        self.seed = seed

    @property
    def duration_s(self) -> float:
        return len(self.rotations) * self.dwell_s + (len(self.rotations) - 1) * self.move_s

    def static_intervals(self) -> list[tuple[int, int, np.ndarray]]:
        """(start_ns, end_ns, true specific force in the body frame) of each dwell."""
        out = []
        for i, rotation in enumerate(self.rotations):
            start = i * (self.dwell_s + self.move_s)
            up = rotation.inv().apply([0.0, 0.0, self.gravity])
            out.append((int(start * 1e9), int((start + self.dwell_s) * 1e9), up))
        return out

    def samples(self) -> SyntheticSamples:
        rng = np.random.default_rng(self.seed)
        n = int(round(self.duration_s * self.rate_hz))
        t = np.arange(n) / self.rate_hz
        period = self.dwell_s + self.move_s
        index = np.minimum((t // period).astype(int), len(self.rotations) - 1)
        phase = t - index * period
        moving = (phase >= self.dwell_s) & (index < len(self.rotations) - 1)
        world_up = np.array([0.0, 0.0, self.gravity])
        accel_true = np.empty((n, 3))
        gyro_true = np.zeros((n, 3))
        for i, rotation in enumerate(self.rotations):
            still = (index == i) & ~moving
            accel_true[still] = rotation.inv().apply(world_up)
            here = (index == i) & moving
            if not here.any():
                continue
            # R(s) = R_i exp(s * log(R_i^-1 R_{i+1})): the body rate is s'(t) times that fixed body vector.
            relative = (rotation.inv() * self.rotations[i + 1]).as_rotvec()
            u = (phase[here] - self.dwell_s) / self.move_s
            s = u * u * (3.0 - 2.0 * u)
            ds_dt = 6.0 * u * (1.0 - u) / self.move_s
            current = rotation * Rotation.from_rotvec(s[:, None] * relative)
            accel_true[here] = current.inv().apply(world_up)
            gyro_true[here] = ds_dt[:, None] * relative
        temperature = np.asarray(self.temperature(t), dtype=float)
        e = self.errors
        accel_raw = e.raw_from_true(accel_true, temperature) + rng.normal(0.0, e.noise_mps2, (n, 3))
        gyro_raw = gyro_true + e.gyro_bias_radps + rng.normal(0.0, e.gyro_noise_radps, (n, 3))
        return SyntheticSamples(
            t_ns=np.round(t * 1e9).astype(np.int64),
            accel_raw=accel_raw,
            gyro_raw=gyro_raw,
            temperature_degc=temperature,
            accel_true=accel_true,
            static=~moving,
        )
