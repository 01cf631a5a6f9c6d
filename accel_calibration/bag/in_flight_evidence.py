"""What a flight log says of each IMU in flight, beside its still moments on the ground
(bag/flight_evidence.py): the autopilot filter's settled bias estimate (bag/estimator_bias.py) and the IMU's
agreement with its siblings (bag/imu_agreement.py). Both are read once per log, for all its IMUs (a fleet
task asks for each IMU in turn: the last logs' answers are kept), and given per IMU as the history stores
them: a JSON-ready dict, or {"reason": ...} where the log gives none."""
from __future__ import annotations

import functools
import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

Said = dict[str, Any]


def in_flight_of(recording: object) -> tuple[Said | None, Said | None]:
    """(estimator, agreement) of the IMU `recording` read (a ULog instance or sensor_combined's device, a
    DataFlash instance); (None, None) for a recording that is no autopilot log."""
    from .recording import LOGS, Recording

    if not isinstance(recording, Recording) or recording.format not in LOGS:
        return None, None
    try:
        stat = os.stat(recording.path)
    except OSError as error:
        reason = {"reason": f"{Path(recording.path).name}: cannot read ({error.strerror or error})"}
        return reason, reason
    estimators, agreements, devices, unreadable = _log_wide(recording.path, stat.st_size, stat.st_mtime_ns)
    if unreadable is not None:  # the log's one reason, for each of its IMUs
        return unreadable, unreadable
    instance = _instance_of(recording, devices)
    missing = {"reason": f"{Path(recording.path).name}: no IMU instance of this device in the log"}
    return estimators.get(instance, missing), agreements.get(instance, missing)


def _instance_of(recording: Any, devices: dict[int, int | None]) -> int:
    if recording.accel_device_id is not None:
        found = [k for k, device in devices.items() if device == recording.accel_device_id]
        if found:
            return found[0]
    match = re.search(r"instance (\d+)", recording.stream)
    return int(match.group(1)) if match else 0


@functools.lru_cache(maxsize=2)
def _log_wide(path: str, size: int, mtime_ns: int
              ) -> tuple[dict[int, Said], dict[int, Said], dict[int, int | None], Said | None]:
    """Per IMU instance of the log: its estimator's bias and its agreement, read once (keyed by the file's
    size and time too, so a log rewritten in place is read again); or, last, why the log's flight cannot be
    read at all (then for every IMU of it)."""
    from ..core.errors import AccelCalibrationError
    from .recording import detect_format

    del size, mtime_ns  # the cache's key only
    log = None
    try:
        if detect_format(path) == "ulog":
            log, devices, means, flight_state = _ulog_flight_means(path)
            if not devices:  # sensor_combined alone: its selected IMU, as replay reads it
                means, flight_state = _flight_means(path, devices)
        else:
            log, devices, means, flight_state = _dataflash_flight_means(path)
    except AccelCalibrationError as error:
        return {}, {}, {}, {"reason": str(error)}
    devices = devices or {0: None}  # a ULog of sensor_combined alone: its selected IMU
    no_flight = _no_flight(Path(path).name, flight_state)
    if no_flight is not None:
        return {k: {"reason": no_flight} for k in devices}, {k: {"reason": no_flight} for k in devices}, devices, None
    estimators = _estimators(path, devices, flight_state, log)
    try:
        agreements = _agreements(path, means)
    except (np.linalg.LinAlgError, ValueError) as error:  # degenerate seconds (a dead IMU's zeros): its reason
        agreements = {k: {"reason": f"{Path(path).name}: agreement not measurable ({error})"} for k in devices}
    return estimators, agreements, devices, None


def _no_flight(name: str, flight_state: Any) -> str | None:
    """Why the log shows no flight, None when it does."""
    if flight_state is None or not flight_state.found:
        return f"{name}: no flight state in the log: the flight cannot be told from the ground"
    if not len(flight_state.spans_ns):
        return f"{name}: no flight in the log (the vehicle was never armed or airborne)"
    return None


