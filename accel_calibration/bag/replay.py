"""Recalibrate from a recording (a rosbag2, a .mcap/.db3 file, a PX4 ULog, a CSV stream: see
recording.py): the same detector, temperature filter, pose store, fit and quality gates as the live
node, fed from the recording instead of the network, so a session gives the same calibration either
way. An adapter: bag I/O lives in bag_io, the other readers beside it."""
from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.calibration import Calibration
from ..core.fit import FitResult
from ..core.pose import Pose
from ..core.pose_map import PoseStatus
from ..core.session import CalibrationSession
from ..core.settings import Settings
from ..core.stream.feed import RecordingFeed
from ..core.stream.temperature_filter import TemperatureFilter
from .bag_io import BagError, missing_module

if TYPE_CHECKING:
    from ..core.flight_state import FlightState
    from ..core.gyro_fit import GyroFitResult
    from ..core.prior import Prior
    from .dataflash import AutopilotCalibration
    from .recording import BagStream, Recording, StreamedLog


def distinct_directions(poses: list[Pose], merge_angle_deg: float) -> int:
    """How many directions the poses hold: one within merge_angle_deg of a direction counted is that one (the
    pose store keeps holds of one direction apart when their means disagree, so its length is no count)."""
    cos_merge = np.cos(np.radians(merge_angle_deg))
    counted: list[np.ndarray] = []
    for pose in poses:
        if all(float(pose.direction @ direction) < cos_merge for direction in counted):
            counted.append(pose.direction)
    return len(counted)


@dataclass(frozen=True)
class ReplaySettings:
    """The session's settings (the node's parameters, same defaults and checks) and which topics to read."""

    session: Settings = field(default_factory=Settings)
    imu_topic: str | None = None
    temperature_topic: str | None = None
    # How to read a recording other than a bag directory (recording.open_recording); None = not given.
    format: str | None = None  # rosbag2, mcap, sqlite3, ulog, csv; None = from the path and content
    instance: int | None = None  # ULog: sensor_accel/sensor_gyro instance instead of sensor_combined
    time_unit: str | None = None  # CSV: s, ms, us, ns (default: t in s, t_ns in ns)
    units: str | None = None  # CSV: mps2, g, counts (default mps2)
    counts_per_g: float | None = None  # CSV with units counts
    # Flight state (core.flight_state): nothing armed or airborne, nor within the margin, is collected.
    armed_topic: str | None = None  # a bag's topic saying armed/flying (default: the known topics present)
    armed_field: str | None = None  # its field or test, e.g. "arming_state == 2" (flight_sources.field_test)
    armed_margin_s: float = 2.0
    ignore_flight_state: bool = False  # a bench log armed on purpose: every sample is collected
    # An autopilot log's ground only (fleet's flight evidence): what the still moments need, memory bounded by
    # the time on the ground (recording.open_recording's ground_margin_s), or by a block where that is long; the
    # same poses as the whole log. A streamed log's temperature readings are not kept (ReplayResult.temperatures:
    # what a corrected copy needs).
    ground_only: bool = False
    prior: Prior | None = None  # recalibrate against it (--prior): the poses fit what they observe
    prior_path: str | None = None  # where it came from, written beside the parameters' sources
    part_rows: int = RecordingFeed.PART_ROWS  # samples per detector call (the poses do not depend on it)

    def reader_options(self) -> dict[str, Any]:
        return {"format": self.format, "imu_topic": self.imu_topic, "temperature_topic": self.temperature_topic,
                "instance": self.instance, "time_unit": self.time_unit, "units": self.units,
                "counts_per_g": self.counts_per_g,
                "ground_margin_s": self.armed_margin_s if self.ground_only and not self.ignore_flight_state else None}


