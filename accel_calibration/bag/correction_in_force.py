"""The calibration an autopilot applied while logging, read from the log's own parameters, as a calibration
of the raw sensor: shared by the ground evidence (bag/flight_evidence.py) and the in-flight agreement
(bag/in_flight_evidence.py)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..core.calibration import Calibration
    from .logged_correction import LoggedCorrection


def calibration_in_force(correction: LoggedCorrection) -> Calibration:
    """The log's offsets and scales as a calibration of the raw sensor (no uncertainty: the log keeps none)."""
    from ..core.calibration import Calibration

    return Calibration(bias=np.array(correction.axis_wise.offset_mps2, dtype=float),
                       matrix=np.diag(np.array(correction.axis_wise.scale, dtype=float)), model="six",
                       sensor_id=correction.names)


def ulog_correction(path: str, device: int | None, gyro_device: int | None = None) -> LoggedCorrection | None:
    """PX4's CAL_ACCn slot of this device (and CAL_GYROn of `gyro_device`, when given) from the parameters the
    log starts with (a sensor_accel instance is logged raw: the correction is not undone on read, and is looked
    up here)."""
    from pyulog import ULog

    from .logged_correction import px4_correction

    log = ULog(path, [], parse_header_only=True)  # the parameters the log starts with are in its definitions
    params = {str(k): float(v) for k, v in log.initial_parameters.items()}
    return px4_correction(params, device, gyro_device, path)
