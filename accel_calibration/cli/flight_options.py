"""The flight-state options `replay` and `fleet` share: which bag topic says armed or flying, the margin
kept around a flight, and the switch for a bench log armed on purpose (bag/flight_sources.py reads them)."""
from __future__ import annotations

import argparse
from typing import Any

from ..core.errors import CalibrationError

DEFAULT_MARGIN_S = 2.0


def add_flight_state_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--armed-topic", default=None, metavar="TOPIC",
                        help="bag: topic saying the vehicle is armed or flying (std_msgs/Bool, mavros_msgs/msg/State, "
                             "px4_msgs/msg/VehicleStatus, ...); default: /mavros/state, /fmu/out/vehicle_status and "
                             "/fmu/out/vehicle_land_detected where present. Logs (ULog, DataFlash) carry their own")
    parser.add_argument("--armed-field", default=None, metavar="EXPR",
                        help="with --armed-topic: FIELD, 'not FIELD' or 'FIELD OP VALUE' that is true while flying, "
                             "e.g. armed, 'arming_state == 2' (default: the type's own)")
    parser.add_argument("--armed-margin-s", type=float, default=DEFAULT_MARGIN_S, metavar="S",
                        help="nothing within S seconds before arming or after disarming and landing is a pose "
                             f"(default {DEFAULT_MARGIN_S:g}: motors spin up and run down)")
    parser.add_argument("--ignore-flight-state", action="store_true",
                        help="collect while armed (a bench log recorded armed on purpose)")


def flight_state_settings(args: argparse.Namespace) -> dict[str, Any]:
    """ReplaySettings fields from the options (absent options: their defaults), checked."""
    margin = getattr(args, "armed_margin_s", DEFAULT_MARGIN_S)
    if not 0.0 <= margin <= 3600.0:
        raise CalibrationError(f"--armed-margin-s must be from 0 to 3600 seconds, got {margin:g}")
    topic, field = getattr(args, "armed_topic", None), getattr(args, "armed_field", None)
    if field is not None and topic is None:
        raise CalibrationError("--armed-field needs --armed-topic (the topic whose field it reads)")
    if field is not None:
        from ..bag.flight_sources import field_test

        field_test(field)  # refused in one line before any recording is read
    return {"armed_topic": topic, "armed_field": field, "armed_margin_s": margin,
            "ignore_flight_state": bool(getattr(args, "ignore_flight_state", False))}