@dataclass(frozen=True)
class ReplaySource:
    """What was read: the recording, its streams and its extent."""

    path: str
    imu_topic: str
    temperature_topic: str | None
    messages: int  # IMU samples read (messages of a bag, rows of a CSV)
    duration_s: float  # from the earliest to the latest IMU stamp
    start_ns: int | None  # the earliest IMU stamp; None without samples
    frame_id: str
    sensor_id: str  # as the recording names the sensor, for people (a ULog's "px4 device N"), "" where it does not
    recording: Recording | BagStream  # read whole, or streamed
    accel_device_id: int | None = None  # the accelerometer's device ID, where the log says it (a bag: never)

    def same_device(self, other: ReplaySource) -> bool:
        """Both read the one accelerometer: their logs say its device ID and it is the same (names are for
        people: two alike say nothing, two that differ may name one device)."""
        return self.accel_device_id is not None and self.accel_device_id == other.accel_device_id


@dataclass(frozen=True)
class HeldTemperatures:
    """A recording's temperature readings (stamps ns, degC) as read, and the temperature the correction holds
    at any sample from them: what a corrected copy corrects each sample at."""

    readings: tuple[np.ndarray, np.ndarray]
    timeout_s: float

    @cached_property
    def _held(self) -> tuple[TemperatureFilter, tuple[np.ndarray, np.ndarray]]:
        # A copy asks once per group: the readings are filtered once, on first use.
        held_filter = TemperatureFilter(timeout_s=self.timeout_s)
        return held_filter, held_filter.take(*self.readings)

    def filtered(self) -> tuple[np.ndarray, np.ndarray]:
        """The readings filtered as the node takes them, (stamps ns, degC) in stamp order."""
        return self._held[1]

    def at(self, t_ns: np.ndarray) -> np.ndarray:
        """The filtered temperature held at each of these sample stamps (NaN where none or stale), from all
        the readings: a sample's value does not depend on the others asked with it, so a copy corrected a
        group at a time gets what the whole recording at once gets."""
        held_filter, held = self._held
        return held_filter.held_at(*held, t_ns)[0]


@dataclass(frozen=True)
class FlightStateNote:
    """What replay says of the flight state it kept out: "left out 14.2 s armed or airborne (...)", or, when
    the recording carries none (`found` False), the warning that it does not."""

    line: str
    found: bool

    def report_line(self) -> str:
        return self.line if self.found else f"warning: {self.line}"


@dataclass(frozen=True)
class AutopilotComparison:
    """The autopilot's calibration logged with the recording (DataFlash), and how far ours moves its output."""

    calibration: AutopilotCalibration
    difference_mg: float | None  # worst orientation at 1 g; None without a calibration of ours


@dataclass(frozen=True)
class ReplayResult:
    """One recording through the session: what was read, what the session found and decided, and notes."""

    source: ReplaySource
    poses: list[Pose]
    # Per pose found (in `poses`): used or outlier by the fit, dropped (the store gave it up at
    # capacity) or not fitted (no fit was run: too few poses, wrong units).
    pose_status: list[PoseStatus]
    result: FitResult | None
    problem: str | None  # why no calibration (None when `calibration` is usable)
    counts: dict[str, int]
    elapsed_s: float
    temperatures: HeldTemperatures | None = None  # None without a temperature topic or readings
    gyro: GyroFitResult | None = None  # the gyro fit tried from the motions (None: none ran)
    gyro_refusal: str | None = None  # why it was not applied (None: it was, or none ran)
    flight_state: FlightStateNote | None = None  # None where it was not looked for
    autopilot: AutopilotComparison | None = None  # None: the recording logs no autopilot calibration

    @property
    def calibration(self) -> Calibration | None:
        return self.result.calibration if self.problem is None and self.result is not None else None


class ReplayError(BagError):
    """One line: the bag and what was (not) found in it."""


