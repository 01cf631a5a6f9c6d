"""One pass over an ArduPilot DataFlash log for all that the fleet asks of it, kept for the asks that follow
(ulog_pass.py does the same for a PX4 ULog): the fleet replays each IMU of a log in turn, asks which IMUs it
holds, then reads its flight, and every walk of an hour-long log steps through its ten million records.

The pass walks the file twice. First the small types: ARM and EV (the flight state), the filter's XKF/NKF
records (estimator_bias.ardupilot_biases), and the parameters and IMU instances every walk follows. Then the
IMU records, keeping of each instance its rows on the ground and next to it (FlightState.ground_kept), how
many it has and its first and last stamps, and per second in flight the sums of its AccX..Z, GyrX..Z, T
(imu_agreement.SecondSums). Two walks, not one: a row can be left out only once the flight state around it
is known, and the ARM and EV records lie among the IMU records; one walk would hold every row not yet decided
(a whole flight until its DISARMED is read: about the file, 583 MB for an hour of three IMUs at 1 kHz), or
decide by the events read so far, which the order of the records in a log does not promise. Measured on that
hour: the small walk 2.1 s (its step per record is most of a walk), the IMU walk 4.7 s; calibrate_recording
of its three IMUs 8 s, where a walk per ask (nine) took 24 to 28 s. Memory: the time on the ground, not the
flight; a ground longer than KEEP_BYTES is not kept but streamed to each IMU's replay (streamed_samples)."""
from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core.flight_state import FlightState
from .dataflash import DataflashSamples, _check_head, _device_ids, _flight_state, _ImuRead, _samples
from .dataflash_records import IMU_TYPES, DataflashError, RecordReader
from .estimator_bias import ARDUPILOT_FILTER_TYPES, in_flight
from .imu_agreement import SecondSums
from .last_pass import LastPass
from .last_pass import identity as file_identity

KEEP_BYTES = 64 << 20  # ground rows a pass keeps at most (ulog_pass.KEEP_BYTES: beyond, each replay streams)


@dataclass
class LogPass:
    """What one pass read of a log (see the module's text)."""

    identity: tuple[str, int, int]  # path, size, mtime: a log rewritten in place is read again
    margin_s: float
    params: dict[str, float]
    imu_instances: tuple[int, ...]
    flight: FlightState
    kept: dict[int, _ImuRead] | None  # None: no flight to leave out, or more ground than KEEP_BYTES (streamed)
    refused: dict[int, str]  # an instance whose records cannot be read: why (said when it is asked for)
    flying: dict[int, SecondSums]
    filter_records: dict[str, np.ndarray]
    filter_refused: str | None  # why the filter's records cannot be read (said when they are asked for)
    counted: dict[int, _ImuRead] = dataclasses.field(default_factory=dict)  # each instance's count, its rows
    # dropped where `kept` is None: a ground too long to keep (KEEP_BYTES) is streamed to each replay

    def filter_read(self) -> tuple[dict[str, np.ndarray], dict[str, float]]:
        """The filter's records and the parameters, as dataflash.scan_messages gives them."""
        if self.filter_refused is not None:
            raise DataflashError(self.filter_refused)
        return self.filter_records, self.params

    def check_instances(self) -> None:
        """One DataflashError for the first instance whose records cannot be read."""
        if self.refused:
            raise DataflashError(self.refused[min(self.refused)])


def ground_samples(path: str | os.PathLike[str], instance: int | None, margin_s: float, progress: Any = None
                   ) -> DataflashSamples | None:
    """dataflash.DataflashSamples of IMU `instance` (default 0) on the ground and next to it, from the log's
    pass; None where the pass kept none (streamed_samples gives them)."""
    passed = log_pass(path, margin_s, progress)
    if passed.kept is None:
        return None
    wanted = 0 if instance is None else instance
    if wanted in passed.refused:
        raise DataflashError(passed.refused[wanted])
    found = passed.kept.get(wanted) or _ImuRead(Path(path), wanted)
    imu = dataclasses.replace(found, stamps=list(found.stamps), values=list(found.values))  # the pass keeps its own
    return _samples(Path(path), imu, passed.params, passed.imu_instances, passed.flight)


def streamed_samples(path: str | os.PathLike[str], instance: int | None, margin_s: float, progress: Any = None
                     ) -> Iterator[DataflashSamples] | None:
    """A log read for its ground whose ground the pass did not keep (it never flew: all of it is ground; or its
    ground outgrew KEEP_BYTES): its samples on the ground and next to it come a block at a time, each block's
    dataflash.DataflashSamples of IMU `instance` (default 0), never the whole log at once; None where the pass
    kept them (ground_samples gives them) or the log has no such instance (the whole read says so)."""
    passed = log_pass(path, margin_s, progress)
    wanted = 0 if instance is None else instance
    if passed.kept is not None or wanted not in passed.imu_instances:
        return None
    if wanted in passed.refused:
        raise DataflashError(passed.refused[wanted])
    where, flight = Path(path), passed.flight
    flown = flight.found and len(flight.spans_ns) > 0
    counted = passed.counted.get(wanted)

    def blocks() -> Iterator[DataflashSamples]:
        from . import dataflash_records

        for block in RecordReader(where, IMU_TYPES, dataflash_records.BLOCK_BYTES).blocks():
            imu = _ImuRead(where, wanted, keep=(lambda t_ns: flight.ground_kept(t_ns, margin_s)) if flown else None)
            imu.add(block)
            if imu.stamps and len(imu.stamps[0]):
                if counted is not None:  # the whole log's count and extent, as a whole read says them
                    imu.read, imu.first_ns, imu.last_ns = counted.read, counted.first_ns, counted.last_ns
                found = _samples(where, imu, passed.params, passed.imu_instances, passed.flight)
                # Uncounted (a log that never flew: no walk before), the replay counts what it is fed: all of it.
                yield found if counted is not None else dataclasses.replace(found, first_last_ns=None)

    return blocks()


