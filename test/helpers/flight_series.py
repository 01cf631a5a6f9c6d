"""Per-flight evidence of a fleet's IMUs simulated cheaply (no log written): the z reading of each flight's
still moments on the ground (bias z or scale z at 1 g, against the calibration in force) with check's
sigma, a scatter between flights (the ground, the temperature, the parking spot) beyond it, and a known
change: steady, a steady drift per flight, or a step."""
from __future__ import annotations

import json

import numpy as np

from accel_calibration.io.flight_history import EvidenceRecord

from helpers.flight_logs import ALL_DEVICES, MG
from helpers.history_records import DAY_NS, START_NS

SIGMA_MPS2 = 0.015 * MG  # check's sigma of one flight's ground poses (measured on the simulated logs)
SCATTER_MPS2 = 0.5 * MG  # between flights, beyond it (an assumption: what a parked vehicle's z varies by)
IN_FORCE = "CAL_ACC0_OFF/SCALE, SENS_BOARD_ROT 0 (offsets +0.1000 -0.2000 +0.3000 m/s^2, scales 1.0 1.0 1.0)"


def z_series(seed: int, flights: int, drift_mg_per_flight: float = 0.0, drift_from: int = 0,
             step_mg: float = 0.0, step_at: int | None = None) -> np.ndarray:
    rng = np.random.default_rng(seed)
    z = rng.normal(0.0, 0.3, 1)[0] * MG + rng.normal(0.0, SCATTER_MPS2, flights) + rng.normal(0.0, SIGMA_MPS2, flights)
    index = np.arange(flights)
    z += np.where(index >= drift_from, (index - drift_from + 1) * drift_mg_per_flight * MG, 0.0)
    if step_at is not None:
        z += np.where(index >= step_at, step_mg * MG, 0.0)
    return z


def rows(vehicle: str, imu: int, z: np.ndarray, hour: int = 10) -> list[EvidenceRecord]:
    """The series as the fleet writes it: a row per flight, one flight a day at `hour`:14 UTC."""
    return [EvidenceRecord(recording_id=f"{vehicle}-{imu}-{i:04d}", path=f"/fleet/{vehicle}/{i:04d}.ulg",
                           vehicle=vehicle, sensor=f"px4 device {ALL_DEVICES[imu]}", status="evidence", imu=imu,
                           device=str(ALL_DEVICES[imu]), start_ns=START_NS + i * DAY_NS + (hour * 60 + 14) * 60 * 10**9,
                           poses=1, verdict="cannot tell", in_force=IN_FORCE, z_mps2=float(value),
                           z_sigma_mps2=SIGMA_MPS2,
                           changes=json.dumps({"bias z or scale z": [float(value), SIGMA_MPS2]}))
            for i, value in enumerate(z)]


# In flight, per flight: the filter's settled accel bias (its own sigma, and a scatter between flights: the
# turn-on bias differs from power-up to power-up) and an IMU's mean difference from its siblings.
ESTIMATOR_SIGMA_MPS2 = 0.15 * MG
ESTIMATOR_SCATTER_MPS2 = 0.5 * MG
GYRO_SIGMA_RADPS, GYRO_SCATTER_RADPS = 3e-5, 2e-4
AGREEMENT_SIGMA_MPS2, AGREEMENT_SCATTER_MPS2 = 0.05 * MG, 0.1 * MG


def axis_series(seed: int, flights: int, sigma: float, scatter: float, change_per_flight: float = 0.0,
                change_from: int = 0, step: float = 0.0, step_at: int | None = None) -> np.ndarray:
    """(flights, 3): a constant per axis, the scatter and sigma per flight, and a known change on z."""
    rng = np.random.default_rng(seed)
    values = rng.normal(0.0, 2.0 * scatter, 3) + rng.normal(0.0, scatter, (flights, 3)) + rng.normal(0.0, sigma,
                                                                                                    (flights, 3))
    index = np.arange(flights)
    values[:, 2] += np.where(index >= change_from, (index - change_from + 1) * change_per_flight, 0.0)
    if step_at is not None:
        values[:, 2] += np.where(index >= step_at, step, 0.0)
    return values


def with_in_flight(records: list[EvidenceRecord], estimator: np.ndarray | None = None,
                   agreement: np.ndarray | None = None, against: str = "IMU 1 (device 1310988)", siblings: int = 2,
                   seed: int = 0) -> list[EvidenceRecord]:
    """The rows with the in-flight evidence as the fleet stores it (JSON), a gyro bias beside the accel's."""
    import dataclasses

    gyro = axis_series(seed + 1000, len(records), GYRO_SIGMA_RADPS, GYRO_SCATTER_RADPS)
    out = []
    for i, record in enumerate(records):
        said: dict[str, str | None] = {}
        if estimator is not None:
            said["estimator"] = json.dumps({
                "source": "PX4 estimator_sensor_bias", "samples": 100, "accel": list(map(float, estimator[i])),
                "accel_sigma": [ESTIMATOR_SIGMA_MPS2] * 3, "gyro": list(map(float, gyro[i])),
                "gyro_sigma": [GYRO_SIGMA_RADPS] * 3})
        if agreement is not None:
            said["agreement"] = json.dumps({
                "against": against, "siblings": siblings, "seconds": 300, "accel": list(map(float, agreement[i])),
                "accel_sigma": [AGREEMENT_SIGMA_MPS2] * 3, "gyro": [0.0, 0.0, 0.0],
                "gyro_sigma": [GYRO_SIGMA_RADPS] * 3})
        out.append(dataclasses.replace(record, **said))
    return out