def replay_bag(path: str | os.PathLike[str], settings: ReplaySettings | None = None, progress: bool = False,
               through_rosbags: bool = False) -> ReplayResult:
    """Any recording (recording.open_recording: a bag directory, a .mcap/.db3 file, a ULog, a CSV stream)
    through the session. A bag whose storage can be read directly is streamed (memory bounded by a part,
    whatever its length), the rest read whole. `through_rosbags`: read a bag whole with rosbags' reader,
    message by message (what the direct reads are checked against)."""
    from .mcap_scan import DamagedChunk, NotStreamable
    from .recording import StreamedLog, open_recording, stream_bag

    s = settings or ReplaySettings()
    started = time.perf_counter()
    try:
        if not through_rosbags:
            try:
                bag = stream_bag(path, progress=progress, **s.reader_options())
                if bag is not None:
                    return _replay_stream(bag, s, started)
            except NotStreamable:
                pass  # read whole below: the same poses, or the reason it cannot be read
        recording = open_recording(path, progress=progress, through_rosbags=through_rosbags, **s.reader_options())
        if isinstance(recording, StreamedLog):  # a log that never flew, read for its ground: a block at a time
            return _replay_stream(recording, s, started)
    except BagError as error:
        raise ReplayError(str(error)) from None
    except DamagedChunk as error:
        raise ReplayError(f"{path}: damaged mcap file {error}") from None
    except ModuleNotFoundError as error:  # an install without a reader's module, not a damaged recording
        if (missing := missing_module(error, path)) is None:
            raise
        raise ReplayError(str(missing)) from None
    except (Exception, RecursionError) as error:  # noqa: BLE001 - the bag layer's boundary: a damaged
        # recording makes the readers (sqlite3, zstd, lz4, rosbags, pyulog) raise their own types
        first_line = str(error).splitlines()[0][:120] if str(error) else ""
        raise ReplayError(f"{path}: unreadable, damaged recording ({type(error).__name__}: {first_line})") from None
    return replay_recording(recording, s, started)


def _replay_stream(bag: BagStream | StreamedLog, s: ReplaySettings, started: float) -> ReplayResult:
    """A streamed bag (recording.BagStream), or a log read for its ground a block at a time
    (recording.StreamedLog), through a fresh session, piece by piece."""
    from .recording import Recording

    flight = flight_state_of(bag.path, bag.format, getattr(bag, "flight_state", None), s)
    session = CalibrationSession(s.session)
    feed = session.recording_feed(has_temperature=bag.temperature_stream is not None, part_rows=s.part_rows)
    low = high = None
    readings: list[tuple[np.ndarray, np.ndarray]] = []
    for imu, temperatures in bag.pieces():
        if temperatures is not None:
            feed.add_temperatures(*temperatures)
            if not s.ground_only:  # what a corrected copy corrects at (ReplayResult.temperatures); the fleet
                readings.append(temperatures)  # makes none, and an hour's readings at 1 kHz are 58 MB
        if imu is not None:
            t, accel, gyro = imu
            if not session.frame_id:
                session.frame_id = bag.frame_id
            feed.add_samples(t, accel, gyro, None if flight is None else flight.collecting(t, s.armed_margin_s))
            if len(t):
                low = int(t.min()) if low is None else min(low, int(t.min()))
                high = int(t.max()) if high is None else max(high, int(t.max()))
    poses = feed.finish()
    samples = feed.samples
    if isinstance(bag, Recording) and bag.first_last_ns is not None:  # a log fed its ground: the whole log's
        (low, high), samples = bag.first_last_ns, bag.samples_read or samples
    duration = (high - low) / 1e9 if low is not None and high is not None and samples > 1 else 0.0
    temperature_readings = None
    if bag.temperature_stream is not None and not s.ground_only:
        temperature_readings = (np.concatenate([t for t, _ in readings] or [np.zeros(0, np.int64)]),
                                np.concatenate([v for _, v in readings] or [np.zeros(0)]))
    has_gyro = getattr(bag, "gyro_radps", True) is not None  # a bag's Imu messages always carry one
    result = _verdict(session, poses, bag, samples, duration, low, s, started, has_gyro=has_gyro,
                      temperature_readings=temperature_readings)
    return _with_flight_state(result, flight, low, high, s)