def _flight_means(path: str, devices: dict[int, int | None]) -> tuple[dict[int, Any], Any]:
    """Each IMU's per-second means in flight, its calibration in force applied (the log's own offsets and
    scales; a gyro's offsets)."""
    from .correction_in_force import calibration_in_force, ulog_correction
    from .estimator_bias import in_flight
    from .imu_agreement import flight_means
    from .recording import open_recording

    means: dict[int, Any] = {}
    flight_state = None
    read: list[tuple[int | None, int | None]] = [*devices.items()] if devices else [(None, None)]  # sensor_combined
    for asked, device in read:
        recording = open_recording(path, instance=asked)
        instance = asked or 0
        flight_state = flight_state or recording.flight_state
        correction = recording.logged_correction
        if correction is None and recording.format == "ulog":
            correction = ulog_correction(path, recording.accel_device_id, recording.gyro_device_id)
        accel = recording.accel_mps2 if correction is None else calibration_in_force(correction).apply(
            recording.accel_mps2)
        gyro = recording.gyro_radps
        if gyro is not None and correction is not None and correction.gyro_offset_radps is not None:
            gyro = gyro - correction.gyro_offset_radps  # the gyro offsets in force (PX4, ArduPilot alike)
        name = f"IMU {instance + 1}" + (f" (device {device})" if device is not None else "")
        means[instance] = flight_means(name, recording.t_ns, accel, gyro,
                                       in_flight(recording.t_ns, recording.flight_state))
    return means, flight_state


def _ulog_flight_means(path: str) -> tuple[Any, dict[int, int | None], dict[int, Any], Any]:
    """A ULog's (small topics' log (the flight state, the filter's bias), {instance: device}, each IMU's
    per-second means in flight, the flight state), from its one pass (ulog_pass.py: the fleet's replays made it;
    made now otherwise). The calibration in force is affine (a = M (raw - b), a gyro's offset), so it is
    applied to the means; each gyro's means are taken on its own stamps (the seconds line up)."""
    from .correction_in_force import calibration_in_force
    from .imu_agreement import FlightMeans
    from .logged_correction import px4_correction
    from .replay import ReplaySettings
    from .ulog_pass import cached_pass, log_pass
    from .ulog_reader import ACCEL, GYRO, _device_id, paired_gyro

    passed = cached_pass(path) or log_pass(path, ReplaySettings().armed_margin_s)
    log = passed.log_of_first_rows()
    devices = {n: _device_id(columns) for (name, n), columns in sorted(passed.first.items()) if name == ACCEL}
    params = {str(k): float(v) for k, v in log.initial_parameters.items()}
    means = {}
    for instance, device in devices.items():
        gyro_set = paired_gyro(log, instance, device)
        correction = px4_correction(params, device, None if gyro_set is None else _device_id(gyro_set.data), path)
        flying = passed.flying.get((ACCEL, instance))
        blocks, accel = flying.means() if flying is not None else (np.zeros(0, np.int64), np.zeros((0, 3)))
        if correction is not None and len(accel):
            accel = calibration_in_force(correction).apply(accel)
        name = f"IMU {instance + 1}" + (f" (device {device})" if device is not None else "")
        means[instance] = FlightMeans(name, blocks, accel, None)
        gyro_flying = None if gyro_set is None else passed.flying.get((GYRO, gyro_set.multi_id))
        if gyro_flying is not None:
            gyro_blocks, gyro = gyro_flying.means()
            if correction is not None and correction.gyro_offset_radps is not None:
                gyro = gyro - correction.gyro_offset_radps
            means[instance] = with_gyro(means[instance], FlightMeans(name, gyro_blocks, gyro, None))
    return log, devices, means, passed.flight


