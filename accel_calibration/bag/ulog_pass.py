"""One pass over a PX4 ULog for all that the fleet asks of it, kept for the asks that follow: the fleet replays
each IMU of a log in turn and then reads its flight, and every pass over an hour-long log costs a walk of its
tens of millions of records. The pass reads the small topics through pyulog (parameters, flight state, the
filter's bias, sensor_selection, vehicle_imu), then the high-rate ones a block at a time (ulog_stream.py),
keeping of sensor_combined, sensor_accel and sensor_gyro only the rows on the ground and next to it
(FlightState.ground_kept), the first row of each instance (its device ID), and per second in flight the sums
of each instance's x, y, z (imu_agreement.SecondSums). Memory: the time on the ground, not the flight; a
ground longer than KEEP_BYTES is not kept but streamed to each IMU's replay (streamed_samples)."""
from __future__ import annotations

import copy
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .imu_agreement import SecondSums
from .last_pass import LastPass
from .last_pass import identity as file_identity
from .ulog_stream import KeptRows, Subscription

Key = tuple[str, int]  # (topic, instance)
# The ground rows a pass keeps for the log's IMUs at most: a log with more time on the ground (one that flew a
# minute of an hour) is streamed to each IMU's replay instead (streamed_samples), a walk of the file each.
KEEP_BYTES = 64 << 20


@dataclass
class LogPass:
    """What one pass read of a log (see the module's text)."""

    identity: tuple[str, int, int]  # path, size, mtime: a log rewritten in place is read again
    log: Any  # pyulog's ULog of the small topics
    flight: Any  # FlightState
    margin_s: float
    kept: dict[Key, KeptRows] | None  # None: no flight to leave out, or more ground than KEEP_BYTES (streamed)
    first: dict[Key, dict[str, np.ndarray]]
    subscriptions: dict[Key, Subscription]  # the whole log's rows and first and last stamps of each
    flying: dict[Key, SecondSums]

    def log_with(self, topics: set[str]) -> Any:
        """The small topics' log with the kept rows of `topics` as pyulog's datasets (a copy: the pass stays)."""
        from .ulog_reader import _Dataset

        log = copy.copy(self.log)
        log._data_list = [*self.log.data_list, *(_Dataset(name, multi_id, rows.columns) for (name, multi_id), rows
                                                 in (self.kept or {}).items() if name in topics)]
        return log

    def log_of_first_rows(self) -> Any:
        """The small topics' log with each high-rate instance's first row (what pairs an IMU's gyro)."""
        from .ulog_reader import _Dataset

        log = copy.copy(self.log)
        log._data_list = [*self.log.data_list, *(_Dataset(name, multi_id, columns)
                                                 for (name, multi_id), columns in self.first.items())]
        return log


def ground_samples(path: str | os.PathLike[str], instance: int | None, margin_s: float, progress: Any = None
                   ) -> Any:
    """ulog_reader.UlogSamples of sensor_combined (`instance` None) or sensor_accel `instance` on the ground
    and next to it, from the log's pass; None where the pass kept none (streamed_samples gives them)."""
    from .ulog_reader import ACCEL, COMBINED, GYRO, samples_of_log

    passed = log_pass(path, margin_s, progress)
    if passed.kept is None:
        return None
    samples = samples_of_log(Path(path), passed.log_with({COMBINED, ACCEL} if instance is None else {ACCEL, GYRO}),
                             instance)
    counted = passed.subscriptions.get((COMBINED, 0) if instance is None else (ACCEL, instance))
    if counted is not None and counted.first_us is not None and counted.last_us is not None:
        samples.samples_read = counted.rows
        samples.first_last_ns = (counted.first_us * 1000, counted.last_us * 1000)
    return samples


