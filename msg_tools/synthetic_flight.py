"""A simulated multirotor mission: a person turns the vehicle through orientations on the ground, it
flies for a long time, lands, and is turned again. Pure numpy/scipy (no ROS, nothing of
accel_calibration), vectorised: 40 minutes at 200 Hz take about a second.

In flight the accelerometer reads the specific force f = R^T (a_world + g z_up) of a vehicle whose
thrust axis follows its own acceleration (a multirotor tilts to accelerate) with a slow attitude
wander on top, plus motor vibration: a few rotor harmonics (80-200 Hz, aliased at the sample rate,
their frequencies following the throttle) and broadband noise. The gyro reads the body rate of the
same attitude history plus rotational vibration. Around the flight the motors idle on the ground
for a few seconds (vibration, no motion); the throttle comes up to hover in the second before lift-off
and goes back to idle in the second after touch-down; after disarm the propellers run down.

Times of a flight (from motors start): lift-off at `idle_s`, touch-down at `duration_s - idle_s`,
disarm at `duration_s - spin_down_s`, motors stopped at `duration_s`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.signal import butter, sosfilt
from scipy.spatial.transform import Rotation

from .synthetic_imu import STANDARD_GRAVITY, SensorErrors, SyntheticImu, SyntheticSamples, rotation_with_up

LEVEL = rotation_with_up([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class FlightProfile:
    """What the flight does (SI units; rms values per axis)."""

    duration_s: float = 2400.0  # motors start to motors stopped
    vibration_rms_mps2: float = 0.25  # motor vibration at cruise throttle, per axis
    gyro_vibration_rms_radps: float = 0.03
    harmonics_hz: tuple[float, ...] = (83.0, 124.0, 166.0, 197.0)  # rotor and blade-pass harmonics
    broadband_share: float = 0.3  # of the vibration power that is broadband rather than harmonic
    idle_s: float = 3.0  # motors idling on the ground before take-off and after touch-down
    idle_vibration: float = 0.4  # vibration at idle, as a fraction of cruise
    spool_s: float = 1.0  # throttle from idle to hover before lift-off, and back after touch-down
    spin_down_s: float = 0.3  # after disarm the propellers run down (vibration fading) until motors stop
    wander_deg: float = 2.0  # slow attitude wander (controller error, wind), rms per tilt axis
    gust_rms_mps2: float = 0.3  # the vehicle's own horizontal accelerations from gusts (below ~1 Hz)
    manoeuvre_every_s: float = 40.0  # mean time between manoeuvres (speed up, cruise, slow down)
    manoeuvre_mps: float = 8.0  # largest horizontal speed change of a manoeuvre
    climb_every_s: float = 60.0  # mean time between climbs and descents
    climb_mps: float = 3.0  # largest vertical speed change


@dataclass(frozen=True)
class Mission:
    """A whole recording and where its flight is in it (header-time ns, from 0)."""

    samples: SyntheticSamples
    flight_start_ns: int  # motors start
    flight_end_ns: int  # motors stopped (the propellers' spin-down after disarm is over)
    disarm_ns: int  # motors no longer driven: the spin-down begins
    takeoff_ns: int  # lift-off (the throttle is at hover from spool_s before)
    touchdown_ns: int  # back on the ground (the throttle at idle spool_s after)

    @property
    def in_flight(self) -> np.ndarray:
        t = self.samples.t_ns
        return (t >= self.flight_start_ns) & (t <= self.flight_end_ns)

    def without_flight(self) -> SyntheticSamples:
        """The same recording with every flight sample deleted (the ground parts alone, same stamps)."""
        return _select(self.samples, ~self.in_flight)


def _select(s: SyntheticSamples, mask: np.ndarray) -> SyntheticSamples:
    return SyntheticSamples(t_ns=s.t_ns[mask], accel_raw=s.accel_raw[mask], gyro_raw=s.gyro_raw[mask],
                            temperature_degc=s.temperature_degc[mask], accel_true=s.accel_true[mask],
                            static=s.static[mask])


def _lowpass(rng: np.random.Generator, n: int, rate_hz: float, cutoff_hz: float, rms: float,
             axes: int = 3) -> np.ndarray:
    """Band-limited Gaussian noise (2nd-order Butterworth), scaled to `rms` per axis."""
    if rms == 0.0 or n == 0:
        return np.zeros((n, axes))
    sos = butter(2, cutoff_hz, fs=rate_hz, output="sos")
    x = sosfilt(sos, rng.normal(0.0, 1.0, (n + int(5 * rate_hz / cutoff_hz), axes)), axis=0)[-n:]
    return np.asarray(x * (rms / x.std(axis=0)))


def _smooth_step(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    smoothed: np.ndarray = x * x * (3.0 - 2.0 * x)
    return smoothed


def _legs(rng: np.random.Generator, t: np.ndarray, every_s: float, speed_mps: float, axes: int,
          quiet_head_s: float, quiet_tail_s: float) -> np.ndarray:
    """Accelerations of manoeuvre legs: speed up smoothly (1-3 s) to a random velocity change of up to
    `speed_mps`, hold it for 5-40 s, slow down again as smoothly, at random times and directions. A
    pose cut anywhere in a leg has a net acceleration in it (a climb that starts in one minute and ends
    in the next): that is what makes flight poses wrong."""
    n = len(t)
    out = np.zeros((n, axes))
    if every_s <= 0 or speed_mps == 0 or n < 2:
        return out
    rate = 1.0 / (t[1] - t[0])
    span = t[-1] - quiet_head_s - quiet_tail_s
    count = int(span / every_s) if span > 0 else 0
    for start in np.sort(rng.uniform(quiet_head_s, quiet_head_s + max(span, 0.0), count)):
        ramp, hold = rng.uniform(1.0, 3.0), rng.uniform(5.0, 40.0)
        if start + 2 * ramp + hold > t[-1] - quiet_tail_s:
            continue
        direction = rng.normal(size=axes)
        direction /= np.linalg.norm(direction)
        dv = rng.uniform(0.3, 1.0) * speed_mps
        k = np.arange(int(ramp * rate))
        lobe = dv / ramp * 2.0 * np.sin(np.pi * k / len(k)) ** 2  # integrates to dv over the ramp
        for first, sign in ((int(start * rate), 1.0), (int((start + ramp + hold) * rate), -1.0)):
            stop = min(n, first + len(k))
            out[first:stop] += sign * lobe[: stop - first, None] * direction
    return out


def _quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternions of rotation vectors."""
    angle = np.linalg.norm(rotvec, axis=1)
    half = 0.5 * angle
    # sin(half)/angle, with its limit 0.5 for tiny angles
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(angle > 1e-8, np.sin(half) / angle, 0.5 - angle**2 / 48.0)
    return np.column_stack([rotvec * scale[:, None], np.cos(half)])


