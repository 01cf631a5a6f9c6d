"""Simulated warm-ups with a known truth: an IMU sitting still while it warms (a fast rise, then a slow
one), its biases following smooth curves no polynomial follows exactly (tanh and exponential shapes:
tens of mg and a few mrad/s over 30 degC), MPU-6050-class noise at 200 Hz (400 ug/sqrt(Hz), 0.005
deg/s/sqrt(Hz)), a temperature register quantised as the part's (1/340 degC), optionally lagging the die."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from accel_calibration.core.calibration import Calibration
from accel_calibration.core.units import MG, STANDARD_GRAVITY
from accel_calibration.core.warmup import WarmupRecording

RATE_HZ = 200.0
ACCEL_NOISE_MPS2 = 4.0 * MG  # 400 ug/sqrt(Hz) over ~100 Hz
GYRO_NOISE_RADPS = 0.87e-3  # 0.005 deg/s/sqrt(Hz) over ~100 Hz
REGISTER_DEGC = 1.0 / 340.0


@dataclass(frozen=True)
class WarmupTruth:
    """One IMU's true drift shapes (amplitudes per axis, m/s^2 and rad/s) and its calibration in force:
    raw = M^-1 a_true + b + drift(T), w_raw = G^-1 w_true + b_g + drift_g(T)."""

    accel_amplitude: np.ndarray  # (3,)
    accel_centre_degc: np.ndarray  # (3,)
    gyro_amplitude: np.ndarray  # (3,)
    gyro_centre_degc: np.ndarray  # (3,)
    calibration: Calibration

    def accel_drift(self, degc: np.ndarray) -> np.ndarray:
        x = np.asarray(degc, dtype=float).reshape(-1, 1)
        shape = np.tanh((x - self.accel_centre_degc) / 6.0)
        shape[:, 1] = 1.0 - np.exp(-(x[:, 0] - 5.0) / 9.0)  # y: an exponential approach
        result: np.ndarray = self.accel_amplitude * shape
        return result

    def gyro_drift(self, degc: np.ndarray) -> np.ndarray:
        x = np.asarray(degc, dtype=float).reshape(-1, 1)
        shape = np.tanh((x - self.gyro_centre_degc) / 5.0)
        shape[:, 2] = np.exp(-(x[:, 0] - 5.0) / 12.0)
        result: np.ndarray = self.gyro_amplitude * shape
        return result


def two_imus() -> tuple[WarmupTruth, WarmupTruth]:
    first = WarmupTruth(np.array([12.0, -20.0, 15.0]) * MG, np.array([30.0, 0.0, 25.0]),
                        np.array([2.0e-3, -1.5e-3, 2.5e-3]), np.array([28.0, 33.0, 0.0]),
                        Calibration(bias=np.array([0.21, -0.34, 0.15]),
                                    matrix=np.array([[1.012, 0.0, 0.0], [0.008, 0.991, 0.0], [-0.006, 0.011, 1.009]]),
                                    gyro_bias_radps=np.array([0.01, -0.02, 0.005])))
    second = WarmupTruth(np.array([-18.0, 10.0, -22.0]) * MG, np.array([34.0, 0.0, 29.0]),
                         np.array([-1.2e-3, 3.0e-3, -2.0e-3]), np.array([24.0, 36.0, 0.0]),
                         Calibration(bias=np.array([-0.12, 0.08, -0.3]),
                                     matrix=np.array([[0.993, 0.0, 0.0], [-0.01, 1.015, 0.0], [0.004, -0.007, 0.988]]),
                                     gyro_bias_radps=np.array([-0.004, 0.012, -0.03])))
    return first, second


@dataclass(frozen=True)
class Heating:
    """T(t) = end - (end - start) exp(-t / tau_s) for `minutes`; then, when cool_minutes, back towards
    `start` with the same time constant. The register lags the die by `lag_s` (first order)."""

    start_degc: float = 15.0
    end_degc: float = 45.0
    tau_s: float = 200.0
    minutes: float = 15.0
    cool_minutes: float = 0.0
    lag_s: float = 0.0


def die_temperature(t_s: np.ndarray, heating: Heating) -> np.ndarray:
    h = heating
    warm = h.end_degc - (h.end_degc - h.start_degc) * np.exp(-t_s / h.tau_s)
    if not h.cool_minutes:
        return warm
    turn = h.minutes * 60.0
    top = h.end_degc - (h.end_degc - h.start_degc) * np.exp(-turn / h.tau_s)
    cool = h.start_degc + (top - h.start_degc) * np.exp(-(t_s - turn) / h.tau_s)
    return np.where(t_s < turn, warm, cool)


def warmup_recording(truth: WarmupTruth, rng: np.random.Generator, heating: Heating = Heating(),
                     gravity_direction: tuple[float, float, float] = (0.0, 0.0, 1.0),
                     accel_turn_on: np.ndarray | None = None, gyro_turn_on: np.ndarray | None = None,
                     step: tuple[float, np.ndarray, np.ndarray] | None = None,
                     bump: tuple[float, float, np.ndarray] | None = None, rate_hz: float = RATE_HZ) -> WarmupRecording:
    """A still warm-up's raw samples. `*_turn_on`: this power-on's constant offset; `step`: (time s, accel
    jump, gyro jump) lasting from then on; `bump`: (start s, duration s, accel jump) that comes back."""
    t = np.arange(0.0, (heating.minutes + heating.cool_minutes) * 60.0, 1.0 / rate_hz)
    die = die_temperature(t, heating)
    register = die
    if heating.lag_s:
        share = 1.0 / (rate_hz * heating.lag_s)
        register = lfilter([share], [1.0, share - 1.0], die - die[0]) + die[0]
    register = np.round(register / REGISTER_DEGC) * REGISTER_DEGC
    calibration = truth.calibration
    true_accel = STANDARD_GRAVITY * np.asarray(gravity_direction, dtype=float) / np.linalg.norm(gravity_direction)
    accel = np.linalg.solve(calibration.matrix, true_accel) + calibration.bias + truth.accel_drift(die)
    gyro = np.zeros((len(t), 3)) + (calibration.gyro_bias_radps if calibration.gyro_bias_radps is not None else 0.0)
    gyro = gyro + truth.gyro_drift(die)
    if accel_turn_on is not None:
        accel = accel + accel_turn_on
    if gyro_turn_on is not None:
        gyro = gyro + gyro_turn_on
    if step is not None:
        after = t >= step[0]
        accel[after] += step[1]
        gyro[after] += step[2]
    if bump is not None:
        inside = (t >= bump[0]) & (t < bump[0] + bump[1])
        accel[inside] += bump[2]
    accel = accel + rng.normal(0.0, ACCEL_NOISE_MPS2, accel.shape)
    gyro = gyro + rng.normal(0.0, GYRO_NOISE_RADPS, gyro.shape)
    return WarmupRecording(np.round(t * 1e9).astype(np.int64), accel, gyro, register)


def true_accel_curve(truth: WarmupTruth, degc: np.ndarray, reference_degc: float) -> np.ndarray:
    """The accelerometer's drift in the corrected frame, zero at the reference: what a warm-up's curve
    should be (M times the raw drift)."""
    drift = truth.accel_drift(degc) - truth.accel_drift(np.array([reference_degc]))
    result: np.ndarray = drift @ truth.calibration.matrix.T
    return result


def true_gyro_bias(truth: WarmupTruth, degc: np.ndarray) -> np.ndarray:
    """The corrected gyro's bias at each temperature (the calibration in force has no gyro matrix)."""
    return truth.gyro_drift(degc)