def streamed_samples(path: str | os.PathLike[str], instance: int | None, margin_s: float, progress: Any = None
                     ) -> Iterator[Any] | None:
    """A log read for its ground whose ground the pass did not keep (it never flew: all of it is ground; or its
    ground outgrew KEEP_BYTES): its samples on the ground and next to it come a block at a time, each block's
    ulog_reader.UlogSamples of sensor_combined (`instance` None) or sensor_accel `instance`, never the whole
    log at once; None where the pass kept them (ground_samples gives them) or the log has none of this IMU.
    The last row of each interpolated source (the gyro; sensor_accel's temperature beside sensor_combined) goes
    on into the next block, so a sample at a block's start is interpolated as in the whole log."""
    from .ulog_reader import topic_blocks

    passed = log_pass(path, margin_s, progress)
    if passed.kept is not None:
        return None
    sample_topic = (COMBINED_TOPIC, 0) if instance is None else (ACCEL_TOPIC, instance)
    if sample_topic not in passed.subscriptions:
        return None  # nothing of it to stream: the whole read says what the log has
    needed = _sources(passed, instance)
    where = Path(path)

    flight = passed.flight
    flown = flight.found and len(flight.spans_ns) > 0

    def blocks() -> Iterator[Any]:
        carried: dict[Key, dict[str, np.ndarray]] = {}  # each source's rows: its last one before the block
        waiting: dict[str, np.ndarray] | None = None  # samples stamped after their sources read so far
        for block in topic_blocks(where, {sample_topic[0], *(name for name, _ in needed)}):
            samples = waiting
            for subscription, columns in block:
                key = (subscription.name, subscription.multi_id)
                if key == sample_topic:
                    if flown:  # the flight's inside is no pose: only its border goes to the session
                        ground = flight.ground_kept(np.asarray(_stamps(columns), dtype=np.int64) * 1000, margin_s)
                        columns = {k: v[ground] for k, v in columns.items()}
                    samples = columns if samples is None else _joined_rows(samples, columns)
                elif key in needed:
                    carried[key] = columns if key not in carried else _joined_rows(carried[key], columns)
            if samples is None:
                continue
            limit = min((int(_stamps(rows).max()) for rows in carried.values() if len(_stamps(rows))), default=None)
            ready = _stamps(samples) <= (limit if limit is not None else np.iinfo(np.uint64).max)
            if len(ready) - int(ready.sum()) > MAX_WAITING:  # a source that ended: the rest is held at its last
                ready[:] = True
            waiting = {k: v[~ready] for k, v in samples.items()} if not ready.all() else None
            if ready.any():
                yield from _samples_of(where, passed, {k: v[ready] for k, v in samples.items()}, sample_topic,
                                       carried, instance)
            carried = {key: {k: v[-1:] for k, v in rows.items()} for key, rows in carried.items()}
        if waiting is not None:
            yield from _samples_of(where, passed, waiting, sample_topic, carried, instance)

    return blocks()


MAX_WAITING = 1 << 18  # samples held for their source's next rows at most (a source that stopped: held flat)
ACCEL_TOPIC, COMBINED_TOPIC = "sensor_accel", "sensor_combined"


def _sources(passed: LogPass, instance: int | None) -> set[Key]:
    """What the samples are interpolated from: an IMU's paired gyro (ulog_reader.paired_gyro), or beside
    sensor_combined the sensor_accel of the device sensor_selection names (its temperature), or the only one."""
    from .ulog_reader import SELECTION, _datasets, _device_id, paired_gyro

    log = passed.log_of_first_rows()
    if instance is not None:
        gyro = paired_gyro(log, instance, _device_id(passed.first[(ACCEL_TOPIC, instance)]))
        return set() if gyro is None else {(gyro.name, gyro.multi_id)}
    accels = {n: columns for (name, n), columns in passed.first.items() if name == ACCEL_TOPIC}
    selection = _datasets(log, SELECTION)
    if selection and "accel_device_id" in selection[0].data:
        device = int(selection[0].data["accel_device_id"][-1])
        return {(ACCEL_TOPIC, n) for n, columns in accels.items() if _device_id(columns) == device}
    return {(ACCEL_TOPIC, n) for n in accels} if len(accels) == 1 else set()


def _stamps(columns: dict[str, np.ndarray]) -> np.ndarray:
    return columns["timestamp_sample"] if "timestamp_sample" in columns else columns["timestamp"]


def _joined_rows(first: dict[str, np.ndarray], then: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([first[k], then[k]]) for k in then}


