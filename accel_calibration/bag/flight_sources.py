"""The flight state a recording carries, read into core.flight_state.FlightState:
- a PX4 ULog: `vehicle_status.arming_state` (ARMED = 2), `vehicle_land_detected.landed`, `actuator_armed.armed`;
- a bag: a topic named with `--armed-topic` (std_msgs/Bool, mavros_msgs/msg/State, px4_msgs/msg/VehicleStatus,
  px4_msgs/msg/VehicleLandDetected, or any type with `--armed-field EXPR`), else the known topics
  (/mavros/state, /fmu/out/vehicle_status, /fmu/out/vehicle_land_detected) used by themselves when present,
  decoded with the definitions recorded in the bag (rosbags' AnyReader builds its typestore from them);
- an ArduPilot DataFlash log: `ARM.ArmState` and the `EV` events ARMED/DISARMED, NOT_LANDED/LAND_COMPLETE
  (read in dataflash.py, turned into spans here).

Stamps: a bag message's header stamp where it has a std_msgs/Header (the IMU's header clock), else the time
it was recorded at (px4_msgs carry the autopilot's boot time in `timestamp`, not the IMU's clock).
"""
from __future__ import annotations

import operator
import os
import re
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core.flight_state import FlightState, combined, spans_from_states
from ..core.text import quoted
from .bag_io import BagError

# PX4 (msg/VehicleStatus.msg): ARMING_STATE_ARMED = 2 in every version since 1.4 (INIT 0, STANDBY/DISARMED 1).
PX4_ARMING_STATE_ARMED = 2
ULOG_TOPICS = ("vehicle_status", "vehicle_land_detected", "actuator_armed")

# ArduPilot AP_Logger LogEvent ids (EV.Id).
EV_ARMED, EV_DISARMED, EV_LAND_COMPLETE, EV_NOT_LANDED = 10, 11, 18, 28

BOOL = "std_msgs/msg/Bool"
DEFAULT_FIELDS = {
    BOOL: "data",
    "mavros_msgs/msg/State": "armed",
    "px4_msgs/msg/VehicleStatus": f"arming_state == {PX4_ARMING_STATE_ARMED}",
    "px4_msgs/msg/VehicleLandDetected": "not landed",
}
# Used by themselves when the bag has them (PX4 1.16 names versioned topics *_v1).
KNOWN_TOPICS = ("/mavros/state", "/fmu/out/vehicle_status", "/fmu/out/vehicle_status_v1",
                "/fmu/out/vehicle_land_detected")


class FlightStateError(BagError):
    """A flight-state topic or field that cannot be read as asked: one line."""


# ------------------------------------------------------------------------------------------------- ULog
def ulog_flight_state(log: Any) -> FlightState:  # pyulog ships no types: a ULog is Any here
    """From a pyulog ULog read with ULOG_TOPICS among its topics: armed (vehicle_status, actuator_armed)
    or airborne (vehicle_land_detected), each reading held until the next."""
    found: list[FlightState] = []
    readings: tuple[tuple[str, str, Callable[[np.ndarray], np.ndarray]], ...] = (
        ("vehicle_status", "arming_state", lambda v: v == PX4_ARMING_STATE_ARMED),
        ("vehicle_land_detected", "landed", lambda v: v == 0),
        ("actuator_armed", "armed", lambda v: v != 0))
    for name, field, flying_of in readings:
        datasets = [d for d in log.data_list if d.name == name and field in d.data and len(d.data["timestamp"])]
        if not datasets:
            continue
        data = datasets[0].data  # instance 0: the vehicle's own
        stamps_ns = np.asarray(data["timestamp"], dtype=np.int64) * 1000
        label = f"PX4 {name}" if not found else name
        found.append(FlightState(spans_from_states(stamps_ns, flying_of(np.asarray(data[field]))), (label,)))
    return combined(found)


# ------------------------------------------------------------------------------------------- DataFlash
def dataflash_flight_state(arm: tuple[np.ndarray, np.ndarray] | None,
                           events: tuple[np.ndarray, np.ndarray] | None) -> FlightState:
    """From ARM (stamps ns, ArmState) and EV (stamps ns, Id) records: armed between ARMED and DISARMED,
    airborne between NOT_LANDED and LAND_COMPLETE (events: the state before the first is its opposite)."""
    found = []
    if arm is not None and len(arm[0]):
        found.append(FlightState(spans_from_states(arm[0], np.asarray(arm[1]) != 0, initial=False),
                                 ("ArduPilot ARM",)))
    if events is not None and len(events[0]):
        stamps, ids = np.asarray(events[0], dtype=np.int64), np.asarray(events[1])
        for wanted_on, wanted_off, label in ((EV_ARMED, EV_DISARMED, "EV armed/disarmed"),
                                             (EV_NOT_LANDED, EV_LAND_COMPLETE, "EV not landed/land complete")):
            use = (ids == wanted_on) | (ids == wanted_off)
            if np.any(use):
                found.append(FlightState(spans_from_states(stamps[use], ids[use] == wanted_on, initial=False),
                                         (label if found else f"ArduPilot {label}",)))
    return combined(found)


# ------------------------------------------------------------------------------------------------- bags
_COMPARISONS: dict[str, Callable[[Any, Any], object]] = {
    "==": operator.eq, "!=": operator.ne, "<=": operator.le, ">=": operator.ge, "<": operator.lt, ">": operator.gt}
_EXPRESSION = re.compile(r"^\s*(not\s+)?([A-Za-z_]\w*(?:\.[A-Za-z_]\w*)*)\s*(?:(==|!=|<=|>=|<|>)\s*(\S+))?\s*$")