def _quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton products p q, rows of (x, y, z, w): q applied first, then p."""
    pv, pw, qv, qw = p[:, :3], p[:, 3:], q[:, :3], q[:, 3:]
    return np.column_stack([pw * qv + qw * pv + np.cross(pv, qv), pw * qw - np.sum(pv * qv, axis=1, keepdims=True)])


def _quat_conjugate(q: np.ndarray) -> np.ndarray:
    return np.column_stack([-q[:, :3], q[:, 3:]])


def _rotate_into_body(body_to_world: np.ndarray, world: np.ndarray) -> np.ndarray:
    """world vectors expressed in the body frame: R^T v (the inverse rotation)."""
    v, w = -body_to_world[:, :3], body_to_world[:, 3:]
    t = 2.0 * np.cross(v, world)
    return np.asarray(world + w * t + np.cross(v, t))


def _quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    q = np.where(q[:, 3:] < 0.0, -q, q)  # the short way round
    sin_half = np.linalg.norm(q[:, :3], axis=1)
    angle = 2.0 * np.arctan2(sin_half, q[:, 3])
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(sin_half > 1e-12, angle / sin_half, 2.0)
    return np.asarray(q[:, :3] * scale[:, None])


def simulate_flight(errors: SensorErrors, profile: FlightProfile = FlightProfile(), *, rate_hz: float = 200.0,
                    gravity: float = STANDARD_GRAVITY, temperature_degc: float = 25.0, seed: int = 0,
                    heading_deg: float = 0.0) -> SyntheticSamples:
    """Motors start (level on the ground), idle, take off, fly, land level, idle, motors stop.
    Stream time from 0; `static` is False throughout (nothing of a flight is a still pose)."""
    rng = np.random.default_rng(seed)
    n = int(round(profile.duration_s * rate_hz))
    t = np.arange(n) / rate_hz
    idle = profile.idle_s
    airborne_s = profile.duration_s - 2 * idle
    if airborne_s <= 20.0 or profile.idle_s < profile.spool_s + profile.spin_down_s:
        raise ValueError("a flight needs duration_s > 2 idle_s + 20 s and idle_s >= spool_s + spin_down_s")
    # 0 on the ground, 1 in the air, with 5 s lift-off and touch-down blends.
    airborne = _smooth_step((t - idle) / 5.0) * _smooth_step((profile.duration_s - idle - t) / 5.0)

    # World-frame acceleration of the vehicle: gusts and manoeuvres (horizontal), climbs (vertical),
    # and a take-off climb / landing descent whose velocity changes cancel.
    horizontal = _lowpass(rng, n, rate_hz, 0.8, profile.gust_rms_mps2, 2)
    horizontal += _legs(rng, t, profile.manoeuvre_every_s, profile.manoeuvre_mps, 2, idle + 10, idle + 10)
    vertical = _lowpass(rng, n, rate_hz, 0.5, 0.3 * profile.gust_rms_mps2, 1)[:, 0]
    vertical += _legs(rng, t, profile.climb_every_s, profile.climb_mps, 1, idle + 10, idle + 10)[:, 0]
    for centre, sign in ((idle + 3.0, 1.0), (profile.duration_s - idle - 4.0, -1.0)):
        u = (t - centre) / 3.0  # climb out (up, then level off) and descend (down, then flare) over 6 s
        vertical += sign * 1.5 * np.where(np.abs(u) < 1.0, np.sin(np.pi * (u + 1.0)), 0.0)
    accel_world = np.column_stack([horizontal, vertical]) * airborne[:, None]

    # Attitude: thrust axis along the required specific force, a slow wander about it, a slow heading.
    thrust = accel_world + np.array([0.0, 0.0, gravity])
    z_axis = thrust / np.linalg.norm(thrust, axis=1)[:, None]
    axis = np.cross([0.0, 0.0, 1.0], z_axis)
    sin_angle = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(sin_angle, z_axis[:, 2])
    with np.errstate(invalid="ignore", divide="ignore"):
        rotvec = np.where(sin_angle[:, None] > 1e-12, axis / sin_angle[:, None] * angle[:, None], 0.0)
    wander = _lowpass(rng, n, rate_hz, 0.15, np.radians(profile.wander_deg), 2) * airborne[:, None]
    heading_rate = _lowpass(rng, n, rate_hz, 0.05, 0.05, 1)[:, 0] * airborne
    heading = np.radians(heading_deg) + np.cumsum(heading_rate) / rate_hz
    # Body-to-world attitude: tilt to the thrust, heading about it, wander in the body (quaternions in
    # numpy: scipy's Rotation products cost ~0.4 s each at this length).
    yaw = np.column_stack([np.zeros((n, 2)), heading])
    attitude = _quat_multiply(_quat_multiply(_quat_from_rotvec(rotvec), _quat_from_rotvec(yaw)),
                              _quat_from_rotvec(np.column_stack([wander, np.zeros(n)])))
    accel_true = _rotate_into_body(attitude, accel_world + np.array([0.0, 0.0, gravity]))
    # Body rate: the rotation between consecutive attitudes, over the sample period.
    gyro_true = np.zeros((n, 3))
    if n > 1:
        gyro_true[1:] = _quat_to_rotvec(_quat_multiply(_quat_conjugate(attitude[:-1]), attitude[1:])) * rate_hz

    # Motor vibration: harmonics following the throttle (thrust), and broadband; idle on the ground.
    throttle = np.linalg.norm(thrust, axis=1) / gravity
    touchdown = profile.duration_s - idle
    spool = profile.spool_s
    throttle_up = _smooth_step((t - idle + spool) / spool) * _smooth_step((touchdown + spool - t) / spool)
    level = profile.idle_vibration + (1.0 - profile.idle_vibration) * throttle_up
    running = _smooth_step(t / 0.1) * _smooth_step((profile.duration_s - t) / profile.spin_down_s)
    envelope = level * running
    vibration = np.zeros((n, 3))
    gyro_vibration = np.zeros((n, 3))
    rpm = np.sqrt(throttle) * (1.0 + 0.02 * np.sin(2 * np.pi * 0.03 * t + rng.uniform(0, 2 * np.pi)))
    for f in profile.harmonics_hz:
        phase = 2 * np.pi * np.cumsum(f * rpm) / rate_hz
        for target in (vibration, gyro_vibration):
            amplitude = rng.uniform(0.3, 1.0, 3)
            offset = rng.uniform(0, 2 * np.pi, 3)
            target += amplitude * np.sin(phase[:, None] + offset)
    harmonic_share = np.sqrt(1.0 - profile.broadband_share)
    broadband_share = np.sqrt(profile.broadband_share)
    for target, rms in ((vibration, profile.vibration_rms_mps2), (gyro_vibration, profile.gyro_vibration_rms_radps)):
        target *= harmonic_share * rms / target.std(axis=0)
        target += rng.normal(0.0, broadband_share * rms, (n, 3))
        target *= envelope[:, None]

    temperature = np.full(n, float(temperature_degc))
    accel_raw = (errors.raw_from_true(accel_true + vibration, temperature)
                 + rng.normal(0.0, errors.noise_mps2, (n, 3)))
    gyro_raw = gyro_true + gyro_vibration + errors.gyro_bias_radps + rng.normal(0.0, errors.gyro_noise_radps, (n, 3))
    return SyntheticSamples(t_ns=np.round(t * 1e9).astype(np.int64), accel_raw=accel_raw, gyro_raw=gyro_raw,
                            temperature_degc=temperature, accel_true=accel_true, static=np.zeros(n, dtype=bool))


def _shifted(s: SyntheticSamples, offset_ns: int) -> SyntheticSamples:
    return replace(s, t_ns=s.t_ns + offset_ns)


def _concatenate(parts: list[SyntheticSamples]) -> SyntheticSamples:
    return SyntheticSamples(*(np.concatenate([getattr(p, name) for p in parts]) for name in
                              ("t_ns", "accel_raw", "gyro_raw", "temperature_degc", "accel_true", "static")))


def ground_flight_ground(errors: SensorErrors, ground: list[Rotation], *, flight: FlightProfile = FlightProfile(),
                         after_landing: list[Rotation] | None = None, dwell_s: float = 3.0, move_s: float = 1.5,
                         rate_hz: float = 200.0, temperature_degc: float = 25.0, seed: int = 0) -> Mission:
    """A person turns the vehicle through `ground` (held `dwell_s` each), sets it down level, it flies
    (`flight`), lands level and, when `after_landing` is given, sits level for one dwell and is then
    turned through those orientations too. One stream, stamps from 0, samples every 1/rate_hz."""
    period_ns = int(round(1e9 / rate_hz))
    before = SyntheticImu(errors, [*ground, LEVEL], dwell_s=dwell_s, move_s=move_s, rate_hz=rate_hz,
                          temperature_degc=temperature_degc, seed=seed).samples()
    airborne = simulate_flight(errors, flight, rate_hz=rate_hz, temperature_degc=temperature_degc, seed=seed + 1)
    flight_start = int(before.t_ns[-1]) + period_ns
    parts = [before, _shifted(airborne, flight_start)]
    flight_end = flight_start + int(airborne.t_ns[-1])
    disarm = flight_end - int(flight.spin_down_s * 1e9)
    takeoff = flight_start + int(flight.idle_s * 1e9)
    touchdown = flight_start + int((flight.duration_s - flight.idle_s) * 1e9)
    if after_landing is not None:
        after = SyntheticImu(errors, [LEVEL, *after_landing], dwell_s=dwell_s, move_s=move_s, rate_hz=rate_hz,
                             temperature_degc=temperature_degc, seed=seed + 2).samples()
        parts.append(_shifted(after, flight_end + period_ns))
    return Mission(_concatenate(parts), flight_start, flight_end, disarm, takeoff, touchdown)