def replay_recording(recording: Recording, settings: ReplaySettings | None = None,
                     started: float | None = None) -> ReplayResult:
    """A recording's sample arrays (recording.Recording) through a fresh session, as the node would take them."""
    s = settings or ReplaySettings()
    started = time.perf_counter() if started is None else started
    # The recording's own order is the order the node received the messages: the session takes them
    # in that order, so a stamp going backwards is dropped here as it is live.
    t = recording.t_ns
    session = CalibrationSession(s.session)
    session.frame_id = recording.frame_id
    temperature_stamps, temperature_values = (recording.temperature if recording.temperature is not None
                                              else (None, None))
    # No gyro (a CSV without gx,gy,gz): zeros, which never look like motion; taken out again below.
    gyro = recording.gyro_radps if recording.gyro_radps is not None else np.zeros_like(recording.accel_mps2)
    flight = flight_state_of(recording.path, recording.format, recording.flight_state, s)
    collecting = None if flight is None else flight.collecting(t, s.armed_margin_s)
    poses = session.add_recording(t, recording.accel_mps2, gyro, temperature_stamps, temperature_values,
                                  collecting=collecting, part_rows=s.part_rows)
    # A log read for its ground only says the whole log's extent, as a whole read does.
    first, last = recording.first_last_ns or ((int(t.min()), int(t.max())) if len(t) else (None, None))
    samples = len(t) if recording.samples_read is None else recording.samples_read
    duration = (last - first) / 1e9 if first is not None and last is not None and samples > 1 else 0.0
    result = _verdict(session, poses, recording, samples, duration, first, s, started,
                      has_gyro=recording.gyro_radps is not None, temperature_readings=recording.temperature)
    return _with_flight_state(result, flight, first, last, s)


def flight_state_of(path: str | os.PathLike[str], recording_format: str, carried: FlightState | None,
                    s: ReplaySettings) -> FlightState | None:
    """The flight state to keep out of the poses (core.flight_state.FlightState), or None when it is not
    looked for: --ignore-flight-state, or a CSV stream (it carries none). A bag's comes from its topics,
    a log's (ULog, DataFlash) from the log (`carried`)."""
    from ..core.flight_state import FlightState
    from .flight_sources import bag_flight_state
    from .recording import BAGS

    if recording_format not in BAGS and (s.armed_topic is not None or s.armed_field is not None):
        raise ReplayError(f"{path}: --armed-topic/--armed-field apply to bags; a {recording_format} recording "
                          "carries its own flight state")
    if s.ignore_flight_state:
        return None
    if recording_format in BAGS:
        return bag_flight_state(path, s.armed_topic, s.armed_field)
    if recording_format == "csv":
        return None
    return carried if carried is not None else FlightState()


def _with_flight_state(result: ReplayResult, flight: FlightState | None, first_ns: int | None, last_ns: int | None,
                       s: ReplaySettings) -> ReplayResult:
    """The flight-state line, and the autopilot's calibration beside ours, into the result."""
    from ..core.flight_state import report_line
    from .recording import Recording

    recording = result.source.recording
    # Only a log read whole carries an autopilot's calibration (DataFlash); a bag's messages say nothing.
    autopilot = recording.autopilot_calibration if isinstance(recording, Recording) else None
    logged = recording.logged_correction if isinstance(recording, Recording) else None
    difference = None
    if autopilot is not None and result.calibration is not None:
        from .dataflash import correction_on_top_mg
        from .logged_correction import difference_mg

        calibration = result.calibration
        difference = (correction_on_top_mg(calibration.matrix, calibration.bias, calibration.gravity) if logged is None
                      else difference_mg(calibration.matrix, calibration.bias, calibration.gravity, logged))
    note = None if flight is None else FlightStateNote(report_line(flight, first_ns, last_ns, s.armed_margin_s),
                                                       flight.found)
    return dataclasses.replace(result, flight_state=note,
                               autopilot=None if autopilot is None else AutopilotComparison(autopilot, difference))