def cached_devices(path: str | os.PathLike[str]) -> dict[int, int | None] | None:
    """{IMU instance: its accelerometer's device ID} from this log's pass kept from an earlier ask, None without one."""
    passed = cached_pass(path)
    if passed is None:
        return None
    return {n: _device_ids(passed.params, n)[0] for n in passed.imu_instances}


def cached_pass(path: str | os.PathLike[str]) -> LogPass | None:
    """The pass of this file kept from an earlier ask (whatever its margin), None when there is none."""
    return _passes.cached(path)


def log_pass(path: str | os.PathLike[str], margin_s: float, progress: Any = None) -> LogPass:
    """The pass of this file for this margin: kept from the last ask, or read now (replacing it)."""
    return _passes.get(path, margin_s, progress)


def _read(path: Path, margin_s: float, progress: Any) -> LogPass:
    identity = file_identity(path)
    _check_head(path)
    small = RecordReader(path, ["ARM", "EV", *ARDUPILOT_FILTER_TYPES])
    parts: dict[str, list[np.ndarray]] = {}
    for block in _counted(small, progress, 0):
        for name, rows in block.items():
            parts.setdefault(name, []).append(rows)
    records, unjoined = _joined(path, parts)
    state = [n for n in ("ARM", "EV") if n in unjoined]
    if state:
        raise DataflashError(unjoined[state[0]])
    flight = _flight_state(path, records.get("ARM"), records.get("EV"))
    filter_refused = next(iter(unjoined.values()), None)
    filter_records = {k: v for k, v in records.items() if k in ARDUPILOT_FILTER_TYPES}
    made = LogPass(identity, margin_s, dict(small.params), small.imu_instances, flight, None, {}, {}, filter_records,
                   filter_refused)
    if flight.found and len(flight.spans_ns):
        reads, made.refused, made.flying, overflowed = _imu_walk(path, made, progress)
        made.counted = reads
        made.kept = None if overflowed else reads
    return made


def _imu_walk(path: Path, made: LogPass, progress: Any
              ) -> tuple[dict[int, _ImuRead], dict[int, str], dict[int, SecondSums], bool]:
    """Each instance's kept rows, why an instance cannot be read, its per-second sums in flight, and whether
    the ground outgrew KEEP_BYTES (then no rows are kept, the counts are): one walk."""
    flight, margin_s = made.flight, made.margin_s
    reads = {n: _ImuRead(path, n, keep=lambda t_ns: flight.ground_kept(t_ns, margin_s)) for n in made.imu_instances}
    flying = {n: SecondSums() for n in made.imu_instances}
    refused: dict[int, str] = {}
    held = 0
    for block in _counted(RecordReader(path, IMU_TYPES), progress, 1):
        for instance, imu in reads.items():
            if held > KEEP_BYTES:  # a long time on the ground: the replays stream it; only the counts go on
                imu.keep = lambda t_ns: np.zeros(len(t_ns), dtype=bool)
                imu.stamps.clear()
                imu.values.clear()
            if instance in refused:
                continue
            try:
                found = imu.rows(block)
            except DataflashError as error:  # this instance's reason; the others are read on
                refused[instance] = str(error)
                continue
            if found is not None:
                flying[instance].add(found[0], found[1], in_flight(found[0], flight))
                imu.keep_rows(*found)
                held += sum(v.nbytes for v in imu.values[-1:])
    for imu in reads.values():  # one array each: a block's piece per list item would hold the blocks' overhead
        if imu.stamps:
            imu.stamps[:], imu.values[:] = [np.concatenate(imu.stamps)], [np.concatenate(imu.values)]
    return {n: imu for n, imu in reads.items() if n not in refused}, refused, flying, held > KEEP_BYTES


def _joined(path: Path, parts: dict[str, list[np.ndarray]]) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """Each type's records as one array, and why a type's cannot be (dataflash_records.read_records's words)."""
    records, unjoined = {}, {}
    for name, pieces in parts.items():
        try:
            records[name] = np.concatenate(pieces)
        except (TypeError, ValueError):  # two types of one name with other layouts
            unjoined[name] = f"{path}: damaged DataFlash log: two FMT records define {name} with other layouts"
    return records, unjoined


def _counted(reader: RecordReader, progress: Any, rounding: int) -> Iterator[dict[str, np.ndarray]]:
    """The reader's blocks, half of the bytes read counted on `progress`: each of the pass's two walks is half
    of the work (the first rounds down, `rounding` 0, the second up, 1: together the file's size)."""
    said = 0
    for block in reader.blocks():
        if progress is not None:
            progress.update((reader.bytes_read + rounding) // 2 - said)
            said = (reader.bytes_read + rounding) // 2
        yield block
    if progress is not None:
        progress.update((reader.bytes_read + rounding) // 2 - said)


_passes: LastPass[LogPass] = LastPass(_read)  # the last log's (a fleet task reads its logs in turn)
