"""What an ordinary flight recorded as a rosbag2 (sqlite3 or mcap) says of its IMU: the still moments on the
ground checked with `check`'s statistics (core/check.py), as bag/flight_evidence.py does for autopilot logs.

A bag carries no calibration in force. Given one (`fleet --calibration CAL.yaml`), the recorded Imu stream is
taken as the raw output that calibration corrects, and its still moments are checked against it, as `check
CAL.yaml BAG` does. Without one they are checked against the nominal sensor (no bias, unit gains): the
evidence is then the recorded stream's own offset from 1 g, the raw sensor's where the topic is raw (a
level vehicle: its z bias and z gain together), what is left of a correction's error where the topic is a
corrected output. Flight after flight, it is its change that says a calibration moved; its level is the
sensor's, not a verdict on a calibration.

Flight state: the bag's (bag/flight_sources.py: `--armed-topic`, or /mavros/state, /fmu/out/vehicle_status
or vehicle_land_detected), which keeps the flight out. A bag without one still gives the detector's still
moments, and the row says so: a steady hover may count among them.

In flight (bag_in_flight.py): the replayed topic's agreement with the bag's other Imu topics, and PX4's
filter bias where the bag records /fmu/out/estimator_sensor_bias."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..core.calibration import Calibration
    from .flight_evidence import FlightEvidence
    from .replay import ReplayResult, ReplaySettings

NOMINAL = "nominal (no bias, unit gains): a bag carries no calibration in force; give one with --calibration"
NO_FLIGHT_STATE = ("no flight state in the bag (an arming or landed topic): the still moments are the "
                   "detector's alone, a steady hover may count among them")


@dataclass(frozen=True)
class GivenCalibration:
    """The calibration in force of a bag's IMU, from a file (a bag names none)."""

    calibration: Calibration
    path: str


def is_bag(replay: ReplayResult) -> bool:
    """The replay read a rosbag2 (a directory, or a .mcap or .db3 file), streamed or whole."""
    from .recording import BAGS

    return str(getattr(replay.source.recording, "format", "")) in BAGS


def bag_evidence(replay: ReplayResult, given: GivenCalibration | None = None,
                 settings: ReplaySettings | None = None) -> FlightEvidence:
    """The evidence of the bag's IMU (the Imu topic replay read): its still moments on the ground, then what
    the bag says of it in flight (bag_in_flight.py; the flight state as `settings` read it for the replay);
    never raises for what the bag lacks: the reason says it."""
    import dataclasses

    from .bag_in_flight import bag_in_flight

    source = replay.source
    estimator, agreement = bag_in_flight(
        source.path, source.imu_topic, None if given is None else given.calibration,
        "" if given is None else given.path, None if settings is None else settings.armed_topic,
        None if settings is None else settings.armed_field, source.temperature_topic)
    return dataclasses.replace(_ground_evidence(replay, given), estimator=estimator, agreement=agreement)


def _ground_evidence(replay: ReplayResult, given: GivenCalibration | None) -> FlightEvidence:
    from ..core.calibration import Calibration
    from ..core.check import check_calibration
    from .flight_evidence import FlightEvidence, _observed

    name = Path(replay.source.path).name
    in_force = f"{given.path} (calibration file)" if given is not None else NOMINAL
    found = replay.flight_state is not None and replay.flight_state.found
    note = None if found else f"{name}: {NO_FLIGHT_STATE}"
    poses = list(replay.poses)
    if not poses:
        where = "on the ground (before arming or after landing)" if found else "(no flight state either)"
        return FlightEvidence("", 0, in_force, "none", reason=f"{name}: no still moment {where}")
    reference = given.calibration if given is not None else Calibration(bias=np.zeros(3), matrix=np.eye(3),
                                                                        model="six")
    result = check_calibration(reference, poses)
    temperatures = [p.temperature_degc for p in poses if p.temperature_degc is not None
                    and np.isfinite(p.temperature_degc)]
    return FlightEvidence("", len(poses), in_force, result.verdict, _observed(result), reason=note,
                          temperature_degc=float(np.mean(temperatures)) if temperatures else None)