def field_test(expression: str) -> Callable[[object], bool]:
    """A message -> bool test from `FIELD`, `not FIELD` or `FIELD OP VALUE` (OP one of == != < <= > >=,
    VALUE a number, true or false; FIELD may be dotted: header.frame_id). No code is evaluated."""
    match = _EXPRESSION.match(expression)
    if match is None:
        raise FlightStateError(f"--armed-field {quoted(expression)}: write FIELD, 'not FIELD' or 'FIELD OP VALUE' "
                               "(OP: == != < <= > >=), e.g. armed or 'arming_state == 2'")
    negate, path, op, text = match.groups()
    private = [name for name in path.split(".") if name.startswith("_")]
    if private:
        # Message fields never start with an underscore; such a name reaches Python's own attributes
        # (__class__ is truthy for every message: the whole recording would count as armed).
        raise FlightStateError(f"--armed-field {quoted(expression)}: {quoted(private[0])} starts with an underscore: "
                               "name a field of the message (e.g. armed, arming_state)")
    value: object = None
    if op is not None:
        lowered = text.lower()
        if lowered in ("true", "false"):
            value = lowered == "true"
        else:
            try:
                value = int(text)
            except ValueError:
                try:
                    value = float(text)
                except ValueError:
                    raise FlightStateError(f"--armed-field {quoted(expression)}: {quoted(text)} is not a number, "
                                           "true or false") from None
    names = path.split(".")
    compare = _COMPARISONS[op] if op is not None else None

    def test(message: object) -> bool:
        current = message
        for name in names:
            current = getattr(current, name)
        result = bool(compare(current, value)) if compare is not None else bool(current)
        return not result if negate else result

    return test


def _stamp_ns(message: object, recorded_ns: int) -> int:
    header = getattr(message, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is not None and hasattr(stamp, "sec") and hasattr(stamp, "nanosec"):
        return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return int(recorded_ns)


def bag_flight_state(path: str | os.PathLike[str], armed_topic: str | None = None,
                     armed_field: str | None = None) -> FlightState:
    """The bag's flight state: `armed_topic` (its field as given or the type's default), else every known
    topic present. No such topic: an empty FlightState (replay warns). Errors are one line."""
    from .bag_io import open_reader, recorded_definitions

    if armed_field is not None and armed_topic is None:
        raise FlightStateError("--armed-field needs --armed-topic (the topic whose field it reads)")
    # The topics as the storage records them (its summary, no rosbags reader): a bag without any flight-state
    # topic costs nothing more (rosbags' reader and its definition parser take ~0.3 s to import and open).
    recorded = recorded_definitions(path)
    if recorded is not None and armed_topic is None and not any(topic in recorded for topic in KNOWN_TOPICS):
        return FlightState()
    reader = open_reader(path)
    try:
        by_topic = {c.topic: c for c in reader.connections}
        if armed_topic is not None:
            if armed_topic not in by_topic:
                have = ", ".join(sorted(f"{c.topic} ({c.msgtype})" for c in reader.connections)) or "no topics"
                raise FlightStateError(f"{path}: --armed-topic {armed_topic} is not in the bag; it has {have}")
            chosen = [armed_topic]
        else:
            chosen = [topic for topic in KNOWN_TOPICS if topic in by_topic]
        found = []
        for topic in chosen:
            connection = by_topic[topic]
            expression = armed_field if armed_field is not None else DEFAULT_FIELDS.get(connection.msgtype)
            if expression is None:
                known = ", ".join(DEFAULT_FIELDS)
                raise FlightStateError(f"{path}: {topic} is {connection.msgtype}; give --armed-field EXPR (e.g. "
                                       f"'armed' or 'arming_state == 2'), or use a topic of {known}")
            test = field_test(expression)
            try:
                stamps, flying = _read_states(path, reader, connection, test, expression)
            except FlightStateError:
                raise
            except Exception as error:  # noqa: BLE001 - a damaged storage makes the readers raise their own types
                first = str(error).splitlines()[0][:100] if str(error) else ""
                raise FlightStateError(f"{path}: cannot read {topic} ({type(error).__name__}: {first})") from None
            if len(stamps):
                found.append(FlightState(spans_from_states(np.array(stamps, dtype=np.int64), np.array(flying, bool)),
                                         (f"{topic} {expression}",)))
        return combined(found)
    finally:
        reader.close()


def _read_states(path: str | os.PathLike[str], reader: Any, connection: Any, test: Callable[[object], bool],
                 expression: str) -> tuple[list[int], list[bool]]:
    stamps: list[int] = []
    flying: list[bool] = []
    for _, recorded_ns, raw in reader.messages(connections=[connection]):
        try:
            message = reader.deserialize(raw, connection.msgtype)
        except Exception as error:  # noqa: BLE001 - rosbags raises per cause; the bag is the problem
            first = str(error).splitlines()[0][:100] if str(error) else type(error).__name__
            raise FlightStateError(f"{path}: cannot decode {connection.topic} ({connection.msgtype}) with the "
                                   f"definitions recorded in the bag ({first})") from None
        try:
            state = test(message)
        except AttributeError as error:
            raise FlightStateError(f"{path}: --armed-field {quoted(expression)}: {connection.topic} "
                                   f"({connection.msgtype}) has no field {error.name!r}") from None
        except TypeError:
            raise FlightStateError(f"{path}: --armed-field {quoted(expression)}: cannot compare that field of "
                                   f"{connection.topic} ({connection.msgtype})") from None
        stamps.append(_stamp_ns(message, recorded_ns))
        flying.append(state)
    return stamps, flying