def _samples_of(path: Path, passed: LogPass, samples: dict[str, np.ndarray], sample_topic: Key,
                sources: dict[Key, dict[str, np.ndarray]], instance: int | None) -> Iterator[Any]:
    """The block's UlogSamples: its samples beside the sources they are interpolated from (the IMU instances
    the whole log holds, as a whole read says); none where the block has no usable sample (sensor_combined rows
    with no accelerometer)."""
    from .ulog_reader import UlogError, _Dataset, samples_of_log

    log = copy.copy(passed.log)
    log._data_list = [*passed.log.data_list, _Dataset(*sample_topic, samples),
                      *(_Dataset(name, multi_id, rows) for (name, multi_id), rows in sources.items())]
    try:
        found = samples_of_log(path, log, instance)
    except UlogError:
        return
    found.imu_instances = tuple(sorted(n for name, n in passed.first if name == ACCEL_TOPIC))
    counted = passed.subscriptions[sample_topic]  # the whole log's, as a whole read says them
    if counted.first_us is not None and counted.last_us is not None:
        found.samples_read, found.first_last_ns = counted.rows, (counted.first_us * 1000, counted.last_us * 1000)
    yield found


def cached_devices(path: str | os.PathLike[str]) -> dict[int, int | None] | None:
    """{sensor_accel instance: its device ID} from this log's pass kept from an earlier ask, None without one."""
    from .ulog_reader import ACCEL, _device_id

    passed = cached_pass(path)
    if passed is None:
        return None
    return {n: _device_id(columns) for (name, n), columns in sorted(passed.first.items()) if name == ACCEL}


def cached_pass(path: str | os.PathLike[str]) -> LogPass | None:
    """The pass of this file kept from an earlier ask (whatever its margin), None when there is none."""
    return _passes.cached(path)


def log_pass(path: str | os.PathLike[str], margin_s: float, progress: Any = None) -> LogPass:
    """The pass of this file for this margin: kept from the last ask, or read now (replacing it)."""
    return _passes.get(path, margin_s, progress)


def _read(path: Path, margin_s: float, progress: Any) -> LogPass:
    from .estimator_bias import in_flight
    from .flight_sources import ULOG_TOPICS, ulog_flight_state
    from .ulog_reader import ACCEL, COMBINED, GYRO, SELECTION, VEHICLE_IMU, _load, _stamps_us, _xyz, topic_blocks

    identity = file_identity(path)
    log = _load(path, [SELECTION, VEHICLE_IMU, "estimator_sensor_bias", *ULOG_TOPICS], progress)
    flight = ulog_flight_state(log)
    leaves_out = flight.found and len(flight.spans_ns) > 0
    parts: dict[Key, list[dict[str, np.ndarray]]] = {}
    first: dict[Key, dict[str, np.ndarray]] = {}
    subscriptions: dict[Key, Subscription] = {}
    flying: dict[Key, SecondSums] = {}
    keeping, held = True, 0
    for block in topic_blocks(path, {COMBINED, ACCEL, GYRO}):
        for subscription, columns in block:
            key = (subscription.name, subscription.multi_id)
            subscriptions[key] = subscription
            new = key not in first
            if new:
                first[key] = {k: v[:1] for k, v in columns.items()}
            if not leaves_out:
                continue
            stamps = columns["timestamp_sample"] if "timestamp_sample" in columns else columns["timestamp"]
            t_ns = _stamps_us(path, stamps, "sample") * 1000
            kept = flight.ground_kept(t_ns, margin_s)
            kept[0] |= new  # each instance's first row: it says which device it is, even where all of it flew
            if keeping and kept.any():
                parts.setdefault(key, []).append({k: v[kept] for k, v in columns.items()})
                held += sum(v.nbytes for v in parts[key][-1].values())
                if held > KEEP_BYTES:  # a long time on the ground: each IMU's replay streams it instead
                    keeping = False
                    parts.clear()
            if subscription.name != COMBINED:
                flying.setdefault(key, SecondSums()).add(t_ns, _xyz(columns, ("x", "y", "z")), in_flight(t_ns, flight))
    kept_rows = None
    if leaves_out and keeping:
        kept_rows = {key: KeptRows(subscriptions[key], {k: np.concatenate([p[k] for p in found]) for k in found[0]})
                     for key, found in parts.items()}
    return LogPass(identity, log, flight, margin_s, kept_rows, first, subscriptions, flying)


_passes: LastPass[LogPass] = LastPass(_read)  # the last log's (a fleet task reads its logs in turn)