def _dataflash_flight_means(path: str) -> tuple[Any, dict[int, int | None], dict[int, Any], Any]:
    """A DataFlash log's (pass (the filter's records, the parameters), {instance: device}, each IMU's per-second
    means in flight, the flight state), from its one pass (dataflash_pass.py: the fleet's replays made it; made
    now otherwise): its IMU records summed per second as logged, with their temperature; the log's correction
    undone on each second's means (at its mean temperature: affine in the samples, the thermal part barely
    moves within a second) and the calibration in force applied, as the whole read does per sample."""
    from .correction_in_force import calibration_in_force
    from .dataflash import _device_ids
    from .dataflash_pass import cached_pass, log_pass
    from .imu_agreement import FlightMeans
    from .logged_correction import ardupilot_correction
    from .replay import ReplaySettings

    passed = cached_pass(path) or log_pass(path, ReplaySettings().armed_margin_s)
    passed.check_instances()
    devices = {n: _device_ids(passed.params, n)[0] for n in passed.imu_instances}
    means = {}
    for instance, device in devices.items():
        flying = passed.flying.get(instance)
        blocks, logged = flying.means() if flying is not None else (np.zeros(0, np.int64), np.zeros((0, 3)))
        accel, gyro = (logged[:, 0:3], logged[:, 3:6]) if len(logged) else (np.zeros((0, 3)), np.zeros((0, 3)))
        correction = ardupilot_correction(passed.params, instance, path)
        if correction is not None and len(logged):
            raw = correction.raw_accel(accel, logged[:, 6])
            accel = calibration_in_force(correction).apply(raw)
            gyro = correction.raw_gyro(gyro)
            if correction.gyro_offset_radps is not None:
                gyro = gyro - correction.gyro_offset_radps
        name = f"IMU {instance + 1}" + (f" (device {device})" if device is not None else "")
        means[instance] = FlightMeans(name, blocks, accel, gyro)
    return passed, devices, means, passed.flight


def with_gyro(accel: Any, gyro: Any) -> Any:
    """The accelerometer's per-second means with the gyro's (taken on the gyro's stamps) over its seconds."""
    import dataclasses

    at = np.searchsorted(gyro.blocks, accel.blocks).clip(0, max(len(gyro.blocks) - 1, 0))
    rates = np.full_like(accel.accel_mps2, np.nan)
    if len(gyro.blocks):
        found = gyro.blocks[at] == accel.blocks
        rates[found] = gyro.accel_mps2[at[found]]
    return dataclasses.replace(accel, gyro_radps=rates)


def _estimators(path: str, devices: dict[int, int | None], flight_state: Any, log: Any = None) -> dict[int, Said]:
    from ..core.errors import AccelCalibrationError
    from .estimator_bias import ardupilot_biases, px4_biases
    from .recording import detect_format

    name = Path(path).name
    try:
        if detect_format(path) == "ulog":
            by_device = px4_biases(path, flight_state, log)
            found = by_device if isinstance(by_device, str) else {
                k: by_device[d] for k, d in devices.items() if d is not None and d in by_device}
        else:
            found = ardupilot_biases(path, flight_state, None if log is None else log.filter_read())
    except AccelCalibrationError as error:
        found = str(error)
    if isinstance(found, str):
        return {k: {"reason": found} for k in devices}
    return {k: _clean(found[k].as_json()) if k in found else
            {"reason": f"{name}: the filter's bias estimates name no estimate of this IMU in flight"} for k in devices}


def _agreements(path: str, means: dict[int, Any]) -> dict[int, Said]:
    from .imu_agreement import agreement

    name = Path(path).name
    return {k: {"reason": f"{name}: {v}"} if isinstance(v, str) else _clean(v.as_json())
            for k, v in agreement(means).items()}


def _clean(said: Said) -> Said:
    """Non-finite numbers as None (JSON null), as the history stores NaN."""
    def clean(value: Any) -> Any:
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, (float, np.floating)):
            return float(value) if math.isfinite(value) else None
        return value

    return {k: clean(v) for k, v in said.items()}