def _verdict(session: CalibrationSession, poses: list[Pose], recording: Recording | BagStream, samples: int,
             duration: float,
             start_ns: int | None, s: ReplaySettings, started: float, has_gyro: bool,
             temperature_readings: tuple[np.ndarray, np.ndarray] | None) -> ReplayResult:
    """The poses found into the store, /calibrate's verdict, and what replay reports of it."""
    from .recording import Recording

    if not has_gyro:
        poses = [dataclasses.replace(p, gyro_radps=None) for p in poses]
        # The zeros standing in for a missing gyro are no motions to fit.
        session.update_settings(dataclasses.replace(session.settings, gyro_calibrate=False))
    session.prior = s.prior
    events, verdict = session.verdict_for(poses)
    slots: list[int | None] = []  # per pose, its place in the store (None once the store gave it to a newer pose)
    for event in events:
        if event.replaced_oldest:
            slots = [None if slot == event.index else slot for slot in slots]
        slots.append(event.index)
    counts = session.counters.as_dict()
    problem = None
    if not verdict.success:
        problem = verdict.message
        need = session.poses_needed()
        if len(session.store) < need and s.prior is None:
            problem = ("too few static poses for a calibration (no multi-pose session in this recording; "
                       f"{session.settings.model} needs {need} orientations): " + problem)
        directions = distinct_directions(session.store.poses, session.settings.merge_angle_deg)
        problem = (f"found {len(poses)} static pose{'' if len(poses) == 1 else 's'} ({directions} distinct "
                   f"direction{'' if directions == 1 else 's'}) "
                   f"in {recording.stream} ({samples} {recording.unit}, {duration:.1f} s): {problem}")
    result = verdict.result
    if verdict.success:
        calibration = verdict.calibration
        assert calibration is not None and verdict.result is not None, "a calibration that succeeded carries both"
        if not has_gyro:
            calibration = calibration.replace(gyro_bias_radps=None)
        if recording.sensor_id and not calibration.sensor_id:
            calibration = calibration.replace(sensor_id=recording.sensor_id)
        fitted_to = recording.fitted_to if isinstance(recording, Recording) else ""  # a bag's messages say nothing
        if fitted_to:
            calibration = calibration.replace(fitted_to=fitted_to)
        if isinstance(recording, Recording):  # the devices fitted, as the log names them (export's CAL_*_ID)
            calibration = calibration.replace(
                accel_device_id=recording.accel_device_id,
                gyro_device_id=recording.gyro_device_id if calibration.gyro_bias_radps is not None else None)
        result = dataclasses.replace(verdict.result, calibration=calibration)
    # Poses the fit left out (fit.FitResult.outliers: each with its index into the store's poses).
    outliers = set(result.outlier_indices) if result is not None else set()
    status = [PoseStatus.DROPPED if slot is None else PoseStatus.NOT_FITTED if result is None
              else PoseStatus.OUTLIER if slot in outliers else PoseStatus.USED for slot in slots]
    source = ReplaySource(path=str(recording.path), imu_topic=recording.stream,
                          temperature_topic=recording.temperature_stream, messages=samples, duration_s=duration,
                          start_ns=start_ns, frame_id=session.frame_id, sensor_id=recording.sensor_id,
                          recording=recording,
                          accel_device_id=recording.accel_device_id if isinstance(recording, Recording) else None)
    held = (HeldTemperatures(temperature_readings, s.session.temperature_timeout_s)
            if temperature_readings is not None and len(temperature_readings[0]) else None)
    return ReplayResult(
        source=source,
        poses=poses,
        pose_status=status,
        result=result,
        problem=problem,
        counts=counts,
        elapsed_s=time.perf_counter() - started,
        temperatures=held,
        gyro=verdict.gyro if has_gyro else None,
        gyro_refusal=verdict.gyro_refusal if has_gyro else None,
    )