def temperature_errors(calibration: Calibration, truth: WarmupTruth, degc: np.ndarray,
                       gravity_direction: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> tuple[float, float]:
    """Worst temperature error of `calibration` over `degc` on noise-free samples of `truth` at rest: the
    accelerometer's change from its output at the calibration's reference (one orientation does not see
    the constant), mg; the gyro's whole output (at rest it reads zero), mrad/s."""
    assert calibration.temperature is not None
    direction = np.asarray(gravity_direction, dtype=float) / np.linalg.norm(gravity_direction)
    still = np.linalg.solve(truth.calibration.matrix, STANDARD_GRAVITY * direction) + truth.calibration.bias
    temps = np.append(np.asarray(degc, dtype=float), calibration.temperature.reference_degc)
    accel = calibration.apply(still + truth.accel_drift(temps), temps)
    gyro_bias = truth.calibration.gyro_bias_radps if truth.calibration.gyro_bias_radps is not None else 0.0
    gyro = calibration.apply_gyro(gyro_bias + truth.gyro_drift(temps), temps)
    return float(np.abs(accel[:-1] - accel[-1]).max() / MG), float(np.abs(gyro).max() * 1e3)


def warmup_board(seed: int, heating: Heating = Heating(), rate_hz: float = 50.0):
    """Both IMUs of `two_imus` on one board warming up still and level, as test/helpers/autopilot_logs writes
    a log of it (a stale calibration in force, the board turned 90 deg in yaw): its Board and the truths."""
    from msg_tools.synthetic_imu import SensorErrors

    from helpers.autopilot_logs import START_US, Board, Imu

    rng = np.random.default_rng(seed)
    imus, recordings = [], []
    for truth in two_imus():
        recording = warmup_recording(truth, rng, heating, rate_hz=rate_hz)
        recordings.append(recording)
        imus.append(Imu(SensorErrors(), recording.accel_mps2, recording.gyro_radps,
                        stale_offset=rng.uniform(-0.3, 0.3, 3), stale_scale=1.0 + rng.uniform(-0.03, 0.03, 3),
                        gyro_offset=rng.normal(0.0, 0.01, 3), gyro_bias=np.zeros(3)))
    t_us = START_US + recordings[0].t_ns // 1000
    up = np.tile([0.0, 0.0, STANDARD_GRAVITY], (len(t_us), 1))
    return Board(t_us, recordings[0].temperature_degc, imus, up), two_imus()


ARDUPILOT_REFERENCE_DEGC = 35.0  # TCal's fixed reference (AP_InertialSensor_tempcal.cpp)
ARDUPILOT_SCALE = 1e6  # INS_TCALn_* coefficients are stored x 1e6


def read_params(path: Path) -> dict[str, float]:
    """NAME VALUE (the peer's .parm) or NAME,VALUE (Mission Planner's .param, ours) per line."""
    values = {}
    for line in path.read_text().splitlines():
        parts = line.replace(",", " ").split()
        if len(parts) == 2 and not line.startswith("#"):
            values[parts[0]] = float(parts[1])
    return values


def ardupilot_applied(params: dict[str, float], instance: int, raw: np.ndarray, gyro_raw: np.ndarray,
                      degc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What ArduPilot publishes for these raw samples: TCal::correct_sensor, then offsets (and scales), then
    the board rotation (AHRS_ORIENTATION 2: yaw 90)."""
    n = instance + 1
    suffix = "" if instance == 0 else str(n)
    tcal = f"INS_TCAL{n}_"
    accel, gyro = raw.copy(), gyro_raw.copy()
    if params.get(tcal + "ENABLE", 0) == 1:
        low, high = params.get(tcal + "TMIN", 0.0), params.get(tcal + "TMAX", 70.0)
        at = np.clip(degc, low, high)[:, None] - ARDUPILOT_REFERENCE_DEGC
        for kind, values, caltemp in (("ACC", accel, f"INS_ACC{n}_CALTEMP"), ("GYR", gyro, f"INS_GYR{n}_CALTEMP")):
            rows = np.array([[params.get(f"{tcal}{kind}{k}_{a}", 0.0) for a in "XYZ"] for k in (1, 2, 3)])
            rows = rows / ARDUPILOT_SCALE
            zero = np.clip(params.get(caltemp, -300.0), low, high) - ARDUPILOT_REFERENCE_DEGC
            values -= sum(rows[k] * at ** (k + 1) for k in range(3)) - sum(rows[k] * zero ** (k + 1) for k in range(3))
    offset = np.array([params[f"INS_ACC{suffix}OFFS_{a}"] for a in "XYZ"])
    scale = np.array([params[f"INS_ACC{suffix}SCAL_{a}"] for a in "XYZ"])
    gyro_offset = np.array([params[f"INS_GYR{suffix}OFFS_{a}"] for a in "XYZ"])
    from helpers.autopilot_logs import YAW_90

    return ((accel - offset) * scale) @ YAW_90.T, (gyro - gyro_offset) @ YAW_90.T


def read_px4_params(path: Path) -> dict[str, float]:
    """QGroundControl's tab-separated parameter file: vehicle, component, name, value, type."""
    values = {}
    for line in path.read_text().splitlines():
        parts = line.split("\t")
        if len(parts) == 5 and not line.startswith("#"):
            values[parts[2]] = float(parts[3])
    return values


def px4_applied(params: dict[str, float], slot: int, raw: np.ndarray, gyro_raw: np.ndarray,
                degc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What PX4 publishes for these raw samples in the sensor's axes (the board rotation left out): the
    thermal offset X0 + X1 dT + X2 dT^2 + X3 dT^3, dT = clamp(T, TMIN, TMAX) - TREF, where its switch is on,
    then Accelerometer::Correct's (raw - offset) * scale, Gyroscope::Correct's raw - offset."""
    out = []
    for kind, values, offset_names, scale_names in (
            ("A", raw, [f"CAL_ACC{slot}_{a}OFF" for a in "XYZ"], [f"CAL_ACC{slot}_{a}SCALE" for a in "XYZ"]),
            ("G", gyro_raw, [f"CAL_GYRO{slot}_{a}OFF" for a in "XYZ"], None)):
        values = values.copy()
        tc = f"TC_{kind}{slot}_"
        if params.get(f"TC_{kind}_ENABLE", 0) == 1:
            dt = np.clip(degc, params[tc + "TMIN"], params[tc + "TMAX"])[:, None] - params[tc + "TREF"]
            rows = np.array([[params[f"{tc}X{k}_{axis}"] for axis in range(3)] for k in range(4)])
            values -= sum(rows[k] * dt**k for k in range(4))
        values -= np.array([params[name] for name in offset_names])
        if scale_names is not None:
            values *= np.array([params[name] for name in scale_names])
        out.append(values)
    return out[0], out[1]


def turned_then_warmed(truth: WarmupTruth, seed: int, held_degc: float = 30.0,
                       rate_hz: float = 100.0) -> tuple[WarmupRecording, WarmupRecording, np.random.Generator]:
    """A person's 16 orientations at `held_degc` (2.5 s each), then the sensor still and level while it
    warms for 8 minutes from there: (the turns, the warm-up starting 1 s after them, the generator after
    both, for the checks' own orientations)."""
    from msg_tools.synthetic_imu import SensorErrors, SyntheticImu, spread_orientations

    rng = np.random.default_rng(seed)
    c = truth.calibration
    assert c.gyro_bias_radps is not None
    errors = SensorErrors(bias_mps2=c.bias + truth.accel_drift(np.array([held_degc]))[0], matrix=c.matrix,
                          noise_mps2=0.02, gyro_noise_radps=1e-3,
                          gyro_bias_radps=c.gyro_bias_radps + truth.gyro_drift(np.array([held_degc]))[0])
    turned = SyntheticImu(errors, spread_orientations(16, rng), dwell_s=2.5, move_s=1.0, rate_hz=rate_hz, seed=seed,
                          temperature_degc=held_degc).samples()
    warm = warmup_recording(truth, rng, Heating(start_degc=held_degc, tau_s=150.0, minutes=8.0), rate_hz=rate_hz)
    turns = WarmupRecording(turned.t_ns, turned.accel_raw, turned.gyro_raw, turned.temperature_degc)
    later = WarmupRecording(warm.t_ns + turned.t_ns[-1] + 10**9, warm.accel_mps2, warm.gyro_radps,
                            warm.temperature_degc)
    return turns, later, rng
